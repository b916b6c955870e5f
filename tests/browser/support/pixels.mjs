// Pixel checks on viewer frames, computed inside the page (frames never leave it): a frame is
// the canvas right after a render (`meshwikiViewer.snapshot()`), classified per pixel.

/** Captures a frame under `name`; returns counts of surface, tinted and outline pixels, the
 * background (the top-left pixel) and the mean brightness of pixels unlike it. */
export function capture(page, name) {
  return page.evaluate(async (name) => {
    const url = window.meshwikiViewer.snapshot();
    const img = new Image();
    img.src = url;
    await img.decode();
    const c = document.createElement('canvas');
    c.width = img.width;
    c.height = img.height;
    const g = c.getContext('2d');
    g.drawImage(img, 0, 0);
    const d = g.getImageData(0, 0, c.width, c.height).data;
    const n = c.width * c.height;
    const surface = new Uint8Array(n);
    const rgb = new Uint8Array(n * 3);
    let count = 0;
    let hover = 0;
    let selected = 0;
    let outline = 0;
    const corner = [d[0], d[1], d[2]];
    let unlike = 0;
    let brightness = 0;
    for (let i = 0; i < n; i++) {
      const r = d[i * 4];
      const gg = d[i * 4 + 1];
      const b = d[i * 4 + 2];
      rgb[i * 3] = r;
      rgb[i * 3 + 1] = gg;
      rgb[i * 3 + 2] = b;
      // Background 0x1d2026.
      const bg = Math.abs(r - 29) + Math.abs(gg - 32) + Math.abs(b - 38) <= 12;
      surface[i] = bg ? 0 : 1;
      if (Math.abs(r - corner[0]) + Math.abs(gg - corner[1]) + Math.abs(b - corner[2]) > 12) {
        unlike++;
        brightness += (r + gg + b) / 3;
      }
      count += surface[i];
      if (r > 200 && gg > 170 && b < 90) outline++;
      else if (r - b > 60 && gg - b > 30) hover++;
      else if (b - r > 60) selected++;
    }
    window.__frames = window.__frames || {};
    window.__frames[name] = { w: c.width, h: c.height, surface };
    window.__frames[`${name}:rgb`] = rgb;
    return { width: c.width, height: c.height, surface: count, fraction: count / n, hover, selected, outline, background: corner, meanSurface: unlike ? brightness / unlike : 0 };
  }, name);
}

/**
 * Pixels that are surface in frame `final` (eroded by `erode` pixels, so silhouettes of
 * coarser levels do not count) but background in frame `name`: holes.
 */
export function holes(page, name, final, erode = 4) {
  return page.evaluate(({ name, final, erode }) => {
    const a = window.__frames[name];
    const f = window.__frames[final];
    if (a.w !== f.w || a.h !== f.h) throw new Error('frames differ in size');
    let holes = 0;
    let interior = 0;
    for (let y = erode; y < f.h - erode; y++) {
      for (let x = erode; x < f.w - erode; x++) {
        let inside = true;
        for (let dy = -erode; dy <= erode && inside; dy++) {
          for (let dx = -erode; dx <= erode; dx++) {
            if (!f.surface[(y + dy) * f.w + x + dx]) {
              inside = false;
              break;
            }
          }
        }
        if (!inside) continue;
        interior++;
        if (!a.surface[y * f.w + x]) holes++;
      }
    }
    return { holes, interior };
  }, { name, final, erode });
}

/** The server render (`GET /api/v1/models/{id}/render`) of the viewer's current camera at the
 * size of the captured `frame`. */
export async function serverRenderUrl(page, modelId, frame) {
  const cam = await page.evaluate(() => window.meshwikiViewer.camera());
  const q = new URLSearchParams({
    eye: cam.eye.join(','),
    target: cam.target.join(','),
    up: cam.up.join(','),
    fovy: String(cam.fovy),
    w: String(frame.width),
    h: String(frame.height),
  });
  return `/api/v1/models/${modelId}/render?${q}`;
}

/** Compares frame `name` with an image URL (same origin), over pixels that are surface in both. */
export function compareWithImage(page, name, url) {
  return page.evaluate(async ({ name, url }) => {
    const f = window.__frames[name];
    const img = new Image();
    img.src = url;
    await img.decode();
    const c = document.createElement('canvas');
    c.width = f.w;
    c.height = f.h;
    const g = c.getContext('2d');
    g.drawImage(img, 0, 0, f.w, f.h);
    const d = g.getImageData(0, 0, f.w, f.h).data;
    const ours = window.__frames[name + ':rgb'];
    let both = 0;
    let onlyOurs = 0;
    let onlyTheirs = 0;
    let diff = 0;
    let squared = 0;
    for (let i = 0; i < f.w * f.h; i++) {
      const theirs = d[i * 4 + 3] > 128 && d[i * 4] + d[i * 4 + 1] + d[i * 4 + 2] > 0;
      if (f.surface[i] && theirs) {
        both++;
        if (ours) {
          for (let k = 0; k < 3; k++) {
            const e = ours[i * 3 + k] - d[i * 4 + k];
            diff += Math.abs(e);
            squared += e * e;
          }
        }
      } else if (f.surface[i]) onlyOurs++;
      else if (theirs) onlyTheirs++;
    }
    const union = both + onlyOurs + onlyTheirs;
    const mse = both && ours ? squared / (both * 3) : null;
    // PSNR over the pixels both show (the silhouettes' agreement is `iou`).
    const psnr = mse === null ? null : mse === 0 ? Infinity : 10 * Math.log10((255 * 255) / mse);
    return { iou: union ? both / union : 1, meanAbsDiff: both && ours ? diff / (both * 3) : null, psnr, both, onlyOurs, onlyTheirs };
  }, { name, url });
}
