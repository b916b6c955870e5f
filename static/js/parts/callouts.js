// Callouts (system paper §2.2): each part's title in a label joined to its anchor by a leader
// line, as an HTML overlay. A label is shown when its anchor is in view and not hidden behind
// the surface, and when the part is large enough on screen at the current viewing scale;
// labels are placed greedily (selected and hovered first, then by on-screen size) by the
// engine's rule (./place.js, the same as the server's `render/callouts`, without the cover
// penalty: the overlay has no depth buffer), never overlapping one another.

import { placeLabels } from './place.js';

const SVG = 'http://www.w3.org/2000/svg';
/** Smallest gap (px) between labels and from the overlay's border. */
const GAP = 4;
/** Smallest on-screen part radius (px) at which its label shows. */
export const MIN_PART_PIXELS = 3;

export class Callouts {
  /**
   * @param {HTMLElement} overlay positioned over the canvas
   * @param {{onHover: (id: number|null) => void, onClick: (id: number) => void}} handlers
   */
  constructor(overlay, handlers) {
    this.overlay = overlay;
    this.handlers = handlers;
    this.svg = document.createElementNS(SVG, 'svg');
    this.svg.setAttribute('class', 'callout-leaders');
    overlay.appendChild(this.svg);
    this.labels = new Map(); // id -> {el, title, w, h}
    this.placed = [];
  }

  label(id, title) {
    let l = this.labels.get(id);
    if (!l) {
      const el = document.createElement('button');
      el.type = 'button';
      el.className = 'callout';
      el.dataset.partId = String(id);
      el.addEventListener('pointerenter', () => this.handlers.onHover(id));
      el.addEventListener('pointerleave', () => this.handlers.onHover(null));
      el.addEventListener('click', (e) => {
        e.stopPropagation();
        this.handlers.onClick(id);
      });
      this.overlay.appendChild(el);
      l = { el, title: null, w: 0, h: 0 };
      this.labels.set(id, l);
    }
    if (l.title !== title) {
      l.title = title;
      l.el.textContent = title;
      l.el.title = title;
      l.w = 0;
    }
    if (l.w === 0) {
      l.el.style.visibility = 'hidden';
      l.el.hidden = false;
      l.w = Math.ceil(l.el.offsetWidth);
      l.h = Math.ceil(l.el.offsetHeight);
    }
    return l;
  }

  /**
   * Lays the labels out.
   * @param {{id: number, title: string, x: number, y: number, radiusPx: number, priority: number}[]} items
   *   candidates whose anchors are in view and unoccluded, in CSS pixels
   * @param {number} width
   * @param {number} height
   * @param {{selected: number|null, hovered: number|null}} state
   */
  layout(items, width, height, state) {
    const shown = items
      .filter((it) => it.radiusPx >= MIN_PART_PIXELS || it.id === state.selected || it.id === state.hovered)
      .sort((a, b) => b.priority - a.priority);
    const labels = shown.map((it) => this.label(it.id, it.title));
    const spots = placeLabels(
      shown.map((it, k) => ({ anchor: [it.x, it.y], size: [labels[k].w, labels[k].h] })),
      width,
      height,
      GAP,
    );
    const visible = new Set();
    this.placed = [];
    shown.forEach((it, k) => {
      const spot = spots[k];
      if (!spot) return;
      const l = labels[k];
      const box = spot.label;
      visible.add(it.id);
      this.placed.push({ id: it.id, box, anchor: { x: it.x, y: it.y }, end: { x: spot.end[0], y: spot.end[1] } });
      l.el.style.transform = `translate(${Math.round(box.x)}px, ${Math.round(box.y)}px)`;
      l.el.style.visibility = 'visible';
      l.el.hidden = false;
      l.el.classList.toggle('selected', it.id === state.selected);
      l.el.classList.toggle('hovered', it.id === state.hovered);
    });
    for (const [id, l] of this.labels) {
      if (!visible.has(id)) l.el.hidden = true;
    }
    this.drawLeaders(width, height, state);
  }

  drawLeaders(width, height, state) {
    this.svg.setAttribute('width', String(width));
    this.svg.setAttribute('height', String(height));
    this.svg.setAttribute('viewBox', `0 0 ${width} ${height}`);
    while (this.svg.firstChild) this.svg.firstChild.remove();
    for (const p of this.placed) {
      const end = p.end;
      const cls = p.id === state.selected ? ' selected' : p.id === state.hovered ? ' hovered' : '';
      const line = document.createElementNS(SVG, 'line');
      line.setAttribute('x1', String(p.anchor.x));
      line.setAttribute('y1', String(p.anchor.y));
      line.setAttribute('x2', String(end.x));
      line.setAttribute('y2', String(end.y));
      line.setAttribute('class', `leader${cls}`);
      const dot = document.createElementNS(SVG, 'circle');
      dot.setAttribute('cx', String(p.anchor.x));
      dot.setAttribute('cy', String(p.anchor.y));
      dot.setAttribute('r', '3');
      dot.setAttribute('class', `anchor${cls}`);
      this.svg.append(line, dot);
    }
  }

  /** Removes the labels of parts that no longer exist. */
  prune(ids) {
    for (const [id, l] of this.labels) {
      if (!ids.has(id)) {
        l.el.remove();
        this.labels.delete(id);
      }
    }
  }

  /** Ids of the labels currently shown. */
  shownIds() {
    return this.placed.map((p) => p.id);
  }
}
