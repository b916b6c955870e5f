// The "assign information" step after a region is confirmed: drop a file (image, PDF, text)
// onto the region or the drop zone, give a link, write a note (Markdown), or pick existing
// information found by the search. A file is stored (`POST /api/v1/attachments`), a content
// made around it (`POST /api/v1/contents`), the file attached to it (`PUT /api/v1/contents/{id}/
// attachments/{attachment}`) and the content assigned to the part (`POST /api/v1/parts/{id}/
// contents`); a link or a note becomes a content of its own. The server's messages show in the
// step.

const TEXT_INLINE_BYTES = 64 * 1024;

function el(tag, cls, text) {
  const e = document.createElement(tag);
  if (cls) e.className = cls;
  if (text !== undefined) e.textContent = text;
  return e;
}

function field(label, input) {
  const l = el('label', 'assign-field', label);
  l.append(input);
  return l;
}

function input(type, name, attrs = {}) {
  const i = document.createElement('input');
  i.type = type;
  i.name = name;
  Object.assign(i, attrs);
  return i;
}

/** Markdown of a link (brackets and parentheses escaped). */
function mdLink(text, url) {
  const t = text.replace(/([\\[\]])/g, '\\$1');
  return `[${t}](<${url.replace(/[<>]/g, encodeURIComponent)}>)`;
}

/** A title from a note's first line: Markdown markers off, at most 80 characters. */
export function noteTitle(body) {
  const line = body.split('\n').map((l) => l.trim()).find((l) => l) || '';
  const plain = line
    .replace(/^(#{1,6}\s+|>\s*|[-*+]\s+|\d+[.)]\s+)+/, '')
    .replace(/!?\[([^\]]*)\]\([^)]*\)/g, '$1')
    .replace(/[*_`~]+/g, '')
    .trim();
  return plain.length > 80 ? `${plain.slice(0, 79).trimEnd()}…` : plain;
}

function isText(file) {
  return file.type.startsWith('text/') || /\.(txt|md|markdown)$/i.test(file.name);
}

export class AssignStep {
  /**
   * @param {HTMLElement} host the viewer, where the step shows in the information panel's place
   * @param {HTMLElement} stage the 3D view: files dropped onto the region land there
   * @param {import('./api.js').Api} api
   * @param {{assigned: (partId: number, content: object) => void,
   *   closed: (partId: number) => void}} handlers `closed`: the user is done
   */
  constructor(host, stage, api, handlers) {
    this.stage = stage;
    this.api = api;
    this.handlers = handlers;
    this.partId = null;
    this.root = el('aside', 'select-assign');
    this.root.hidden = true;
    host.appendChild(this.root);
    this.onDragOver = (e) => {
      if (!this.isOpen() || !e.dataTransfer || ![...e.dataTransfer.types].includes('Files')) return;
      e.preventDefault();
      e.dataTransfer.dropEffect = 'copy';
      this.setDropTarget(true);
    };
    this.onDragLeave = (e) => {
      if (!e.currentTarget.contains(e.relatedTarget)) this.setDropTarget(false);
    };
    this.onDrop = (e) => {
      if (!this.isOpen() || !e.dataTransfer || e.dataTransfer.files.length === 0) return;
      e.preventDefault();
      this.setDropTarget(false);
      this.addFiles([...e.dataTransfer.files]);
    };
    for (const target of [stage, this.root]) {
      target.addEventListener('dragover', this.onDragOver);
      target.addEventListener('dragleave', this.onDragLeave);
      target.addEventListener('drop', this.onDrop);
    }
  }

  /** Marks the region and the drop zone while files are dragged over them. */
  setDropTarget(on) {
    this.stage.classList.toggle('drop-target', on);
    this.root.classList.toggle('drop-target', on);
  }

  isOpen() {
    return !this.root.hidden;
  }

  /** Opens the step on part `partId`; `title` is the suggested title of new information. */
  open(partId, title) {
    this.partId = partId;
    this.busy = false;
    this.root.replaceChildren();
    this.root.hidden = false;
    this.root.dataset.partId = String(partId);
    this.root.setAttribute('aria-label', `Assign information to part ${partId}`);
    const head = el('header', 'assign-head');
    head.append(el('h3', null, `Assign information to part ${partId}`));
    const done = el('button', 'assign-done', 'Done');
    done.type = 'button';
    done.dataset.action = 'assign-done';
    done.addEventListener('click', () => this.close());
    head.append(done);

    this.title = input('text', 'title', { placeholder: title, maxLength: 200 });
    this.caption = input('text', 'caption', { placeholder: 'One line shown with the title', maxLength: 500 });
    const details = el('div', 'assign-details');
    details.append(field('Title ', this.title), field('Caption ', this.caption));

    const drop = el('div', 'assign-drop');
    drop.tabIndex = 0;
    drop.setAttribute('role', 'button');
    drop.append(el('span', null, 'Drop an image, PDF or text file here or onto the region, or '));
    const choose = el('label', 'assign-choose', 'choose a file');
    this.file = input('file', 'file', { accept: 'image/*,application/pdf,text/*,.md,.txt' });
    this.file.className = 'sr-only';
    this.file.addEventListener('change', () => {
      if (this.file.files.length) this.addFiles([...this.file.files]);
      this.file.value = '';
    });
    choose.append(this.file);
    drop.append(choose);
    drop.addEventListener('keydown', (e) => {
      if (e.key === 'Enter' || e.key === ' ') {
        e.preventDefault();
        this.file.click();
      }
    });

    const linkForm = el('form', 'assign-link');
    this.url = input('url', 'url', { placeholder: 'https://…', required: true });
    this.url.setAttribute('aria-label', 'Link to the information');
    const addLink = el('button', null, 'Add link');
    addLink.type = 'submit';
    linkForm.append(this.url, addLink);
    linkForm.addEventListener('submit', (e) => {
      e.preventDefault();
      this.addLink(this.url.value.trim());
    });

    const noteForm = el('form', 'assign-note');
    this.note = document.createElement('textarea');
    this.note.name = 'note';
    this.note.rows = 5;
    this.note.placeholder = 'What is this region? Markdown: **bold**, lists, links…';
    const addNote = el('button', null, 'Add note');
    addNote.type = 'submit';
    noteForm.append(field('Write a note (Markdown) ', this.note), addNote);
    noteForm.addEventListener('submit', (e) => {
      e.preventDefault();
      this.addNote(this.note.value);
    });
    // Ctrl+Enter (⌘+Enter) in the note saves it.
    this.note.addEventListener('keydown', (e) => {
      if (e.key === 'Enter' && (e.ctrlKey || e.metaKey)) {
        e.preventDefault();
        noteForm.requestSubmit();
      }
    });

    const searchForm = el('form', 'assign-search');
    searchForm.setAttribute('role', 'search');
    this.query = input('search', 'q', { placeholder: 'Search existing information…' });
    this.query.setAttribute('aria-label', 'Search existing information');
    const go = el('button', null, 'Search');
    go.type = 'submit';
    searchForm.append(this.query, go);
    searchForm.addEventListener('submit', (e) => {
      e.preventDefault();
      this.search(this.query.value.trim());
    });
    this.results = el('ul', 'assign-results');

    this.message = el('p', 'assign-message');
    this.message.setAttribute('role', 'status');
    this.message.setAttribute('aria-live', 'polite');
    this.assignedList = el('ul', 'assign-assigned');
    this.root.append(head, details, drop, linkForm, noteForm, searchForm, this.results, this.message, this.assignedList);
    this.title.focus();
  }

  /** Ends the step (Done, Escape): the part's information opens. */
  close() {
    const id = this.partId;
    if (this.hide()) this.handlers.closed(id);
  }

  /** Hides the step without further ado; true when it was open. */
  hide() {
    if (!this.isOpen()) return false;
    this.root.hidden = true;
    this.setDropTarget(false);
    this.partId = null;
    return true;
  }

  say(text, isError = false) {
    this.message.textContent = text;
    this.message.classList.toggle('error', isError);
    // The step scrolls on its own: bring a message below its fold into view.
    if (isError) this.message.scrollIntoView({ block: 'nearest' });
  }

  /** Whether Escape pressed on `target` should leave the step open: a field of the step that
   * holds typed text (a note being written is not thrown away by a stray key). */
  holdsText(target) {
    if (!(target instanceof HTMLElement) || !this.root.contains(target)) return false;
    const typed = target instanceof HTMLTextAreaElement || (target instanceof HTMLInputElement && target.type !== 'file');
    return typed && target.value.trim() !== '';
  }

  titleFor(fallback) {
    return this.title.value.trim() || fallback || this.title.placeholder;
  }

  /** Runs one assignment at a time, reporting its outcome. */
  async run(what, job) {
    if (this.busy) return;
    this.busy = true;
    this.root.classList.add('busy');
    this.say(`${what}…`);
    try {
      let content;
      try {
        content = await job();
      } catch (e) {
        throw new Error(`${what} failed: ${e.message}`);
      }
      try {
        await this.api.post(`/api/v1/parts/${this.partId}/contents`, { content_id: content.id });
      } catch (e) {
        throw new Error(`“${content.title}” (content #${content.id}) could not be assigned to part ${this.partId}: ${e.message}`);
      }
      const li = el('li', null, content.title);
      li.dataset.contentId = String(content.id);
      this.assignedList.append(li);
      this.say(`Assigned “${content.title}” to part ${this.partId}.`);
      this.title.value = '';
      this.caption.value = '';
      this.handlers.assigned(this.partId, content);
    } catch (e) {
      this.say(e.message, true);
    } finally {
      this.busy = false;
      this.root.classList.remove('busy');
    }
  }

  addFiles(files) {
    const file = files[0];
    if (!file) return;
    if (files.length > 1) this.say('One file at a time: the first is used.');
    return this.run(`Uploading ${file.name}`, async () => {
      const form = new FormData();
      form.append('file', file, file.name);
      const att = await this.api.post('/api/v1/attachments', form);
      const href = `/api/v1/attachments/${att.id}/download`;
      const image = att.media_type.startsWith('image/');
      let body = image ? `!${mdLink(att.original_name, href)}\n` : `${mdLink(att.original_name, href)}\n`;
      if (isText(file) && file.size <= TEXT_INLINE_BYTES) body = `${(await file.text()).trim()}\n\n${body}`;
      const content = await this.api.post('/api/v1/contents', {
        title: this.titleFor(file.name.replace(/\.[^.]+$/, '')),
        caption: this.caption.value.trim(),
        body,
        ...(image ? { thumbnail_attachment_id: att.id } : {}),
      });
      await this.api.put(`/api/v1/contents/${content.id}/attachments/${att.id}`);
      return content;
    });
  }

  addLink(url) {
    let parsed;
    try {
      parsed = new URL(url);
    } catch {
      this.say('Give a full link, such as https://example.org/page.', true);
      return;
    }
    if (parsed.protocol !== 'http:' && parsed.protocol !== 'https:') {
      this.say('Only http and https links can be assigned.', true);
      return;
    }
    return this.run('Adding the link', async () => {
      const content = await this.api.post('/api/v1/contents', {
        title: this.titleFor(parsed.hostname),
        caption: this.caption.value.trim(),
        body: `${mdLink(parsed.href, parsed.href)}\n`,
      });
      this.url.value = '';
      return content;
    });
  }

  addNote(text) {
    const body = text.replace(/\r\n/g, '\n').trim();
    if (!body) {
      this.say('Write the note first: its text is empty.', true);
      this.note.focus();
      return;
    }
    return this.run('Saving the note', async () => {
      const content = await this.api.post('/api/v1/contents', {
        title: this.titleFor(noteTitle(body)),
        caption: this.caption.value.trim(),
        body: `${body}\n`,
      });
      this.note.value = '';
      return content;
    });
  }

  async search(q) {
    this.results.replaceChildren();
    if (!q) return;
    try {
      const hits = await this.api.get(`/api/v1/search?${new URLSearchParams({ q, limit: '10' })}`);
      if (hits.length === 0) this.results.append(el('li', 'muted', 'Nothing found.'));
      for (const h of hits) {
        const li = el('li');
        li.dataset.contentId = String(h.id);
        li.append(el('strong', null, h.title));
        if (h.caption) li.append(el('span', 'muted', ` — ${h.caption}`));
        const pick = el('button', 'assign-pick', 'Assign');
        pick.type = 'button';
        pick.addEventListener('click', () => this.run(`Assigning “${h.title}”`, async () => ({ id: h.id, title: h.title })));
        li.append(' ', pick);
        this.results.append(li);
      }
    } catch (e) {
      this.say(e.message, true);
    }
  }
}
