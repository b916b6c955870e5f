// Accessibility (issue 16): axe-core (WCAG 2.0/2.1 A and AA rules) on the pages people use —
// models, a model with its viewer, a content, search, and the admin pages — reports no
// serious or critical violation.

import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { mkdtempSync, readFileSync, rmSync } from 'node:fs';
import { createRequire } from 'node:module';
import { tmpdir } from 'node:os';
import { join } from 'node:path';

import { ROOT, writeRelief } from './support/env.mjs';
import { ADMIN, importScan, seedPart, startServer } from './support/server.mjs';
import { launch, login, waitViewer } from './support/browser.mjs';

let server;
let browser;
let tmp;
let model;
let seeded;

before(async () => {
  tmp = mkdtempSync(join(tmpdir(), 'mw-a11y-'));
  server = await startServer();
  model = await importScan(server.api, writeRelief(join(tmp, 'relief.ply'), 60), 'Accessible relief');
  seeded = await seedPart(server.api, model.id, { title: 'Rosette', body: 'A *carved* rosette.', vertexIds: [0, 1, 2, 60, 61], center: [-0.5, -0.5, 0] });
  browser = await launch();
});

after(async () => {
  await browser?.close();
  await server?.stop();
  if (tmp) rmSync(tmp, { recursive: true, force: true });
});

const AXE = readFileSync(createRequire(join(ROOT, 'static', 'package.json')).resolve('axe-core/axe.min.js'), 'utf8');

async function violations(page) {
  // The pages' CSP forbids inline scripts: the checker is evaluated through the debugger.
  await page.evaluate(AXE);
  return page.evaluate(async () => {
    const r = await window.axe.run(document, { runOnly: { type: 'tag', values: ['wcag2a', 'wcag2aa', 'wcag21a', 'wcag21aa'] } });
    return r.violations
      .filter((v) => v.impact === 'serious' || v.impact === 'critical')
      .map((v) => `${v.id} (${v.impact}): ${v.help} — ${v.nodes.slice(0, 3).map((n) => n.target.join(' ')).join(', ')}`);
  });
}

test('no serious or critical accessibility violation on the everyday pages', { timeout: 300_000 }, async () => {
  const page = await browser.page();
  await login(page, server.base, ADMIN);
  const pages = [
    '/models',
    `/models/${model.id}`,
    `/contents/${seeded.content.id}`,
    `/contents/${seeded.content.id}/history`,
    `/contents/${seeded.content.id}/edit`,
    '/search?q=rosette',
    '/admin/jobs',
    '/admin/users',
  ];
  const found = [];
  for (const path of pages) {
    await page.goto(`${server.base}${path}`);
    if (path === `/models/${model.id}`) await waitViewer(page, (s) => s.drawn > 0);
    for (const v of await violations(page)) found.push(`${path}: ${v}`);
  }
  const anon = await browser.page();
  await anon.context().clearCookies();
  await anon.goto(`${server.base}/login`);
  for (const v of await violations(anon)) found.push(`/login: ${v}`);
  assert.deepEqual(found, [], found.join('\n'));
});
