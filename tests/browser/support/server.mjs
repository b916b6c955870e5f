// A real meshwiki server for the browser tests and the bench: the binary on a temporary data
// directory and an ephemeral port, an admin created through the CLI, an API client with the
// session cookie and CSRF token, and the import of a scan through the real pipeline.

import { spawn, execFileSync } from 'node:child_process';
import { mkdtempSync, readFileSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { basename, join } from 'node:path';
import { createInterface } from 'node:readline';

import { binary } from './env.mjs';

export const ADMIN = { username: 'admin', password: 'admin-password-1' };

export class Api {
  constructor(base) {
    this.base = base;
    this.cookie = '';
    this.csrf = '';
    this.bytesIn = 0;
  }

  async request(method, path, { json, body, headers = {}, raw = false } = {}) {
    const h = { ...headers };
    if (this.cookie) h.Cookie = this.cookie;
    if (method !== 'GET' && this.csrf) h['X-CSRF-Token'] = this.csrf;
    let payload = body;
    if (json !== undefined) {
      h['Content-Type'] = 'application/json';
      payload = JSON.stringify(json);
    }
    const send = () => fetch(this.base + path, { method, headers: h, body: payload, redirect: 'manual' });
    let res;
    try {
      res = await send();
    } catch (e) {
      // A kept-alive connection the server closed while idle (after a long pause of the
      // caller) fails once: a read is sent again on a fresh one.
      if (method !== 'GET') throw e;
      res = await send();
    }
    const set = res.headers.getSetCookie ? res.headers.getSetCookie() : (res.headers.get('set-cookie') || '').split(/,(?=\s*\w+=)/);
    for (const c of set) if (c.trim().startsWith('meshwiki_session=')) this.cookie = c.trim().split(';')[0];
    if (raw) return res;
    const text = await res.text();
    if (!res.ok) throw new Error(`${method} ${path}: HTTP ${res.status}: ${text.slice(0, 300)}`);
    return text ? JSON.parse(text) : null;
  }

  get(path) {
    return this.request('GET', path);
  }

  post(path, json) {
    return this.request('POST', path, { json });
  }

  async login(user = ADMIN) {
    const r = await this.post('/api/v1/session', user);
    this.csrf = r.csrf_token;
    return r;
  }
}

/** Adds a user through `meshwiki user add` (password on standard input). */
export function addUser(dataDir, name, role, password) {
  execFileSync(binary(), ['user', 'add', name, '--role', role, '--data-dir', dataDir], { input: `${password}\n`, env: { ...process.env, MESHWIKI_LOG: 'warn' } });
}

/** Starts `meshwiki serve` on a fresh data directory; resolves once it listens. */
export async function startServer({ env = {} } = {}) {
  const dataDir = mkdtempSync(join(tmpdir(), 'mw-browser-'));
  addUser(dataDir, ADMIN.username, 'admin', ADMIN.password);
  const child = spawn(binary(), ['serve', '--data-dir', dataDir, '--bind', '127.0.0.1:0', '--workers', '2'], {
    env: { ...process.env, MESHWIKI_LOG: process.env.MESHWIKI_LOG || 'warn', ...env },
    stdio: ['ignore', 'pipe', 'inherit'],
  });
  const base = await new Promise((resolve, reject) => {
    const timer = setTimeout(() => reject(new Error('server did not start within 60 s')), 60_000);
    child.on('exit', (code) => reject(new Error(`server exited with ${code}`)));
    createInterface({ input: child.stdout }).on('line', (line) => {
      const m = /^meshwiki listening on (\S+)/.exec(line);
      if (m) {
        clearTimeout(timer);
        resolve(m[1]);
      }
    });
  });
  const api = new Api(base);
  await api.login();
  return {
    base,
    dataDir,
    api,
    async stop() {
      child.kill('SIGKILL');
      await new Promise((r) => (child.exitCode !== null ? r() : child.once('exit', r)));
      rmSync(dataDir, { recursive: true, force: true });
    },
  };
}

/** Uploads a scan through `POST /api/v1/models/upload` and waits for its build; returns the model. */
export async function importScan(api, path, title, timeoutMs = 600_000, build = {}) {
  const bytes = readFileSync(path);
  const q = new URLSearchParams({ title, filename: basename(path), ...build });
  const res = await api.request('POST', `/api/v1/models/upload?${q}`, { body: bytes, headers: { 'Content-Type': 'application/octet-stream' }, raw: true });
  const text = await res.text();
  if (res.status !== 202) throw new Error(`upload: HTTP ${res.status}: ${text}`);
  const { model, job } = JSON.parse(text);
  const deadline = Date.now() + timeoutMs;
  for (;;) {
    const j = await api.get(`/api/v1/jobs/${job.id}`);
    if (j.status === 'done') break;
    if (j.status === 'failed' || j.status === 'cancelled') throw new Error(`import job ${j.status}: ${j.message}`);
    if (Date.now() > deadline) throw new Error('import did not finish in time');
    await new Promise((r) => setTimeout(r, 250));
  }
  return api.get(`/api/v1/models/${model.id}`);
}

/** Creates a content and a region part holding `vertexIds`, the content assigned to it. */
export async function seedPart(api, modelId, { title, caption = '', body = '', vertexIds, center, camera }) {
  const content = await api.post('/api/v1/contents', { title, caption, body });
  const part = await api.post(`/api/v1/models/${modelId}/parts`, { kind: 'region', center, vertex_ids: vertexIds, ...(camera ? { camera } : {}) });
  await api.post(`/api/v1/parts/${part.id}/contents`, { content_id: content.id });
  return { part, content };
}

/** The unit direction the viewer first looks at model `modelId` from (the server's home view,
 * the side the model's thumbnail shows), read from the model page's viewer data. */
export async function homeDirection(api, modelId) {
  const res = await api.request('GET', `/models/${modelId}`, { raw: true });
  const html = await res.text();
  const m = /<script type="application\/json" id="viewer-data">(.*?)<\/script>/s.exec(html);
  if (!m) throw new Error(`the model page of ${modelId} has no viewer data`);
  const home = JSON.parse(m[1]).home;
  if (!home) throw new Error(`the model page of ${modelId} has no home view`);
  const d = home.eye.map((v, k) => v - home.target[k]);
  const l = Math.hypot(...d);
  return d.map((v) => v / l);
}
