// Region selection in the viewer (issue 6; system paper §4): ties the Select toolbar group,
// the drawing layer, the mask rasteriser and encoder, the chain of server drafts, the draft's
// exact highlight and the assign-information step together. A stroke becomes a label mask
// of the current camera's size (capped to the server's limits, camera scaled alike) and a
// draft; markup strokes accumulate on one view and refine one draft (Lazy Snapping); Escape
// drops the stroke being drawn, else ends the assign step, else cancels.

import { Api, csrfToken } from './api.js';
import { AssignStep } from './assign.js';
import { StrokeLayer } from './draw.js';
import { DraftHighlight } from './highlight.js';
import { encodeMask } from './png.js';
import { fitSize, rasterise } from './raster.js';
import { SegmentPreview } from './segments.js';
import { SelectionSession } from './session.js';
import { SelectTools } from './tools.js';

const HINTS = {
  lasso: 'drag a polygon around the region',
  markup: 'paint on the region, then around it with Shift (background)',
  heavy_lasso: 'trace the boundary with one thick closed stroke',
  point: 'click a surface point',
  segment: 'hover to preview a surface segment, click to select it (Shift: add, Alt: subtract)',
};
const MIN_LASSO_AREA_PX = 4;

function polygonArea(points) {
  let a = 0;
  for (let i = 0, j = points.length - 1; i < points.length; j = i++) a += (points[j].x + points[i].x) * (points[j].y - points[i].y);
  return Math.abs(a) / 2;
}

export class SelectController {
  /**
   * @param {HTMLElement} root the viewer element (its `data-csrf`)
   * @param {HTMLElement} stage the viewer's stage
   * @param {{modelId: number, radius: number, vertices: number,
   *   limits: {maxSide: number, maxPixels: number}|null,
   *   camera: () => {eye: number[], target: number[], up: number[], fovy: number, width: number, height: number},
   *   pauseNavigation: (on: boolean) => void, highlightChanged: () => void,
   *   partConfirmed: (part: object, created: boolean) => Promise<void>,
   *   assignDone: (partId: number) => void, contentsChanged: (partId: number) => void,
   *   partTitle: (id: number) => string,
   *   pick: (clientX: number, clientY: number) => {vertex: number|null}|null}} host
   */
  constructor(root, stage, host) {
    this.host = host;
    this.api = new Api(csrfToken(root));
    this.session = new SelectionSession(host.modelId, this.api, () => this.render());
    if (host.limits) this.session.limits = { ...host.limits };
    this.highlight = new DraftHighlight(host.modelId, host.radius, host.vertices);
    this.segments = new SegmentPreview(host.modelId, this.api, host.radius, host.vertices, () => host.highlightChanged());
    this.hovered = null; // the pointer over the view (segment tool), followed once a frame
    this.tool = null;
    this.mode = 'replace';
    this.background = false;
    this.brushes = { markup: 10, heavy_lasso: 28 };
    this.group = null; // markup strokes on one view: {key, strokes, drafted, pending}
    this.openPart = null;
    this.inFlight = false; // a mask being encoded or a request running
    this.hint = '';
    this.error = '';
    this.tools = new SelectTools(
      {
        setTool: (t) => this.setTool(t),
        setMode: (m) => this.setMode(m),
        setBackground: (on) => {
          this.background = on;
          this.render();
        },
        setBrush: (px) => {
          if (this.tool in this.brushes) this.brushes[this.tool] = px;
          this.render();
        },
        undo: () => this.undo(),
        confirm: () => this.confirm(),
        cancel: () => this.cancel(),
        editRegion: () => this.editRegion(),
        setScale: (scale) => {
          this.segments.setScale(scale);
          this.render();
        },
      },
      { brush: this.brushes.heavy_lasso },
    );
    this.layer = new StrokeLayer(stage, {
      brush: (e) => this.brush(e),
      onStroke: (s) => this.stroke(s),
      onClick: (p, keys) => this.click(p, keys),
      onHover: (p) => this.hover(p),
    });
    // The step opens in the view's drawer (the viewer adopts `assign.root`).
    this.assign = new AssignStep(stage, stage, this.api, {
      assigned: (partId) => host.contentsChanged(partId),
      closed: (partId) => {
        this.render();
        host.assignDone(partId);
      },
    });
    // Escape: drops the stroke being drawn, else ends the assign step (unless it is pressed in
    // one of the step's fields holding typed text), else cancels the selection. A key used here
    // is marked (preventDefault) so that the viewer does not also close its panel.
    this.onKey = (e) => {
      if (e.key !== 'Escape' || e.defaultPrevented) return;
      if (this.layer.abort()) {
        e.preventDefault();
        return;
      }
      if (this.assign.isOpen()) {
        if (this.assign.holdsText(e.target)) return;
        e.preventDefault();
        this.assign.close();
      } else if (this.tool !== null || this.session.stack.length || this.session.partId !== null) {
        e.preventDefault();
        this.cancel();
      }
    };
    document.addEventListener('keydown', this.onKey);
    this.render();
  }

  /** The toolbar group's element. */
  get element() {
    return this.tools.root;
  }

  /** The surface point the point tool picked (its draft's anchor), or null. */
  pickedPoint() {
    const top = this.session.top;
    const d = top ? top.draft : null;
    return d && d.kind === 'point' && Array.isArray(d.center) ? d.center : null;
  }

  /** Whether a draft's highlight replaces the selected part's. */
  hasDraft() {
    return this.highlight.active;
  }

  /** The part open in the panel (null: none), for *Edit region*; another part's information
   * taking the panel's place ends the assign step. */
  setOpenPart(id) {
    this.openPart = id;
    if (id !== null) this.assign.hide();
    this.render();
  }

  /** What a drag draws now (null when no tool is active). */
  brush(e) {
    switch (this.tool) {
      case 'lasso':
        return { kind: 'lasso', width: 1 };
      case 'heavy_lasso':
        return { kind: 'heavy', width: this.brushes.heavy_lasso };
      case 'point':
        return { kind: 'point', width: 1 };
      case 'segment':
        return { kind: 'segment', width: 1 };
      case 'markup': {
        const bg = this.background || (e && (e.shiftKey || e.altKey || e.button === 2 || (e.buttons & 2) !== 0));
        return { kind: bg ? 'background' : 'foreground', width: this.brushes.markup };
      }
      default:
        return null;
    }
  }

  setTool(tool) {
    this.tool = tool;
    this.endGroup();
    this.hint = tool ? HINTS[tool] : '';
    if (tool === 'segment') {
      this.segments.load().then(() => {
        if (this.segments.unavailable && this.tool === 'segment') this.setError(this.segments.unavailable);
        this.render();
      });
    } else this.segments.hover(null);
    this.layer.setActive(tool !== null);
    this.host.pauseNavigation(tool !== null);
    this.render();
  }

  setMode(mode) {
    this.mode = mode;
    this.endGroup();
    this.render();
  }

  endGroup() {
    this.group = null;
    this.layer.keep([]);
  }

  setError(message) {
    this.error = message || '';
    this.tools.showError(this.error);
  }

  get busy() {
    return this.inFlight || this.session.busy;
  }

  render() {
    const top = this.session.top;
    this.tools.render({
      tool: this.tool,
      mode: this.mode,
      background: this.background,
      busy: this.busy,
      drafts: this.session.stack.length,
      draft: top ? top.draft : null,
      editing: this.session.partId,
      openPart: this.openPart,
      hint: this.hint,
      segments: {
        scale: this.segments.scale,
        scales: this.segments.scales ? this.segments.scales.length : 0,
        count: this.segments.count,
      },
    });
    if (this.tool in this.brushes) this.tools.brush.value = String(this.brushes[this.tool]);
    this.layer.setDisabled(this.busy && this.tool !== 'markup');
  }

  /** Shows the newest draft's highlight (or none). */
  showTop() {
    const top = this.session.top;
    this.highlight.show(top ? top.draft : null, top ? top.bitmap : null);
    this.host.highlightChanged();
  }

  /** The request camera: the current view at the mask's size. */
  requestCamera(view, size) {
    return { eye: view.eye, target: view.target, up: view.up, fovy: view.fovy, width: size.width, height: size.height };
  }

  async stroke(s) {
    const view = this.host.camera();
    if (this.tool === 'lasso') {
      if (s.points.length < 3 || polygonArea(s.points) < MIN_LASSO_AREA_PX) {
        this.hint = 'drag to draw the lasso around the region';
        this.render();
        return;
      }
      await this.send('lasso', [{ kind: 'lasso', points: s.points }], view);
    } else if (this.tool === 'heavy_lasso') {
      await this.send('heavy_lasso', [{ kind: 'heavy', points: s.points, width: s.width }], view);
    } else if (this.tool === 'markup') {
      const key = JSON.stringify(view);
      if (!this.group || this.group.key !== key) this.group = { key, strokes: [], drafted: false, pending: false };
      this.group.strokes.push({ kind: s.kind, points: s.points, width: s.width });
      this.layer.keep(this.group.strokes);
      await this.sendMarkup(view);
    }
  }

  async sendMarkup(view) {
    const g = this.group;
    const has = (kind) => g.strokes.some((s) => s.kind === kind);
    if (!has('foreground') || !has('background')) {
      this.hint = has('foreground') ? 'now paint the background around the region (Shift or right button)' : 'now paint on the region itself';
      this.render();
      return;
    }
    if (this.busy) {
      g.pending = true;
      return;
    }
    g.pending = false;
    const ok = await this.send('markup', g.strokes, view, { replaceTop: g.drafted });
    if (this.group !== g) return;
    if (ok) g.drafted = true;
    if (g.pending) await this.sendMarkup(view);
  }

  /** The pointer over the view: the segment tool previews the segment under it (once a frame). */
  hover(p) {
    if (this.tool !== 'segment') return;
    const pending = this.hovered !== null;
    this.hovered = p;
    if (p === null) {
      this.segments.hover(null);
      return;
    }
    if (pending) return;
    requestAnimationFrame(() => {
      const q = this.hovered;
      this.hovered = null;
      if (!q || this.tool !== 'segment') return;
      const hit = this.host.pick(q.clientX, q.clientY);
      this.segments.hover(hit ? hit.vertex : null);
    });
  }

  async click(p, keys = {}) {
    if ((this.tool !== 'point' && this.tool !== 'segment') || this.busy) return;
    const view = this.host.camera();
    const size = fitSize(view.width, view.height, await this.session.viewLimits());
    const point = [p.x * size.sx, p.y * size.sy];
    const camera = this.requestCamera(view, size);
    if (this.tool === 'point') {
      await this.request({ tool: 'point', mode: 'replace', camera, point }, null, {});
      return;
    }
    await this.segments.load();
    if (this.segments.scale === null) return;
    const mode = keys.shiftKey ? 'add' : keys.altKey ? 'subtract' : this.mode;
    await this.request({ tool: 'segment', mode, camera, point, scale: this.segments.scale }, null, {});
  }

  /** Rasterises `strokes` for the view, sends them; true when a draft came back. */
  async send(tool, strokes, view, options = {}) {
    const size = fitSize(view.width, view.height, await this.session.viewLimits());
    const request = { tool, mode: this.mode, camera: this.requestCamera(view, size) };
    return this.request(request, () => encodeMask(rasterise(strokes, size), size.width, size.height), options);
  }

  /** Sends one selection (`makeMask` resolves to the PNG, or is null); true on a draft. */
  async request(request, makeMask, options) {
    if (this.busy) return false;
    this.inFlight = true;
    this.setError('');
    this.render();
    try {
      const mask = makeMask ? await makeMask() : null;
      await this.session.select(request, mask, options);
      this.hint = '';
      this.showTop();
      return true;
    } catch (e) {
      if (!e.cancelled) this.setError(e.message);
    } finally {
      this.inFlight = false;
      this.render();
    }
    return false;
  }

  undo() {
    if (this.busy || !this.session.undo()) return;
    this.endGroup();
    this.setError('');
    this.showTop();
  }

  async confirm() {
    if (this.busy) return;
    this.setError('');
    let result;
    try {
      result = await this.session.confirm();
    } catch (e) {
      this.setError(e.message);
      return;
    }
    const { part, created } = result;
    this.endGroup();
    this.setTool(null);
    try {
      await this.host.partConfirmed(part, created);
    } finally {
      this.showTop();
    }
    this.assign.open(part.id, this.host.partTitle(part.id) || `Part ${part.id}`);
    this.render();
  }

  async cancel() {
    this.endGroup();
    this.layer.abort();
    this.setTool(null);
    this.setError('');
    await this.session.cancel();
    this.showTop();
  }

  async editRegion() {
    const id = this.openPart;
    if (id === null) return;
    this.endGroup();
    this.setError('');
    await this.session.edit(id);
    this.showTop();
    this.mode = 'add';
    this.setTool(this.tool || 'lasso');
  }

  /** The selection's state (tests). */
  state() {
    return {
      tool: this.tool,
      mode: this.mode,
      busy: this.busy,
      editing: this.session.partId,
      drafts: this.session.stack.map(({ draft: d, bitmap }) => ({
        id: d.id,
        vertex_count: d.vertex_count,
        bitmap: bitmap.size,
        tool: d.tool,
        mode: d.mode,
        part_id: d.part_id,
        base: d.base,
        selected_pixels: d.selected_pixels,
        width: d.width,
        height: d.height,
      })),
      matched: this.highlight.matched(),
      segment: this.segments.shown ? { ...this.segments.shown, matched: this.segments.highlight.matched() } : null,
      segmentScale: this.segments.scale,
      segmentPending: this.hovered !== null || this.segments.fetching,
      error: this.error,
      assigning: this.assign.isOpen() ? this.assign.partId : null,
      limits: { ...this.session.limits },
    };
  }
}
