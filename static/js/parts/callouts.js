// Callouts (system paper §2.2): each part's title in a label joined to its anchor by a leader
// line, as an HTML overlay. A label is shown when its anchor is in view and not hidden behind
// the surface, and when the part is large enough on screen at the current viewing scale;
// labels are placed greedily (selected and hovered first, then by on-screen size) at the
// cheapest free position around their anchor, never overlapping one another.

const SVG = 'http://www.w3.org/2000/svg';
const DISTANCES = [36, 64, 100, 150];
const ANGLES = [-40, -140, 40, 140, -90, 90, 0, 180].map((a) => (a * Math.PI) / 180);
const GAP = 4;
/** Smallest on-screen part radius (px) at which its label shows. */
export const MIN_PART_PIXELS = 3;

function overlaps(a, b) {
  return a.x < b.x + b.w + GAP && b.x < a.x + a.w + GAP && a.y < b.y + b.h + GAP && b.y < a.y + a.h + GAP;
}

function crosses(p1, p2, p3, p4) {
  const d = (a, b, c) => (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x);
  const d1 = d(p3, p4, p1);
  const d2 = d(p3, p4, p2);
  const d3 = d(p1, p2, p3);
  const d4 = d(p1, p2, p4);
  return d1 * d2 < 0 && d3 * d4 < 0;
}

/** Point of box `b` nearest to `p`. */
function nearestOnBox(b, p) {
  return { x: Math.min(Math.max(p.x, b.x), b.x + b.w), y: Math.min(Math.max(p.y, b.y), b.y + b.h) };
}

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
    const boxes = [];
    const leaders = [];
    const anchors = shown.map((it) => ({ x: it.x, y: it.y }));
    const visible = new Set();
    this.placed = [];
    for (const it of shown) {
      const l = this.label(it.id, it.title);
      let best = null;
      for (const dist of DISTANCES) {
        for (const angle of ANGLES) {
          const cx = it.x + Math.cos(angle) * dist;
          const cy = it.y + Math.sin(angle) * dist;
          const box = { x: cx - (Math.cos(angle) < -0.3 ? l.w : Math.cos(angle) > 0.3 ? 0 : l.w / 2), y: cy - l.h / 2, w: l.w, h: l.h };
          if (box.x < GAP || box.y < GAP || box.x + box.w > width - GAP || box.y + box.h > height - GAP) continue;
          if (boxes.some((b) => overlaps(b, box))) continue;
          const end = nearestOnBox(box, it);
          let cost = dist;
          for (const [a, b] of leaders) if (crosses(it, end, a, b)) cost += 80;
          for (const a of anchors) {
            if (a.x >= box.x - GAP && a.x <= box.x + box.w + GAP && a.y >= box.y - GAP && a.y <= box.y + box.h + GAP) cost += 120;
          }
          if (!best || cost < best.cost) best = { box, end, cost };
        }
        if (best && best.cost < DISTANCES[DISTANCES.length - 1]) break;
      }
      if (!best) continue;
      boxes.push(best.box);
      leaders.push([{ x: it.x, y: it.y }, best.end]);
      visible.add(it.id);
      this.placed.push({ id: it.id, box: best.box, anchor: { x: it.x, y: it.y } });
      l.el.style.transform = `translate(${Math.round(best.box.x)}px, ${Math.round(best.box.y)}px)`;
      l.el.style.visibility = 'visible';
      l.el.hidden = false;
      l.el.classList.toggle('selected', it.id === state.selected);
      l.el.classList.toggle('hovered', it.id === state.hovered);
    }
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
      const end = nearestOnBox(p.box, p.anchor);
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
