// Helpers of the region-selection browser test: pointer gestures on the viewer (a closed path
// dragged with the mouse), where the surface is in a captured frame, the selection's state and
// the draft count shown in the toolbar, and dropping a file onto an element.

import { poll } from './browser.mjs';

/** `n` points on a circle of radius `r` around (cx, cy), in page coordinates. */
export function circle(cx, cy, r, n = 28) {
  return Array.from({ length: n }, (_, k) => {
    const a = (k / n) * Math.PI * 2;
    return { x: cx + Math.cos(a) * r, y: cy + Math.sin(a) * r };
  });
}

/** Presses the left button at the first point, moves through the others, releases. */
export async function drag(page, points, { modifiers = [] } = {}) {
  for (const m of modifiers) await page.keyboard.down(m);
  await page.mouse.move(points[0].x, points[0].y);
  await page.mouse.down();
  for (const p of points.slice(1)) await page.mouse.move(p.x, p.y, { steps: 3 });
  await page.mouse.up();
  for (const m of modifiers) await page.keyboard.up(m);
}

/** Centroid (CSS px inside the canvas) of the surface pixels of captured frame `name` that no
 * open drawer covers, and where the uncovered part of the view ends (`right`). */
export function surfaceCentre(page, name) {
  return page.evaluate((name) => {
    const f = window.__frames[name];
    const canvas = document.querySelector('.viewer-canvas');
    const dpr = f.w / canvas.clientWidth;
    // Only what an open drawer (the information panel, the assign step) leaves in sight.
    const view = canvas.getBoundingClientRect();
    const drawer = [...document.querySelectorAll('.drawer')].find((d) => !d.hidden);
    const right = drawer ? Math.min(f.w, Math.floor((drawer.getBoundingClientRect().left - view.left) * dpr)) : f.w;
    let n = 0;
    let sx = 0;
    let sy = 0;
    for (let y = 0; y < f.h; y++) {
      for (let x = 0; x < right; x++) {
        if (!f.surface[y * f.w + x]) continue;
        n++;
        sx += x;
        sy += y;
      }
    }
    return { x: sx / n / dpr, y: sy / n / dpr, pixels: n, right: right / dpr };
  }, name);
}

/** The viewer's selection state. */
export function selection(page) {
  return page.evaluate(() => window.meshwikiViewer.selection());
}

/** Waits until the selection is idle and `pred(state)` holds. */
export function waitSelection(page, pred, timeout = 30_000) {
  return poll(page, () => window.meshwikiViewer.selection(), (s) => s && !s.busy && pred(s), timeout);
}

/** The vertex count the toolbar shows for the draft (null when none). */
export async function shownVertexCount(page) {
  const v = await page.locator('.select-status').getAttribute('data-vertex-count');
  return v === null ? null : Number(v);
}

/** Drops a text file onto `selector` (dragover then drop, with a real DataTransfer). */
export function dropFile(page, selector, { name, type, text }) {
  return page.evaluate(({ selector, name, type, text }) => {
    const target = document.querySelector(selector);
    const dt = new DataTransfer();
    dt.items.add(new File([text], name, { type }));
    const over = new DragEvent('dragover', { dataTransfer: dt, bubbles: true, cancelable: true });
    target.dispatchEvent(over);
    const drop = new DragEvent('drop', { dataTransfer: dt, bubbles: true, cancelable: true });
    target.dispatchEvent(drop);
    return { accepted: over.defaultPrevented, handled: drop.defaultPrevented };
  }, { selector, name, type, text });
}
