// three.js scene of the streamed patches: one mesh per resident patch, drawn with the same
// shading as the server's renderer (shaders/render.wgsl: vertex colour or base albedo, times
// ambient + (1 - ambient)·|n·v| from a headlight) so browser and server images agree; parts
// are tinted per vertex (exact: marks come from original ids), the hovered/selected part gets
// a bold outline (outline.js). The reader may change the light (a softer headlight, or a raking
// light from the upper left of the view that shows shallow relief, as conservators light
// carvings) and the background; the defaults are the server's. Textured patches (docs/FORMAT.md "Textures") take their colour
// from their atlas instead of their vertex colours, as the server's `albedo` does: the JPEG is
// decoded to a bitmap here (until then the patch shows its vertex colours) and sampled as it
// is, RGBA8 without sRGB decoding, bilinear and clamped, like the server's atlas sampler.

import * as THREE from 'three';
import { OutlinePass } from './outline.js';

export const BACKGROUND = 0x1d2026;
const BASE_COLOR = [209 / 255, 204 / 255, 194 / 255, 1];
const AMBIENT = 0.25;
/** Tints (rgb, strength) of the hovered and the selected part. */
export const HOVER_TINT = [1, 176 / 255, 0, 0.45];
export const SELECT_TINT = [0, 160 / 255, 1, 0.5];

const VERTEX = /* glsl */ `
in vec4 aColor;
in vec2 aMark;
uniform vec4 uBaseColor;
uniform float uHasColor;
out vec3 vNormal;
out vec3 vWorld;
out vec4 vColor;
out vec2 vMark;
out vec2 vUv;
void main() {
  vec4 world = modelMatrix * vec4(position, 1.0);
  vWorld = world.xyz;
  vNormal = normal;
  vColor = uHasColor > 0.5 ? aColor : uBaseColor;
  vMark = aMark;
  vUv = uv;
  gl_Position = projectionMatrix * viewMatrix * world;
}`;

const FRAGMENT = /* glsl */ `
uniform float uAmbient;
// 0: headlight (from the eye, |n·v|, as the server shades); 1: from direction uLight (world)
uniform float uLightMode;
uniform vec3 uLight;
uniform vec4 uHoverTint;
uniform vec4 uSelectTint;
uniform sampler2D uMap;
uniform float uTextured;
in vec3 vNormal;
in vec3 vWorld;
in vec4 vColor;
in vec2 vMark;
in vec2 vUv;
void main() {
  vec3 v = normalize(cameraPosition - vWorld);
  vec3 n = vNormal;
  float l = length(n);
  n = l > 1e-20 ? n / l : v;
  if (!gl_FrontFacing) n = -n;
  float ndl = uLightMode > 0.5 ? max(dot(n, uLight), 0.0) : abs(dot(n, v));
  vec3 albedo = uTextured > 0.5 ? textureLod(uMap, vUv, 0.0).rgb : vColor.rgb;
  vec3 rgb = albedo * (uAmbient + (1.0 - uAmbient) * ndl);
  if (vMark.y > 0.5) rgb = mix(rgb, uSelectTint.rgb, uSelectTint.a);
  else if (vMark.x > 0.5) rgb = mix(rgb, uHoverTint.rgb, uHoverTint.a);
  gl_FragColor = vec4(clamp(rgb, 0.0, 1.0), 1.0);
}`;

// Visibility pass: every drawn patch in a flat colour encoding its node id + 1, at a reduced
// resolution, so the streamer knows which drawn patches no pixel of the frame shows.
const ID_VERTEX = /* glsl */ `
void main() {
  gl_Position = projectionMatrix * modelViewMatrix * vec4(position, 1.0);
}`;
const ID_FRAGMENT = /* glsl */ `
uniform vec3 uId;
void main() {
  gl_FragColor = vec4(uId, 1.0);
}`;
/** The visibility pass renders at 1/VISIBILITY_DOWNSCALE of the canvas in each direction. */
export const VISIBILITY_DOWNSCALE = 2;

/**
 * A patch atlas as a texture: the bitmap as it is (no flip: v = 0 is the image's top row, no
 * colour conversion), RGBA8 (not sRGB), bilinear, clamped, without mipmaps.
 */
function atlasTexture(bitmap) {
  const tex = new THREE.Texture(bitmap);
  tex.flipY = false;
  tex.premultiplyAlpha = false;
  tex.colorSpace = THREE.NoColorSpace;
  tex.format = THREE.RGBAFormat;
  tex.type = THREE.UnsignedByteType;
  tex.generateMipmaps = false;
  tex.minFilter = THREE.LinearFilter;
  tex.magFilter = THREE.LinearFilter;
  tex.wrapS = THREE.ClampToEdgeWrapping;
  tex.wrapT = THREE.ClampToEdgeWrapping;
  // Once on the GPU, the bitmap's memory is not needed any more.
  tex.onUpdate = () => bitmap.close();
  tex.needsUpdate = true;
  return tex;
}

export class SceneView {
  /**
   * @param {HTMLElement} container
   * @param {object} table the LOD tables (bounds of each node)
   * @param {{onChange?: Function}} [options] `onChange`: something drawn changed on its own
   *   (a patch's texture became ready), so a frame should be rendered
   */
  constructor(container, table, options = {}) {
    this.table = table;
    this.container = container;
    this.onChange = options.onChange || (() => {});
    this.renderer = new THREE.WebGLRenderer({ antialias: true, powerPreference: 'high-performance' });
    this.renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
    this.renderer.setClearColor(BACKGROUND, 1);
    this.canvas = this.renderer.domElement;
    this.canvas.className = 'viewer-canvas';
    this.canvas.setAttribute('aria-label', '3D view of the model: drag or use the arrow keys to turn it, Shift+arrows to move, + and − to zoom, Home to reset');
    this.canvas.tabIndex = 0;
    container.appendChild(this.canvas);
    this.scene = new THREE.Scene();
    this.camera = new THREE.PerspectiveCamera(40, 1, 0.01, 100);
    // Bound to `uMap` while an untextured patch is drawn (never sampled: `uTextured` is 0).
    this.noTexture = new THREE.DataTexture(new Uint8Array([255, 255, 255, 255]), 1, 1);
    this.noTexture.needsUpdate = true;
    this.material = new THREE.ShaderMaterial({
      vertexShader: VERTEX,
      fragmentShader: FRAGMENT,
      side: THREE.DoubleSide,
      uniforms: {
        uBaseColor: { value: new THREE.Vector4(...BASE_COLOR) },
        uHasColor: { value: table.hasColors ? 1 : 0 },
        uAmbient: { value: AMBIENT },
        uLightMode: { value: 0 },
        uLight: { value: new THREE.Vector3(0, 0, 1) },
        uHoverTint: { value: new THREE.Vector4(...HOVER_TINT) },
        uSelectTint: { value: new THREE.Vector4(...SELECT_TINT) },
        uMap: { value: this.noTexture },
        uTextured: { value: 0 },
      },
    });
    this.idMaterial = new THREE.ShaderMaterial({
      vertexShader: ID_VERTEX,
      fragmentShader: ID_FRAGMENT,
      side: THREE.DoubleSide,
      uniforms: { uId: { value: new THREE.Vector3() } },
    });
    this.visTarget = null;
    this.visPixels = null;
    this.outline = new OutlinePass(this.renderer);
    this.meshes = new Map();
    this.drawn = [];
    this.width = 1;
    this.height = 1;
    this.resize();
  }

  /**
   * The light: `mode` 'headlight' (from the eye) or 'raking' (from the upper left of the view,
   * grazing the surface), with `ambient` in [0, 1].
   */
  setLighting(mode, ambient) {
    const u = this.material.uniforms;
    u.uLightMode.value = mode === 'raking' ? 1 : 0;
    u.uAmbient.value = ambient;
    this.material.uniformsNeedUpdate = true;
  }

  setBackground(color) {
    this.renderer.setClearColor(color, 1);
  }

  /** Matches the drawing buffer to the container's size. */
  resize() {
    const w = Math.max(1, this.container.clientWidth);
    const h = Math.max(1, this.container.clientHeight);
    if (w === this.width && h === this.height) return false;
    this.width = w;
    this.height = h;
    this.renderer.setSize(w, h, true);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
    this.outline.setSize(w * this.renderer.getPixelRatio(), h * this.renderer.getPixelRatio());
    return true;
  }

  /**
   * Adds a decoded patch (arrays from the worker) as a hidden mesh. A textured patch (`image`
   * and `uvs`) gets its texture once the image decodes; it is drawn with its vertex colours
   * until then.
   */
  addPatch(node, patch) {
    const g = new THREE.BufferGeometry();
    g.setAttribute('position', new THREE.BufferAttribute(patch.positions, 3));
    g.setAttribute('normal', new THREE.BufferAttribute(patch.normals, 3));
    if (patch.colors) g.setAttribute('aColor', new THREE.BufferAttribute(patch.colors, 4, true));
    const textured = !!(patch.image && patch.uvs);
    if (textured) g.setAttribute('uv', new THREE.BufferAttribute(patch.uvs, 2));
    const marks = new THREE.BufferAttribute(new Uint8Array(patch.vertexCount * 2), 2, false);
    marks.setUsage(THREE.DynamicDrawUsage);
    g.setAttribute('aMark', marks);
    g.setIndex(new THREE.BufferAttribute(patch.indices, 1));
    const b = this.table.bounds;
    g.boundingSphere = new THREE.Sphere(new THREE.Vector3(b[node * 4], b[node * 4 + 1], b[node * 4 + 2]), b[node * 4 + 3]);
    const mesh = new THREE.Mesh(g, this.material);
    mesh.matrixAutoUpdate = false;
    mesh.visible = false;
    mesh.userData = { node, ids: patch.ids, vertexCount: patch.vertexCount, texture: null };
    const id = node + 1;
    mesh.onBeforeRender = (_r, _s, _c, _g, material) => {
      if (material === this.material) {
        // The shared material's texture uniforms follow the mesh drawn (uploaded on change).
        const u = material.uniforms;
        const tex = mesh.userData.texture;
        const map = tex || this.noTexture;
        const on = tex ? 1 : 0;
        if (u.uMap.value !== map || u.uTextured.value !== on) {
          u.uMap.value = map;
          u.uTextured.value = on;
          material.uniformsNeedUpdate = true;
        }
        return;
      }
      if (material !== this.idMaterial) return;
      material.uniforms.uId.value.set(((id >> 16) & 255) / 255, ((id >> 8) & 255) / 255, (id & 255) / 255);
      material.uniformsNeedUpdate = true;
    };
    this.scene.add(mesh);
    this.meshes.set(node, mesh);
    if (textured) this.loadTexture(node, mesh, patch.image);
    return mesh;
  }

  /** Decodes a patch's atlas (JPEG bytes) and gives it to its mesh, if still resident. */
  async loadTexture(node, mesh, bytes) {
    let bitmap;
    try {
      // The texels as stored: no colour management (sRGB bytes, like vertex colours).
      bitmap = await createImageBitmap(new Blob([bytes], { type: 'image/jpeg' }), { premultiplyAlpha: 'none', colorSpaceConversion: 'none' });
    } catch (e) {
      console.warn(`meshwiki viewer: texture of patch ${node}:`, (e && e.message) || e);
      return;
    }
    if (this.meshes.get(node) !== mesh) {
      // Evicted (or the view disposed) while decoding.
      bitmap.close();
      return;
    }
    mesh.userData.texture = atlasTexture(bitmap);
    this.onChange();
  }

  removePatch(node) {
    const mesh = this.meshes.get(node);
    if (!mesh) return;
    this.scene.remove(mesh);
    mesh.geometry.dispose();
    const tex = mesh.userData.texture;
    if (tex) {
      const u = this.material.uniforms;
      if (u.uMap.value === tex) {
        // Never bind a disposed texture again (three would upload it anew).
        u.uMap.value = this.noTexture;
        u.uTextured.value = 0;
        this.material.uniformsNeedUpdate = true;
      }
      tex.dispose();
      // Never uploaded (evicted before it was drawn): its bitmap is still open.
      if (tex.image && tex.image.width > 0 && typeof tex.image.close === 'function') tex.image.close();
      mesh.userData.texture = null;
    }
    this.meshes.delete(node);
  }

  /** Shows exactly the nodes of `draw`. */
  setDrawn(draw) {
    for (const node of this.drawn) {
      const m = this.meshes.get(node);
      if (m) m.visible = false;
    }
    for (const node of draw) {
      const m = this.meshes.get(node);
      if (m) m.visible = true;
    }
    this.drawn = draw;
  }

  /** Visible meshes (for picking). */
  visibleMeshes() {
    const out = [];
    for (const node of this.drawn) {
      const m = this.meshes.get(node);
      if (m) out.push(m);
    }
    return out;
  }

  /** Near and far planes around what is drawn (tight near plane keeps depth precise). */
  fitClipPlanes() {
    const eye = this.camera.position;
    const b = this.table.bounds;
    let near = Infinity;
    let far = 0;
    for (const node of this.drawn) {
      const d = Math.hypot(b[node * 4] - eye.x, b[node * 4 + 1] - eye.y, b[node * 4 + 2] - eye.z);
      near = Math.min(near, d - b[node * 4 + 3]);
      far = Math.max(far, d + b[node * 4 + 3]);
    }
    const c = this.table.center;
    const dc = Math.hypot(c[0] - eye.x, c[1] - eye.y, c[2] - eye.z);
    far = Math.max(far, dc + this.table.radius) * 1.01;
    near = Math.max(Number.isFinite(near) ? near * 0.5 : far * 1e-3, far * 1e-5);
    this.camera.near = near;
    this.camera.far = far;
    this.camera.updateProjectionMatrix();
  }

  /** Renders; `outline` (0 none, 1 hovered, 2 selected) draws the bold boundary. */
  render(outline = 0) {
    this.fitClipPlanes();
    if (this.material.uniforms.uLightMode.value > 0.5) {
      // Raking light, fixed to the view: from the upper left, grazing the surface facing us.
      const m = this.camera.matrixWorld.elements;
      const right = new THREE.Vector3(m[0], m[1], m[2]);
      const up = new THREE.Vector3(m[4], m[5], m[6]);
      const back = new THREE.Vector3(m[8], m[9], m[10]);
      this.material.uniforms.uLight.value.copy(right.multiplyScalar(-0.75).addScaledVector(up, 0.45).addScaledVector(back, 0.5).normalize());
      this.material.uniformsNeedUpdate = true;
    }
    this.renderer.render(this.scene, this.camera);
    // The outline costs two full-screen passes: only when a drawn patch holds a marked vertex.
    if (outline && this.scene.children.some((m) => m.visible && m.userData.marked)) this.outline.render(this.scene, this.camera, outline);
  }

  /**
   * Renders the drawn patches as ids at reduced resolution (same camera and clip planes as the
   * last frame) and returns the set of nodes that cover at least one sample.
   */
  visibleNodes() {
    const w = Math.max(1, Math.round(this.width / VISIBILITY_DOWNSCALE));
    const h = Math.max(1, Math.round(this.height / VISIBILITY_DOWNSCALE));
    if (!this.visTarget || this.visTarget.width !== w || this.visTarget.height !== h) {
      if (this.visTarget) this.visTarget.dispose();
      this.visTarget = new THREE.WebGLRenderTarget(w, h, { depthBuffer: true, type: THREE.UnsignedByteType });
      this.visPixels = new Uint8Array(w * h * 4);
    }
    const clear = this.renderer.getClearColor(new THREE.Color());
    const alpha = this.renderer.getClearAlpha();
    this.renderer.setClearColor(0x000000, 1);
    this.scene.overrideMaterial = this.idMaterial;
    this.renderer.setRenderTarget(this.visTarget);
    this.renderer.render(this.scene, this.camera);
    this.renderer.readRenderTargetPixels(this.visTarget, 0, 0, w, h, this.visPixels);
    this.renderer.setRenderTarget(null);
    this.scene.overrideMaterial = null;
    this.renderer.setClearColor(clear, alpha);
    const seen = new Set();
    const px = this.visPixels;
    let last = -1;
    for (let i = 0; i < px.length; i += 4) {
      const id = (px[i] << 16) | (px[i + 1] << 8) | px[i + 2];
      if (id !== last && id !== 0) seen.add(id - 1);
      last = id;
    }
    return seen;
  }

  dispose() {
    for (const node of [...this.meshes.keys()]) this.removePatch(node);
    this.material.dispose();
    this.noTexture.dispose();
    this.idMaterial.dispose();
    if (this.visTarget) this.visTarget.dispose();
    this.outline.dispose();
    this.renderer.dispose();
    this.canvas.remove();
  }
}
