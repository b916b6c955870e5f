// The drawer the information panel and the assign step open in: over the right side of the 3D
// view (never squeezing it), as wide as the reader makes it. While one is open, a handle on its
// left edge resizes it: dragged, or moved with the arrow keys (a focusable separator); the
// width is kept for the next visit. On phones the drawer is a sheet over the lower part of the
// view (style.css), without a handle.

const KEY = 'meshwiki-drawer-width';
const DEFAULT_PX = 384;
const MIN_PX = 260;
const STEP_PX = 32;

function stored() {
  try {
    const v = Number(window.localStorage.getItem(KEY));
    return Number.isFinite(v) && v > 0 ? v : DEFAULT_PX;
  } catch {
    return DEFAULT_PX;
  }
}

export class Drawers {
  /**
   * @param {HTMLElement} host the viewer: its CSS variable `--drawer-width` sizes the drawers
   * @param {HTMLElement} stage the 3D view the drawers cover
   * @param {(width: number) => void} onChange the open drawer or its width changed
   */
  constructor(host, stage, onChange = () => {}) {
    this.host = host;
    this.stage = stage;
    this.onChange = onChange;
    this.width = stored();
    this.drawers = [];
    const handle = document.createElement('div');
    handle.className = 'drawer-handle';
    handle.hidden = true;
    handle.tabIndex = 0;
    handle.setAttribute('role', 'separator');
    handle.setAttribute('aria-orientation', 'vertical');
    handle.setAttribute('aria-label', 'Resize the information panel');
    handle.setAttribute('aria-valuemin', String(MIN_PX));
    handle.title = 'Drag to resize the panel (or use the arrow keys)';
    handle.addEventListener('pointerdown', (e) => {
      if (e.button !== 0) return;
      e.preventDefault();
      handle.setPointerCapture(e.pointerId);
      const right = this.host.getBoundingClientRect().right;
      const move = (ev) => this.set(right - ev.clientX);
      const up = () => {
        handle.removeEventListener('pointermove', move);
        handle.removeEventListener('pointerup', up);
        handle.removeEventListener('pointercancel', up);
      };
      handle.addEventListener('pointermove', move);
      handle.addEventListener('pointerup', up);
      handle.addEventListener('pointercancel', up);
    });
    handle.addEventListener('keydown', (e) => {
      const now = this.apply();
      const to = { ArrowLeft: now + STEP_PX, ArrowRight: now - STEP_PX, Home: MIN_PX, End: this.max() }[e.key];
      if (to === undefined) return;
      e.preventDefault();
      this.set(to);
    });
    this.handle = handle;
    stage.appendChild(handle);
    this.observer = new MutationObserver(() => this.update());
    new ResizeObserver(() => this.apply()).observe(host);
    this.apply();
  }

  max() {
    return Math.max(MIN_PX, Math.floor(this.host.clientWidth * 0.7));
  }

  /** Sets the CSS width from the wanted one, within bounds; returns it. */
  apply() {
    const w = Math.round(Math.min(this.max(), Math.max(MIN_PX, this.width)));
    this.host.style.setProperty('--drawer-width', `${w}px`);
    this.handle.setAttribute('aria-valuenow', String(w));
    this.handle.setAttribute('aria-valuemax', String(this.max()));
    return w;
  }

  set(width) {
    this.width = width;
    const w = this.apply();
    try {
      window.localStorage.setItem(KEY, String(w));
    } catch {
      /* private browsing: the width lasts for the page */
    }
    this.onChange(w);
  }

  /** Makes `el` (shown and hidden through its `hidden` attribute) a drawer. */
  adopt(el) {
    el.classList.add('drawer');
    this.drawers.push(el);
    this.observer.observe(el, { attributes: true, attributeFilter: ['hidden'] });
    this.update();
  }

  update() {
    const open = this.drawers.some((d) => !d.hidden);
    this.host.classList.toggle('drawer-open', open);
    this.handle.hidden = !open;
    this.onChange(this.apply());
  }

  /** The pixels of the view's width an open drawer covers (0 when none is, or on phones). */
  covered() {
    const open = this.drawers.find((d) => !d.hidden);
    if (!open) return 0;
    const r = open.getBoundingClientRect();
    const v = this.stage.getBoundingClientRect();
    // A sheet along the bottom (phones) covers no width.
    if (r.width >= v.width * 0.95) return 0;
    return Math.max(0, Math.min(v.width, v.right - r.left));
  }
}
