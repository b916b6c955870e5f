// A shared view survives the login (issue 16, item 5): a logged-out colleague opening a link
// with the viewer's camera (`/models/1#camera=…`) is sent to the login page and, once logged
// in, lands on that link with its camera, not on the default view. A failed attempt keeps it.

import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';

import { ADMIN, startServer } from './support/server.mjs';
import { launch } from './support/browser.mjs';

let server;
let browser;

before(async () => {
  server = await startServer();
  browser = await launch();
});

after(async () => {
  await browser?.close();
  await server?.stop();
});

test('a camera link survives the login redirect, even after a wrong password', { timeout: 60_000 }, async () => {
  const model = await server.api.post('/api/v1/models', { title: 'Shared view' });
  const hash = '#camera=0.5,-1.25,2,0,0,0.1,0,0,1,38';
  const link = `${server.base}/models/${model.id}${hash}`;
  const page = await browser.page();
  await page.goto(link);
  assert.match(new URL(page.url()).pathname, /^\/login$/, 'a logged-out visitor is asked to log in');
  assert.equal(new URL(page.url()).searchParams.get('next'), `/models/${model.id}`);

  // A wrong password first: the page comes back, the view still travels with the form.
  await page.fill('input[name=username]', ADMIN.username);
  await page.fill('input[name=password]', 'not-the-password');
  await Promise.all([page.waitForNavigation(), page.click('button[type=submit]')]);
  assert.ok(await page.locator('[role=alert]').count(), 'the failure is said');
  assert.equal(await page.inputValue('input[name=next]'), `/models/${model.id}${hash}`);

  await page.fill('input[name=username]', ADMIN.username);
  await page.fill('input[name=password]', ADMIN.password);
  await Promise.all([page.waitForNavigation(), page.click('button[type=submit]')]);
  const landed = new URL(page.url());
  assert.equal(landed.pathname, `/models/${model.id}`);
  assert.equal(landed.hash, hash, 'the camera of the link is kept');
  assert.match(await page.textContent('h1'), /Shared view/);
});
