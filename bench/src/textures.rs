//! `meshwiki-bench textures`: fragment quality by feature density (issue 11, item 3; the
//! TexMesh paper, `004_28b2044bb56fb245.txt` §3) against uniform quality at equal bytes.
//!
//! A textured scan is built with the fragments' JPEG quality following their feature density
//! (base quality `Q`, spreads `ΔQ`), and with uniform qualities bisected until their atlases
//! take the same bytes (the two integer qualities around it, PSNR interpolated in bytes).
//! Every build measures each atlas' JPEG against its raw texels, over the texels inside its
//! triangles ([`meshwiki_engine::lod::build::TextureReport`]); fragments are split into the
//! featured ones (at or above their level's mean feature value) and the plain ones, which
//! are the same fragments in every build (the geometry and atlases do not depend on the
//! quality). Figures are printed, never asserted.
//!
//! With `synth:N`, the scan is the demo generator's relief of N triangles with its texture
//! ([`meshwiki_engine::mesh::Relief::stream_textured`], `--texture-side` texels a side), and
//! the bench first builds it without and with the texture, side by side: time, peak memory
//! and the atlases' bytes per texel against the source texture as one JPEG of the same
//! quality (issue 11: throughput and memory within 2× of the untextured build, output per
//! texel no larger than the source JPEG's), and, like for like, the leaves' against the
//! source's and the coarse levels' against the source's mip chain as JPEGs (a coarser texel
//! holds more detail, and costs more).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::Args as ClapArgs;
use meshwiki_engine::lod::VertexOrder;
use meshwiki_engine::lod::atlas::{AtlasCodec, encode_jpeg};
use meshwiki_engine::lod::build::{BuildOptions, BuildReport, TextureBytes, TextureReport};
use meshwiki_engine::mesh::{self, MeshSink, Relief};
use meshwiki_engine::progress::NoProgress;

/// The scan measured when none is named (relative to the repository root).
const DEFAULT_SCAN: &str =
    "../shared/data/meshes/mask_bali_100k_textured_gltf/mask-gltf-2.0_separated-valid.gltf";

/// Options of `bench textures`.
#[derive(Debug, Clone, ClapArgs)]
pub struct Args {
    /// A textured scan, or `synth:N` for the generated relief of N triangles with a texture
    /// (default: the Bali mask from `../shared/data`).
    pub scan: Option<String>,
    /// Texels a side of the generated relief's texture (`synth:N`).
    #[arg(long, default_value_t = 4096)]
    pub texture_side: u32,
    /// Base JPEG quality `Q` (the mean of each level's fragments).
    #[arg(long, default_value_t = BuildOptions::default().texture_quality)]
    pub quality: u8,
    /// Spreads `ΔQ` to measure.
    #[arg(long, value_delimiter = ',', default_values_t = [10u8, 20, 30])]
    pub spreads: Vec<u8>,
    /// Instead of measuring: write the generated relief (`synth:N`) with its texture as
    /// `scan.obj`, `scan.mtl` and `scan.jpg` (JPEG q95) into this folder, a textured scan to
    /// upload (`scripts/bench-textures-stream --mesh synth:N`).
    #[arg(long)]
    pub write_obj: Option<PathBuf>,
}

struct Measured {
    report: TextureReport,
    seconds: f64,
}

/// What is built: a scan file or the generated relief (with its texture, made once).
enum Source {
    File(PathBuf),
    Relief {
        triangles: u64,
        side: u32,
        texture: std::sync::Arc<mesh::Texture>,
    },
}

impl Source {
    fn name(&self) -> String {
        match self {
            Source::File(p) => p.display().to_string(),
            Source::Relief {
                triangles, side, ..
            } => {
                format!("generated relief, {triangles} triangles, {side}² texture")
            }
        }
    }

    /// Builds it (`textured` false: the relief without its texture).
    fn build(&self, out: &Path, options: &BuildOptions, textured: bool) -> Result<BuildReport> {
        // Peak memory per build: reset the process' high-water mark (Linux).
        let _ = std::fs::write("/proc/self/clear_refs", "5");
        let report = match self {
            Source::File(p) => meshwiki_engine::lod::build_file(p, out, options, &NoProgress),
            Source::Relief {
                triangles, texture, ..
            } => {
                let relief = Relief::new(*triangles, mesh::synth::DEFAULT_SEED);
                meshwiki_engine::lod::build_from(
                    |sink: &mut dyn MeshSink| {
                        if textured {
                            relief.stream_with_texture(texture.clone(), sink)?;
                        } else {
                            relief.stream(sink)?;
                        }
                        Ok(relief.stats(textured))
                    },
                    out,
                    options,
                    &NoProgress,
                )
            }
        };
        report.with_context(|| format!("building {}", self.name()))
    }
}

impl Measured {
    fn all(&self) -> TextureBytes {
        self.report.featured.plus(&self.report.plain)
    }
}

fn build(scan: &Source, dir: &Path, quality: u8, spread: u8) -> Result<Measured> {
    let out = dir.join("textures.mwlod");
    let options = BuildOptions {
        texture_quality: quality,
        texture_spread: spread,
        measure_textures: true,
        vertex_order: VertexOrder::Morton,
        ..BuildOptions::default()
    };
    let t = Instant::now();
    let report = scan.build(&out, &options, true)?;
    let _ = std::fs::remove_file(&out);
    let report = report
        .textures
        .context("the scan has no textures (the bench needs a textured scan)")?;
    Ok(Measured {
        report,
        seconds: t.elapsed().as_secs_f64(),
    })
}

/// Runs `bench textures`.
pub fn run(args: Args) -> Result<()> {
    let scan = match args.scan.as_deref().unwrap_or(DEFAULT_SCAN) {
        s if s.starts_with("synth:") => {
            let n = s["synth:".len()..].trim().replace('_', "");
            let triangles: u64 = n
                .parse()
                .with_context(|| format!("synth:N needs a triangle count, got {s:?}"))?;
            let side = args.texture_side.clamp(2, 16384);
            let t = Instant::now();
            let texture = std::sync::Arc::new(
                Relief::new(triangles, mesh::synth::DEFAULT_SEED).texture(side),
            );
            println!(
                "generated the relief's {side}² texture in {:.1} s (not timed below: a scan's \
                 texture is decoded, not computed)",
                t.elapsed().as_secs_f64()
            );
            Source::Relief {
                triangles,
                side,
                texture,
            }
        }
        s => {
            let path = PathBuf::from(s);
            if !path.is_file() {
                bail!("no scan at {s} (the default is the Bali mask under ../shared/data)");
            }
            Source::File(path)
        }
    };
    if let Some(out) = &args.write_obj {
        let Source::Relief {
            triangles, texture, ..
        } = &scan
        else {
            bail!("--write-obj writes the generated relief: give synth:N");
        };
        return write_obj(*triangles, texture.clone(), out);
    }
    let dir = std::env::temp_dir().join(format!("meshwiki-bench-textures-{}", std::process::id()));
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let result = bench(&args, &scan, &dir);
    let _ = std::fs::remove_dir_all(&dir);
    result
}

/// Writes the relief of `triangles` with `texture` as an OBJ with its MTL and JPEG in `dir`
/// (one `vt` per distinct vertex and coordinate; OBJ's `v` counts from the bottom row).
fn write_obj(triangles: u64, texture: std::sync::Arc<mesh::Texture>, dir: &Path) -> Result<()> {
    use std::io::Write as _;
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let mut scan = mesh::TexturedMesh::default();
    Relief::new(triangles, mesh::synth::DEFAULT_SEED)
        .stream_with_texture(texture.clone(), &mut scan)?;
    std::fs::write(dir.join("scan.jpg"), encode_jpeg(&texture, 95))?;
    std::fs::write(
        dir.join("scan.mtl"),
        "newmtl relief\nKd 1 1 1\nmap_Kd scan.jpg\n",
    )?;
    let file = std::fs::File::create(dir.join("scan.obj"))?;
    let mut w = std::io::BufWriter::new(file);
    writeln!(
        w,
        "# generated relief, {triangles} triangles\nmtllib scan.mtl\nusemtl relief"
    )?;
    for p in &scan.mesh.positions {
        writeln!(w, "v {} {} {}", p[0], p[1], p[2])?;
    }
    let mut vt: std::collections::HashMap<(u32, [u32; 2]), usize> = Default::default();
    let mut faces = Vec::with_capacity(scan.faces.len());
    for (tri, face) in scan.mesh.indices.chunks_exact(3).zip(&scan.faces) {
        let mut corners = [(0u32, 0usize); 3];
        for k in 0..3 {
            let uv = face.uv[k];
            let next = vt.len() + 1;
            let id = match vt.entry((tri[k], [uv[0].to_bits(), uv[1].to_bits()])) {
                std::collections::hash_map::Entry::Occupied(e) => *e.get(),
                std::collections::hash_map::Entry::Vacant(e) => {
                    writeln!(w, "vt {} {}", uv[0], 1.0 - uv[1])?;
                    *e.insert(next)
                }
            };
            corners[k] = (tri[k] + 1, id);
        }
        faces.push(corners);
    }
    for c in faces {
        writeln!(
            w,
            "f {}/{} {}/{} {}/{}",
            c[0].0, c[0].1, c[1].0, c[1].1, c[2].0, c[2].1
        )?;
    }
    w.flush()?;
    println!(
        "wrote {} (and scan.mtl, scan.jpg): {} triangles, {}² texture",
        dir.join("scan.obj").display(),
        scan.faces.len(),
        texture.width()
    );
    Ok(())
}

/// Without and with the texture, side by side.
fn throughput(args: &Args, scan: &Source, dir: &Path) -> Result<()> {
    let Source::Relief {
        triangles, texture, ..
    } = scan
    else {
        return Ok(());
    };
    let out = dir.join("throughput.mwlod");
    let options = BuildOptions {
        texture_quality: args.quality,
        vertex_order: VertexOrder::Morton,
        ..BuildOptions::default()
    };
    let mut rows = Vec::new();
    for textured in [false, true] {
        let t = Instant::now();
        let report = scan.build(&out, &options, textured)?;
        let seconds = t.elapsed().as_secs_f64();
        let _ = std::fs::remove_file(&out);
        let peak = report.peak_rss_bytes.unwrap_or(0) as f64 / 1e6;
        println!(
            "  {:<10} build {seconds:>6.1} s, {:>6.2} M triangles/s, peak memory {peak:>6.0} MB, \
             output {:>7.2} MB",
            if textured { "textured" } else { "untextured" },
            *triangles as f64 / seconds / 1e6,
            report.output_bytes as f64 / 1e6,
        );
        let stages: Vec<String> = report
            .stages
            .iter()
            .map(|(name, s)| format!("{name} {s:.1} s"))
            .collect();
        println!("             stages: {}", stages.join(", "));
        rows.push((seconds, peak, report));
    }
    let (plain, textured) = (&rows[0], &rows[1]);
    println!(
        "  textured / untextured: time {:.2}x, peak memory {:.2}x (issue 11: within 2x)",
        textured.0 / plain.0,
        textured.1 / plain.1.max(1.0)
    );
    if let Some(t) = &textured.2.textures {
        let all = t.featured.plus(&t.plain);
        let jpeg = encode_jpeg(texture, args.quality).len();
        let texels = u64::from(texture.width()) * u64::from(texture.height());
        println!(
            "  atlases: {:.2} MB for {:.1} M covered texels = {:.3} bytes a texel; the source \
             texture as one JPEG q{}: {:.2} MB for {:.1} M texels = {:.3} bytes a texel",
            all.image_bytes as f64 / 1e6,
            all.covered_texels as f64 / 1e6,
            all.image_bytes as f64 / all.covered_texels.max(1) as f64,
            args.quality,
            jpeg as f64 / 1e6,
            texels as f64 / 1e6,
            jpeg as f64 / texels.max(1) as f64,
        );
        // Like for like: a hierarchy carries the texture at every level's density, as the
        // source's mip chain does; coarser texels hold more detail each, and cost more.
        let chain = mip_chain_jpeg(texture, args.quality);
        let (leaf_ref, coarse_ref) = (&chain[0], &chain[1..]);
        let coarse_bytes: usize = coarse_ref.iter().map(|m| m.0).sum();
        let coarse_texels: u64 = coarse_ref.iter().map(|m| m.1).sum();
        println!(
            "  the source's mip chain as JPEGs q{}: level 0 {:.3} bytes a texel, levels 1–{} \
             {:.2} MB for {:.1} M texels = {:.3} bytes a texel",
            args.quality,
            leaf_ref.0 as f64 / leaf_ref.1.max(1) as f64,
            coarse_ref.len(),
            coarse_bytes as f64 / 1e6,
            coarse_texels as f64 / 1e6,
            coarse_bytes as f64 / coarse_texels.max(1) as f64,
        );
        let per_texel = |b: &TextureBytes| b.image_bytes as f64 / b.covered_texels.max(1) as f64;
        let coarse = TextureBytes {
            fragments: all.fragments - t.leaves.fragments,
            covered_texels: all.covered_texels - t.leaves.covered_texels,
            image_bytes: all.image_bytes - t.leaves.image_bytes,
            header_bytes: all.header_bytes - t.leaves.header_bytes,
            ..TextureBytes::default()
        };
        let reference = [
            leaf_ref.0 as f64 / leaf_ref.1.max(1) as f64,
            coarse_bytes as f64 / coarse_texels.max(1) as f64,
        ];
        for ((name, b), r) in [("leaves", &t.leaves), ("coarse levels", &coarse)]
            .into_iter()
            .zip(reference)
        {
            println!(
                "    {name}: {} fragments, {:.2} MB for {:.1} M covered texels = {:.3} bytes a \
                 texel ({:.3} without the image headers, {:.1}% of the bytes); {:.2}x the \
                 source's mip chain at that density",
                b.fragments,
                b.image_bytes as f64 / 1e6,
                b.covered_texels as f64 / 1e6,
                per_texel(b),
                (b.image_bytes - b.header_bytes) as f64 / b.covered_texels.max(1) as f64,
                100.0 * b.header_bytes as f64 / b.image_bytes.max(1) as f64,
                per_texel(b) / r.max(1e-12),
            );
        }
        if let Some(m) = &t.webp {
            match m.offset {
                Some(o) => println!(
                    "  atlas codec: WebP at quality {o:+.1} from each fragment's, the least \
                     offset at which {} sampled atlases have JPEG's error ({:.0} against {:.0}): \
                     {:.2} MB there against JPEG's {:.2} MB ({:.2}x)",
                    m.samples,
                    m.webp_error,
                    m.jpeg_error,
                    m.webp_bytes as f64 / 1e6,
                    m.jpeg_bytes as f64 / 1e6,
                    m.webp_bytes as f64 / m.jpeg_bytes.max(1) as f64,
                ),
                None => println!(
                    "  atlas codec: JPEG (WebP did not reach JPEG's error in fewer bytes on the \
                     sampled atlases: {:.2} MB and error {:.0} against {:.2} MB and {:.0})",
                    m.webp_bytes as f64 / 1e6,
                    m.webp_error,
                    m.jpeg_bytes as f64 / 1e6,
                    m.jpeg_error,
                ),
            }
        }
        // The two codecs side by side, every atlas measured against its raw texels.
        println!("  atlases by codec (every atlas measured; builds not timed):");
        for codec in [AtlasCodec::Webp, AtlasCodec::Jpeg] {
            let measured = BuildOptions {
                atlas_codec: codec,
                measure_textures: true,
                ..options.clone()
            };
            let report = scan.build(&out, &measured, true)?;
            let _ = std::fs::remove_file(&out);
            if let Some(t) = &report.textures {
                let all = t.featured.plus(&t.plain);
                println!(
                    "    {:<5} {:>6.2} MB, {:.3} bytes a covered texel ({:.2}x the source \
                     JPEG's), PSNR {:.2} dB, SSIM {:.4}; .mwlod {:.2} MB",
                    format!("{codec:?}"),
                    all.image_bytes as f64 / 1e6,
                    per_texel(&all),
                    per_texel(&all) / (jpeg as f64 / texels.max(1) as f64),
                    all.psnr(),
                    all.ssim(),
                    report.output_bytes as f64 / 1e6,
                );
            }
        }
    }
    Ok(())
}

/// The texture's mip chain (each level half the last in linear light, down to 64 texels a
/// side) as JPEGs of `quality`: per level, its bytes and texels.
fn mip_chain_jpeg(texture: &mesh::Texture, quality: u8) -> Vec<(usize, u64)> {
    let mut halved: Option<mesh::Texture> = None;
    let mut chain = Vec::new();
    loop {
        let level = halved.as_ref().unwrap_or(texture);
        let (w, h) = (level.width(), level.height());
        chain.push((
            encode_jpeg(level, quality).len(),
            u64::from(w) * u64::from(h),
        ));
        if w.min(h) < 128 {
            return chain;
        }
        let texels = crate::normals::half(level.texels(), w as usize, h as usize);
        match mesh::Texture::from_texels(w / 2, h / 2, texels) {
            Some(t) => halved = Some(t),
            None => return chain,
        }
    }
}

fn bench(args: &Args, scan: &Source, dir: &Path) -> Result<()> {
    println!(
        "bench textures: {}, base quality {}",
        scan.name(),
        args.quality
    );
    throughput(args, scan, dir)?;
    println!("  fragment quality by feature density against uniform quality at equal bytes:");
    let mut uniform: BTreeMap<u8, Measured> = BTreeMap::new();
    let uniform_at = |q: u8, uniform: &mut BTreeMap<u8, Measured>| -> Result<u64> {
        if let std::collections::btree_map::Entry::Vacant(e) = uniform.entry(q) {
            e.insert(build(scan, dir, q, 0)?);
        }
        Ok(uniform[&q].all().image_bytes)
    };
    let base_bytes = uniform_at(args.quality, &mut uniform)?;
    let base = &uniform[&args.quality];
    let (f, p) = (base.report.featured, base.report.plain);
    println!(
        "  fragments: {} featured ({:.1} M texels), {} plain ({:.1} M texels); uniform q{} \
         build {:.1} s, atlases {:.2} MB",
        f.fragments,
        f.covered_texels as f64 / 1e6,
        p.fragments,
        p.covered_texels as f64 / 1e6,
        args.quality,
        base.seconds,
        base_bytes as f64 / 1e6
    );
    println!(
        "  {:<24} {:>8} {:>7} | {:>6} {:>6} {:>6} | {:>6} {:>6} {:>6} | {:>6} {:>6}",
        "fragment quality",
        "bytes",
        "q",
        "PSNR",
        "feat.",
        "plain",
        "SSIM",
        "feat.",
        "plain",
        "feat.",
        "plain"
    );
    for &spread in &args.spreads {
        let v = build(scan, dir, args.quality, spread)?;
        let bytes = v.all().image_bytes;
        let (f, p) = (v.report.featured, v.report.plain);
        println!(
            "  {:<24} {:>7.3}M {:>7} | {:>6.2} {:>6.2} {:>6.2} | {:>6.4} {:>6.4} {:>6.4} | {:>5.3}M {:>5.3}M",
            format!("by features, ΔQ {spread}"),
            bytes as f64 / 1e6,
            format!("{}–{}", v.report.quality.0, v.report.quality.2),
            v.all().psnr(),
            f.psnr(),
            p.psnr(),
            v.all().ssim(),
            f.ssim(),
            p.ssim(),
            f.image_bytes as f64 / 1e6,
            p.image_bytes as f64 / 1e6,
        );
        // Uniform quality at the same bytes: bisect the integer quality, then interpolate.
        let (mut lo, mut hi) = (5u8, 100u8);
        if uniform_at(lo, &mut uniform)? > bytes || uniform_at(hi, &mut uniform)? < bytes {
            println!("    (no uniform quality within 5–100 takes {bytes} bytes)");
            continue;
        }
        while hi - lo > 1 {
            let mid = lo + (hi - lo) / 2;
            if uniform_at(mid, &mut uniform)? <= bytes {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let (a, b) = (&uniform[&lo], &uniform[&hi]);
        let (ba, bb) = (a.all().image_bytes as f64, b.all().image_bytes as f64);
        let t = if bb > ba {
            (bytes as f64 - ba) / (bb - ba)
        } else {
            0.0
        };
        let mix = |pick: &dyn Fn(&Measured) -> f64| pick(a) + (pick(b) - pick(a)) * t;
        println!(
            "  {:<24} {:>7.3}M {:>7} | {:>6.2} {:>6.2} {:>6.2} | {:>6.4} {:>6.4} {:>6.4} | {:>5.3}M {:>5.3}M",
            "  uniform, same bytes",
            bytes as f64 / 1e6,
            format!("{:.1}", f64::from(lo) + t),
            mix(&|m| m.all().psnr()),
            mix(&|m| m.report.featured.psnr()),
            mix(&|m| m.report.plain.psnr()),
            mix(&|m| m.all().ssim()),
            mix(&|m| m.report.featured.ssim()),
            mix(&|m| m.report.plain.ssim()),
            mix(&|m| m.report.featured.image_bytes as f64) / 1e6,
            mix(&|m| m.report.plain.image_bytes as f64) / 1e6,
        );
    }
    println!(
        "  (bytes: the atlases' images; PSNR and luminance SSIM over the covered texels; \
         \"feat.\": fragments at or above their level's mean feature value, the same fragments \
         in every build)"
    );
    Ok(())
}
