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
  await page.fill('input[name=username]', user.username);
  await page.fill('input[name=password]', user.password);
  await Promise.all([page.waitForNavigation(), page.click('button[type=submit]')]);
}

/** Waits until the viewer exposes its API and `pred(stats)` holds. */
export async function waitViewer(page, pred = 'true', timeout = 120_000) {
  await page.waitForFunction(() => document.getElementById('viewer')?.dataset.ready === 'true' || document.getElementById('viewer')?.dataset.error, null, { timeout });
  const error = await page.evaluate(() => document.getElementById('viewer').dataset.error);
  if (error) throw new Error(`viewer failed: ${error}`);
  await page.waitForFunction((p) => p(window.meshwikiViewer.stats()), pred, { timeout, polling: 100 });
  return page.evaluate(() => window.meshwikiViewer.stats());
}
