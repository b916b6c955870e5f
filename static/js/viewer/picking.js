// Picking on the drawn patches: the surface point under a screen position, the patch and
// triangle there and the original ids of its corners (what part highlights are made of).

import * as THREE from 'three';

const raycaster = new THREE.Raycaster();
const ndc = new THREE.Vector2();

/**
 * The nearest surface hit at client coordinates (x, y), or null.
 * @returns {{point: THREE.Vector3, distance: number, node: number, ids: number[], vertex: number|null,
 *   normal: THREE.Vector3|null}|null} `vertex`: the original id of the corner nearest to the hit
 */
export function pick(view, clientX, clientY) {
  const rect = view.canvas.getBoundingClientRect();
  if (rect.width === 0 || rect.height === 0) return null;
  ndc.set(((clientX - rect.left) / rect.width) * 2 - 1, -((clientY - rect.top) / rect.height) * 2 + 1);
  raycaster.setFromCamera(ndc, view.camera);
  const hits = raycaster.intersectObjects(view.visibleMeshes(), false);
  if (hits.length === 0) return null;
  const h = hits[0];
  const ids = h.object.userData.ids;
  const face = h.face;
  return {
    point: h.point.clone(),
    distance: h.distance,
    node: h.object.userData.node,
    ids: face ? [ids[face.a], ids[face.b], ids[face.c]] : [],
    vertex: face ? nearestCorner(h, ids) : null,
    normal: face ? face.normal.clone() : null,
  };
}

const corner = new THREE.Vector3();

/** The original id of the hit triangle's corner nearest to the hit point. */
function nearestCorner(hit, ids) {
  const pos = hit.object.geometry.getAttribute('position');
  let best = null;
  let bestD = Infinity;
  for (const v of [hit.face.a, hit.face.b, hit.face.c]) {
    corner.fromBufferAttribute(pos, v).applyMatrix4(hit.object.matrixWorld);
    const d = corner.distanceToSquared(hit.point);
    if (d < bestD) {
      bestD = d;
      best = ids[v];
    }
  }
  return best;
}

/** Distance along the ray to the first surface between the camera and `point` (occlusion). */
export function firstHitDistance(view, point) {
  const origin = view.camera.position;
  const dir = new THREE.Vector3().subVectors(point, origin);
  const len = dir.length();
  if (len === 0) return Infinity;
  raycaster.set(origin, dir.divideScalar(len));
  raycaster.near = 0;
  raycaster.far = len;
  const hits = raycaster.intersectObjects(view.visibleMeshes(), false);
  raycaster.far = Infinity;
  return hits.length ? hits[0].distance : Infinity;
}
