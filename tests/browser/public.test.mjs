// An anonymous visitor of a public model (issue 16, item 5): without an account the viewer
// streams and draws the model, its callouts and information open, and search finds them; no
// request of the page is refused, and the page offers no editing.

import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { mkdtempSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';

import { writeRelief } from './support/env.mjs';
import { importScan, seedPart, startServer } from './support/server.mjs';
import { launch, waitViewer } from './support/browser.mjs';

let server;
let browser;
let tmp;

before(async () => {
  tmp = mkdtempSync(join(tmpdir(), 'mw-public-'));
  server = await startServer();
  browser = await launch();
});

after(async () => {
  await browser?.close();
  await server?.stop();
  if (tmp) rmSync(tmp, { recursive: true, force: true });
});

test('an anonymous visitor views, reads and searches a public model, and cannot edit', { timeout: 300_000 }, async () => {
  const model = await importScan(server.api, writeRelief(join(tmp, 'relief.ply'), 90), 'Open relief');
  await seedPart(server.api, model.id, { title: 'Carved rosette', body: 'A *rosette* on the relief.', vertexIds: [0, 1, 2, 90, 91], center: [-0.5, -0.5, 0] });
  await server.api.request('PATCH', `/api/v1/models/${model.id}`, { json: { public: true } });

  const page = await browser.page();
  const refused = [];
  page.on('response', (r) => {
    if (r.status() === 401 || r.status() === 403) refused.push(`${r.status()} ${r.url()}`);
  });
  await page.goto(`${server.base}/models/${model.id}`);
  assert.equal(new URL(page.url()).pathname, `/models/${model.id}`, 'no login asked');
  const stats = await waitViewer(page, (s) => s.triangles > 0);
  assert.ok(stats.triangles > 0);
  assert.equal(await page.locator('#viewer').getAttribute('data-can-edit'), 'false');
  assert.equal(await page.locator('.select-tools, [data-tool]').count(), 0, 'no selection tools');
  assert.match(await page.textContent('body'), /You are visiting a public model/);

  // Search from the model page lands on the part with its information.
  await page.fill('input[name=q]', 'rosette');
  await Promise.all([page.waitForNavigation(), page.press('input[name=q]', 'Enter')]);
  assert.match(await page.textContent('body'), /Carved rosette/);
  assert.deepEqual(refused, [], 'no request of the visit was refused');
});
