#!/usr/bin/env python3
"""JPEG against lossy WebP on atlas-like images: how far apart the two quality scales are at
equal error, and what WebP saves there (`engine/src/lod/webp_match.rs` finds the offset on
each build's own atlases).

An atlas holds charts (irregular regions of a photograph) with a smooth fill between them
(the build's push-pull). Each crop here is a random square of the texture, with a blob-shaped
region of 40–60% kept as the chart and the rest filled by diffusion from it. Every crop is
encoded by JPEG (libjpeg's standard tables, 4:2:0, the build's baseline layout) and by WebP
(libwebp, method 2 as the build uses, `atlas::WEBP_METHOD`), and scored over the chart's
texels only, as the build's `TextureReport` scores an atlas. Bytes are per chart texel:
JPEG's as the build stores them (without the JFIF segment and tables, `jpegtables`), WebP's
whole.

For each JPEG quality it prints the PSNR and the WebP quality of equal PSNR (interpolated).

    python3 scripts/atlas-codecs.py IMAGE [IMAGE ...] [--crops 40] [--side 192]

Needs numpy, scipy and Pillow (with WebP).
"""
import argparse
import io

import numpy as np
from PIL import Image
from scipy import ndimage


def stored_jpeg_len(b):
    """Bytes of a baseline JPEG as the build stores it: APP0, DQT and DHT segments dropped
    (restored by the decoder from one quality byte, `jpegtables`)."""
    i, drop = 2, 0
    while i + 4 <= len(b):
        marker, length = b[i + 1], b[i + 2] * 256 + b[i + 3]
        if marker in (0xE0, 0xDB, 0xC4):
            drop += length + 2
        if marker == 0xDA:
            break
        i += length + 2
    return len(b) - drop + 1


def crops_of(path, count, side, rng):
    src = np.asarray(Image.open(path).convert("RGB")).astype(np.float32)
    h, w, _ = src.shape
    out = []
    for _ in range(count):
        y, x = rng.integers(0, h - side), rng.integers(0, w - side)
        crop = src[y : y + side, x : x + side]
        noise = ndimage.gaussian_filter(rng.standard_normal((side, side)), side / 10)
        chart = noise > np.quantile(noise, rng.uniform(0.4, 0.6))
        filled = crop.copy()
        filled[~chart] = crop[chart].mean(0)
        for _ in range(60):
            blur = ndimage.uniform_filter(filled, size=(3, 3, 1))
            filled[~chart] = blur[~chart]
        out.append((np.clip(filled + 0.5, 0, 255).astype(np.uint8), crop, chart))
    return out


def score(crops, encode, size):
    nbytes, se, n, texels = 0, 0.0, 0, 0
    for image, crop, chart in crops:
        data = encode(image)
        nbytes += size(data)
        back = np.asarray(Image.open(io.BytesIO(data)).convert("RGB")).astype(np.float32)
        se += ((back - crop) ** 2)[chart].sum()
        n += chart.sum() * 3
        texels += chart.sum()
    return nbytes / texels, 10 * np.log10(255.0**2 / (se / n))


def encoder(fmt, **options):
    """An encoder of crops to `fmt` with Pillow's `options` (quality and the like)."""

    def encode(image):
        b = io.BytesIO()
        Image.fromarray(image).save(b, fmt, **options)
        return b.getvalue()

    return encode


def jpeg(q):
    return encoder("JPEG", quality=q, subsampling=2)


def webp(q):
    return encoder("WEBP", quality=q, method=2)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("images", nargs="+")
    ap.add_argument("--crops", type=int, default=40)
    ap.add_argument("--side", type=int, default=192)
    ap.add_argument("--seed", type=int, default=7)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    for path in args.images:
        crops = crops_of(path, args.crops, args.side, rng)
        curve = [(q, *score(crops, webp(q), len)) for q in range(60, 101, 2)]
        print(f"{path}: {args.crops} crops of {args.side}²")
        print("  jpeg q | B/texel    PSNR | webp q of equal PSNR, its B/texel, ratio")
        for q in (70, 75, 80, 85, 90, 95):
            b, p = score(crops, jpeg(q), stored_jpeg_len)
            match = None
            for (qa, ba, pa), (qb, bb, pb) in zip(curve, curve[1:]):
                if pa <= p <= pb and pb > pa:
                    t = (p - pa) / (pb - pa)
                    match = (qa + t * (qb - qa), ba + t * (bb - ba))
                    break
            if match:
                print(f"  {q:6} | {b:7.3f} {p:7.2f} | {match[0]:5.1f} {match[1]:7.3f} {match[1] / b:6.2f}x")
            else:
                print(f"  {q:6} | {b:7.3f} {p:7.2f} | beyond WebP's range")


if __name__ == "__main__":
    main()
