// Navigation: orbit, pan and zoom with mouse, wheel and touch (three's OrbitControls: one
// finger orbits, two pan and pinch-zoom), double-click to centre on the surface point, reset
// to the home view, animated camera moves, and the camera kept in the URL.

import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { pick } from './picking.js';
import { writeCamera } from './url.js';

const FOVY = 40;

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
   */
  constructor(view, model, onChange) {
    this.view = view;
    this.model = model;
    this.onChange = onChange;
    this.home = framing(model.center, model.radius);
    this.animation = null;
    this.urlTimer = null;
    this.makeControls([0, 1, 0]);
    this.onDoubleClick = (e) => this.centreOn(e.clientX, e.clientY);
    view.canvas.addEventListener('dblclick', this.onDoubleClick);
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
    this.controls.dispose();
  }
}
