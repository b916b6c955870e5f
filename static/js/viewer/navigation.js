// Navigation: orbit, pan and zoom with mouse, wheel and touch (three's OrbitControls: one
// finger orbits, two pan and pinch-zoom) and with the keyboard on the focused view (arrows
// turn, Shift+arrows move, + and − zoom, Home resets), double-click to centre on the surface
// point, reset to the home view (the side the model's thumbnail shows), animated camera
// moves, and the camera kept in the URL.

import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { pick } from './picking.js';
import { writeCamera } from './url.js';

const FOVY = 40;
/** One arrow key turns the view by this many degrees. */
const KEY_TURN_DEG = 7.5;
/** One Shift+arrow moves the view by this fraction of the target's distance. */
const KEY_PAN = 0.08;
/** One + or − brings the eye this much closer or farther. */
const KEY_ZOOM = 0.8;

/** The home view: the model's bounding sphere framed from `home`'s direction (the server's
 * choice, the side its thumbnail shows), else from +z. */
export function homeView(model, home) {
  if (!home) return framing(model.center, model.radius);
  const dir = home.eye.map((v, k) => v - home.target[k]);
  if (!(Math.hypot(...dir) > 0)) return framing(model.center, model.radius);
  return framing(model.center, model.radius, dir, home.up);
}

/** `v` rotated by `angle` (radians) about the unit axis `k` (Rodrigues). */
function rotate(v, k, angle) {
  const c = Math.cos(angle);
  const s = Math.sin(angle);
  const dot = v[0] * k[0] + v[1] * k[1] + v[2] * k[2];
  const cross = [k[1] * v[2] - k[2] * v[1], k[2] * v[0] - k[0] * v[2], k[0] * v[1] - k[1] * v[0]];
  return v.map((x, i) => x * c + cross[i] * s + k[i] * dot * (1 - c));
}

function unit(v) {
  const l = Math.hypot(...v) || 1;
  return v.map((x) => x / l);
}

/** A camera {eye, target, up, fovy} that frames a sphere from direction `dir`. */
export function framing(center, radius, dir = [0, 0, 1], up = [0, 1, 0], fovy = FOVY) {
  const l = Math.hypot(dir[0], dir[1], dir[2]) || 1;
  const distance = (radius / Math.sin((fovy * Math.PI) / 360)) * 1.05;
  return {
    eye: center.map((c, k) => c + (dir[k] / l) * distance),
    target: [...center],
    up: [...up],
    fovy,
  };
}

export class Navigation {
  /**
   * @param {import('./scene.js').SceneView} view
   * @param {{center: number[], radius: number}} model bounds of the model
   * @param {() => void} onChange called when the camera moved
   * @param {{eye: number[], target: number[], up: number[]}|null} [home] the server's first view
   */
  constructor(view, model, onChange, home = null) {
    this.view = view;
    this.model = model;
    this.onChange = onChange;
    this.home = homeView(model, home);
    this.animation = null;
    this.urlTimer = null;
    this.makeControls([0, 1, 0]);
    this.onDoubleClick = (e) => this.centreOn(e.clientX, e.clientY);
    view.canvas.addEventListener('dblclick', this.onDoubleClick);
    this.onKey = (e) => this.key(e);
    view.canvas.addEventListener('keydown', this.onKey);
  }

  /** Keyboard control of the focused view; true when the key was used. */
  key(e) {
    if (e.defaultPrevented || e.ctrlKey || e.metaKey || e.altKey || !this.controls.enabled) return false;
    const c = this.get();
    const offset = c.eye.map((v, k) => v - c.target[k]);
    const dist = Math.hypot(...offset);
    const forward = unit(offset.map((v) => -v));
    const right = unit([forward[1] * c.up[2] - forward[2] * c.up[1], forward[2] * c.up[0] - forward[0] * c.up[2], forward[0] * c.up[1] - forward[1] * c.up[0]]);
    const upScreen = unit([right[1] * forward[2] - right[2] * forward[1], right[2] * forward[0] - right[0] * forward[2], right[0] * forward[1] - right[1] * forward[0]]);
    const turn = (KEY_TURN_DEG * Math.PI) / 180;
    let next = null;
    const arrows = { ArrowLeft: [-1, 0], ArrowRight: [1, 0], ArrowUp: [0, 1], ArrowDown: [0, -1] };
    if (e.key in arrows) {
      const [x, y] = arrows[e.key];
      if (e.shiftKey) {
        const d = right.map((v, k) => (v * x + upScreen[k] * y) * dist * KEY_PAN);
        next = { ...c, eye: c.eye.map((v, k) => v + d[k]), target: c.target.map((v, k) => v + d[k]) };
      } else if (x !== 0) {
        // Around the up axis, as dragging sideways turns the model.
        const o = rotate(offset, unit(c.up), -x * turn);
        next = { ...c, eye: c.target.map((v, k) => v + o[k]) };
      } else {
        // Over the top, not past it: the view stays upright.
        const o = rotate(offset, right, y * turn);
        const upness = o.reduce((a, v, k) => a + v * c.up[k], 0) / dist;
        if (Math.abs(upness) < 0.995) next = { ...c, eye: c.target.map((v, k) => v + o[k]) };
        else next = c;
      }
    } else if (e.key === '+' || e.key === '=' || e.key === '-' || e.key === '_') {
      const f = e.key === '+' || e.key === '=' ? KEY_ZOOM : 1 / KEY_ZOOM;
      const d = Math.min(this.controls.maxDistance, Math.max(this.controls.minDistance, dist * f));
      next = { ...c, eye: c.target.map((v, k) => v + (offset[k] / dist) * d) };
    } else if (e.key === 'Home' || e.key === '0') {
      this.reset();
      e.preventDefault();
      return true;
    }
    if (!next) return false;
    e.preventDefault();
    this.stopAnimation();
    this.set(next);
    return true;
  }

  makeControls(up) {
    if (this.controls) this.controls.dispose();
    this.view.camera.up.set(up[0], up[1], up[2]).normalize();
    const c = new OrbitControls(this.view.camera, this.view.canvas);
    c.enableDamping = false;
    c.screenSpacePanning = true;
    c.zoomToCursor = true;
    c.minDistance = this.model.radius * 1e-4;
    c.maxDistance = this.model.radius * 50;
    c.addEventListener('change', () => this.changed());
    c.addEventListener('start', () => this.stopAnimation());
    this.controls = c;
    this.up = [...up];
  }

  /** The current camera as {eye, target, up, fovy}. */
  get() {
    const cam = this.view.camera;
    return {
      eye: cam.position.toArray(),
      target: this.controls.target.toArray(),
      up: cam.up.toArray(),
      fovy: cam.fov,
    };
  }

  /** Sets the camera at once. */
  set(c) {
    const cam = this.view.camera;
    const upChanged = c.up.some((v, k) => Math.abs(v - this.up[k]) > 1e-9);
    if (upChanged) this.makeControls(c.up);
    cam.position.set(c.eye[0], c.eye[1], c.eye[2]);
    cam.fov = c.fovy;
    cam.updateProjectionMatrix();
    this.controls.target.set(c.target[0], c.target[1], c.target[2]);
    cam.lookAt(this.controls.target);
    this.controls.update();
    this.changed();
  }

  /** Moves the camera smoothly to `c` over `ms` milliseconds. */
  animateTo(c, ms = 450) {
    this.stopAnimation();
    const from = this.get();
    if (c.up.some((v, k) => Math.abs(v - from.up[k]) > 1e-9) || ms <= 0) {
      this.set(c);
      return;
    }
    const start = performance.now();
    const lerp = (a, b, t) => a.map((v, k) => v + (b[k] - v) * t);
    const step = (now) => {
      const t = Math.min(1, (now - start) / ms);
      const s = t * t * (3 - 2 * t);
      this.set({ eye: lerp(from.eye, c.eye, s), target: lerp(from.target, c.target, s), up: c.up, fovy: from.fovy + (c.fovy - from.fovy) * s });
      this.animation = t < 1 ? requestAnimationFrame(step) : null;
    };
    this.animation = requestAnimationFrame(step);
  }

  stopAnimation() {
    if (this.animation) cancelAnimationFrame(this.animation);
    this.animation = null;
  }

  /** Double-click: look at the surface point under the cursor from the same distance. */
  centreOn(clientX, clientY) {
    const hit = pick(this.view, clientX, clientY);
    if (!hit) return;
    const c = this.get();
    const p = hit.point.toArray();
    const dist = Math.hypot(c.eye[0] - p[0], c.eye[1] - p[1], c.eye[2] - p[2]);
    const dir = c.target.map((v, k) => v - c.eye[k]);
    const l = Math.hypot(...dir) || 1;
    this.animateTo({ eye: p.map((v, k) => v - (dir[k] / l) * dist), target: p, up: c.up, fovy: c.fovy });
  }

  reset() {
    this.animateTo(this.home);
  }

  changed() {
    this.onChange();
    clearTimeout(this.urlTimer);
    this.urlTimer = setTimeout(() => writeCamera(this.get()), 250);
  }

  dispose() {
    this.stopAnimation();
    clearTimeout(this.urlTimer);
    this.view.canvas.removeEventListener('dblclick', this.onDoubleClick);
    this.view.canvas.removeEventListener('keydown', this.onKey);
    this.controls.dispose();
  }
}
