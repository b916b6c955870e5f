// The streaming benches' common ground: the scan they run on and their fixed camera path
// (scripts/bench-stream, scripts/bench-network), so both measure the same views.

import { existsSync } from 'node:fs';
import { join } from 'node:path';

import { SHARED_MESHES, sampleMesh } from '../tests/browser/support/env.mjs';
import { login, waitViewer } from '../tests/browser/support/browser.mjs';

/** `--name value` options of `args`: `opt(name, default)`. */
export function option(args) {
  return (name, dflt) => {
    const i = args.indexOf(`--${name}`);
    return i >= 0 ? args[i + 1] : dflt;
  };
}

/** The scan of a bench: `given`, else the first real scan of ../shared, else a sample. */
export function pickMesh(given) {
  if (given) return { path: given, name: given.split('/').pop(), real: true };
  for (const name of ['stanford_dragon_vrip_871k.ply', 'stanford_armadillo_346k.ply', 'igea_269k.ply']) {
    const p = join(SHARED_MESHES, name);
    if (existsSync(p)) return { path: p, name, real: true };
  }
  return sampleMesh('/tmp');
}

const add = (a, b) => a.map((v, k) => v + b[k]);
const scale = (a, s) => a.map((v) => v * s);
const round = (c) => ({ ...c, eye: c.eye.map((v) => Number(v.toPrecision(7))), target: c.target.map((v) => Number(v.toPrecision(7))) });

/** The fixed path: whole model, an orbit, then closer and closer to a surface point, a pan. */
export function cameraPath(center, radius, p) {
  const far = radius / Math.sin((20 * Math.PI) / 180) * 1.05;
  const rot = (deg) => [Math.sin((deg * Math.PI) / 180), 0, Math.cos((deg * Math.PI) / 180)];
  const toward = (d) => ({ eye: add(p, [0, 0.1 * d, d]), target: p, up: [0, 1, 0], fovy: 40 });
  return [
    { name: 'whole model', eye: add(center, scale(rot(0), far)), target: center, up: [0, 1, 0], fovy: 40 },
    { name: 'orbit 50°', eye: add(center, scale(rot(50), far)), target: center, up: [0, 1, 0], fovy: 40 },
    { name: 'approach', ...toward(1.0 * radius) },
    { name: 'closer', ...toward(0.45 * radius) },
    { name: 'close-up', ...toward(0.2 * radius) },
    { name: 'pan', eye: add(toward(0.2 * radius).eye, [0.08 * radius, 0, 0]), target: add(p, [0.08 * radius, 0, 0]), up: [0, 1, 0], fovy: 40 },
  ].map(round);
}

/**
 * Opens model `model` as `user` in a new page of `browser` on an emulated link (`mbps`,
 * `latencyMs`, cache off), at the path's first camera; resolves once the viewer runs, with the
 * page and the time navigation started.
 */
export async function openOnLink(browser, server, model, user, path, { mbps, latencyMs, timeout }) {
  const page = await browser.page();
  await login(page, server.base, user);
  const cdp = await page.context().newCDPSession(page);
  await cdp.send('Network.enable');
  await cdp.send('Network.setCacheDisabled', { cacheDisabled: true });
  await cdp.send('Network.emulateNetworkConditions', { offline: false, latency: latencyMs, downloadThroughput: (mbps * 1e6) / 8, uploadThroughput: (mbps * 1e6) / 8 });
  const first = path[0];
  const hash = `camera=${[...first.eye, ...first.target, ...first.up, first.fovy].join(',')}`;
  const t0 = Date.now();
  await page.goto(`${server.base}/models/${model.id}#${hash}`);
  await waitViewer(page, () => true, timeout);
  return { page, t0 };
}
