// The camera in the page URL (`#camera=eye,target,up,fovy`, 10 numbers), so any view can be
// shared as a link; `?part=ID` names the part a link lands on (search results, content pages),
// `&q=…` the search that found it (its words are marked in the part's information).

const DIGITS = 6;

/** `#camera=…` for a camera {eye, target, up, fovy}. */
export function formatCamera(c) {
  const nums = [...c.eye, ...c.target, ...c.up, c.fovy].map((v) => Number(v.toPrecision(DIGITS)));
  return `camera=${nums.join(',')}`;
}

/** Parses `#camera=…` from a hash string; null when absent or invalid. */
export function parseCamera(hash) {
  const m = /(?:^#|&)camera=([^&]+)/.exec(hash || '');
  if (!m) return null;
  const nums = m[1].split(',').map(Number);
  if (nums.length !== 10 || !nums.every(Number.isFinite)) return null;
  const c = { eye: nums.slice(0, 3), target: nums.slice(3, 6), up: nums.slice(6, 9), fovy: nums[9] };
  const dir = c.eye.map((v, k) => c.target[k] - v);
  if (Math.hypot(...dir) === 0 || Math.hypot(...c.up) === 0 || !(c.fovy > 1 && c.fovy < 170)) return null;
  return c;
}

/** The `part` query parameter, or null. */
export function linkedPart(search) {
  const v = new URLSearchParams(search).get('part');
  const id = Number(v);
  return v !== null && Number.isInteger(id) && id > 0 ? id : null;
}

/** Replaces the URL's hash with the camera (no history entry). */
export function writeCamera(c) {
  const url = new URL(window.location.href);
  url.hash = formatCamera(c);
  history.replaceState(history.state, '', url);
}

/** Sets or clears `?part=` (no history entry). */
export function writePart(id) {
  const url = new URL(window.location.href);
  if (id) url.searchParams.set('part', String(id));
  else url.searchParams.delete('part');
  history.replaceState(history.state, '', url);
}

/** The search (`?q=`) a search result's link carries, or null. */
export function linkedQuery(search) {
  const q = new URLSearchParams(search).get('q');
  return q && q.trim() ? q.trim().slice(0, 1000) : null;
}

/** Drops `?q=` once the search's part is left (no history entry). */
export function clearQuery() {
  const url = new URL(window.location.href);
  if (!url.searchParams.has('q')) return;
  url.searchParams.delete('q');
  history.replaceState(history.state, '', url);
}
