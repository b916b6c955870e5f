// The information browser (system paper §2.2): a side panel with the contents assigned to the
// clicked part (rendered, sanitised Markdown from the server, attachments, edit and history
// links), and the hover preview (title, caption, thumbnail).

function el(tag, cls, text) {
  const e = document.createElement(tag);
  if (cls) e.className = cls;
  if (text !== undefined) e.textContent = text;
  return e;
}

function link(href, text, cls) {
  const a = el('a', cls, text);
  a.href = href;
  return a;
}

async function getJson(url) {
  const res = await fetch(url, { credentials: 'same-origin', headers: { Accept: 'application/json' } });
  if (!res.ok) throw new Error(`HTTP ${res.status}`);
  return res.json();
}

export class InfoPanel {
  /**
   * @param {HTMLElement} host element the panel is added to
   * @param {{canEdit: boolean, onClose: () => void}} options
   */
  constructor(host, options) {
    this.options = options;
    this.root = el('aside', 'viewer-panel');
    this.root.hidden = true;
    this.root.setAttribute('aria-live', 'polite');
    this.root.setAttribute('aria-label', 'Information about the selected part');
    host.appendChild(this.root);
    this.partId = null;
    this.generation = 0;
  }

  isOpen() {
    return !this.root.hidden;
  }

  close() {
    this.root.hidden = true;
    this.partId = null;
    this.generation++;
  }

  /** Opens (or refreshes) the panel on part `id`. */
  async open(id, store) {
    const generation = ++this.generation;
    this.partId = id;
    const entry = store.parts.get(id);
    this.root.replaceChildren();
    this.root.hidden = false;
    this.root.dataset.partId = String(id);
    const head = el('header', 'panel-head');
    const h = el('h2', null, store.title(id));
    const close = el('button', 'panel-close', '×');
    close.type = 'button';
    close.title = 'Close';
    close.setAttribute('aria-label', 'Close the information panel');
    close.addEventListener('click', () => {
      this.close();
      this.options.onClose();
    });
    head.append(h, close);
    this.root.append(head);
    if (!entry) {
      this.root.append(el('p', 'muted', 'This part no longer exists.'));
      return;
    }
    const meta = el('p', 'muted small', `Part ${id} · ${entry.part.kind} · ${entry.part.vertex_count} vertices`);
    this.root.append(meta);
    if (entry.contents.length === 0) {
      this.root.append(el('p', 'muted', 'No information is assigned to this part yet.'));
      return;
    }
    const bodies = await Promise.all(
      entry.contents.map((c) => getJson(`/api/v1/contents/${c.id}`).catch((e) => ({ id: c.id, title: c.title, error: e.message }))),
    );
    if (generation !== this.generation) return;
    for (const c of bodies) this.root.append(this.article(c));
  }

  article(c) {
    const a = el('article', 'panel-content');
    a.dataset.contentId = String(c.id);
    a.append(el('h3', null, c.title));
    if (c.error) {
      a.append(el('p', 'error', `Cannot load this content (${c.error}).`));
      return a;
    }
    if (c.caption) a.append(el('p', 'caption', c.caption));
    if (c.thumbnail_attachment_id) {
      const img = el('img', 'thumb');
      img.alt = '';
      img.src = `/api/v1/attachments/${c.thumbnail_attachment_id}/download`;
      a.append(img);
    }
    const body = el('div', 'prose');
    body.innerHTML = c.html; // rendered and sanitised by the server (wiki/markdown.rs)
    a.append(body);
    if (c.attachments && c.attachments.length > 0) {
      const list = el('ul', 'attachments');
      for (const att of c.attachments) {
        const li = el('li');
        li.append(link(`/api/v1/attachments/${att.id}/download`, att.original_name || `attachment ${att.id}`));
        li.append(el('span', 'muted', ` ${att.media_type}, ${att.size} bytes`));
        list.append(li);
      }
      a.append(el('h4', null, 'Attachments'), list);
    }
    const links = el('p', 'panel-links');
    links.append(link(`/contents/${c.id}`, 'Open page'), ' · ', link(`/contents/${c.id}/history`, 'History'));
    if (this.options.canEdit) links.append(' · ', link(`/contents/${c.id}/edit`, 'Edit'));
    links.append(el('span', 'muted', ` · revision ${c.current_revision}`));
    a.append(links);
    return a;
  }
}

export class Preview {
  constructor(host) {
    this.root = el('div', 'viewer-preview');
    this.root.hidden = true;
    this.root.setAttribute('role', 'tooltip');
    host.appendChild(this.root);
    this.shownId = null;
  }

  /** Shows part `id` near (x, y) (CSS pixels inside the host). */
  show(id, store, x, y, width) {
    const entry = store.parts.get(id);
    if (!entry) return this.hide();
    if (this.shownId !== id || this.version !== entry) {
      this.shownId = id;
      this.version = entry;
      this.root.replaceChildren();
      this.root.dataset.partId = String(id);
      const first = entry.contents[0];
      const thumb = entry.part.thumbnail_attachment_id || (first && first.thumbnail_attachment_id);
      if (thumb) {
        const img = el('img', 'thumb');
        img.alt = '';
        img.src = `/api/v1/attachments/${thumb}/download`;
        this.root.append(img);
      }
      this.root.append(el('strong', null, store.title(id)));
      if (first && first.caption) this.root.append(el('p', 'caption', first.caption));
      const more = entry.contents.length - 1;
      this.root.append(el('p', 'muted small', more > 0 ? `and ${more} more · click for details` : 'click for details'));
    }
    this.root.hidden = false;
    const w = this.root.offsetWidth || 220;
    const left = x + 16 + w > width ? x - 16 - w : x + 16;
    this.root.style.transform = `translate(${Math.max(4, Math.round(left))}px, ${Math.round(y + 12)}px)`;
  }

  hide() {
    this.root.hidden = true;
    this.shownId = null;
  }
}
