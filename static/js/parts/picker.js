// The content picker of the model page's assignment forms (`form[data-content-picker]`): the
// text field searches contents as the editor types (`GET /api/v1/search`; `#12` looks up
// content 12) and lists them in a listbox (ARIA combobox: arrow keys, Enter, Escape, or the
// pointer); the choice fills the form's `content_id`. Without this script the form still works:
// the server takes the typed title or number. Listeners sit on the document, so forms the
// viewer re-renders (the page's parts list) keep working.

const DEBOUNCE_MS = 180;
const LIMIT = 8;
let serial = 0;

function el(tag, cls, text) {
  const e = document.createElement(tag);
  if (cls) e.className = cls;
  if (text !== undefined) e.textContent = text;
  return e;
}

async function getJson(url) {
  const res = await fetch(url, { credentials: 'same-origin', headers: { Accept: 'application/json' } });
  if (res.status === 404) return null;
  if (!res.ok) {
    let message = `HTTP ${res.status}`;
    try {
      message = (await res.json()).error || message;
    } catch {
      // not JSON: keep the status
    }
    throw new Error(message);
  }
  return res.json();
}

/** The picker of one form, made on first use. */
class Picker {
  constructor(form) {
    this.form = form;
    this.input = form.querySelector('input[name=content]');
    this.hidden = form.querySelector('input[name=content_id]');
    const id = this.input.id || `content-picker-${++serial}`;
    this.input.id = id;
    this.list = el('ul', 'picker-list');
    this.list.id = `${id}-list`;
    this.list.setAttribute('role', 'listbox');
    this.list.setAttribute('aria-label', 'Matching contents');
    this.list.hidden = true;
    this.status = el('span', 'picker-status sr-only');
    this.status.setAttribute('role', 'status');
    this.status.setAttribute('aria-live', 'polite');
    form.append(this.list, this.status);
    this.input.setAttribute('role', 'combobox');
    this.input.setAttribute('aria-autocomplete', 'list');
    this.input.setAttribute('aria-expanded', 'false');
    this.input.setAttribute('aria-controls', this.list.id);
    this.options = [];
    this.active = -1;
    this.timer = null;
    this.generation = 0;
  }

  typed() {
    this.hidden.value = '';
    this.form.dataset.picked = '';
    clearTimeout(this.timer);
    this.timer = setTimeout(() => this.search(this.input.value.trim()), DEBOUNCE_MS);
  }

  async search(q) {
    const generation = ++this.generation;
    if (!q) return this.close();
    let hits;
    try {
      const number = /^#?\s*(\d+)$/.exec(q);
      if (number) {
        const c = await getJson(`/api/v1/contents/${number[1]}`);
        hits = c ? [{ id: c.id, title: c.title, caption: c.caption }] : [];
      } else {
        hits = (await getJson(`/api/v1/search?${new URLSearchParams({ q, limit: String(LIMIT) })}`)) || [];
      }
    } catch (e) {
      if (generation !== this.generation) return;
      this.show([], `The search failed: ${e.message}`);
      return;
    }
    if (generation !== this.generation) return;
    this.show(hits, hits.length ? `${hits.length} matching content${hits.length > 1 ? 's' : ''}` : `No content matches “${q}”.`);
  }

  show(hits, message) {
    this.list.replaceChildren();
    this.options = hits.map((h, k) => {
      const li = el('li', 'picker-option');
      li.id = `${this.list.id}-${k}`;
      li.setAttribute('role', 'option');
      li.setAttribute('aria-selected', 'false');
      li.dataset.contentId = String(h.id);
      li.append(el('strong', null, h.title), el('span', 'muted', ` #${h.id}${h.caption ? ` — ${h.caption}` : ''}`));
      // mousedown: picked before the field loses focus (which closes the list).
      li.addEventListener('mousedown', (e) => {
        e.preventDefault();
        this.pick(h);
      });
      this.list.append(li);
      return { li, hit: h };
    });
    if (hits.length === 0) {
      const li = el('li', 'picker-empty muted', message);
      li.setAttribute('aria-disabled', 'true');
      this.list.append(li);
    }
    this.status.textContent = message;
    this.setActive(-1);
    this.list.hidden = false;
    this.input.setAttribute('aria-expanded', 'true');
  }

  setActive(k) {
    this.active = k;
    this.options.forEach((o, i) => {
      o.li.classList.toggle('active', i === k);
      o.li.setAttribute('aria-selected', String(i === k));
    });
    if (k >= 0) {
      this.input.setAttribute('aria-activedescendant', this.options[k].li.id);
      this.options[k].li.scrollIntoView({ block: 'nearest' });
    } else this.input.removeAttribute('aria-activedescendant');
  }

  pick(hit) {
    this.input.value = hit.title;
    this.hidden.value = String(hit.id);
    this.form.dataset.picked = String(hit.id);
    this.close();
    this.status.textContent = `Picked “${hit.title}” (#${hit.id}); press Assign.`;
  }

  close() {
    this.generation++;
    clearTimeout(this.timer);
    this.list.hidden = true;
    this.input.setAttribute('aria-expanded', 'false');
    this.setActive(-1);
  }

  key(e) {
    const open = !this.list.hidden;
    const n = this.options.length;
    if (e.key === 'ArrowDown' || e.key === 'ArrowUp') {
      e.preventDefault();
      if (!open) {
        this.search(this.input.value.trim());
        return;
      }
      if (n === 0) return;
      const step = e.key === 'ArrowDown' ? 1 : -1;
      this.setActive(this.active < 0 ? (step > 0 ? 0 : n - 1) : (this.active + step + n) % n);
    } else if (e.key === 'Enter' && open && this.active >= 0) {
      e.preventDefault();
      this.pick(this.options[this.active].hit);
    } else if (e.key === 'Escape' && open) {
      e.preventDefault();
      this.close();
    }
  }
}

const pickers = new WeakMap();

function pickerOf(target) {
  if (!(target instanceof HTMLInputElement) || target.name !== 'content') return null;
  const form = target.closest('form[data-content-picker]');
  if (!form) return null;
  let p = pickers.get(form);
  if (!p) {
    p = new Picker(form);
    pickers.set(form, p);
  }
  return p;
}

document.addEventListener('input', (e) => pickerOf(e.target)?.typed());
document.addEventListener('keydown', (e) => pickerOf(e.target)?.key(e));
document.addEventListener('focusout', (e) => {
  const p = pickerOf(e.target);
  if (p) setTimeout(() => p.close(), 0);
});
