// The information browser (system paper §2.2): a side panel with the contents assigned to the
// clicked part (rendered, sanitised Markdown from the server, attachments, edit and history
// links), and the hover preview (title, caption, thumbnail). Opened from a search result, the
// panel marks the query's words (<mark>) and scrolls the first matching paragraph into view.

import { markTerms, searchTerms } from './match.js';

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
    this.root.tabIndex = -1; // focusable (after the assign step), not a tab stop
    host.appendChild(this.root);
    this.partId = null;
    this.generation = 0;
    this.highlight = null; // {partId, terms, scrolled}
  }

  /** Marks the words of search `query` when part `partId` is shown (null: no marking). */
  setHighlight(partId, query) {
    const terms = query ? searchTerms(query) : [];
    this.highlight = partId !== null && terms.length ? { partId, terms, scrolled: false } : null;
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
    delete this.root.dataset.searchHit;
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
    const meta = el('p', 'muted small', `Part ${id} · ${entry.part.kind} · ${entry.part.vertex_count.toLocaleString()} ${entry.part.vertex_count === 1 ? 'vertex' : 'vertices'}`);
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
    const hl = this.highlight;
    if (hl && hl.partId === id) this.markMatches(hl);
  }

  /** Marks the search words in the contents; the first time, scrolls the paragraph with the most
   * of them (the first such) into view. */
  markMatches(h) {
    const blocks = new Map(); // block -> distinct terms, in document order
    for (const a of this.root.querySelectorAll('.panel-content')) {
      for (const part of a.querySelectorAll(':scope > h3, :scope > .caption, :scope > .prose')) {
        for (const { mark, term } of markTerms(part, h.terms)) {
          const b = mark.closest('p, li, blockquote, pre, td, th, h1, h2, h3, h4, h5, h6, .caption') || mark.parentElement;
          if (!blocks.has(b)) blocks.set(b, new Set());
          blocks.get(b).add(term);
        }
      }
    }
    let block = null;
    let best = 0;
    for (const [b, terms] of blocks) {
      // Body paragraphs before titles: the title is in view anyway.
      const score = terms.size * 2 + (b.tagName === 'H3' ? 0 : 1);
      if (score > best) {
        best = score;
        block = b;
      }
    }
    if (!block) return;
    block.classList.add('search-hit');
    this.root.dataset.searchHit = 'true';
    if (h.scrolled) return;
    h.scrolled = true;
    // Centre the paragraph in the panel (which scrolls on its own), then bring the panel's part of
    // it into the page's view if needed (narrow screens, where the panel is below the view).
    const panel = this.root.getBoundingClientRect();
    const box = block.getBoundingClientRect();
    const offset = box.top - panel.top + this.root.scrollTop;
    this.root.scrollTop = Math.max(0, offset - Math.max(0, (this.root.clientHeight - box.height) / 2));
    block.scrollIntoView({ block: 'nearest', inline: 'nearest' });
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
    // The server says whether the body shows the thumbnail already (a dropped picture is both).
    if (c.thumbnail_attachment_id && c.show_thumbnail !== false) {
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
