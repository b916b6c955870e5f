//! Deterministic demo/benchmark scan: a coloured bas-relief, generated row by row.
//!
//! Like `../shared/tools/make_mesh.py --shape relief` (the generator the benchmark figures were
//! measured on): a heightfield on an `(n+1)²` vertex grid over [-1, 1]², `2n²` triangles in the
//! same order and winding, slight in-plane jitter, scanner-like noise and RGB colour. The
//! surface is a carved stone panel rather than terrain: a raised frame with a groove, rosettes,
//! a sun disk with rays, a scroll band, weathering (fractal relief, pits and bumps). Colour is
//! weathered stone — dark in recesses, light on worn ridges — with remnants of red-ochre and
//! blue pigment in the carvings. Rows are computed on the fly (three rows of heights in
//! memory), so 50M triangles stream into a [`MeshSink`] or a PLY file in constant memory.
//!
//! The textured variant ([`Relief::stream_textured`], issue 11's demo of a photogrammetry-like
//! scan) adds one square texture: the colours of the same relief sampled on a finer grid (the
//! carvings, weathering and pigment are functions of position, so the finer grid shows the
//! same panel with more detail), mapped by the vertices' grid coordinates.

use super::ply_write::{PlyLayout, PlyWriter};
use super::{
    ImportError, MeshSink, SourceInfo, SourceTexture, Texture, TexturedFace, VertexBatch, Wrap,
};
use std::f64::consts::{PI, TAU};
use std::path::Path;

/// Seed of the demo scan.
pub const DEFAULT_SEED: u64 = 12345;

/// Largest grid: `(n+1)²` vertices must fit PLY `int` indices.
const MAX_GRID: u32 = 46_339;

/// Streams the demo relief of about `target_triangles` triangles into `sink`.
pub fn generate_relief(target_triangles: u64, sink: &mut dyn MeshSink) -> Result<(), ImportError> {
    Relief::new(target_triangles, DEFAULT_SEED).stream(sink)
}

/// Writes the demo relief of about `target_triangles` triangles as binary PLY (RGB colour);
/// returns the vertex and triangle counts.
pub fn write_relief_ply(path: &Path, target_triangles: u64) -> std::io::Result<(u64, u64)> {
    let r = Relief::new(target_triangles, DEFAULT_SEED);
    r.write_ply(path)?;
    Ok((r.vertex_count(), r.triangle_count()))
}

/// One sinusoid `amp · sin(2π(ku·u + kv·v) + phase)`.
#[derive(Clone, Copy)]
struct Wave {
    ku: f64,
    kv: f64,
    amp: f64,
    phase: f64,
}

#[derive(Clone, Copy)]
struct Bump {
    cx: f64,
    cy: f64,
    r: f64,
    a: f64,
}

#[derive(Clone, Copy)]
struct Rosette {
    cx: f64,
    cy: f64,
    radius: f64,
    petals: f64,
    turn: f64,
    depth: f64,
}

/// A relief generator with a given size and seed.
pub struct Relief {
    n: u32,
    seed: u64,
    waves: Vec<Wave>,
    stain: Vec<Wave>,
    bumps: Vec<Bump>,
    rosettes: Vec<Rosette>,
}

/// Hash of (seed, stream, index) to [0, 1).
fn hash01(seed: u64, stream: u64, i: u64) -> f64 {
    let mut z = seed
        .wrapping_add(stream.wrapping_mul(0xD1B5_4A32_D192_ED03))
        .wrapping_add(i.wrapping_mul(0x9E37_79B9_7F4A_7C15));
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 53) as f64
}

/// Rough standard normal from three uniforms (Irwin–Hall).
fn gauss(seed: u64, stream: u64, i: u64) -> f64 {
    let s: f64 = (0..3).map(|k| hash01(seed, stream + k, i)).sum();
    (s - 1.5) * 2.0
}

fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

fn mix(a: [f64; 3], b: [f64; 3], t: f64) -> [f64; 3] {
    [
        a[0] + (b[0] - a[0]) * t,
        a[1] + (b[1] - a[1]) * t,
        a[2] + (b[2] - a[2]) * t,
    ]
}

/// Smooth height and the pigment zone at one grid point (0 none, 1 ochre, 2 blue).
struct Sample {
    h: f64,
    zone: u8,
}

impl Relief {
    /// A relief with about `target_triangles` triangles (`2n²`, `n = round(sqrt(t/2))`).
    pub fn new(target_triangles: u64, seed: u64) -> Relief {
        let n = ((target_triangles as f64 / 2.0).sqrt().round() as u32).clamp(1, MAX_GRID);
        let mut k = 0u64;
        let mut next = || {
            k += 1;
            hash01(seed, 1, k)
        };
        let mut waves = Vec::new();
        let (mut amp, mut freq) = (1.0, 2.0);
        for _ in 0..7 {
            for _ in 0..3 {
                let ang = next() * TAU;
                waves.push(Wave {
                    ku: freq * ang.cos(),
                    kv: freq * ang.sin(),
                    amp,
                    phase: next() * TAU,
                });
            }
            amp *= 0.55;
            freq *= 2.03;
        }
        let norm: f64 = waves.iter().map(|w| w.amp).sum();
        for w in &mut waves {
            w.amp *= 0.018 / norm;
        }
        let stain = (0..6)
            .map(|i| {
                let ang = next() * TAU;
                let f = 1.5 + i as f64;
                Wave {
                    ku: f * ang.cos(),
                    kv: f * ang.sin(),
                    amp: 1.0 / (1.0 + i as f64),
                    phase: next() * TAU,
                }
            })
            .collect();
        let bumps = (0..60)
            .map(|_| Bump {
                cx: next() * 2.0 - 1.0,
                cy: next() * 2.0 - 1.0,
                r: 0.008 + 0.04 * next(),
                a: -0.012 + 0.018 * next(),
            })
            .collect();
        let mut rosettes = Vec::new();
        for (i, cx) in [-0.5, 0.0, 0.5].into_iter().enumerate() {
            rosettes.push(Rosette {
                cx,
                cy: 0.42,
                radius: 0.2,
                petals: [8.0, 12.0, 6.0][i],
                turn: next() * TAU,
                depth: 0.045,
            });
        }
        for cx in [-0.52, 0.52] {
            rosettes.push(Rosette {
                cx,
                cy: -0.05,
                radius: 0.14,
                petals: 5.0,
                turn: next() * TAU,
                depth: 0.035,
            });
        }
        Relief {
            n,
            seed,
            waves,
            stain,
            bumps,
            rosettes,
        }
    }

    /// Grid cells per side.
    pub fn grid(&self) -> u32 {
        self.n
    }

    pub fn vertex_count(&self) -> u64 {
        (self.n as u64 + 1).pow(2)
    }

    pub fn triangle_count(&self) -> u64 {
        2 * (self.n as u64).pow(2)
    }

    /// What an import of the relief reports ([`Relief::stream`], or with `textured`,
    /// [`Relief::stream_textured`]).
    pub fn stats(&self, textured: bool) -> super::ImportStats {
        super::ImportStats {
            vertices: self.vertex_count(),
            triangles: self.triangle_count(),
            has_colors: true,
            textures: u32::from(textured),
            ..super::ImportStats::default()
        }
    }

    fn coord(&self, i: u32) -> f64 {
        -1.0 + 2.0 * i as f64 / self.n as f64
    }

    /// Height of the carvings (no weathering) and the pigment zone.
    fn carving(&self, u: f64, v: f64) -> Sample {
        let d = u.abs().max(v.abs());
        // Slab with a raised frame, a groove inside it and a bevelled outer edge.
        let mut h = 0.07 * smoothstep(0.80, 0.84, d) - 0.05 * smoothstep(0.95, 1.0, d);
        h -= 0.018 * (-((d - 0.875) / 0.012).powi(2)).exp();
        let mut zone = if (0.86..0.89).contains(&d) { 2 } else { 0 };
        if d >= 0.80 {
            return Sample { h, zone };
        }
        // Rosettes: petals raised from the ground, a boss in the middle.
        for r in &self.rosettes {
            let (du, dv) = (u - r.cx, v - r.cy);
            if du.abs() > r.radius || dv.abs() > r.radius {
                continue;
            }
            let rr = (du * du + dv * dv).sqrt() / r.radius;
            if rr >= 1.0 {
                continue;
            }
            let th = dv.atan2(du) + r.turn;
            let petal = (r.petals * th / 2.0).cos().abs();
            let outline = 0.35 + 0.65 * petal.powf(0.7);
            let inside = smoothstep(1.0, 0.9, rr / outline);
            let vein =
                1.0 - 0.25 * (-(petal - 1.0).powi(2) / 0.002).exp() * smoothstep(0.2, 0.4, rr);
            h += r.depth * inside * vein * (1.0 - 0.4 * rr);
            h += 1.3 * r.depth * (-(rr / 0.16).powi(2)).exp();
            if inside > 0.5 && rr > 0.2 {
                zone = 1;
            }
        }
        // Sun disk with rays, lower centre.
        let (du, dv) = (u, v + 0.08);
        let rs = (du * du + dv * dv).sqrt();
        if rs < 0.3 {
            let th = dv.atan2(du);
            let rays = (16.0 * th).cos().max(0.0).powi(3) * smoothstep(0.3, 0.12, rs);
            h += 0.03 * rays * smoothstep(0.09, 0.12, rs);
            h += 0.05 * smoothstep(0.1, 0.08, rs) * (1.0 - (rs / 0.1).powi(2)).max(0.0).sqrt();
            if rs < 0.1 {
                zone = 1;
            }
        }
        // Scroll band: a carved running wave between two raised fillets.
        if (-0.72..-0.36).contains(&v) {
            let t = (v + 0.54) / 0.18; // -1..1 across the band
            let fillet = (-((t.abs() - 0.95) / 0.06).powi(2)).exp();
            h += 0.02 * fillet;
            let wave = 0.55 * (TAU * 3.0 * u).sin();
            let g = (t - wave).abs();
            let groove = smoothstep(0.22, 0.08, g);
            h -= 0.022 * groove;
            // Spirals at the crests of the wave.
            let s = (3.0 * u + 0.25).rem_euclid(1.0) - 0.5;
            let ds =
                (s * s / 0.01 + (t - 0.55 * (TAU * 3.0 * u).sin().signum()).powi(2) / 0.09).sqrt();
            h -= 0.01 * smoothstep(0.6, 0.3, ds) * (1.0 - (6.0 * PI * ds).cos()) * 0.5;
            if t.abs() < 0.9 && groove < 0.5 {
                zone = 2;
            }
        }
        Sample { h, zone }
    }

    /// Weathering relief: fractal waves (from per-column tables) and pits/bumps.
    fn row_samples(&self, r: u32, cols: &[Vec<(f32, f32)>], out: &mut Vec<Sample>) {
        out.clear();
        let v = self.coord(r);
        let rows: Vec<(f64, f64)> = self
            .waves
            .iter()
            .map(|w| {
                let b = TAU * w.kv * v + w.phase;
                (b.sin(), b.cos())
            })
            .collect();
        let bumps: Vec<&Bump> = self
            .bumps
            .iter()
            .filter(|b| (v - b.cy).abs() < 4.0 * b.r)
            .collect();
        for c in 0..=self.n {
            let u = self.coord(c);
            let mut s = self.carving(u, v);
            let col = &cols[c as usize];
            for (k, w) in self.waves.iter().enumerate() {
                // sin(a + b) = sin a cos b + cos a sin b
                let (sa, ca) = col[k];
                let (sb, cb) = rows[k];
                s.h += w.amp * (sa as f64 * cb + ca as f64 * sb);
            }
            for b in &bumps {
                let (du, dv) = (u - b.cx, v - b.cy);
                if du.abs() < 4.0 * b.r {
                    s.h += b.a * (-(du * du + dv * dv) / (2.0 * b.r * b.r)).exp();
                }
            }
            out.push(s);
        }
    }

    fn column_tables(&self) -> Vec<Vec<(f32, f32)>> {
        (0..=self.n)
            .map(|c| {
                let u = self.coord(c);
                self.waves
                    .iter()
                    .map(|w| {
                        let a = TAU * w.ku * u;
                        (a.sin() as f32, a.cos() as f32)
                    })
                    .collect()
            })
            .collect()
    }

    /// Positions and colours of row `r` from the smooth heights of rows r-1, r, r+1.
    fn emit_row(
        &self,
        r: u32,
        [prev, cur, next]: [&[Sample]; 3],
        pos: &mut Vec<[f32; 3]>,
        col: &mut Vec<[u8; 4]>,
    ) {
        let n = self.n;
        let cell = 2.0 / n as f64;
        let v = self.coord(r);
        let seed = self.seed;
        let row_base = r as u64 * (n as u64 + 1);
        for c in 0..=n {
            let i = row_base + c as u64;
            let u = self.coord(c);
            let s = &cur[c as usize];
            let left = &cur[c.saturating_sub(1) as usize];
            let right = &cur[(c + 1).min(n) as usize];
            let lap = (left.h + right.h + prev[c as usize].h + next[c as usize].h - 4.0 * s.h)
                / (cell * cell);
            // Concave (positive Laplacian) collects grime, convex ridges are worn light.
            let cavity = (lap / 60.0).clamp(-1.0, 1.0);
            let stain: f64 = self
                .stain
                .iter()
                .map(|w| w.amp * (TAU * (w.ku * u + w.kv * v) + w.phase).sin())
                .sum::<f64>()
                * 0.4
                + 0.5;
            let stone = mix(
                [205.0, 188.0, 158.0],
                [158.0, 152.0, 142.0],
                stain.clamp(0.0, 1.0),
            );
            let mut rgb = mix(stone, [92.0, 84.0, 74.0], cavity.max(0.0) * 0.8);
            rgb = mix(rgb, [232.0, 224.0, 206.0], (-cavity).max(0.0) * 0.5);
            let patchy = hash01(seed, 7, i / 7 + (i % 3)) * 0.3 + stain * 0.7;
            let pigment = match s.zone {
                1 => Some(([156.0, 64.0, 42.0], smoothstep(0.45, 0.7, patchy))),
                2 => Some(([64.0, 92.0, 138.0], smoothstep(0.5, 0.75, patchy))),
                _ => None,
            };
            if let Some((p, a)) = pigment {
                rgb = mix(rgb, p, a * 0.85 * (0.6 + 0.4 * cavity.max(0.0)));
            }
            let noise = |k: u64| gauss(seed, 20 + 3 * k, i) * 4.0;
            let color =
                [0, 1, 2].map(|k| (rgb[k] + noise(k as u64)).round().clamp(0.0, 255.0) as u8);
            let jitter = 0.12 * cell;
            let h = s.h + gauss(seed, 10, i) * 0.0004;
            let x = u + gauss(seed, 13, i) * jitter;
            let y = v + gauss(seed, 16, i) * jitter;
            pos.push([x as f32, y as f32, h as f32]);
            col.push([color[0], color[1], color[2], 255]);
        }
    }

    /// Calls `f` with the positions and colours of each row, top to bottom.
    fn for_each_row<E>(
        &self,
        mut f: impl FnMut(u32, &[[f32; 3]], &[[u8; 4]]) -> Result<(), E>,
    ) -> Result<(), E> {
        let cols = self.column_tables();
        let mut ring: [Vec<Sample>; 3] = Default::default();
        self.row_samples(0, &cols, &mut ring[1]);
        self.row_samples(1.min(self.n), &cols, &mut ring[2]);
        let mut pos = Vec::with_capacity(self.n as usize + 1);
        let mut col = Vec::with_capacity(self.n as usize + 1);
        for r in 0..=self.n {
            pos.clear();
            col.clear();
            let prev = if r == 0 { &ring[1] } else { &ring[0] };
            let next = if r == self.n { &ring[1] } else { &ring[2] };
            self.emit_row(r, [prev, &ring[1], next], &mut pos, &mut col);
            f(r, &pos, &col)?;
            if r < self.n {
                ring.rotate_left(1);
                self.row_samples((r + 2).min(self.n), &cols, &mut ring[2]);
            }
        }
        Ok(())
    }

    /// Triangles between rows `r` and `r + 1`, as in make_mesh.py (counter-clockwise from +z).
    fn row_triangles(&self, r: u32, out: &mut Vec<[u32; 3]>) {
        let w = self.n + 1;
        for c in 0..self.n {
            let a = r * w + c;
            let (b, d) = (a + 1, a + w);
            let e = d + 1;
            out.push([a, b, d]);
            out.push([b, e, d]);
        }
    }

    /// The relief's colours on a `side × side` grid (`side ≥ 2`): the texture of
    /// [`Relief::stream_textured`], row 0 at `v = -1` as the relief's own row 0.
    pub fn texture(&self, side: u32) -> Texture {
        let side = side.clamp(2, MAX_GRID + 1);
        let finer = Relief::new(2 * u64::from(side - 1).pow(2), self.seed);
        let mut texels = Vec::with_capacity(side as usize * side as usize);
        let _ = finer.for_each_row(|_, _, c| -> Result<(), ()> {
            texels.extend_from_slice(c);
            Ok(())
        });
        let side = finer.n + 1;
        Texture::from_texels(side, side, texels).unwrap_or_else(|| {
            // Unreachable (the finer grid has side² colours); a grey texel keeps it total.
            Texture::from_texels(1, 1, vec![[128, 128, 128, 255]]).expect("1x1")
        })
    }

    /// [`Relief::stream`] with a `side × side` texture ([`Relief::texture`]): every corner's
    /// texture coordinate is its vertex's grid position, at the centre of the texel there.
    pub fn stream_textured(&self, side: u32, sink: &mut dyn MeshSink) -> Result<(), ImportError> {
        self.stream_with_texture(std::sync::Arc::new(self.texture(side)), sink)
    }

    /// [`Relief::stream_textured`] with its texture made beforehand (benchmarks time the build
    /// without the texture's generation, as a scan's texture is decoded, not computed).
    pub fn stream_with_texture(
        &self,
        texture: std::sync::Arc<Texture>,
        sink: &mut dyn MeshSink,
    ) -> Result<(), ImportError> {
        let m = f64::from(texture.width() - 1);
        let texels = f64::from(texture.width());
        let w = self.n + 1;
        let n = f64::from(self.n);
        let uv = |i: u32| {
            let (c, r) = (f64::from(i % w), f64::from(i / w));
            [
                ((c * m / n + 0.5) / texels) as f32,
                ((r * m / n + 0.5) / texels) as f32,
            ]
        };
        let mut texture = Some(texture);
        let mut faces = Vec::new();
        self.stream_with(
            sink,
            &mut |sink: &mut dyn MeshSink| match texture.take() {
                Some(t) => sink.texture(SourceTexture {
                    image: t,
                    wrap_s: Wrap::Clamp,
                    wrap_t: Wrap::Clamp,
                }),
                None => Ok(()),
            },
            &mut |sink: &mut dyn MeshSink, tris: &[[u32; 3]]| {
                faces.clear();
                faces.extend(tris.iter().map(|t| TexturedFace {
                    uv: t.map(uv),
                    texture: 0,
                }));
                sink.textured_triangles(tris, &faces)
            },
        )
    }

    /// Streams the relief into `sink` (vertices row by row, each band of triangles after
    /// the rows it joins).
    pub fn stream(&self, sink: &mut dyn MeshSink) -> Result<(), ImportError> {
        self.stream_with(sink, &mut |_| Ok(()), &mut |sink, tris| {
            sink.triangles(tris)
        })
    }

    /// [`Relief::stream`] with `after_begin` called once after `begin` and triangles handed
    /// over by `triangles`.
    #[allow(clippy::type_complexity)]
    fn stream_with(
        &self,
        sink: &mut dyn MeshSink,
        after_begin: &mut dyn FnMut(&mut dyn MeshSink) -> Result<(), ImportError>,
        triangles: &mut dyn FnMut(&mut dyn MeshSink, &[[u32; 3]]) -> Result<(), ImportError>,
    ) -> Result<(), ImportError> {
        sink.begin(&SourceInfo {
            vertex_count: Some(self.vertex_count()),
            triangle_count_hint: Some(self.triangle_count()),
            has_colors: true,
            has_normals: false,
        })?;
        after_begin(sink)?;
        let mut tris = Vec::new();
        let mut pos = Vec::new();
        let mut col = Vec::new();
        let mut flush = |sink: &mut dyn MeshSink,
                         pos: &mut Vec<[f32; 3]>,
                         col: &mut Vec<[u8; 4]>,
                         tris: &mut Vec<[u32; 3]>|
         -> Result<(), ImportError> {
            if !pos.is_empty() {
                sink.vertices(VertexBatch {
                    positions: pos,
                    colors: Some(col),
                    normals: None,
                })?;
            }
            if !tris.is_empty() {
                triangles(sink, tris)?;
            }
            pos.clear();
            col.clear();
            tris.clear();
            Ok(())
        };
        self.for_each_row(|r, p, c| {
            pos.extend_from_slice(p);
            col.extend_from_slice(c);
            if r > 0 {
                self.row_triangles(r - 1, &mut tris);
            }
            if tris.len() >= super::common::BATCH || pos.len() >= super::common::BATCH {
                flush(sink, &mut pos, &mut col, &mut tris)?;
            }
            Ok(())
        })?;
        flush(sink, &mut pos, &mut col, &mut tris)
    }

    /// Writes the relief as binary PLY with RGB colour (temporary file, then rename).
    pub fn write_ply(&self, path: &Path) -> std::io::Result<()> {
        let mut w = PlyWriter::create(
            path,
            PlyLayout {
                vertices: self.vertex_count(),
                triangles: self.triangle_count(),
                colors: true,
                ..PlyLayout::default()
            },
        )?;
        self.for_each_row(|_, p, c| w.write_vertices(p, Some(c), None, &[]))?;
        let mut tris = Vec::new();
        for r in 0..self.n {
            tris.clear();
            self.row_triangles(r, &mut tris);
            w.write_triangles(&tris)?;
        }
        w.finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{Mesh, TexturedMesh};

    #[test]
    fn counts_and_determinism() {
        let mut a = Mesh::default();
        let mut b = Mesh::default();
        Relief::new(20_000, 7).stream(&mut a).unwrap();
        Relief::new(20_000, 7).stream(&mut b).unwrap();
        assert_eq!(a, b);
        assert_eq!(a.vertex_count(), 101 * 101);
        assert_eq!(a.triangle_count(), 20_000);
        assert!(a.positions.iter().flatten().all(|c| c.is_finite()));
        // Colour varies: stone, grime and pigment.
        let distinct: std::collections::HashSet<_> = a.colors.iter().collect();
        assert!(distinct.len() > 1000);
        let mut c = Mesh::default();
        Relief::new(20_000, 8).stream(&mut c).unwrap();
        assert_ne!(a.positions, c.positions);
    }

    /// Mean difference (per channel) between each corner's texel and its vertex colour.
    fn texel_to_vertex(t: &TexturedMesh, plain: &Mesh) -> f64 {
        let image = &t.textures[0].image;
        let (w, h) = (image.width() as f32, image.height() as f32);
        let mut err = 0.0f64;
        let mut n = 0usize;
        for (face, tri) in t.faces.iter().zip(plain.indices.chunks_exact(3)) {
            assert_eq!(face.texture, 0);
            for (&[u, v], &vertex) in face.uv.iter().zip(tri) {
                assert!((0.0..=1.0).contains(&u) && (0.0..=1.0).contains(&v));
                let texel = image.texels()[(v * h) as usize * w as usize + (u * w) as usize];
                let colour = plain.colors[vertex as usize];
                err += (0..3)
                    .map(|c| (f64::from(texel[c]) - f64::from(colour[c])).abs())
                    .sum::<f64>();
                n += 3;
            }
        }
        err / n as f64
    }

    #[test]
    fn the_textured_relief_maps_its_own_colours_at_finer_detail() {
        let relief = Relief::new(20_000, 7);
        let mut plain = Mesh::default();
        relief.stream(&mut plain).unwrap();
        // At the vertices' own resolution the texture is exactly the vertex colours, each
        // corner on its vertex's texel.
        let mut same = TexturedMesh::default();
        relief.stream_textured(101, &mut same).unwrap();
        assert_eq!(same.mesh, plain);
        assert_eq!(same.textures.len(), 1);
        assert_eq!(same.faces.len(), plain.triangle_count());
        assert_eq!(texel_to_vertex(&same, &plain), 0.0);
        // Finer: the same panel (the finer cavities and the colour noise differ) with more
        // detail than the vertices carry.
        let mut fine = TexturedMesh::default();
        relief.stream_textured(401, &mut fine).unwrap();
        assert_eq!(fine.mesh, plain);
        let image = &fine.textures[0].image;
        assert_eq!((image.width(), image.height()), (401, 401));
        let mean = texel_to_vertex(&fine, &plain);
        assert!(
            mean < 30.0,
            "mean texel-to-vertex colour difference {mean:.1}"
        );
        let distinct: std::collections::HashSet<_> = image.texels().iter().collect();
        assert!(
            distinct.len() > 2 * plain.vertex_count(),
            "{}",
            distinct.len()
        );
    }
}
