// Bold boundary of a highlighted part (system paper §2.2: "the boundaries of those regions are
// highlighted with bold lines"), as the server's outline pass (shaders/outline.wgsl): the
// scene is drawn once more with a mask material (1 where the part's marked vertices are, with
// depth so hidden parts of it stay hidden), then a full-screen pass paints the pixels outside
// the mask within `width` pixels of it.

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

const QUAD_FRAGMENT = /* glsl */ `
uniform sampler2D tMask;
uniform vec2 uTexel;
uniform float uWidth;
uniform int uChannel;
uniform vec3 uColor;
in vec2 vUv;
float marked(vec2 uv) {
  vec4 m = texture(tMask, uv);
  return uChannel == 1 ? m.r : m.g;
}
void main() {
  if (marked(vUv) > 0.5) discard;
  int r = int(uWidth);
  float best = 1e9;
  for (int dy = -8; dy <= 8; dy++) {
    for (int dx = -8; dx <= 8; dx++) {
      if (abs(dx) > r || abs(dy) > r) continue;
      float d2 = float(dx * dx + dy * dy);
      if (d2 < best && marked(vUv + vec2(float(dx), float(dy)) * uTexel) > 0.5) best = d2;
    }
  }
  float d = sqrt(best);
  if (d > uWidth + 0.5) discard;
  gl_FragColor = vec4(uColor, clamp(uWidth + 0.5 - d, 0.0, 1.0));
}`;

export class OutlinePass {
  constructor(renderer) {
    this.renderer = renderer;
    this.target = new THREE.WebGLRenderTarget(1, 1, { depthBuffer: true, stencilBuffer: false });
    this.target.texture.minFilter = THREE.NearestFilter;
    this.target.texture.magFilter = THREE.NearestFilter;
    this.mask = new THREE.ShaderMaterial({ vertexShader: MASK_VERTEX, fragmentShader: MASK_FRAGMENT, side: THREE.DoubleSide });
    this.quadMaterial = new THREE.ShaderMaterial({
      vertexShader: QUAD_VERTEX,
      fragmentShader: QUAD_FRAGMENT,
      transparent: true,
      depthTest: false,
      depthWrite: false,
      uniforms: {
        tMask: { value: this.target.texture },
        uTexel: { value: new THREE.Vector2(1, 1) },
        uWidth: { value: WIDTH },
        uChannel: { value: 1 },
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
    this.target.setSize(Math.max(1, Math.round(w)), Math.max(1, Math.round(h)));
    this.quadMaterial.uniforms.uTexel.value.set(1 / Math.max(1, w), 1 / Math.max(1, h));
    this.quadMaterial.uniforms.uWidth.value = Math.min(8, Math.round(WIDTH * this.renderer.getPixelRatio()));
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
    r.setRenderTarget(null);
    r.setClearColor(clear, clearAlpha);
    this.quadMaterial.uniforms.uChannel.value = channel;
    const autoClear = r.autoClear;
    r.autoClear = false;
    r.render(this.quadScene, this.quadCamera);
    r.autoClear = autoClear;
  }

  dispose() {
    this.target.dispose();
    this.mask.dispose();
    this.quadMaterial.dispose();
    this.quad.geometry.dispose();
  }
}
