// Paths and helpers shared by the browser tests and the streaming bench: the repository root,
// the meshwiki binary, the front-end packages in static/node_modules, the real scans of
// ../shared/data (or a generated relief when it is absent).

import { createRequire } from 'node:module';
import { execFileSync } from 'node:child_process';
import { existsSync, writeFileSync } from 'node:fs';
import { dirname, join, resolve } from 'node:path';
import { fileURLToPath, pathToFileURL } from 'node:url';

export const ROOT = resolve(dirname(fileURLToPath(import.meta.url)), '../../..');
export const SHARED_MESHES = join(ROOT, '../shared/data/meshes');

/** The meshwiki binary: $MESHWIKI_BIN, else the debug build in the cargo target directory. */
export function binary() {
  if (process.env.MESHWIKI_BIN) return process.env.MESHWIKI_BIN;
  const target = process.env.CARGO_TARGET_DIR ? resolve(ROOT, process.env.CARGO_TARGET_DIR) : join(ROOT, 'target');
  const bin = join(target, 'debug', 'meshwiki');
  if (!existsSync(bin)) throw new Error(`${bin} is missing: run cargo build -p meshwiki first (or set MESHWIKI_BIN)`);
  return bin;
}

const staticRequire = createRequire(join(ROOT, 'static', 'package.json'));

/** Imports a package installed in static/node_modules (npm ci --prefix static). */
export async function importStatic(specifier) {
  return import(pathToFileURL(staticRequire.resolve(specifier)).href);
}

/** meshoptimizer's decoder (ready) and fzstd's decompress, as the worker gets them. */
export async function decoderDeps() {
  const { MeshoptDecoder } = await importStatic('meshoptimizer/decoder');
  const fzstd = await importStatic('fzstd');
  await MeshoptDecoder.ready;
  return { meshopt: MeshoptDecoder, decompress: fzstd.decompress };
}

/** Writes an ASCII PLY relief (a coloured height field with bumps), `n`×`n` vertices. */
export function writeRelief(path, n = 160) {
  const lines = [];
  const verts = [];
  for (let y = 0; y < n; y++) {
    for (let x = 0; x < n; x++) {
      const u = x / (n - 1) - 0.5;
      const v = y / (n - 1) - 0.5;
      const z = 0.08 * Math.sin(u * 18) * Math.cos(v * 14) + 0.15 * Math.exp(-(u * u + v * v) * 20);
      const r = Math.round(120 + 100 * (z + 0.1));
      verts.push(`${u.toFixed(6)} ${v.toFixed(6)} ${z.toFixed(6)} ${Math.min(255, Math.max(0, r))} 110 90`);
    }
  }
  const faces = [];
  for (let y = 0; y < n - 1; y++) {
    for (let x = 0; x < n - 1; x++) {
      const i = y * n + x;
      faces.push(`3 ${i} ${i + 1} ${i + n + 1}`, `3 ${i} ${i + n + 1} ${i + n}`);
    }
  }
  lines.push('ply', 'format ascii 1.0', `element vertex ${verts.length}`, 'property float x', 'property float y',
    'property float z', 'property uchar red', 'property uchar green', 'property uchar blue',
    `element face ${faces.length}`, 'property list uchar int vertex_indices', 'end_header');
  writeFileSync(path, `${lines.join('\n')}\n${verts.join('\n')}\n${faces.join('\n')}\n`);
  return path;
}

/**
 * A real scan from ../shared/data/meshes (first of `names` present), else a generated relief
 * written into `tmpDir` (printing that it fell back).
 */
export function sampleMesh(tmpDir, names = ['igea_269k.ply', 'gargoyle_50k_vcolor.ply']) {
  for (const name of names) {
    const p = join(SHARED_MESHES, name);
    if (existsSync(p)) return { path: p, name, real: true };
  }
  console.log(`# ../shared/data is absent: using a generated relief instead of a real scan`);
  return { path: writeRelief(join(tmpDir, 'relief.ply')), name: 'relief.ply', real: false };
}

/** Runs the meshwiki binary with `args`, returning its standard output. */
export function meshwiki(args, options = {}) {
  return execFileSync(binary(), args, { encoding: 'utf8', maxBuffer: 1 << 30, env: { ...process.env, MESHWIKI_LOG: 'warn' }, ...options });
}
