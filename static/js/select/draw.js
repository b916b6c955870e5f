// The drawing layer of the selection tools: a canvas over the 3D view that takes the pointer
// while a tool is active (so drawing never orbits the camera), records each stroke in CSS
// pixels of the view and shows it — the lasso's polygon, the heavy lasso's thick band, the
// markup's foreground (yellow) and background (blue) strokes (system paper §4, Figs. 8, 10) —
// with the brush outline under the cursor. What is drawn here is only for the eye; the mask
// sent to the server is rasterised separately (raster.js).

const MIN_STEP_PX = 1.5;
const STYLE = {
  lasso: { stroke: '#ffffff', fill: 'rgba(255, 255, 255, 0.18)' },
  heavy: { stroke: 'rgba(190, 196, 202, 0.65)' },
  foreground: { stroke: 'rgba(255, 214, 0, 0.85)' },
  background: { stroke: 'rgba(40, 140, 255, 0.85)' },
};

export class StrokeLayer {
  /**
   * @param {HTMLElement} stage the viewer's stage (positioned)
   * @param {{onStroke: (stroke: object) => void,
   *   onClick: (p: {x: number, y: number}, keys: {shiftKey: boolean, altKey: boolean}) => void,
   *   onHover?: (p: {x: number, y: number, clientX: number, clientY: number}|null) => void,
   *   brush: () => {kind: string, width: number} | null}} handlers `brush()` says what a drag
   *   draws now (null: the layer is inactive); `onHover` follows the pointer while no stroke
   *   is drawn (null: it left the view)
   */
  constructor(stage, handlers) {
    this.stage = stage;
    this.handlers = handlers;
    this.canvas = document.createElement('canvas');
    this.canvas.className = 'select-layer';
    this.canvas.hidden = true;
    this.canvas.setAttribute('aria-hidden', 'true');
    stage.appendChild(this.canvas);
    this.g = this.canvas.getContext('2d');
    this.kept = []; // strokes shown until cleared (markup)
    this.current = null;
    this.cursor = null;
    this.disabled = false;
    this.bind();
  }

  /** Shows (takes the pointer) or hides the layer. */
  setActive(on) {
    this.canvas.hidden = !on;
    if (!on) {
      this.current = null;
      this.cursor = null;
    }
    this.redraw();
  }

  get active() {
    return !this.canvas.hidden;
  }

  /** While a request runs: strokes cannot start (`wait` cursor). */
  setDisabled(on) {
    this.disabled = on;
    this.canvas.classList.toggle('busy', on);
  }

  /** Strokes kept on screen (the markup's), replacing the previous ones. */
  keep(strokes) {
    this.kept = strokes;
    this.redraw();
  }

  /** Drops the stroke being drawn; true when there was one. */
  abort() {
    if (!this.current) return false;
    this.current = null;
    this.redraw();
    return true;
  }

  point(e) {
    const r = this.canvas.getBoundingClientRect();
    return { x: e.clientX - r.left, y: e.clientY - r.top };
  }

  bind() {
    const c = this.canvas;
    c.addEventListener('contextmenu', (e) => e.preventDefault());
    c.addEventListener('pointerdown', (e) => {
      e.preventDefault();
      const brush = this.handlers.brush(e);
      if (this.disabled || !brush || this.current) return;
      c.setPointerCapture(e.pointerId);
      this.current = { kind: brush.kind, width: brush.width, points: [this.point(e)], pointerId: e.pointerId, moved: 0 };
      this.redraw();
    });
    c.addEventListener('pointermove', (e) => {
      this.cursor = { ...this.point(e), brush: this.handlers.brush(e) };
      if (!this.current && this.handlers.onHover) this.handlers.onHover({ ...this.point(e), clientX: e.clientX, clientY: e.clientY });
      const s = this.current;
      if (s && e.pointerId === s.pointerId) {
        const p = this.point(e);
        const last = s.points[s.points.length - 1];
        const step = Math.hypot(p.x - last.x, p.y - last.y);
        if (step >= MIN_STEP_PX) {
          s.points.push(p);
          s.moved += step;
        }
      }
      this.redraw();
    });
    const finish = (e, cancelled) => {
      const s = this.current;
      if (!s || e.pointerId !== s.pointerId) return;
      this.current = null;
      if (c.hasPointerCapture(e.pointerId)) c.releasePointerCapture(e.pointerId);
      if (!cancelled) {
        const p = this.point(e);
        const last = s.points[s.points.length - 1];
        if (Math.hypot(p.x - last.x, p.y - last.y) > 0) s.points.push(p);
        const stroke = { kind: s.kind, width: s.width, points: s.points, moved: s.moved };
        if (s.kind === 'point' || s.kind === 'segment') this.handlers.onClick(s.points[0], { shiftKey: e.shiftKey, altKey: e.altKey });
        else this.handlers.onStroke(stroke);
      }
      this.redraw();
    };
    c.addEventListener('pointerup', (e) => finish(e, false));
    c.addEventListener('pointercancel', (e) => finish(e, true));
    c.addEventListener('pointerleave', () => {
      this.cursor = null;
      if (this.handlers.onHover) this.handlers.onHover(null);
      this.redraw();
    });
  }

  /** Matches the canvas to the stage (device pixels) and draws the strokes. */
  redraw() {
    const c = this.canvas;
    if (c.hidden) return;
    const dpr = Math.min(window.devicePixelRatio || 1, 2);
    const w = this.stage.clientWidth;
    const h = this.stage.clientHeight;
    if (c.width !== Math.round(w * dpr) || c.height !== Math.round(h * dpr)) {
      c.width = Math.round(w * dpr);
      c.height = Math.round(h * dpr);
    }
    const g = this.g;
    g.setTransform(dpr, 0, 0, dpr, 0, 0);
    g.clearRect(0, 0, w, h);
    for (const s of this.kept) this.drawStroke(s);
    if (this.current) this.drawStroke(this.current);
    const cur = this.cursor;
    if (cur && cur.brush && !['lasso', 'point', 'segment'].includes(cur.brush.kind)) {
      g.beginPath();
      g.arc(cur.x, cur.y, Math.max(1, cur.brush.width / 2), 0, Math.PI * 2);
      g.strokeStyle = 'rgba(255, 255, 255, 0.8)';
      g.lineWidth = 1;
      g.setLineDash([]);
      g.stroke();
    }
  }

  drawStroke(s) {
    const g = this.g;
    const pts = s.points;
    if (pts.length === 0 || s.kind === 'point' || s.kind === 'segment') return;
    const style = STYLE[s.kind];
    g.beginPath();
    g.moveTo(pts[0].x, pts[0].y);
    for (const p of pts.length > 1 ? pts.slice(1) : pts) g.lineTo(p.x, p.y);
    if (s.kind === 'lasso' || s.kind === 'heavy') g.closePath();
    g.lineJoin = 'round';
    g.lineCap = 'round';
    g.setLineDash(s.kind === 'lasso' ? [6, 4] : []);
    g.lineWidth = s.kind === 'lasso' ? 1.5 : Math.max(1, s.width);
    g.strokeStyle = style.stroke;
    if (style.fill) {
      g.fillStyle = style.fill;
      g.fill('evenodd');
    }
    g.stroke();
  }
}
