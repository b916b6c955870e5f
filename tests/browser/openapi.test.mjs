// The generated OpenAPI document (/api/v1/openapi.json) against a running server: every
// operation is called at least once on a real model (a scan uploaded and built through the
// real pipeline), its status must be one the document lists, its media type the documented
// one, and every JSON body must validate (ajv, JSON Schema 2020-12 as OpenAPI 3.1 uses) against
// the documented schema. Error bodies are validated too.

import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { mkdtempSync, readFileSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { basename, join } from 'node:path';

import { importStatic, writeRelief } from './support/env.mjs';
import { Api, startServer } from './support/server.mjs';

const METHODS = ['get', 'put', 'post', 'delete', 'patch'];

let server;
let tmp;
let doc;
let ajv;
const validators = new Map();
const called = new Map(); // "get /api/v1/…" → statuses seen

before(async () => {
  tmp = mkdtempSync(join(tmpdir(), 'mw-openapi-'));
  server = await startServer();
  doc = await server.api.get('/api/v1/openapi.json');
  const { Ajv2020 } = await importStatic('ajv/dist/2020.js');
  const addFormats = (await importStatic('ajv-formats')).default;
  ajv = new Ajv2020({ strict: false, allErrors: true });
  addFormats(ajv);
  for (const f of ['int32', 'int64', 'uint32', 'uint64', 'float', 'double', 'binary']) ajv.addFormat(f, true);
});

after(async () => {
  await server?.stop();
  if (tmp) rmSync(tmp, { recursive: true, force: true });
});

function validator(key, schema) {
  if (!validators.has(key)) validators.set(key, ajv.compile({ ...schema, components: doc.components }));
  return validators.get(key);
}

/**
 * Calls `method template` (path parameters from `params`) and checks the answer against the
 * document: a listed status, the listed media type, a body valid against the listed schema.
 */
async function call(method, template, params = {}, { json, body, headers = {}, query, api = server.api, expect, stream = false } = {}) {
  const op = doc.paths[template]?.[method];
  assert.ok(op, `${method} ${template} is not documented`);
  const path = template.replace(/\{(\w+)\}/g, (_, k) => {
    assert.ok(params[k] !== undefined, `${template}: no value for ${k}`);
    return encodeURIComponent(params[k]);
  });
  const url = path + (query ? `?${new URLSearchParams(query)}` : '');
  const controller = new AbortController();
  const h = { ...headers };
  if (api.cookie) h.Cookie = api.cookie;
  if (method !== 'get' && api.csrf) h['X-CSRF-Token'] = api.csrf;
  let payload = body;
  if (json !== undefined) {
    h['Content-Type'] = 'application/json';
    payload = JSON.stringify(json);
  }
  const res = await fetch(api.base + url, { method: method.toUpperCase(), headers: h, body: payload, redirect: 'manual', signal: controller.signal });
  const status = res.status;
  const what = `${method} ${url} → ${status}`;
  const type = (res.headers.get('content-type') || '').split(';')[0].trim();
  let data = null;
  let text = '';
  if (stream) {
    controller.abort();
  } else {
    const bytes = new Uint8Array(await res.arrayBuffer());
    text = new TextDecoder().decode(bytes.subarray(0, 4000));
    if (type === 'application/json') data = JSON.parse(new TextDecoder().decode(bytes));
  }
  if (expect !== undefined) assert.equal(status, expect, `${what}: ${text.slice(0, 300)}`);
  const key = `${method} ${template}`;
  if (!called.has(key)) called.set(key, new Set());
  called.get(key).add(status);
  const response = op.responses[String(status)];
  assert.ok(response, `${what}: status not documented (documented: ${Object.keys(op.responses)})`);
  const content = response.content || {};
  if (status === 204 || status === 304) {
    assert.equal(Object.keys(content).length, 0, `${what}: documented with a body`);
  } else {
    const listed = content[type] || content[`${type.split('/')[0]}/*`] || content['*/*'];
    assert.ok(listed, `${what}: media type ${type} not documented (documented: ${Object.keys(content)})`);
    const schema = listed.schema;
    if (type === 'application/json') {
      assert.ok(schema, `${what}: no schema`);
      const validate = validator(`${key} ${status}`, schema);
      assert.ok(validate(data), `${what}: body does not match its schema: ${ajv.errorsText(validate.errors)}\n${text.slice(0, 600)}`);
    }
  }
  return { status, data, headers: res.headers };
}

function multipart(fields) {
  const form = new FormData();
  for (const [name, value] of Object.entries(fields)) form.append(name, value.blob ?? value, value.name);
  return form;
}

test('every operation answers as documented on a running server', { timeout: 600_000 }, async () => {
  assert.ok(doc.openapi.startsWith('3.1'), doc.openapi);
  const api = server.api;

  // Meta and session.
  await call('get', '/api/v1/health', {}, { expect: 200 });
  await call('get', '/api/v1/openapi.json', {}, { expect: 200 });
  const anon = new Api(server.base);
  await call('post', '/api/v1/session', {}, { api: anon, json: { username: 'admin', password: 'wrong-password' }, expect: 401 });
  await call('get', '/api/v1/session', {}, { api: anon, expect: 401 });
  await call('get', '/api/v1/session', {}, { expect: 200 });

  // Users and the audit log.
  await call('get', '/api/v1/users', {}, { query: { limit: 10 }, expect: 200 });
  const user = (await call('post', '/api/v1/users', {}, { json: { username: 'olga', password: 'olga-password-1', role: 'viewer' }, expect: 201 })).data;
  await call('post', '/api/v1/users', {}, { json: { username: 'olga', password: 'olga-password-1', role: 'viewer' }, expect: 409 });
  await call('get', '/api/v1/users/{id}', { id: user.id }, { expect: 200 });
  await call('patch', '/api/v1/users/{id}', { id: user.id }, { json: { role: 'editor' }, expect: 200 });
  await call('get', '/api/v1/users/{id}', { id: 999999 }, { expect: 404 });

  // A scan uploaded and built.
  const scan = writeRelief(join(tmp, 'relief.ply'), 120);
  const upload = await call('post', '/api/v1/models/upload', {}, {
    query: { title: 'OpenAPI relief', filename: basename(scan) },
    body: readFileSync(scan),
    headers: { 'Content-Type': 'application/octet-stream' },
    expect: 202,
  });
  const modelId = upload.data.model.id;
  const jobId = upload.data.job.id;
  for (const deadline = Date.now() + 300_000; ;) {
    const j = (await call('get', '/api/v1/jobs/{id}', { id: jobId }, { expect: 200 })).data;
    if (j.status === 'done') break;
    assert.ok(!['failed', 'cancelled'].includes(j.status), `build ${j.status}: ${j.message}`);
    assert.ok(Date.now() < deadline, 'build did not finish');
    await new Promise((r) => setTimeout(r, 250));
  }
  await call('get', '/api/v1/jobs', {}, { expect: 200 });

  // The same scan through a resumable upload session: a chunk, a stale chunk, the rest.
  const bytes = readFileSync(scan);
  const session = (await call('post', '/api/v1/uploads', {}, { json: { files: [{ path: 'relief.ply', size: bytes.length }] }, expect: 201 })).data;
  const half = Math.floor(bytes.length / 2);
  const chunk = (offset, data, expect) => call('patch', '/api/v1/uploads/{id}/files/{index}', { id: session.id, index: 0 }, {
    body: data,
    headers: { 'Content-Type': 'application/offset+octet-stream', 'Upload-Offset': String(offset) },
    expect,
  });
  await chunk(0, bytes.subarray(0, half), 204);
  await chunk(0, bytes.subarray(0, half), 409);
  await chunk(half, bytes.subarray(half), 204);
  await call('get', '/api/v1/uploads/{id}', { id: session.id }, { expect: 200 });
  await call('post', '/api/v1/uploads/{id}/finish', { id: session.id }, { json: { title: 'Resumed relief' }, expect: 202 });
  const dropped = (await call('post', '/api/v1/uploads', {}, { json: { files: [{ path: 'relief.ply', size: 10 }] }, expect: 201 })).data;
  await call('delete', '/api/v1/uploads/{id}', { id: dropped.id }, { expect: 204 });
  await call('post', '/api/v1/jobs/{id}/cancel', { id: jobId }, { expect: 409 });
  await call('get', '/api/v1/audit', {}, { query: { limit: 5 }, expect: 200 });

  // The limits clients size requests to: one object, served and embedded in the model page.
  const config = (await call('get', '/api/v1/config', {}, { expect: 200 })).data;
  const page = await (await fetch(`${server.base}/models/${modelId}`, { headers: { Cookie: api.cookie } })).text();
  const embedded = /<script type="application\/json" id="viewer-data">(.*?)<\/script>/s.exec(page);
  assert.ok(embedded, 'the model page embeds the viewer data');
  assert.deepEqual(JSON.parse(embedded[1]).config, config);

  // Models.
  await call('get', '/api/v1/models', {}, { expect: 200 });
  const model = (await call('get', '/api/v1/models/{id}', { id: modelId }, { expect: 200 })).data;
  await call('patch', '/api/v1/models/{id}', { id: modelId }, { json: { description: 'A relief for the contract test.' }, expect: 200 });
  const empty = (await call('post', '/api/v1/models', {}, { json: { title: 'Empty' }, expect: 201 })).data;
  await call('get', '/api/v1/models/{id}/lod', { id: empty.id }, { expect: 409 });
  await call('delete', '/api/v1/models/{id}', { id: empty.id }, { expect: 204 });

  // The LOD hierarchy, patches and file.
  const lod = await call('get', '/api/v1/models/{id}/lod', { id: modelId }, { expect: 200 });
  await call('get', '/api/v1/models/{id}/lod', { id: modelId }, { headers: { 'If-None-Match': lod.headers.get('etag') }, expect: 304 });
  await call('get', '/api/v1/models/{id}/lod', { id: modelId }, { query: { format: 'binary' }, expect: 200 });
  await call('get', '/api/v1/models/{id}/lod/patches/{node}', { id: modelId, node: 0 }, { expect: 200 });
  await call('get', '/api/v1/models/{id}/lod/patches/{node}', { id: modelId, node: 0 }, { headers: { Range: 'bytes=0-7' }, expect: 206 });
  await call('get', '/api/v1/models/{id}/lod/patches/{node}', { id: modelId, node: 0 }, { headers: { Range: 'bytes=99999999-' }, expect: 416 });
  await call('get', '/api/v1/models/{id}/lod/file', { id: modelId }, { headers: { Range: 'bytes=0-63' }, expect: 206 });

  // Rendering.
  const view = { w: 64, h: 48 };
  await call('get', '/api/v1/models/{id}/render', { id: modelId }, { query: view, expect: 200 });
  await call('get', '/api/v1/models/{id}/render/buffers', { id: modelId }, { query: view, expect: 200 });
  await call('get', '/api/v1/models/{id}/render', { id: modelId }, { query: { w: 0, h: 48 }, expect: 400 });

  // Parts and their history.
  const [cx, cy, cz] = [0, 0, 0.15];
  const part = (await call('post', '/api/v1/models/{id}/parts', { id: modelId }, { json: { kind: 'region', center: [cx, cy, cz], vertex_ids: [0, 1, 2, 3], comment: 'first' }, expect: 201 })).data;
  await call('get', '/api/v1/models/{id}/parts', { id: modelId }, { expect: 200 });
  await call('get', '/api/v1/parts/{id}', { id: part.id }, { expect: 200 });
  await call('patch', '/api/v1/parts/{id}', { id: part.id }, { json: { vertex_ids: [0, 1, 2, 3, 4], comment: 'grown' }, expect: 200 });
  await call('patch', '/api/v1/parts/{id}', { id: part.id }, { json: { colour: 'red' }, expect: 400 });
  await call('get', '/api/v1/parts/{id}/vertices', { id: part.id }, { expect: 200 });
  const revisions = (await call('get', '/api/v1/parts/{id}/revisions', { id: part.id }, { expect: 200 })).data;
  assert.ok(revisions.length >= 2);
  await call('get', '/api/v1/parts/{id}/revisions/{number}/vertices', { id: part.id, number: 1 }, { expect: 200 });
  await call('get', '/api/v1/models/{id}/render/callouts', { id: modelId }, { query: { ...view, parts: String(part.id) }, expect: 200 });

  // Selections: a point pick on the rendered view, confirmed into a part; a draft discarded.
  const camera = { eye: [0, -0.6, 1.6], target: [0, 0, 0], up: [0, 0, 1], fovy: 45, width: 64, height: 48 };
  const pick = { tool: 'point', camera, point: [32, 24] };
  const draft = (await call('post', '/api/v1/models/{id}/selections', { id: modelId }, { json: pick, expect: 201 })).data;
  await call('get', '/api/v1/selections/{draft}', { draft: draft.id }, { expect: 200 });
  await call('get', '/api/v1/selections/{draft}/mask', { draft: draft.id }, { expect: 200 });
  await call('get', '/api/v1/selections/{draft}/vertices', { draft: draft.id }, { expect: 200 });
  await call('post', '/api/v1/selections/{draft}/confirm', { draft: draft.id }, { json: { comment: 'picked' }, expect: 201 });
  const other = (await call('post', '/api/v1/models/{id}/selections', { id: modelId }, { json: pick, expect: 201 })).data;
  await call('delete', '/api/v1/selections/{draft}', { draft: other.id }, { expect: 204 });
  await call('get', '/api/v1/selections/{draft}', { draft: other.id }, { expect: 404 });
  await call('post', '/api/v1/models/{id}/selections', { id: modelId }, { json: { ...pick, tool: 'brush' }, expect: 400 });

  // Surface segments: the scales, a segment's vertices (and 304), a segment click.
  const scales = (await call('get', '/api/v1/models/{id}/segments', { id: modelId }, { expect: 200 })).data;
  const scale = scales.suggested_scale;
  const seg = await call('get', '/api/v1/models/{id}/segments/{scale}/vertices', { id: modelId, scale }, { query: { vertex: draft.point.vertex }, expect: 200 });
  assert.ok(seg.headers.get('x-segment'), 'X-Segment names the segment');
  await call('get', '/api/v1/models/{id}/segments/{scale}/vertices', { id: modelId, scale }, { query: { vertex: draft.point.vertex }, headers: { 'If-None-Match': seg.headers.get('etag') }, expect: 304 });
  await call('get', '/api/v1/models/{id}/segments/{scale}/vertices', { id: modelId, scale: scales.scales.length }, { query: { vertex: 0 }, expect: 400 });
  await call('get', '/api/v1/models/{id}/segments/{scale}/vertices', { id: modelId, scale }, { query: { vertex: 4000000000 }, expect: 404 });
  const segmentDraft = (await call('post', '/api/v1/models/{id}/selections', { id: modelId }, { json: { ...pick, tool: 'segment', scale }, expect: 201 })).data;
  assert.equal(segmentDraft.segment.id, Number(seg.headers.get('x-segment')));
  await call('delete', '/api/v1/selections/{draft}', { draft: segmentDraft.id }, { expect: 204 });

  // Contents: edits, a conflict, history, diff, revert, preview.
  await call('post', '/api/v1/preview', {}, { json: { body: '*Preview*' }, expect: 200 });
  const content = (await call('post', '/api/v1/contents', {}, { json: { title: 'Apse', caption: 'East end', body: 'First *text*.' }, expect: 201 })).data;
  await call('get', '/api/v1/contents', {}, { expect: 200 });
  await call('get', '/api/v1/contents/{id}', { id: content.id }, { expect: 200 });
  await call('put', '/api/v1/contents/{id}', { id: content.id }, { json: { base_revision: 1, title: 'Apse', body: 'Second text.', comment: 'edit' }, expect: 200 });
  await call('put', '/api/v1/contents/{id}', { id: content.id }, { json: { base_revision: 1, title: 'Apse', body: 'Stale edit.' }, expect: 409 });
  await call('get', '/api/v1/contents/{id}/revisions', { id: content.id }, { expect: 200 });
  await call('get', '/api/v1/contents/{id}/revisions/{number}', { id: content.id, number: 1 }, { expect: 200 });
  await call('get', '/api/v1/contents/{id}/diff', { id: content.id }, { query: { from: 1, to: 2 }, expect: 200 });
  await call('post', '/api/v1/contents/{id}/revert', { id: content.id }, { json: { revision: 1, base_revision: 2, comment: 'back' }, expect: 200 });

  // Assignments.
  const second = (await call('post', '/api/v1/contents', {}, { json: { title: 'Nave', body: '' }, expect: 201 })).data;
  await call('post', '/api/v1/parts/{id}/contents', { id: part.id }, { json: { content_id: content.id }, expect: 201 });
  await call('post', '/api/v1/parts/{id}/contents', { id: part.id }, { json: { content_id: second.id }, expect: 201 });
  await call('get', '/api/v1/parts/{id}/contents', { id: part.id }, { expect: 200 });
  await call('put', '/api/v1/parts/{id}/contents', { id: part.id }, { json: { content_ids: [second.id, content.id] }, expect: 200 });
  await call('get', '/api/v1/contents/{id}/parts', { id: content.id }, { expect: 200 });
  await call('delete', '/api/v1/parts/{id}/contents/{content_id}', { id: part.id, content_id: second.id }, { expect: 204 });

  // Attachments.
  const image = await fetch(`${server.base}/api/v1/models/${modelId}/render?w=16&h=16`, { headers: { Cookie: api.cookie } });
  const imageBytes = new Uint8Array(await image.arrayBuffer());
  const file = () => ({ blob: new Blob([imageBytes], { type: 'image/png' }), name: 'view.png' });
  const attachment = (await call('post', '/api/v1/attachments', {}, { body: multipart({ file: file() }), expect: 201 })).data;
  await call('get', '/api/v1/attachments/{id}', { id: attachment.id }, { expect: 200 });
  await call('get', '/api/v1/attachments/{id}/download', { id: attachment.id }, { expect: 200 });
  await call('post', '/api/v1/contents/{id}/attachments', { id: content.id }, { body: multipart({ file: file() }), expect: 201 });
  await call('put', '/api/v1/contents/{id}/attachments/{attachment_id}', { id: second.id, attachment_id: attachment.id }, { expect: 200 });
  await call('get', '/api/v1/contents/{id}/attachments', { id: second.id }, { expect: 200 });
  await call('delete', '/api/v1/contents/{id}/attachments/{attachment_id}', { id: second.id, attachment_id: attachment.id }, { expect: 204 });

  // The network mode: a small image repository, its images, a refused grid.
  await call('get', '/api/v1/models/{id}/lumigraph', { id: modelId }, { expect: 200 });
  await call('post', '/api/v1/models/{id}/lumigraph', { id: modelId }, { json: { grid: 0 }, expect: 400 });
  const repo = (await call('post', '/api/v1/models/{id}/lumigraph', { id: modelId }, { json: { grid: 2, size: 32 }, expect: 202 })).data;
  for (let k = 0; k < 600; k++) {
    const j = (await call('get', '/api/v1/jobs/{id}', { id: repo.job.id }, { expect: 200 })).data;
    if (j.status === 'done') break;
    assert.ok(j.status === 'queued' || j.status === 'running', `repository job ${j.status}: ${j.message}`);
    await new Promise((r) => setTimeout(r, 200));
  }
  const statuses = new Set();
  for (let k = 0; k < 48; k++) {
    const key = { id: modelId, x: k & 1, y: (k >> 1) & 1, z: (k >> 2) & 1, d: k >> 3 };
    statuses.add((await call('get', '/api/v1/models/{id}/lumigraph/images/{x}/{y}/{z}/{d}', key)).status);
  }
  assert.ok(statuses.has(200), `no image among ${[...statuses]}`);
  await call('get', '/api/v1/models/{id}/lumigraph/images/{x}/{y}/{z}/{d}', { id: modelId, x: 2, y: 0, z: 0, d: 0 }, { expect: 404 });

  // Search and live events.
  await call('get', '/api/v1/search', {}, { query: { q: 'apse' }, expect: 200 });
  await call('get', '/api/v1/models/{id}/events', { id: modelId }, { stream: true, expect: 200 });

  // Deletions, then the session ends.
  await call('delete', '/api/v1/contents/{id}', { id: second.id }, { expect: 204 });
  await call('delete', '/api/v1/parts/{id}', { id: part.id }, { expect: 204 });
  await call('delete', '/api/v1/users/{id}', { id: user.id }, { expect: 200 });
  assert.equal(model.id, modelId);
  const otherSession = new Api(server.base);
  await otherSession.login();
  await call('delete', '/api/v1/session', {}, { api: otherSession, expect: 204 });

  // Every documented operation was called.
  const missing = [];
  for (const [path, item] of Object.entries(doc.paths)) {
    for (const m of METHODS) if (item[m] && !called.has(`${m} ${path}`)) missing.push(`${m} ${path}`);
  }
  assert.deepEqual(missing, [], `operations never called: ${missing.join(', ')}`);
});
