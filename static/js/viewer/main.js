// The 3D viewer of the model page (progressive enhancement of `<div id="viewer">`): streams
// the model's patches view-dependently, draws them with three.js, shows the parts as callouts
// and exact highlights, opens their information in a drawer over the view (Escape closes it,
// its edge resizes it), lands on a linked part (the search that found it marked in its
// information), follows live edits; the reader picks the light and the background, and moves
// with mouse, touch or keyboard; editors also get the region-selection tools (../select/).

import * as THREE from 'three';
import { parseBinary, fromJson } from '../lod/table.js';
import { DEFAULT_SETTINGS, Streamer } from '../lod/stream.js';
import { Repository } from '../lumigraph/repository.js';
import { DecoderPool } from '../lod/workers.js';
import { PartStore } from '../parts/parts.js';
import { Callouts } from '../parts/callouts.js';
import { InfoPanel, Preview } from '../parts/panel.js';
import { listen } from '../parts/live.js';
import { SceneView } from './scene.js';
import { Navigation, framing } from './navigation.js';
import { pick, firstHitDistance } from './picking.js';
import { BACKGROUNDS, LIGHTING, choice, makeToolbar } from './toolbar.js';
import { Drawers } from './drawer.js';
import { clearQuery, linkedPart, linkedQuery, parseCamera, writePart } from './url.js';
import { SelectController } from '../select/controller.js';

const CALLOUT_INTERVAL_MS = 120;
/**
 * Projected error (pixels) of the sparse mesh's cut in image-based mode: coarser than local
 * rendering's, since the mesh only corrects the images (system paper §5.3).
 */
const IMAGE_PIXEL_ERROR = 8;
/** Live events in a burst (a part, then its contents) refresh the page's parts list once. */
const PART_LIST_DEBOUNCE_MS = 300;
/** Visibility passes (streaming occlusion feedback) at most this often while the view changes. */
const VISIBILITY_INTERVAL_MS = 150;
/** Drawn patches smaller than this on screen (sphere radius, CSS px) never count as hidden. */
const VISIBILITY_MIN_RADIUS_PX = 4;
const CLICK_SLOP_PX = 5;
const NEAR_PX = 12;
/** Where the reader's light and background are kept between visits. */
const LOOK_KEY = 'meshwiki-look';

function storedLook() {
  let look = {};
  try {
    look = JSON.parse(window.localStorage.getItem(LOOK_KEY) || '{}') || {};
  } catch {
    look = {};
  }
  return {
    lighting: look.lighting in LIGHTING ? look.lighting : 'headlight',
    background: look.background in BACKGROUNDS ? look.background : 'dark',
  };
}

async function loadTable(modelId) {
  const base = `/api/v1/models/${modelId}/lod`;
  const res = await fetch(`${base}?format=binary`, { credentials: 'same-origin' });
  if (res.ok) return { table: parseBinary(await res.arrayBuffer()), bytes: Number(res.headers.get('Content-Length')) || 0 };
  const json = await fetch(base, { credentials: 'same-origin' });
  if (!json.ok) throw new Error(`the model's hierarchy is not available (HTTP ${json.status})`);
  const text = await json.text();
  return { table: fromJson(JSON.parse(text)), bytes: text.length };
}

class Viewer {
  constructor(root, table, data, tableBytes) {
    this.root = root;
    this.table = table;
    this.modelId = data.model.id;
    this.started = performance.now();
    this.firstImageAt = null;
    this.tableBytes = tableBytes;
    this.frames = 0;
    this.hovered = null;
    this.selected = null;
    this.foveae = [];
    this.foveaMode = false;
    this.lastLayout = 0;
    this.layoutDirty = true;
    this.result = null;
    this.selection = null;

    root.replaceChildren();
    root.classList.add('viewer-live');
    this.stage = document.createElement('div');
    this.stage.className = 'viewer-stage';
    root.appendChild(this.stage);
    this.view = new SceneView(this.stage, table, { onChange: () => this.requestFrame() });
    this.overlay = document.createElement('div');
    this.overlay.className = 'viewer-overlay';
    // Callouts wait for the model: labels over an empty view point at nothing.
    this.overlay.hidden = true;
    this.stage.appendChild(this.overlay);
    this.loading = document.createElement('div');
    this.loading.className = 'viewer-loading';
    this.loading.setAttribute('role', 'status');
    this.loading.textContent = 'Loading the model…';
    this.stage.appendChild(this.loading);
    this.look = storedLook();
    this.applyLook();
    this.store = new PartStore(this.modelId, data.parts, table.radius, table.inputVertices);
    this.callouts = new Callouts(this.overlay, { onHover: (id) => this.setHover(id), onClick: (id) => this.select(id, true) });
    this.preview = new Preview(this.stage);
    this.panel = new InfoPanel(this.stage, { canEdit: !!data.can_edit, onClose: () => this.select(null, false) });
    this.drawers = new Drawers(root, this.stage, () => {
      this.layoutDirty = true;
      this.requestFrame();
    });
    this.drawers.adopt(this.panel.root);
    this.foveaLayer = document.createElement('div');
    this.foveaLayer.className = 'fovea-layer';
    this.overlay.appendChild(this.foveaLayer);

    this.pool = new DecoderPool();
    this.streamer = new Streamer({
      modelId: this.modelId,
      table,
      pool: this.pool,
      onLoad: (node, patch) => this.patchLoaded(node, patch),
      onEvict: (node) => {
        this.view.removePatch(node);
        this.store.removePatch(node);
        if (this.selection) {
          this.selection.highlight.removePatch(node);
          this.selection.segments.removePatch(node);
        }
      },
      onChange: () => this.requestFrame(),
    });
    // A model that keeps its geometry on the server streams no patch finer than its sparse mesh
    // (one patch per request: the whole file is refused) and is seen image-based.
    this.geometryFull = data.geometry?.full !== false;
    this.mode = 'model';
    this.repo = null;
    this.lumigraphStatus = null;
    if (!this.geometryFull) {
      this.streamer.cut.floor = data.geometry.sparse_error;
      this.streamer.setSettings({ batchBytes: 0 });
    }
    this.nav = new Navigation(
      this.view,
      table,
      () => {
        this.layoutDirty = true;
        this.requestFrame();
      },
      data.home || null,
    );
    this.toolbar = makeToolbar(root, this.streamer.settings, this.look, {
      reset: () => this.nav.reset(),
      toggleFoveaMode: (on) => {
        this.foveaMode = on;
        this.stage.classList.toggle('fovea-mode', on);
      },
      clearFoveae: () => this.setFoveae([]),
      setSettings: (changes) => {
        this.streamer.setSettings(changes);
        this.requestFrame();
      },
      setLook: (changes) => {
        this.look = { ...this.look, ...changes };
        try {
          window.localStorage.setItem(LOOK_KEY, JSON.stringify(this.look));
        } catch {
          /* private browsing: the choice lasts for the page */
        }
        this.applyLook();
        this.requestFrame();
      },
    });
    // The server's limits (GET /api/v1/config, embedded in the page).
    const limits = data.config?.view_limits;
    this.viewLimits = limits ? { maxSide: limits.max_side, maxPixels: limits.max_pixels } : null;
    this.selection = data.can_edit ? this.makeSelection() : null;
    if (this.selection) {
      this.toolbar.addGroup(this.selection.element);
      this.drawers.adopt(this.selection.assign.root);
    }
    this.markerLayer = document.createElement('div');
    this.markerLayer.className = 'fovea-layer';
    this.overlay.appendChild(this.markerLayer);
    this.store.onChange(() => this.partsChanged());
    this.bindPointer();
    this.bindKeys();
    new ResizeObserver(() => {
      this.layoutDirty = true;
      this.requestFrame();
    }).observe(this.stage);
    this.stopLive = listen(this.modelId, this.store, (ev) => this.liveEvent(ev));
    this.land();
    this.store.loadBitmaps();
    if (!this.geometryFull || new URLSearchParams(window.location.search).get('view') === 'image') this.setMode('image');
    this.offerModes();
    this.requestFrame();
  }

  /**
   * The model's image repository (GET /api/v1/models/{id}/lumigraph), asked for once:
   * `{ok, description}`, or `{ok: false, problem}`.
   */
  lumigraphDescription() {
    if (!this.describing) {
      this.describing = (async () => {
        try {
          const res = await fetch(`/api/v1/models/${this.modelId}/lumigraph`, { credentials: 'same-origin' });
          if (!res.ok) return { ok: false, problem: `HTTP ${res.status}` };
          return { ok: true, description: await res.json() };
        } catch (e) {
          const problem = String(e.message || e);
          console.warn('meshwiki viewer: image repository:', problem);
          return { ok: false, problem };
        }
      })();
    }
    return this.describing;
  }

  /**
   * The View menu's choice of geometry: full resolution, or image-based once the model has an
   * image repository; a model that keeps its geometry on the server says so instead.
   */
  async offerModes() {
    if (!this.geometryFull) {
      const note = document.createElement('p');
      note.className = 'viewer-keys';
      note.textContent = 'Image-based view: the full-resolution geometry of this model stays on the server.';
      this.toolbar.addSetting(note);
      return;
    }
    const { ok, description } = await this.lumigraphDescription();
    if (!ok || description.status !== 'ready') return;
    this.toolbar.addSetting(
      choice('Geometry', 'viewer-geometry', [['model', 'Full resolution'], ['image', 'Image-based (little data, as over a slow network)']], this.mode, (v) => this.setMode(v)),
    );
  }

  /**
   * `image`: the sparse mesh shaded by the model's image repository (Grid-Lumigraph; its own
   * colours where no image saw it, or while the repository is not built); `model`: the patches
   * at full resolution (refused for a model that keeps its geometry on the server).
   */
  async setMode(mode) {
    if (mode === 'image') {
      if (this.mode !== 'image') this.modelPixelError = this.streamer.settings.pixelError;
      this.mode = 'image';
      this.root.dataset.mode = 'image';
      this.streamer.setSettings({ pixelError: IMAGE_PIXEL_ERROR });
      if (!this.repo) {
        const { ok, description: d, problem } = await this.lumigraphDescription();
        this.lumigraphStatus = ok ? d.status : problem;
        if (ok && d.status === 'ready' && !this.repo) this.repo = new Repository(this.modelId, d, { onChange: () => this.requestFrame(), settings: this.streamer.settings });
      }
      if (this.mode === 'image' && this.repo && this.view.lumigraph !== this.repo) this.view.setLumigraph(this.repo);
    } else if (this.geometryFull) {
      this.mode = 'model';
      this.root.dataset.mode = 'model';
      this.view.setLumigraph(null);
      this.streamer.setSettings({ pixelError: this.modelPixelError ?? DEFAULT_SETTINGS.pixelError });
    }
    this.requestFrame();
    return this.mode;
  }

  /** Applies the reader's light and background. */
  applyLook() {
    const l = LIGHTING[this.look.lighting];
    this.view.setLighting(l.mode, l.ambient);
    this.view.setBackground(BACKGROUNDS[this.look.background].color);
    this.root.dataset.background = this.look.background;
  }

  /** The region-selection tools (editors), drawing on this view. */
  makeSelection() {
    return new SelectController(this.root, this.stage, {
      modelId: this.modelId,
      radius: this.table.radius,
      vertices: this.table.inputVertices,
      limits: this.viewLimits,
      camera: () => this.cameraState(),
      pauseNavigation: (on) => {
        this.nav.controls.enabled = !on;
        this.stage.classList.toggle('selecting', on);
        if (on) this.setHover(null);
      },
      highlightChanged: () => this.markAll(),
      partConfirmed: async (part) => {
        this.refreshPartList();
        await this.store.reloadPart(part.id);
        // Highlighted, its information opens once the assign step is done.
        this.panel.close();
        this.select(part.id, false);
      },
      assignDone: (id) => {
        if (!this.store.parts.has(id)) return;
        this.select(id, true);
        // The panel takes the step's place, and the keyboard focus the step had.
        this.panel.root.focus({ preventScroll: true });
      },
      contentsChanged: async (id) => {
        this.refreshPartList();
        await this.store.reloadContents(id);
        if (this.panel.partId === id) this.panel.open(id, this.store);
      },
      partTitle: (id) => this.store.title(id),
      pick: (x, y) => pick(this.view, x, y),
    });
  }

  /** Initial camera: the URL's, else the linked part's best view, else the home view. */
  land() {
    const fromUrl = parseCamera(window.location.hash);
    const part = linkedPart(window.location.search);
    if (fromUrl) this.nav.set(fromUrl);
    else if (part && this.store.parts.has(part)) this.nav.set(this.bestView(part));
    else this.nav.set(this.nav.home);
    if (part && this.store.parts.has(part)) {
      this.panel.setHighlight(part, linkedQuery(window.location.search));
      this.select(part, true);
      if (!fromUrl) {
        // Once the part's vertices are known, frame it again from its real extent and normal.
        this.store.loadBitmaps().then(() => {
          const e = this.store.parts.get(part);
          if (e && !e.part.camera && this.selected === part) this.nav.animateTo(this.bestView(part), 300);
        });
      }
    }
  }

  /** The part's best view: its stored camera, else a framing of its centre and extent. */
  bestView(id) {
    const e = this.store.parts.get(id);
    if (e.part.camera) return e.part.camera;
    const c = e.part.center;
    const normal = this.store.normal(id);
    const out = c.map((v, k) => v - this.table.center[k]);
    const dir = normal || (Math.hypot(...out) > 1e-9 ? out : [0, 0, 1]);
    const up = Math.abs(dir[1]) / (Math.hypot(...dir) || 1) > 0.9 ? [0, 0, 1] : [0, 1, 0];
    return framing(c, Math.max(this.store.extent(id) * 1.6, this.table.radius * 0.02), dir, up);
  }

  patchLoaded(node, patch) {
    this.view.addPatch(node, patch);
    this.store.addPatch(node, patch);
    if (this.selection) {
      this.selection.highlight.addPatch(node, patch);
      this.selection.segments.addPatch(node, patch);
    }
    this.markNode(node);
    this.layoutDirty = true;
    this.requestFrame();
  }

  requestFrame() {
    if (this.pending) return;
    this.pending = requestAnimationFrame(() => {
      this.pending = null;
      this.frame();
    });
  }

  cameraState() {
    const c = this.nav.get();
    return { ...c, width: this.view.width, height: this.view.height };
  }

  frame() {
    if (this.view.resize()) this.layoutDirty = true;
    const result = this.streamer.update(this.cameraState());
    this.result = result;
    if (this.repo && this.mode === 'image') this.repo.update(this.cameraState(), result.draw, this.table, (node) => this.view.surfacePoints(node));
    this.view.setDrawn(result.draw);
    const drafting = this.selection !== null && this.selection.hasDraft();
    const channel = this.hovered !== null ? 1 : this.selected !== null || drafting ? 2 : 0;
    this.view.render(channel);
    this.frames++;
    if (result.draw.length > 0 && this.firstImageAt === null) {
      this.firstImageAt = performance.now() - this.started;
      this.loading.hidden = true;
      this.overlay.hidden = false;
      this.layoutDirty = true;
    }
    const now = performance.now();
    if (this.layoutDirty) {
      if (now - this.lastLayout >= CALLOUT_INTERVAL_MS) {
        this.layoutDirty = false;
        this.lastLayout = now;
        this.layoutCallouts();
      } else {
        clearTimeout(this.layoutTimer);
        this.layoutTimer = setTimeout(() => this.requestFrame(), CALLOUT_INTERVAL_MS);
      }
    }
    this.drawFoveae();
    this.drawMarkers();
    this.visibility(now);
    this.status();
  }

  /** Tells the streamer which drawn patches the frame shows no pixel of (throttled). */
  visibility(now) {
    if (!this.streamer.visibilityStale()) return;
    if (this.result.draw.length === 0) {
      // Nothing drawn, nothing to hide.
      this.streamer.setVisibility(this.cameraState(), new Set(), VISIBILITY_MIN_RADIUS_PX);
      return;
    }
    const wait = (this.lastVisibility || 0) + VISIBILITY_INTERVAL_MS - now;
    if (wait > 0) {
      clearTimeout(this.visibilityTimer);
      this.visibilityTimer = setTimeout(() => this.requestFrame(), wait);
      return;
    }
    this.lastVisibility = now;
    this.streamer.setVisibility(this.cameraState(), this.view.visibleNodes(), VISIBILITY_MIN_RADIUS_PX);
    // A pass that changed nothing still settles the view: run the cut once more either way.
    this.requestFrame();
  }

  /** Screen position (CSS px) and depth of a world point, or null behind the camera. */
  project(p) {
    const v = new THREE.Vector3(p[0], p[1], p[2]);
    const cam = this.view.camera;
    const depth = v.clone().sub(cam.position).dot(cam.getWorldDirection(new THREE.Vector3()));
    if (depth <= 0) return null;
    v.project(cam);
    return { x: (v.x * 0.5 + 0.5) * this.view.width, y: (-v.y * 0.5 + 0.5) * this.view.height, depth };
  }

  layoutCallouts() {
    const items = [];
    const pixelScale = this.view.height / (2 * Math.tan((this.view.camera.fov * Math.PI) / 360));
    const eye = this.view.camera.position;
    const candidates = [];
    // Labels stay in the part of the view the drawer leaves uncovered.
    const width = Math.max(1, this.view.width - this.drawers.covered());
    for (const e of this.store.parts.values()) {
      const s = this.project(e.part.center);
      if (!s || s.x < 0 || s.y < 0 || s.x > width || s.y > this.view.height) continue;
      const extent = this.store.extent(e.id);
      candidates.push({ e, s, extent, radiusPx: (extent * pixelScale) / s.depth });
    }
    candidates.sort((a, b) => b.radiusPx - a.radiusPx);
    for (const [k, c] of candidates.entries()) {
      const important = c.e.id === this.selected || c.e.id === this.hovered;
      if (k >= 60 && !important) break;
      const p = new THREE.Vector3(...c.e.part.center);
      const dist = p.distanceTo(eye);
      const hit = firstHitDistance(this.view, p);
      const tolerance = Math.max(c.extent * 0.5, this.table.radius * 0.003);
      if (hit < dist - tolerance) continue;
      items.push({
        id: c.e.id,
        title: this.store.title(c.e.id),
        x: c.s.x,
        y: c.s.y,
        radiusPx: c.radiusPx,
        priority: (c.e.id === this.selected ? 1e9 : 0) + (c.e.id === this.hovered ? 1e8 : 0) + c.radiusPx,
      });
    }
    this.callouts.layout(items, width, this.view.height, { selected: this.selected, hovered: this.hovered });
  }

  drawFoveae() {
    this.foveaLayer.replaceChildren();
    for (const f of this.foveae) {
      const s = this.project(f);
      if (!s) continue;
      const dot = document.createElement('div');
      dot.className = 'fovea-marker';
      dot.style.transform = `translate(${Math.round(s.x - 6)}px, ${Math.round(s.y - 6)}px)`;
      this.foveaLayer.appendChild(dot);
    }
  }

  /** The status in plain words; the streaming figures go under View › Advanced. */
  status() {
    const r = this.result;
    const s = this.streamer.stats;
    const refining = r.pending > 0 || r.inFlight > 0;
    const n = this.foveae.length;
    let words;
    if (this.firstImageAt === null) words = 'Loading the model…';
    else if (refining) words = 'Sharpening the view…';
    else words = 'Sharp: every detail this view can show';
    if (n) words += ` · ${n} focus point${n > 1 ? 's' : ''}`;
    this.toolbar.setStatus(words);
    this.toolbar.setFoveaCount(n);
    const mb = (s.bytes / 1e6).toFixed(1);
    const rate = (this.streamer.bandwidth() / 1e6).toFixed(1);
    const quality = refining ? 'refining' : `≤ ${this.streamer.settings.pixelError} px`;
    this.toolbar.setDetails(`${r.draw.length} patches · ${r.triangles.toLocaleString()} triangles · ${mb} MB loaded at ${rate} MB/s · ${quality}`);
  }

  /** The marker of a picked point (the point tool's draft), which a tint of one vertex cannot show. */
  drawMarkers() {
    this.markerLayer.replaceChildren();
    const p = this.selection ? this.selection.pickedPoint() : null;
    if (!p) return;
    const s = this.project(p);
    if (!s) return;
    const dot = document.createElement('div');
    dot.className = 'point-marker';
    dot.dataset.point = 'draft';
    dot.style.transform = `translate(${Math.round(s.x - 8)}px, ${Math.round(s.y - 8)}px)`;
    this.markerLayer.appendChild(dot);
  }

  // --- highlights -------------------------------------------------------------------------

  markNode(node) {
    const mesh = this.view.meshes.get(node);
    if (!mesh) return;
    const attr = mesh.geometry.getAttribute('aMark');
    const marks = attr.array;
    const had = mesh.userData.marked;
    // A selection draft takes the selected part's tint (editing shows the draft, not the part).
    const drafting = this.selection !== null && this.selection.hasDraft();
    // The segment previewed under the cursor (segment tool) takes the hover tint.
    const segment = this.selection !== null ? this.selection.segments.verticesIn(node) : null;
    if (!had && this.hovered === null && this.selected === null && !drafting && !segment) return;
    marks.fill(0);
    let any = false;
    const draft = drafting ? this.selection.highlight.verticesIn(node) : null;
    if (draft) {
      for (const v of draft) marks[v * 2 + 1] = 1;
      any = true;
    }
    if (segment) {
      for (const v of segment) marks[v * 2] = 1;
      any = true;
    }
    for (const [id, channel] of [
      [this.hovered, 0],
      [drafting ? null : this.selected, 1],
    ]) {
      if (id === null) continue;
      const verts = this.store.verticesIn(node, id);
      if (!verts) continue;
      for (const v of verts) marks[v * 2 + channel] = 1;
      any = true;
    }
    mesh.userData.marked = any;
    if (any || had) attr.needsUpdate = true;
  }

  markAll() {
    for (const node of this.view.meshes.keys()) this.markNode(node);
    this.requestFrame();
  }

  setHover(id) {
    if (id === this.hovered) return;
    this.hovered = id;
    this.root.dataset.hovered = id === null ? '' : String(id);
    if (id === null) this.preview.hide();
    this.markAll();
    this.layoutDirty = true;
  }

  /** Selects part `id` (null: none); `open` opens its information. */
  select(id, open) {
    this.selected = id;
    this.root.dataset.selected = id === null ? '' : String(id);
    if (this.panel.highlight && this.panel.highlight.partId !== id) {
      // Another part (or none): the search that led here no longer applies.
      this.panel.setHighlight(null, null);
      clearQuery();
    }
    writePart(id);
    if (id === null) this.panel.close();
    else if (open) {
      // The panel shows what the hover card previewed.
      this.preview.hide();
      this.panel.open(id, this.store);
    }
    if (this.selection) this.selection.setOpenPart(this.panel.partId);
    this.markAll();
    this.layoutDirty = true;
  }

  partsChanged() {
    this.callouts.prune(new Set(this.store.parts.keys()));
    if (this.selected !== null && !this.store.parts.has(this.selected)) this.select(null, false);
    if (this.hovered !== null && !this.store.parts.has(this.hovered)) this.setHover(null);
    this.markAll();
    this.layoutDirty = true;
    this.requestFrame();
  }

  liveEvent(ev) {
    this.refreshPartList();
    if (this.panel.isOpen() && this.panel.partId !== null) {
      const e = this.store.parts.get(this.panel.partId);
      const concerned = ev.part_id === this.panel.partId || (ev.content_id && e && e.contents.some((c) => c.id === ev.content_id));
      if (concerned) this.panel.open(this.panel.partId, this.store);
    }
  }

  /** Re-renders the page's server-side list of parts (below the viewer) after a change. */
  refreshPartList() {
    clearTimeout(this.partListTimer);
    this.partListTimer = setTimeout(async () => {
      const list = document.getElementById('model-parts');
      if (!list) return;
      try {
        const res = await fetch(window.location.pathname, { credentials: 'same-origin' });
        if (!res.ok) return;
        const doc = new DOMParser().parseFromString(await res.text(), 'text/html');
        const fresh = doc.getElementById('model-parts');
        if (fresh) list.replaceWith(document.adoptNode(fresh));
      } catch (e) {
        console.warn('meshwiki viewer: parts list:', e.message || e);
      }
    }, PART_LIST_DEBOUNCE_MS);
  }

  // --- pointer ----------------------------------------------------------------------------

  /** The part under or near client point (x, y): exact vertex sets, then a ring of samples. */
  partAt(clientX, clientY) {
    const hit = pick(this.view, clientX, clientY);
    if (hit) {
      const ids = this.store.partsWithAny(hit.ids);
      if (ids.length) return { id: ids[0], hit };
    }
    for (let k = 0; k < 8; k++) {
      const a = (k * Math.PI) / 4;
      const h = pick(this.view, clientX + Math.cos(a) * NEAR_PX, clientY + Math.sin(a) * NEAR_PX);
      if (!h) continue;
      const ids = this.store.partsWithAny(h.ids);
      if (ids.length) return { id: ids[0], hit: hit || h };
    }
    const rect = this.view.canvas.getBoundingClientRect();
    for (const e of this.store.parts.values()) {
      if (e.part.kind !== 'point') continue;
      const s = this.project(e.part.center);
      if (s && Math.hypot(s.x - (clientX - rect.left), s.y - (clientY - rect.top)) <= NEAR_PX + 2) return { id: e.id, hit };
    }
    return { id: null, hit };
  }

  bindPointer() {
    const canvas = this.view.canvas;
    let down = null;
    let hoverQueued = null;
    canvas.addEventListener('pointerdown', (e) => {
      down = { x: e.clientX, y: e.clientY, t: performance.now() };
    });
    canvas.addEventListener('pointerup', (e) => {
      if (!down) return;
      const moved = Math.hypot(e.clientX - down.x, e.clientY - down.y);
      down = null;
      if (moved > CLICK_SLOP_PX || e.button !== 0) return;
      this.click(e);
    });
    canvas.addEventListener('pointermove', (e) => {
      if (e.buttons !== 0) return;
      if (hoverQueued) {
        hoverQueued = { x: e.clientX, y: e.clientY };
        return;
      }
      hoverQueued = { x: e.clientX, y: e.clientY };
      requestAnimationFrame(() => {
        const q = hoverQueued;
        hoverQueued = null;
        const { id } = this.partAt(q.x, q.y);
        this.setHover(id);
        const rect = this.stage.getBoundingClientRect();
        // No hover card over the part whose information the panel already shows.
        if (id !== null && !(this.panel.isOpen() && this.panel.partId === id)) this.preview.show(id, this.store, q.x - rect.left, q.y - rect.top, rect.width);
        else this.preview.hide();
        this.requestFrame();
      });
    });
    canvas.addEventListener('pointerleave', () => {
      this.setHover(null);
      this.requestFrame();
    });
  }

  /** Escape closes the information panel (after the selection tools had their say: they
   * mark the keys they use with preventDefault); focus inside the panel returns to the part's
   * callout, else to the view. Escape in a text field outside the panel stays the field's. */
  bindKeys() {
    document.addEventListener('keydown', (e) => {
      if (e.key !== 'Escape' || e.defaultPrevented || !this.panel.isOpen()) return;
      const t = e.target;
      const inPanel = t instanceof Node && this.panel.root.contains(t);
      if (!inPanel && t instanceof Element && t.closest('input, textarea, select, [contenteditable]')) return;
      e.preventDefault();
      const id = this.panel.partId;
      const hadFocus = this.panel.root.contains(document.activeElement);
      this.select(null, false);
      if (hadFocus) {
        const label = this.overlay.querySelector(`.callout[data-part-id="${id}"]`);
        (label && !label.hidden ? label : this.view.canvas).focus();
      }
    });
  }

  click(e) {
    if (this.foveaMode || e.ctrlKey || e.altKey || e.metaKey) {
      const hit = pick(this.view, e.clientX, e.clientY);
      if (hit) this.setFoveae([...this.foveae, hit.point.toArray()]);
      if (this.foveaMode) {
        this.foveaMode = false;
        this.stage.classList.remove('fovea-mode');
        this.toolbar.setFoveaMode(false);
      }
      return;
    }
    const { id } = this.partAt(e.clientX, e.clientY);
    if (id !== null) this.select(id, true);
    else if (this.selected !== null) this.select(null, false);
  }

  setFoveae(points) {
    this.foveae = points;
    this.streamer.setFoveae(points);
    this.requestFrame();
  }

  /** Figures for tests and the streaming bench. */
  stats() {
    const r = this.result || { draw: [], triangles: 0, maxError: 0, foveaError: 0, pending: 0, requests: [] };
    // Drawn patches with an atlas (a normal map), and those whose atlas (normal map) is
    // decoded, so drawn with it.
    const drawnMeshes = r.draw.map((n) => this.view.meshes.get(n)).filter((m) => m);
    const textured = drawnMeshes.filter((m) => m.userData.textured);
    const mapped = drawnMeshes.filter((m) => m.userData.mapped);
    return {
      ...this.streamer.stats,
      tableBytes: this.tableBytes,
      drawn: r.draw.length,
      texturesWanted: textured.length,
      texturesReady: textured.filter((m) => m.userData.texture).length,
      normalMapsWanted: mapped.length,
      normalMapsReady: mapped.filter((m) => m.userData.normalMap).length,
      triangles: r.triangles,
      maxError: r.maxError,
      maxRatio: r.maxRatio,
      foveaError: r.foveaError,
      pending: r.pending,
      wanted: r.requests.length,
      hiddenDrawn: r.draw.filter((n) => this.streamer.occluded[n]).length,
      inFlight: this.streamer.inFlight.size,
      settled: this.streamer.settled() && (this.mode !== 'image' || !this.repo || this.repo.settled()),
      mode: this.mode,
      lumigraphStatus: this.lumigraphStatus,
      lumigraph: this.repo ? { ...this.repo.stats, slots: this.repo.slots.filter((s) => s !== null).length, layers: this.repo.loaded.size } : null,
      resident: this.streamer.cache.entries.size,
      residentBytes: this.streamer.cache.bytes,
      throughput: this.streamer.throughput.estimate(),
      firstImageMs: this.firstImageAt,
      frames: this.frames,
      fileBytes: this.table.fileBytes,
      leafBytes: this.table.leafBytes,
      hovered: this.hovered,
      selected: this.selected,
      callouts: this.callouts.shownIds(),
    };
  }
}

async function boot() {
  const root = document.getElementById('viewer');
  if (!root || root.dataset.enabled !== 'true') return;
  const dataEl = document.getElementById('viewer-data');
  const placeholder = root.querySelector('.viewer-placeholder');
  try {
    const data = JSON.parse(dataEl.textContent);
    const canvasProbe = document.createElement('canvas');
    if (!canvasProbe.getContext('webgl2')) throw new Error('this browser has no WebGL2');
    const { table, bytes } = await loadTable(data.model.id);
    const viewer = new Viewer(root, table, data, bytes);
    window.meshwikiViewer = {
      stats: () => viewer.stats(),
      camera: () => viewer.nav.get(),
      setCamera: (c) => viewer.nav.set(c),
      setFoveae: (points) => viewer.setFoveae(points),
      /** Measures `foveaError` at these points instead of the foveae (bench). */
      setProbes: (points) => {
        viewer.streamer.probes = points;
        viewer.requestFrame();
      },
      setSettings: (s) => {
        viewer.streamer.setSettings(s);
        viewer.requestFrame();
      },
      select: (id) => viewer.select(id, true),
      /** `image` or `model` (see Viewer.setMode); resolves to the mode in force. */
      setMode: (mode) => viewer.setMode(mode),
      /** Image-based mode: shade with the repository's images (true) or the sparse mesh's own
       * normals and colours (false; tests compare the two). */
      setImageShading: (on) => {
        viewer.view.setLumigraph(on && viewer.mode === 'image' ? viewer.repo : null);
        viewer.requestFrame();
      },
      /** The region selection's state (editors; null for viewers). */
      selection: () => (viewer.selection ? viewer.selection.state() : null),
      /** Mean milliseconds of `n` frames rendered back to back, each finished on the GPU (bench). */
      timeFrames: (n) => {
        const gl = viewer.view.renderer.getContext();
        const px = new Uint8Array(4);
        const t = performance.now();
        for (let i = 0; i < n; i++) {
          viewer.frame();
          gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, px);
        }
        return (performance.now() - t) / n;
      },
      /** Renders a frame now and returns it as a PNG data URL (tests, bench). */
      snapshot: () => {
        viewer.frame();
        return viewer.view.canvas.toDataURL('image/png');
      },
      project: (p) => viewer.project(p),
      partScreen: (id) => {
        const e = viewer.store.parts.get(id);
        return e ? viewer.project(e.part.center) : null;
      },
      parts: () => [...viewer.store.parts.values()].map((e) => ({ id: e.id, title: viewer.store.title(e.id), bitmap: !!e.bitmap, matched: e.matched })),
      table: () => ({ nodeCount: table.nodeCount, fileBytes: table.fileBytes, leafBytes: table.leafBytes, center: table.center, radius: table.radius }),
    };
    root.dataset.ready = 'true';
  } catch (e) {
    console.error('meshwiki viewer:', e);
    if (placeholder) placeholder.textContent = `The 3D view cannot be shown: ${e.message || e}`;
    root.dataset.error = String(e.message || e);
  }
}

boot();
