// Headless Chromium (Debian's package) driven by playwright-core: no browser download.

import { mkdtempSync, rmSync, existsSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';

import { importStatic } from './env.mjs';

export const CHROMIUM = process.env.MESHWIKI_CHROMIUM || '/usr/bin/chromium';

/** Launches Chromium with a fresh profile; `close()` also removes the profile. */
export async function launch() {
  if (!existsSync(CHROMIUM)) throw new Error(`${CHROMIUM} is missing: apt-get install chromium`);
  const pw = await importStatic('playwright-core');
  const chromium = pw.chromium || pw.default.chromium;
  const profile = mkdtempSync(join(tmpdir(), 'mw-chromium-'));
  const context = await chromium.launchPersistentContext(profile, {
    executablePath: CHROMIUM,
    headless: true,
    viewport: { width: 1100, height: 800 },
    args: [
      '--headless',
      '--no-sandbox',
      '--disable-gpu',
      '--disable-background-networking',
      '--disable-component-update',
      '--disable-sync',
      '--no-first-run',
      '--enable-unsafe-swiftshader',
      '--use-angle=swiftshader',
    ],
  });
  return {
    context,
    async page() {
      const page = await context.newPage();
      page.on('pageerror', (e) => console.log(`# page error: ${e.message}`));
      page.on('console', (m) => {
        if (m.type() === 'error' || m.type() === 'warning') console.log(`# console ${m.type()}: ${m.text()}`);
      });
      return page;
    },
    async close() {
      await context.close();
      rmSync(profile, { recursive: true, force: true });
    },
  };
}

/** Logs the page's context in through the login form. */
export async function login(page, base, user) {
  await page.goto(`${base}/login`);
  if ((await page.locator('input[name=username]').count()) === 0) return; // already logged in
  await page.fill('input[name=username]', user.username);
  await page.fill('input[name=password]', user.password);
  await Promise.all([page.waitForNavigation(), page.click('button[type=submit]')]);
}

const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

/** Longest wait for one evaluation of `poll` before it is asked again. */
const EVALUATE_STALL_MS = 15_000;

/**
 * Polls `fn` in the page (page.evaluate, which the page's CSP allows, unlike string
 * predicates) until `accept(value)` holds in Node; returns the value. A navigation of the
 * page while polling is waited out, not an error.
 */
export async function poll(page, fn, accept = Boolean, timeout = 60_000, arg = undefined) {
  const end = Date.now() + timeout;
  let value;
  for (;;) {
    try {
      // An evaluation caught in a reload can also stall for good instead of failing (seen
      // once: the upload test's zip case hung to its 10-minute timeout after its model was
      // ready): it is abandoned after EVALUATE_STALL_MS and asked again, like a lost one.
      let timer;
      const stalled = new Promise((_, reject) => {
        timer = setTimeout(() => reject(new Error('evaluation stalled')), Math.min(EVALUATE_STALL_MS, Math.max(end - Date.now(), 1000)));
      });
      const evaluation = page.evaluate(fn, arg);
      evaluation.catch(() => {}); // an abandoned evaluation may still fail later
      try {
        value = await Promise.race([evaluation, stalled]);
      } finally {
        clearTimeout(timer);
      }
    } catch (err) {
      // The page may navigate or reload itself (a model page does when its build ends):
      // the evaluation is lost with the old document and asked again of the new one.
      if (!/Execution context was destroyed|because of a navigation|evaluation stalled/i.test(String(err && err.message)) || Date.now() > end) throw err;
      await sleep(100);
      continue;
    }
    if (accept(value)) return value;
    if (Date.now() > end) throw new Error(`timed out; last value ${JSON.stringify(value)?.slice(0, 400)}`);
    await sleep(100);
  }
}

/**
 * `page.goto(url)` on a page that may navigate by itself meanwhile (a model page reloads
 * when its build ends): a navigation interrupted or aborted by it is tried again.
 */
/**
 * Closes a page, giving up after `ms` (the browser closes it with its context at the end).
 * The upload test's zip case twice hung to its 10-minute timeout in a full run after its model
 * was built (never in 10 runs of that file alone); of its awaits, only this one and the
 * evaluations that `poll` now guards had no bound.
 */
export async function closePage(page, ms = 15_000) {
  let timer;
  const gaveUp = new Promise((resolve) => {
    timer = setTimeout(() => resolve('gave up'), ms);
  });
  const closing = page.close();
  closing.catch(() => {});
  const outcome = await Promise.race([closing, gaveUp]);
  clearTimeout(timer);
  if (outcome === 'gave up') console.log(`# closing the page took over ${ms} ms: left to the browser`);
}

export async function gotoSettled(page, url, tries = 5) {
  for (let k = 1; ; k++) {
    try {
      return await page.goto(url);
    } catch (err) {
      if (k >= tries || !/interrupted by another navigation|because of a navigation|net::ERR_ABORTED/i.test(String(err && err.message))) throw err;
      await page.waitForLoadState('load').catch(() => {});
    }
  }
}

/** Waits until the viewer runs and `pred(stats)` holds; returns the stats. */
export async function waitViewer(page, pred = () => true, timeout = 120_000) {
  const state = await poll(page, () => {
    const v = document.getElementById('viewer');
    return v ? { ready: v.dataset.ready === 'true', error: v.dataset.error || null } : { ready: false };
  }, (s) => s.ready || s.error, timeout);
  if (state.error) throw new Error(`viewer failed: ${state.error}`);
  return poll(page, () => window.meshwikiViewer.stats(), pred, timeout);
}
