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
// Coarse patches with a normal map (issue 11 item 4) shade with its texel's mean normal, not
// normalised (diffuse light is then the texel's mean light), as the server's `facing_normal`.

import * as THREE from 'three';
import { OutlinePass } from './outline.js';
import { SHARPNESS, SLOTS } from '../lumigraph/repository.js';
import { isWebp } from '../lod/decode.js';

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
uniform sampler2D uNormalMap;
uniform float uNormalMapped;
in vec3 vNormal;
in vec3 vWorld;
in vec4 vColor;
in vec2 vMark;
in vec2 vUv;
#ifdef LUMIGRAPH
// Image-based mode (../lumigraph/repository.js): the repository's images of the grid points
// nearest to the eye, projected onto this sparse surface (system paper Fig. 15).
uniform highp sampler2DArray uLgAlbedo;
uniform highp sampler2DArray uLgNormal;
uniform highp sampler2DArray uLgDepth;
uniform vec4 uLgPoints[${SLOTS}];
uniform vec4 uLgLayers[${SLOTS * 6}];
uniform vec3 uLgForward[6];
uniform vec3 uLgUp[6];
uniform float uLgTolerance;
uniform float uLgSharpness;
uniform float uLgDepthSide;
uniform float uLgPixel;
// Samples along the view ray when searching an image's depth for the surface, then bisections
// of the stretch where the ray passes behind it.
const int LG_STEPS = 8;
const int LG_BISECT = 2;
// Four neighbouring depth pixels lie on one surface (and are interpolated) where their depths
// differ by at most LG_JUMP · depth / side: 12 image pixels' footprint at that depth (a 90°
// image's pixel spans 2 · depth / side), three depth pixels'.
const float LG_JUMP = 24.0;
// View depth (along the face's forward axis) of the surface image layer saw at depth pixel
// at, or -1 where it saw nothing.
float lgCode(int layer, ivec2 at, vec4 info) {
  int side = int(uLgDepthSide);
  vec3 dz = texelFetch(uLgDepth, ivec3(clamp(at, ivec2(0), ivec2(side - 1)), layer), 0).rgb;
  float q = floor(dz.r * 255.0 + 0.5) * 256.0 + floor(dz.g * 255.0 + 0.5);
  return q >= 65535.0 ? -1.0 : info.y + q / 65534.0 * (info.z - info.y);
}
// The depth seen at uv: its depth pixel's (a block's mean), cheap enough for the search.
float lgNearest(int layer, vec2 uv, vec4 info) {
  return lgCode(layer, ivec2(uv * uLgDepthSide), info);
}
// The depth seen at uv, interpolated bilinearly between the four depth pixels around it where
// they lie on one surface; across a depth jump or the silhouette, uv's own depth pixel (no
// depth between an occluder and what lies behind it).
float lgSeen(int layer, vec2 uv, vec4 info) {
  vec2 p = uv * uLgDepthSide - 0.5;
  ivec2 i0 = ivec2(floor(p));
  vec2 fr = p - floor(p);
  float a = lgCode(layer, i0, info);
  float b = lgCode(layer, i0 + ivec2(1, 0), info);
  float c = lgCode(layer, i0 + ivec2(0, 1), info);
  float d = lgCode(layer, i0 + ivec2(1, 1), info);
  // uv's own depth pixel (lgNearest) is the one of the four it lies nearest to.
  float near = fr.y < 0.5 ? (fr.x < 0.5 ? a : b) : (fr.x < 0.5 ? c : d);
  float lo = min(min(a, b), min(c, d));
  if (lo < 0.0) return near;
  float hi = max(max(a, b), max(c, d));
  if (hi - lo > lo * LG_JUMP * uLgPixel) return near;
  return mix(mix(a, b, fr.x), mix(c, d, fr.x), fr.y);
}
// Depth of point dir (relative to the image's point) in the image of face (f, r, u) minus the
// depth that image saw in that direction (z: the point's depth); -1e30 where it saw nothing.
// fine: the interpolated depth (lgSeen), else the depth pixel's (lgNearest).
float lgDepthGap(vec3 dir, vec3 f, vec3 r, vec3 u, int layer, vec4 info, bool fine, out float z) {
  z = dot(dir, f);
  vec2 uv = vec2(0.5 + 0.5 * dot(dir, r) / z, 0.5 - 0.5 * dot(dir, u) / z);
  float seen = z > 0.0 && all(greaterThanEqual(uv, vec2(0.0))) && all(lessThanEqual(uv, vec2(1.0))) ? (fine ? lgSeen(layer, uv, info) : lgNearest(layer, uv, info)) : -1.0;
  return seen < 0.0 ? -1e30 : z - seen;
}
// Blends the images that saw the surface the view ray through P meets. The sparse mesh lies
// within its error of that surface, not on it, so an image's texel at P's own projection is
// another point of the surface, displaced by that error times the angle between the rays
// (parallax). Instead each image's depth is searched along the view ray, across the sparse
// mesh's error (inverse warping): where the ray passes from in front of the surface the image
// saw to behind it, the image saw the very point the view sees. An image whose depth jumps
// there (an occluder in its way) or that sees nothing on that stretch of the ray is not used,
// so no image lands on a surface it did not see. The images are weighed by how close their ray
// is to the view ray (towards the eye, V) and by their resolution there (1 / depth²).
bool lumigraph(vec3 P, vec3 V, vec3 N, out vec3 albedo, out vec3 normal, out float hasAlbedo) {
  vec3 aSum = vec3(0.0);
  vec3 nSum = vec3(0.0);
  float wSum = 0.0;
  float aw = 0.0;
  // The stretch of the view ray within the sparse mesh's error of P (longer at grazing angles).
  vec3 ray = -V;
  float reach = uLgTolerance / max(abs(dot(N, V)), 0.25);
  float t0 = dot(P - cameraPosition, ray) - reach;
  float dt = 2.0 * reach / float(LG_STEPS - 1);
  for (int k = 0; k < ${SLOTS}; k++) {
    vec4 g = uLgPoints[k];
    if (g.w < 0.5) continue;
    vec3 dirP = P - g.xyz;
    // The face that sees P: its dominant axis (d = 2 axis + negative, checked by the
    // repository against the description's directions).
    vec3 ad = abs(dirP);
    int d = ad.x >= ad.y && ad.x >= ad.z ? (dirP.x >= 0.0 ? 0 : 1) : ad.y >= ad.z ? (dirP.y >= 0.0 ? 2 : 3) : (dirP.z >= 0.0 ? 4 : 5);
    int layer = k * 6 + d;
    vec4 info = uLgLayers[layer];
    if (info.x < 0.5 || dot(dirP, uLgForward[d]) <= 0.0) continue;
    vec3 f = uLgForward[d];
    vec3 r = normalize(cross(f, uLgUp[d]));
    vec3 u = cross(r, f);
    // h = (depth of the ray's point) - (depth the image saw there): < 0 in front of the seen
    // surface (or where the image saw nothing), >= 0 behind it.
    float hPrev = 0.0;
    float tHit = -1.0;
    for (int i = 0; i < LG_STEPS; i++) {
      float z;
      float h = lgDepthGap(cameraPosition + ray * (t0 + float(i) * dt) - g.xyz, f, r, u, layer, info, false, z);
      if (h >= 0.0) {
        // A true crossing: the ray was just in front of the same surface (the depth step of
        // one sample's ray stretch, plus a block of the quarter-resolution depth). It is
        // placed by bisecting that stretch against the interpolated depth, then the secant:
        // a sample's stretch spans several texels of the surface, and the secant across it
        // alone put the texel used up to ten view pixels away on the 5M relief's raised
        // features (with the depth interpolated, the relief's image-based views gained
        // 1.7 dB on average).
        if (i > 0 && hPrev > -1e29 && h <= dt + z * 8.0 * uLgPixel) {
          float ta = t0 + float(i - 1) * dt;
          float tb = t0 + float(i) * dt;
          float ha = hPrev;
          float hb = h;
          for (int j = 0; j < LG_BISECT; j++) {
            float tm = 0.5 * (ta + tb);
            float zm;
            float hm = lgDepthGap(cameraPosition + ray * tm - g.xyz, f, r, u, layer, info, true, zm);
            if (hm >= 0.0) {
              tb = tm;
              hb = hm;
            } else {
              ta = tm;
              ha = hm;
            }
          }
          // (Where the image saw nothing at ta, the ray's first point behind its surface.)
          tHit = ha > -1e29 ? ta + ((tb - ta) * -ha) / (hb - ha) : tb;
        }
        break;
      }
      hPrev = h;
    }
    if (tHit < 0.0) continue;
    vec3 dir = cameraPosition + ray * tHit - g.xyz;
    float z = dot(dir, f);
    vec2 uv = vec2(0.5 + 0.5 * dot(dir, r) / z, 0.5 - 0.5 * dot(dir, u) / z);
    float c = dot(normalize(-dir), V);
    if (c <= 0.0) continue;
    // Closer images hold more texels of the point: at similar angles they count more.
    float w = (exp(uLgSharpness * (c - 1.0)) + 1e-6) / (z * z);
    vec3 n = texture(uLgNormal, vec3(uv, float(layer))).rgb * 2.0 - 1.0;
    if (dot(n, V) < 0.0) n = -n;
    nSum += w * n;
    if (info.w > 0.5) {
      aSum += w * texture(uLgAlbedo, vec3(uv, float(layer))).rgb;
      aw += w;
    }
    wSum += w;
  }
  if (wSum <= 0.0 || dot(nSum, nSum) < 1e-12) return false;
  normal = normalize(nSum);
  hasAlbedo = aw > 0.0 ? 1.0 : 0.0;
  albedo = aw > 0.0 ? aSum / aw : vec3(0.0);
  return true;
}
#endif
void main() {
  vec3 v = normalize(cameraPosition - vWorld);
  vec3 n = uNormalMapped > 0.5 ? textureLod(uNormalMap, vUv, 0.0).rgb * 2.0 - 1.0 : vNormal;
  float l = length(n);
  n = l <= 1e-20 ? v : (uNormalMapped > 0.5 ? n : n / l);
  if (!gl_FrontFacing) n = -n;
  vec3 albedo = uTextured > 0.5 ? textureLod(uMap, vUv, 0.0).rgb : vColor.rgb;
#ifdef LUMIGRAPH
  vec3 lgAlbedo;
  vec3 lgNormal;
  float lgHasAlbedo;
  if (lumigraph(vWorld, v, n, lgAlbedo, lgNormal, lgHasAlbedo)) {
    n = lgNormal;
    if (lgHasAlbedo > 0.5) albedo = lgAlbedo;
  }
#endif
  float ndl = uLightMode > 0.5 ? max(dot(n, uLight), 0.0) : abs(dot(n, v));
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
/**
 * Points of a patch's surface the image repository samples to choose its images. With 27, a
 * corner of the 5M relief's closer view was left to the sparse mesh (no sample asked for the
 * face that sees it); with 64 it is not, for 2% more bytes there and the same on the dragon.
 */
const SURFACE_POINTS = 64;
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
        uNormalMap: { value: this.noTexture },
        uNormalMapped: { value: 0 },
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

  /**
   * Image-based mode: the repository's images (`repo`, ../lumigraph/repository.js) shade the
   * patches drawn, which are then only the sparse mesh; `null` switches back.
   */
  setLumigraph(repo) {
    const u = this.material.uniforms;
    for (const k of Object.keys(u)) if (k.startsWith('uLg')) delete u[k];
    this.material.defines = {};
    if (repo) {
      Object.assign(u, {
        uLgAlbedo: { value: repo.albedo },
        uLgNormal: { value: repo.normal },
        uLgDepth: { value: repo.depth },
        uLgPoints: { value: repo.points },
        uLgLayers: { value: repo.layerInfo },
        uLgForward: { value: repo.forward },
        uLgUp: { value: repo.up },
        uLgTolerance: { value: 0 },
        uLgSharpness: { value: SHARPNESS },
        uLgDepthSide: { value: repo.depthSide },
        uLgPixel: { value: 1 / repo.side },
      });
      this.lumigraphSlack = repo.spacing * 0.002;
      this.material.defines = { LUMIGRAPH: 1 };
    }
    this.lumigraph = repo;
    this.material.needsUpdate = true;
    this.material.uniformsNeedUpdate = true;
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
   * until then. Likewise a normal map (`normalMap`), with its vertex normals until then.
   */
  addPatch(node, patch) {
    const g = new THREE.BufferGeometry();
    g.setAttribute('position', new THREE.BufferAttribute(patch.positions, 3));
    g.setAttribute('normal', new THREE.BufferAttribute(patch.normals, 3));
    if (patch.colors) g.setAttribute('aColor', new THREE.BufferAttribute(patch.colors, 4, true));
    const textured = !!(patch.image && patch.uvs);
    const mapped = !!(patch.normalMap && patch.uvs);
    if (textured || mapped) g.setAttribute('uv', new THREE.BufferAttribute(patch.uvs, 2));
    const marks = new THREE.BufferAttribute(new Uint8Array(patch.vertexCount * 2), 2, false);
    marks.setUsage(THREE.DynamicDrawUsage);
    g.setAttribute('aMark', marks);
    g.setIndex(new THREE.BufferAttribute(patch.indices, 1));
    const b = this.table.bounds;
    g.boundingSphere = new THREE.Sphere(new THREE.Vector3(b[node * 4], b[node * 4 + 1], b[node * 4 + 2]), b[node * 4 + 3]);
    const mesh = new THREE.Mesh(g, this.material);
    mesh.matrixAutoUpdate = false;
    mesh.visible = false;
    mesh.userData = { node, ids: patch.ids, vertexCount: patch.vertexCount, textured, mapped, texture: null, normalMap: null };
    const id = node + 1;
    mesh.onBeforeRender = (_r, _s, _c, _g, material) => {
      if (material === this.material) {
        // The shared material's texture uniforms follow the mesh drawn (uploaded on change).
        const u = material.uniforms;
        if (u.uLgTolerance) {
          // The sparse patch lies within its error of the surface the images saw.
          u.uLgTolerance.value = 1.5 * this.table.lodError[node] + this.lumigraphSlack;
          material.uniformsNeedUpdate = true;
        }
        const tex = mesh.userData.texture;
        const map = tex || this.noTexture;
        const on = tex ? 1 : 0;
        if (u.uMap.value !== map || u.uTextured.value !== on) {
          u.uMap.value = map;
          u.uTextured.value = on;
          material.uniformsNeedUpdate = true;
        }
        const nm = mesh.userData.normalMap;
        const nmOn = nm ? 1 : 0;
        if (u.uNormalMap.value !== (nm || this.noTexture) || u.uNormalMapped.value !== nmOn) {
          u.uNormalMap.value = nm || this.noTexture;
          u.uNormalMapped.value = nmOn;
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
    if (textured) this.loadTexture(node, mesh, patch.image, 'texture');
    if (mapped) this.loadTexture(node, mesh, patch.normalMap, 'normalMap');
    return mesh;
  }

  /**
   * Decodes a patch's atlas or normal map (JPEG or WebP bytes, `key` 'texture' or 'normalMap') and
   * gives it to its mesh, if still resident.
   */
  async loadTexture(node, mesh, bytes, key) {
    let bitmap;
    try {
      // The texels as stored: no colour management (sRGB bytes, like vertex colours).
      const type = isWebp(bytes) ? 'image/webp' : 'image/jpeg';
      bitmap = await createImageBitmap(new Blob([bytes], { type }), { premultiplyAlpha: 'none', colorSpaceConversion: 'none' });
    } catch (e) {
      console.warn(`meshwiki viewer: texture of patch ${node}:`, (e && e.message) || e);
      return;
    }
    if (this.meshes.get(node) !== mesh) {
      // Evicted (or the view disposed) while decoding.
      bitmap.close();
      return;
    }
    mesh.userData[key] = atlasTexture(bitmap);
    this.onChange();
  }

  /**
   * Up to SURFACE_POINTS of a resident patch's vertices, spread over its vertex list (x, y, z
   * triples in world space), or null where the patch is not resident.
   */
  surfacePoints(node) {
    const mesh = this.meshes.get(node);
    if (!mesh) return null;
    if (!mesh.userData.surface) {
      const pos = mesh.geometry.getAttribute('position');
      const n = Math.min(SURFACE_POINTS, pos.count);
      const out = new Float32Array(3 * n);
      for (let k = 0; k < n; k++) {
        const i = Math.floor(((k + 0.5) * pos.count) / n);
        out[3 * k] = pos.getX(i);
        out[3 * k + 1] = pos.getY(i);
        out[3 * k + 2] = pos.getZ(i);
      }
      mesh.userData.surface = out;
    }
    return mesh.userData.surface;
  }

  removePatch(node) {
    const mesh = this.meshes.get(node);
    if (!mesh) return;
    this.scene.remove(mesh);
    mesh.geometry.dispose();
    for (const [key, uniform, flag] of [['texture', 'uMap', 'uTextured'], ['normalMap', 'uNormalMap', 'uNormalMapped']]) {
      const tex = mesh.userData[key];
      if (!tex) continue;
      const u = this.material.uniforms;
      if (u[uniform].value === tex) {
        // Never bind a disposed texture again (three would upload it anew).
        u[uniform].value = this.noTexture;
        u[flag].value = 0;
        this.material.uniformsNeedUpdate = true;
      }
      tex.dispose();
      // Never uploaded (evicted before it was drawn): its bitmap is still open.
      if (tex.image && tex.image.width > 0 && typeof tex.image.close === 'function') tex.image.close();
      mesh.userData[key] = null;
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
    // The repository's points and layers change as images arrive (and its albedo array is
    // made once the first albedo arrives).
    if (this.lumigraph) {
      this.material.uniforms.uLgAlbedo.value = this.lumigraph.albedo;
      this.material.uniformsNeedUpdate = true;
    }
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
