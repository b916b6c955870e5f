// Bold boundary of a highlighted part (system paper §2.2: "the boundaries of those regions are
// highlighted with bold lines"), as the server's outline pass (shaders/outline.wgsl): the
// scene is drawn once more with a mask material (1 where the part's marked vertices are, with
// depth so hidden parts of it stay hidden), then full-screen passes paint the pixels outside
// the mask within `width` pixels of it. Nothing is drawn while no drawn patch holds a marked
// vertex (scene.js).

import * as THREE from 'three';

const OUTLINE_COLOR = [1, 214 / 255, 0];
const WIDTH = 3;

const MASK_VERTEX = /* glsl */ `
in vec2 aMark;
out vec2 vMark;
void main() {
  vMark = aMark;
  gl_Position = projectionMatrix * viewMatrix * modelMatrix * vec4(position, 1.0);
}`;

const MASK_FRAGMENT = /* glsl */ `
in vec2 vMark;
void main() {
  gl_FragColor = vec4(vMark.x > 0.5 ? 1.0 : 0.0, vMark.y > 0.5 ? 1.0 : 0.0, 0.0, 1.0);
}`;

const QUAD_VERTEX = /* glsl */ `
out vec2 vUv;
void main() {
  vUv = position.xy * 0.5 + 0.5;
  gl_Position = vec4(position.xy, 0.0, 1.0);
}`;

// The distance to the nearest marked pixel within the square of radius R is found in two
// separable passes (2·(2R+1) samples a pixel instead of (2R+1)²; a software rasteriser
// shades every pixel of the view): the first stores, per pixel, the smallest |dx| <= R to a
// marked pixel of its row (R + 1: none); the second takes min over |dy| <= R of dx² + dy².
const ROW_FRAGMENT = /* glsl */ `
uniform sampler2D tMask;
uniform vec2 uTexel;
uniform int uChannel;
in vec2 vUv;
float marked(vec2 uv) {
  vec4 m = texture(tMask, uv);
  return uChannel == 1 ? m.r : m.g;
}
void main() {
  float best = float(R + 1);
  for (int dx = -R; dx <= R; dx++) {
    if (marked(vUv + vec2(float(dx), 0.0) * uTexel) > 0.5) best = min(best, abs(float(dx)));
  }
  gl_FragColor = vec4(best / 255.0, 0.0, 0.0, 1.0);
}`;

const QUAD_FRAGMENT = /* glsl */ `
uniform sampler2D tRows;
uniform vec2 uTexel;
uniform vec3 uColor;
in vec2 vUv;
float row(vec2 uv) { return floor(texture(tRows, uv).r * 255.0 + 0.5); }
void main() {
  if (row(vUv) < 0.5) discard; // the pixel is the part's own
  float best = 1e9;
  for (int dy = -R; dy <= R; dy++) {
    float dx = row(vUv + vec2(0.0, float(dy)) * uTexel);
    if (dx <= float(R)) best = min(best, dx * dx + float(dy * dy));
  }
  float d = sqrt(best);
  float width = float(R);
  if (d > width + 0.5) discard;
  gl_FragColor = vec4(uColor, clamp(width + 0.5 - d, 0.0, 1.0));
}`;

export class OutlinePass {
  constructor(renderer) {
    this.renderer = renderer;
    const nearest = (t) => {
      t.texture.minFilter = THREE.NearestFilter;
      t.texture.magFilter = THREE.NearestFilter;
      return t;
    };
    this.target = nearest(new THREE.WebGLRenderTarget(1, 1, { depthBuffer: true, stencilBuffer: false }));
    this.rows = nearest(new THREE.WebGLRenderTarget(1, 1, { depthBuffer: false, stencilBuffer: false }));
    this.mask = new THREE.ShaderMaterial({ vertexShader: MASK_VERTEX, fragmentShader: MASK_FRAGMENT, side: THREE.DoubleSide });
    this.rowMaterial = new THREE.ShaderMaterial({
      vertexShader: QUAD_VERTEX,
      fragmentShader: ROW_FRAGMENT,
      depthTest: false,
      depthWrite: false,
      defines: { R: WIDTH },
      uniforms: {
        tMask: { value: this.target.texture },
        uTexel: { value: new THREE.Vector2(1, 1) },
        uChannel: { value: 1 },
      },
    });
    this.quadMaterial = new THREE.ShaderMaterial({
      vertexShader: QUAD_VERTEX,
      fragmentShader: QUAD_FRAGMENT,
      transparent: true,
      depthTest: false,
      depthWrite: false,
      defines: { R: WIDTH },
      uniforms: {
        tRows: { value: this.rows.texture },
        uTexel: { value: new THREE.Vector2(1, 1) },
        uColor: { value: new THREE.Color(...OUTLINE_COLOR) },
      },
    });
    const quad = new THREE.BufferGeometry();
    quad.setAttribute('position', new THREE.BufferAttribute(new Float32Array([-1, -1, 0, 3, -1, 0, -1, 3, 0]), 3));
    this.quad = new THREE.Mesh(quad, this.quadMaterial);
    this.quad.frustumCulled = false;
    this.quadScene = new THREE.Scene();
    this.quadScene.add(this.quad);
    this.quadCamera = new THREE.OrthographicCamera(-1, 1, 1, -1, 0, 1);
  }

  setSize(w, h) {
    const [width, height] = [Math.max(1, Math.round(w)), Math.max(1, Math.round(h))];
    this.target.setSize(width, height);
    this.rows.setSize(width, height);
    this.rowMaterial.uniforms.uTexel.value.set(1 / width, 1 / height);
    this.quadMaterial.uniforms.uTexel.value.set(1 / width, 1 / height);
    // The radius is a constant of the shaders (loops a software rasteriser can unroll).
    const r = Math.max(1, Math.min(8, Math.round(WIDTH * this.renderer.getPixelRatio())));
    for (const m of [this.rowMaterial, this.quadMaterial]) {
      if (m.defines.R !== r) {
        m.defines.R = r;
        m.needsUpdate = true;
      }
    }
  }

  /** Draws the outline of mask channel `channel` (1 hovered, 2 selected) over the canvas. */
  render(scene, camera, channel) {
    const r = this.renderer;
    const clear = new THREE.Color();
    r.getClearColor(clear);
    const clearAlpha = r.getClearAlpha();
    scene.overrideMaterial = this.mask;
    r.setRenderTarget(this.target);
    r.setClearColor(0x000000, 1);
    r.clear();
    r.render(scene, camera);
    scene.overrideMaterial = null;
    this.rowMaterial.uniforms.uChannel.value = channel;
    this.quad.material = this.rowMaterial;
    r.setRenderTarget(this.rows);
    r.render(this.quadScene, this.quadCamera);
    r.setRenderTarget(null);
    r.setClearColor(clear, clearAlpha);
    this.quad.material = this.quadMaterial;
    const autoClear = r.autoClear;
    r.autoClear = false;
    r.render(this.quadScene, this.quadCamera);
    r.autoClear = autoClear;
  }

  dispose() {
    this.target.dispose();
    this.rows.dispose();
    this.mask.dispose();
    this.rowMaterial.dispose();
    this.quadMaterial.dispose();
    this.quad.geometry.dispose();
  }
}
