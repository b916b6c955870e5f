// Two colleagues edit the same page in two browsers (issue 16, item 1). Edits of different
// lines are merged three-way against their common base and saved with both kept; edits of the
// same line stop at the merge page, both versions between markers, and the page refuses to
// save until the person has resolved them.

import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';

import { addUser, startServer } from './support/server.mjs';
import { launch, login } from './support/browser.mjs';

const ALICE = { username: 'alice', password: 'alice-password-1' };
const BOB = { username: 'bob', password: 'bob-password-1' };
const BODY = [
  '# The apse',
  '',
  'The apse was rebuilt in 1420.',
  '',
  'Its vault is painted.',
  '',
  'The altar is lost.',
  '',
].join('\n');

let server;
let alice;
let bob;

before(async () => {
  server = await startServer();
  addUser(server.dataDir, ALICE.username, 'editor', ALICE.password);
  addUser(server.dataDir, BOB.username, 'editor', BOB.password);
  alice = await launch();
  bob = await launch();
});

after(async () => {
  await alice?.close();
  await bob?.close();
  await server?.stop();
});

async function openEditor(browser, user, id) {
  const page = await browser.page();
  await login(page, server.base, user);
  await page.goto(`${server.base}/contents/${id}/edit`);
  return page;
}

async function body(page) {
  return page.inputValue('textarea[name=body]');
}

async function save(page) {
  await Promise.all([page.waitForNavigation(), page.click('button[name=action][value=save]')]);
}

test('a colleague\'s edit of other lines is merged, never dropped; an overlap asks the person', { timeout: 120_000 }, async () => {
  const content = await server.api.post('/api/v1/contents', { title: 'Apse', caption: 'East end', body: BODY });

  // Both open the editor on revision 1.
  const a = await openEditor(alice, ALICE, content.id);
  const b = await openEditor(bob, BOB, content.id);
  assert.equal(await body(a), BODY);
  assert.equal(await body(b), BODY);

  // Alice saves first; Bob, still on revision 1, changes another line and saves.
  await a.fill('textarea[name=body]', (await body(a)).replace('in 1420.', 'in 1420, as recorded during the May survey.'));
  await save(a);
  assert.match(a.url(), new RegExp(`/contents/${content.id}$`));
  await b.fill('textarea[name=body]', (await body(b)).replace('is painted.', 'is painted with stars.'));
  await b.fill('input[name=comment]', 'the vault');
  await save(b);
  assert.match(b.url(), new RegExp(`/contents/${content.id}\\?merged=2$`), 'the merged save lands on the page');
  const notice = await b.textContent('.notice');
  assert.match(notice, /alice had saved revision 2/);
  const prose = await b.textContent('.prose');
  assert.match(prose, /during the May survey/, 'Alice\'s words are kept');
  assert.match(prose, /painted with stars/, 'Bob\'s words are kept');
  const saved = await server.api.get(`/api/v1/contents/${content.id}`);
  assert.equal(saved.current_revision, 3);
  assert.ok(saved.body.includes('during the May survey') && saved.body.includes('painted with stars'));
  const history = await server.api.get(`/api/v1/contents/${content.id}/revisions`);
  assert.deepEqual(history.map((r) => r.author), ['bob', 'alice', 'admin']);

  // Both change the same line: Bob gets the merge page with both versions between markers.
  const a2 = await openEditor(alice, ALICE, content.id);
  const b2 = await openEditor(bob, BOB, content.id);
  await a2.fill('textarea[name=body]', (await body(a2)).replace('The altar is lost.', 'The altar was moved to the museum.'));
  await save(a2);
  await b2.fill('textarea[name=body]', (await body(b2)).replace('The altar is lost.', 'The altar burnt in 1944.'));
  await save(b2);
  assert.match(await b2.textContent('h1'), /Edit conflict/);
  assert.match(await b2.textContent('[role=alert]'), /1 place where you both changed the same lines/);
  const marked = await body(b2);
  assert.match(marked, /^<<<<<<< yours\nThe altar burnt in 1944\.\n=======\nThe altar was moved to the museum\.\n>>>>>>> theirs$/m);
  assert.match(marked, /during the May survey/);
  assert.match(marked, /painted with stars/);
  assert.match(await b2.textContent('section.theirs'), /moved to the museum/, 'their change is shown as theirs');
  assert.match(await b2.textContent('section.yours'), /burnt in 1944/);

  // Saving with the markers left is refused, and nothing is lost.
  await save(b2);
  assert.match(await b2.textContent('[role=alert]'), /still holds an edit conflict/);
  assert.equal(await body(b2), marked);
  assert.equal((await server.api.get(`/api/v1/contents/${content.id}`)).current_revision, 4);

  // Resolved by hand: both facts kept.
  await b2.fill('textarea[name=body]', marked.replace(/<<<<<<< yours\n(.*)\n=======\n(.*)\n>>>>>>> theirs/, '$2 It had burnt in 1944.'));
  await save(b2);
  assert.match(b2.url(), new RegExp(`/contents/${content.id}$`));
  const final = await server.api.get(`/api/v1/contents/${content.id}`);
  assert.equal(final.current_revision, 5);
  assert.match(final.body, /The altar was moved to the museum\. It had burnt in 1944\./);
  assert.ok(final.body.includes('during the May survey') && final.body.includes('painted with stars'));
});
