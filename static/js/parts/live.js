// Live co-editing: listens to `GET /api/v1/models/{id}/events` (server-sent events) and
// refreshes what changed — a new or edited part, its assigned contents, an edited content —
// within seconds, without reloading. EventSource reconnects by itself; after a gap the
// server's `resync` (or a reconnection) reloads every part.

export function listen(modelId, store, onEvent) {
  const source = new EventSource(`/api/v1/models/${modelId}/events`, { withCredentials: true });
  let connectedBefore = false;
  source.addEventListener('hello', () => {
    if (connectedBefore) store.reloadAll();
    connectedBefore = true;
  });
  source.addEventListener('resync', () => store.reloadAll());
  source.addEventListener('change', async (e) => {
    let ev;
    try {
      ev = JSON.parse(e.data);
    } catch {
      return;
    }
    switch (ev.type) {
      case 'part.created':
      case 'part.updated':
        await store.reloadPart(ev.part_id);
        break;
      case 'part.deleted':
        store.removePart(ev.part_id);
        break;
      case 'part.contents':
        await store.reloadContents(ev.part_id);
        break;
      case 'content.updated':
      case 'content.deleted':
        await store.contentChanged(ev.content_id);
        break;
      default:
        return;
    }
    onEvent(ev);
  });
  return () => source.close();
}
