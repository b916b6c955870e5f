//! The out-of-core build of a model's patch DAG (system paper §3.1–3.2, made better):
//!
//! 1. **Ingest** the streamed scan into flat vertex arrays and a face file (`super::ingest`).
//! 2. **Bucket** faces spatially into pieces that fit the memory budget (`super::buckets`).
//! 3. **Leaves**: partition each bucket into patches of ≤ N triangles that follow features
//!    ([`super::partition`]), in parallel.
//! 4. **Levels**: group neighbouring patches (`super::grouping`), simplify each group with its
//!    outer border locked and split it again ([`super::simplify`]), until a handful of patches
//!    remain. Groups are re-formed at every level so locked borders become interior later.
//! 5. **Write** the tables and compressed patches in locality order ([`super::format`]).
//!
//! Memory stays within the budget whatever the input size: vertex arrays spill to disk,
//! patches live in scratch files between levels, and only a bucket or a group per worker is
//! in memory at a time.

use super::atlas::{
    self, AtlasCodec, FinerPatch, FinerSurface, Maps, PatchTexture, Resampled, SourceColors,
};
use super::bounds::{Sphere, merge_spheres, normal_cone, sphere_of_points};
use super::buckets::{KdSplit, read_bucket, write_buckets};
use super::codec::{self, Grid, PatchRef};
use super::format::{
    GroupRecord, HAS_COLORS, HAS_NORMAL_MAPS, HAS_NORMALS, HAS_TEXTURE, Header,
    MORTON_VERTEX_ORDER, NO_GROUP, NodeRecord, TableWriter,
};
use super::fragment_quality::{self, Features};
use super::grouping::{PatchOutline, group_patches};
use super::ingest::{Ingest, Ingested};
use super::patch::{BuildPatch, ScratchFile};
use super::planar_chart;
use super::segsimplify::Simplifier;
use super::simplify::{merge, simplify_group, split_tracked};
use super::vertex_order::{self, VertexOrder};
use super::webp_match;
use crate::mesh::{self, ImportError, ImportStats, Mesh, MeshSink, SourceTexture, TexturedFace};
use crate::progress::Progress;
use crate::segment::{self, Collector};
use rayon::prelude::*;
use std::io;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Buckets partitioned at the same time (bounds the memory of the leaf stage).
const BUCKET_WORKERS: usize = 4;

/// Most triangles of a bucket, whatever the memory budget: partitioning a bucket into leaves
/// costs more than linearly in its size, so buckets the budget would allow to grow larger
/// only slow the leaf stage down and raise its peak memory. `meshwiki-bench build` on the 5M
/// relief at the default 1 GiB budget (358k-triangle buckets before): leaves 10.0 -> 8.4 s,
/// peak memory 496 -> 390 MB, output 19.79 -> 19.56 MB (more compact leaves).
const BUCKET_TRIANGLES: usize = 1 << 16;

/// Build settings.
#[derive(Debug, Clone)]
pub struct BuildOptions {
    /// Triangle budget of every patch at every level (the paper's N_l).
    pub max_patch_triangles: usize,
    /// Peak memory the build aims to stay under, in bytes.
    pub memory_budget: usize,
    /// Worker threads (default: all cores).
    pub threads: Option<usize>,
    /// Where scratch files go (default: next to the output).
    pub scratch_dir: Option<PathBuf>,
    /// zstd level for patch blobs (0 = store uncompressed).
    pub zstd_level: i32,
    /// Patches per group.
    pub group_size: usize,
    /// Quality (1–100, on JPEG's scale whatever the codec: [`webp_match`]) of the
    /// patches' texture atlases (textured scans): the mean over each level's fragments.
    pub texture_quality: u8,
    /// The image format of the colour atlases (normal maps are JPEGs, 4:4:4, in any case).
    pub atlas_codec: AtlasCodec,
    /// How far a fragment's quality moves from `texture_quality` with the density of
    /// surface and texture features it holds (the TexMesh paper's ΔQ,
    /// [`super::fragment_quality`]); 0 gives every fragment the same quality.
    pub texture_spread: u8,
    /// Measure every atlas image's error against its raw texels ([`TextureReport`]; decodes
    /// each image once more, for benchmarks).
    pub measure_textures: bool,
    /// Bake a normal map into every coarse patch (issue 11 item 4, the progressive-transmission
    /// paper): the finest surface's normals, so a coarse patch shades like the scan. Off by
    /// default: `meshwiki-bench normals` measured no scan here on which they reach an image
    /// quality in fewer bytes than the finer geometry does (`docs/FORMAT.md`, "Normal maps").
    pub normal_maps: bool,
    /// Texels of the normal maps along a coarse patch's mean triangle edge (where that is
    /// finer than its error: a patch is drawn while its error projects to at most the pixel
    /// threshold, so texels smaller than that only matter where triangles are larger).
    pub normal_map_density: f32,
    /// How each group step simplifies (quadric collapses by default; see
    /// `meshwiki-bench simplify` for the comparison with the segment-driven method).
    pub simplifier: Simplifier,
    /// How the model's vertices are numbered (their ids): as the scan lists them (default) or
    /// by the Morton order of their positions (smaller files, [`super::vertex_order`]; what
    /// the server and the CLI build).
    pub vertex_order: VertexOrder,
}

/// The default triangle budget of a patch (the build's, the server's and the CLI's). Larger
/// patches compress better (8192 makes the dragon's file 5% smaller, the 100k scans' 8–10%)
/// but refine the view coarser: along `scripts/bench-stream`'s dragon path 8192 sent 2.82 MB
/// and drew 593k triangles where 4096 sends 2.34 MB and draws 436k.
pub const DEFAULT_MAX_PATCH_TRIANGLES: u32 = 4096;

/// Progress stage of a textured build in which every atlas gets its JPEG (after the levels,
/// before writing).
pub const ATLAS_STAGE: &str = "encoding textures";

/// JPEG quality of the normal maps.
pub const NORMAL_MAP_QUALITY: u8 = 90;

/// The default [`BuildOptions::texture_spread`] (`meshwiki-bench textures` measures it against
/// uniform quality at equal bytes).
pub const DEFAULT_TEXTURE_SPREAD: u8 = 10;

impl Default for BuildOptions {
    fn default() -> Self {
        BuildOptions {
            max_patch_triangles: DEFAULT_MAX_PATCH_TRIANGLES as usize,
            memory_budget: 1 << 30,
            threads: None,
            scratch_dir: None,
            zstd_level: 19,
            group_size: 8,
            texture_quality: 85,
            atlas_codec: AtlasCodec::default(),
            texture_spread: DEFAULT_TEXTURE_SPREAD,
            measure_textures: false,
            normal_maps: false,
            normal_map_density: 4.0,
            simplifier: Simplifier::default(),
            vertex_order: VertexOrder::default(),
        }
    }
}

/// What a build did, for summaries, job records and benchmarks.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct BuildReport {
    pub import: ImportStats,
    pub levels: u32,
    pub nodes: u32,
    pub groups: u32,
    pub roots: u32,
    pub root_triangles: u64,
    pub total_patch_triangles: u64,
    pub output_bytes: u64,
    pub bbox_min: [f32; 3],
    pub bbox_max: [f32; 3],
    pub grid_step: f64,
    pub seconds: f64,
    pub stages: Vec<(String, f64)>,
    /// Peak resident memory of the process (VmHWM), if the platform reports it.
    pub peak_rss_bytes: Option<u64>,
    /// Surface segments per scale, fine first (the `.mwseg` beside the output).
    pub segments: Vec<u32>,
    /// The atlases' JPEGs (textured scans).
    pub textures: Option<TextureReport>,
    /// The coarse patches' normal maps.
    pub normal_maps: NormalMapBytes,
}

/// What the normal maps cost.
#[derive(Debug, Clone, Copy, Default, serde::Serialize)]
pub struct NormalMapBytes {
    /// Patches with a normal map.
    pub maps: u32,
    pub jpeg_bytes: u64,
}

/// What a textured build's atlases cost (issue 11, item 3).
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct TextureReport {
    /// Quality of the fragments (JPEG's scale): least, mean, most.
    pub quality: (u8, f32, u8),
    /// How WebP matched JPEG's error on the sampled atlases (the WebP codec; its offset
    /// `None` where the build kept JPEG).
    pub webp: Option<webp_match::Match>,
    /// Fragments at or above their level's mean feature value ([`fragment_quality`]).
    pub featured: TextureBytes,
    /// The other fragments.
    pub plain: TextureBytes,
    /// The leaves' fragments (of either class): the scan's textures at their own resolution,
    /// where the coarse levels' are resampled from them.
    pub leaves: TextureBytes,
}

/// Bytes and (with [`BuildOptions::measure_textures`]) JPEG error of a class of fragments.
#[derive(Debug, Clone, Copy, Default, serde::Serialize)]
pub struct TextureBytes {
    pub fragments: u32,
    /// Texels inside the atlases' triangles.
    pub covered_texels: u64,
    pub image_bytes: u64,
    /// Of `image_bytes`, the images' headers: everything before the entropy-coded data (JPEG:
    /// markers, quantisation and Huffman tables, frame and scan headers as stored; WebP: its
    /// container and chunk header, [`atlas::header_len`]).
    pub header_bytes: u64,
    /// Squared error of the decoded images' covered texels (8-bit RGB) against the raw atlas.
    pub squared_error: f64,
    /// Channel samples measured (three a covered texel; 0 when not measured).
    pub samples: u64,
    /// Sum over the measured covered texels of the luminance SSIM
    /// ([`fragment_quality::ssim_map`]).
    pub ssim_sum: f64,
}

impl TextureBytes {
    /// PSNR of the measured texels, in dB (infinite when exact, NaN when not measured).
    pub fn psnr(&self) -> f64 {
        if self.samples == 0 {
            return f64::NAN;
        }
        let mse = self.squared_error / self.samples as f64;
        10.0 * (255.0f64 * 255.0 / mse).log10()
    }

    /// Mean SSIM of the measured texels (NaN when not measured).
    pub fn ssim(&self) -> f64 {
        self.ssim_sum / (self.samples / 3) as f64
    }

    /// Both classes together.
    pub fn plus(&self, o: &TextureBytes) -> TextureBytes {
        TextureBytes {
            fragments: self.fragments + o.fragments,
            covered_texels: self.covered_texels + o.covered_texels,
            image_bytes: self.image_bytes + o.image_bytes,
            header_bytes: self.header_bytes + o.header_bytes,
            squared_error: self.squared_error + o.squared_error,
            samples: self.samples + o.samples,
            ssim_sum: self.ssim_sum + o.ssim_sum,
        }
    }
}

/// Why a build failed. Nothing is left at the output path in any case.
#[derive(Debug, thiserror::Error)]
pub enum BuildError {
    #[error("{0}")]
    Import(#[from] ImportError),
    #[error("build I/O failed: {0}")]
    Io(#[from] io::Error),
    #[error("the scan has no triangles")]
    Empty,
    #[error("build cancelled")]
    Cancelled,
    #[error("invalid build options: {0}")]
    Options(String),
}

/// Builds the LOD file for the scan at `input` (format from its extension).
pub fn build_file(
    input: &Path,
    output: &Path,
    options: &BuildOptions,
    progress: &dyn Progress,
) -> Result<BuildReport, BuildError> {
    build_from(
        |sink| mesh::import(input, sink, progress),
        output,
        options,
        progress,
    )
}

/// Builds the LOD file for an in-memory mesh (tests, generated models).
pub fn build_mesh(
    mesh: &Mesh,
    output: &Path,
    options: &BuildOptions,
    progress: &dyn Progress,
) -> Result<BuildReport, BuildError> {
    build_from(
        |sink| {
            mesh.stream_into(sink)?;
            Ok(ImportStats {
                vertices: mesh.positions.len() as u64,
                triangles: mesh.triangle_count() as u64,
                has_colors: !mesh.colors.is_empty(),
                has_normals: !mesh.normals.is_empty(),
                ..Default::default()
            })
        },
        output,
        options,
        progress,
    )
}

/// Builds from any source that streams into a [`MeshSink`].
pub fn build_from(
    source: impl FnOnce(&mut dyn MeshSink) -> Result<ImportStats, ImportError>,
    output: &Path,
    options: &BuildOptions,
    progress: &dyn Progress,
) -> Result<BuildReport, BuildError> {
    if options.max_patch_triangles < 16 || options.max_patch_triangles > 1 << 16 {
        return Err(BuildError::Options(
            "patch triangle budget must be within 16..=65536".into(),
        ));
    }
    if options.memory_budget < 64 << 20 {
        return Err(BuildError::Options(
            "memory budget must be at least 64 MiB".into(),
        ));
    }
    if options.group_size < 2 {
        return Err(BuildError::Options("group size must be at least 2".into()));
    }
    let scratch = ScratchDir::create(options.scratch_dir.as_deref(), output)?;
    let threads = options
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()))
        .max(1);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| BuildError::Io(io::Error::other(e.to_string())))?;

    // 1. Ingest, on the calling thread (readers need not be Send).
    let started = Instant::now();
    let mut ingest = Ingest::new(&scratch.path, options.memory_budget / 5)?;
    let import = source(&mut ingest).map_err(|e| match e.kind {
        mesh::ImportErrorKind::Cancelled => BuildError::Cancelled,
        _ => BuildError::Import(e),
    })?;
    if progress.cancelled() {
        return Err(BuildError::Cancelled);
    }
    let mut ingested = ingest.finish()?;
    if ingested.triangle_count == 0 {
        return Err(BuildError::Empty);
    }
    // The file's grid, which the Morton numbering is defined on (renumbering leaves the
    // bounds and mean edge it is chosen from as they are).
    let grid = choose_grid(&ingested);
    if options.vertex_order == VertexOrder::Morton {
        pool.install(|| {
            vertex_order::renumber(
                &mut ingested,
                &grid,
                &scratch.path,
                options.memory_budget / 5,
            )
        })?;
    }
    pool.install(|| {
        Builder::run(
            ingested,
            grid,
            import,
            started,
            output,
            options,
            progress,
            &scratch.path,
            threads,
        )
    })
}

/// Scratch directory removed on drop (success, error, cancellation or panic).
struct ScratchDir {
    path: PathBuf,
}

impl ScratchDir {
    fn create(base: Option<&Path>, output: &Path) -> io::Result<ScratchDir> {
        let parent = base
            .map(Path::to_path_buf)
            .or_else(|| output.parent().map(Path::to_path_buf))
            .unwrap_or_else(|| PathBuf::from("."));
        let name = output
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let path = parent.join(format!(".{name}.build-{}", std::process::id()));
        std::fs::create_dir_all(&path)?;
        Ok(ScratchDir { path })
    }
}

impl Drop for ScratchDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.path);
    }
}

/// A patch as kept in the node list while building.
#[derive(Debug, Clone)]
struct Node {
    raw_offset: u64,
    raw_len: u32,
    blob_offset: u64,
    blob_len: u32,
    blob_crc: u32,
    triangles: u32,
    vertices: u32,
    level: u32,
    bounds: Sphere,
    cone: [f32; 4],
    lod_sphere: Sphere,
    lod_error: f32,
    /// Bound on the distance of the unquantised patch to the scan (the part of `lod_error`
    /// that carries over to coarser levels; quantisation does not, as every level is
    /// simplified from unquantised positions).
    geometric_error: f32,
    producer: u32,
    parent_sphere: Sphere,
    parent_error: f32,
    member_of: u32,
    /// The patch's atlas in the texture scratch file (length 0: none).
    tex_offset: u64,
    tex_len: u32,
    /// Vertices of the encoded patch (more than `vertices` where atlas charts meet).
    encoded_vertices: u32,
    /// Feature densities of the patch and its atlas (textured scans).
    features: Features,
}

struct Group {
    sphere: Sphere,
    error: f32,
    level: u32,
    members: Vec<u32>,
    products: Vec<u32>,
}

/// A patch stored in the scratch files, before it gets a node id.
struct Stored {
    raw_offset: u64,
    raw_len: u32,
    blob_offset: u64,
    blob_len: u32,
    blob_crc: u32,
    triangles: u32,
    vertices: u32,
    bounds: Sphere,
    cone: [f32; 4],
    outline: PatchOutline,
    tex_offset: u64,
    tex_len: u32,
    encoded_vertices: u32,
    features: Features,
}

/// What a group step returns: its errors and stored products, or `None` when the group could
/// not be simplified (its members move on unchanged).
type GroupOutcome = Option<(GroupErrors, Vec<Stored>)>;

/// A group's error bounds: geometric (unquantised products to the scan) and as stored (what
/// a decoded product may be from the scan).
#[derive(Clone, Copy)]
struct GroupErrors {
    geometric: f32,
    stored: f32,
}

/// A patch of the current level awaiting grouping.
struct PoolItem {
    node: u32,
    outline: PatchOutline,
}

struct Builder<'a> {
    options: &'a BuildOptions,
    progress: &'a dyn Progress,
    raw: ScratchFile,
    blobs: ScratchFile,
    /// Every patch's atlas, for the level above to resample (textured scans).
    atlases: ScratchFile,
    textured: bool,
    normal_map_bytes: NormalMapBytes,
    /// The scratch directory.
    scratch: PathBuf,
    grid: Grid,
    /// Exact bounds of the input vertices.
    bounds: ([f32; 3], [f32; 3]),
    nodes: Vec<Node>,
    groups: Vec<Group>,
    stages: Vec<(String, f64)>,
    /// The surface segments, written to the scratch directory with the leaves, and their
    /// count per scale.
    segments: Option<(PathBuf, Vec<u32>)>,
}

impl<'a> Builder<'a> {
    #[allow(clippy::too_many_arguments)]
    fn run(
        mut ingested: Ingested,
        grid: Grid,
        import: ImportStats,
        started: Instant,
        output: &Path,
        options: &'a BuildOptions,
        progress: &'a dyn Progress,
        scratch: &Path,
        threads: usize,
    ) -> Result<BuildReport, BuildError> {
        let stages = vec![("import".to_string(), started.elapsed().as_secs_f64())];

        let mut builder = Builder {
            options,
            progress,
            raw: ScratchFile::create(&scratch.join("patches.raw"))?,
            blobs: ScratchFile::create(&scratch.join("patches.blobs"))?,
            atlases: ScratchFile::create(&scratch.join("patches.atlases"))?,
            textured: ingested.face_uvs_path.is_some(),
            normal_map_bytes: NormalMapBytes::default(),
            scratch: scratch.to_path_buf(),
            grid,
            bounds: (ingested.bbox.0.into(), ingested.bbox.1.into()),
            nodes: Vec::new(),
            groups: Vec::new(),
            stages,
            segments: None,
        };

        // 2 + 3. Buckets and leaves.
        let t = Instant::now();
        let vertex_count = ingested.positions.len();
        let (pool, segments) = builder.leaves(&mut ingested, scratch, threads)?;
        builder
            .stages
            .push(("leaves".to_string(), t.elapsed().as_secs_f64()));
        // The scan's arrays are done with: the global merge of the segments, the peak of the
        // build's memory on large scans, runs without them.
        drop(ingested);

        // 4. Levels, with the global merge of the segments beside them on a thread of its own:
        // the levels never read the segments, and the merge (one thread) takes the core that
        // each level's last groups leave idle.
        let path = scratch.join("segments.mwseg");
        let t = Instant::now();
        let (roots, merged) = std::thread::scope(|s| {
            let merge = s.spawn(|| {
                let t = Instant::now();
                segments
                    .finish(&path)
                    .map(|c| (c, t.elapsed().as_secs_f64()))
            });
            let roots = builder.levels(pool, vertex_count);
            let merged = merge
                .join()
                .unwrap_or_else(|panic| std::panic::resume_unwind(panic));
            (roots, merged)
        });
        let levels_seconds = t.elapsed().as_secs_f64();
        let (roots, (counts, merge_seconds)) = (roots?, merged?);
        builder.stages.push(("levels".to_string(), levels_seconds));
        builder
            .stages
            .push(("segments beside them".to_string(), merge_seconds));
        builder.segments = Some((path, counts));

        // 5. Atlases (textured scans) and write.
        let textures = if builder.textured || options.normal_maps {
            let t = Instant::now();
            let report = builder.place_atlases()?;
            builder
                .stages
                .push(("atlases".to_string(), t.elapsed().as_secs_f64()));
            builder.textured.then_some(report)
        } else {
            None
        };
        let t = Instant::now();
        let output_bytes = builder.write(output, &import, &roots)?;
        if let Some((scratch_segments, _)) = &builder.segments {
            place(scratch_segments, &segment::path_for(output))?;
        }
        builder
            .stages
            .push(("write".to_string(), t.elapsed().as_secs_f64()));

        let levels = builder.nodes.iter().map(|n| n.level).max().unwrap_or(0) + 1;
        let root_triangles = roots
            .iter()
            .map(|&r| builder.nodes[r as usize].triangles as u64)
            .sum();
        let (bbox_min, bbox_max) = builder.bbox();
        Ok(BuildReport {
            import,
            levels,
            nodes: builder.nodes.len() as u32,
            groups: builder.groups.len() as u32,
            roots: roots.len() as u32,
            root_triangles,
            total_patch_triangles: builder.nodes.iter().map(|n| n.triangles as u64).sum(),
            output_bytes,
            bbox_min,
            bbox_max,
            grid_step: grid.step,
            seconds: started.elapsed().as_secs_f64(),
            stages: builder.stages,
            peak_rss_bytes: peak_rss_bytes(),
            segments: builder.segments.map(|(_, c)| c).unwrap_or_default(),
            textures,
            normal_maps: builder.normal_map_bytes,
        })
    }

    /// Exact bounds of the input geometry.
    fn bbox(&self) -> ([f32; 3], [f32; 3]) {
        self.bounds
    }

    /// Encodes a patch and appends it to both scratch files. Interior vertices are stored at
    /// `2^shift` grid units (0 for leaves).
    fn store(
        &self,
        patch: &BuildPatch,
        shift: u32,
        texture: Option<&PatchTexture>,
    ) -> io::Result<Stored> {
        let raw = patch.to_bytes();
        let raw_offset = self.raw.append(&raw)?;
        // The atlas' JPEG goes in when writing ([`Builder::place_atlases`]), once every
        // fragment's features are known.
        let (tex_offset, tex_len, features) = match texture {
            Some(t) => {
                let bytes = atlas_to_bytes(t);
                let offset = self.atlases.append(&bytes)?;
                let features = t.image.as_ref().map_or_else(Features::default, |image| {
                    fragment_quality::features(
                        &patch.positions,
                        &patch.indices,
                        image,
                        &t.uvs,
                        Some(&t.covered),
                    )
                });
                (offset, bytes.len() as u32, features)
            }
            None => (0, 0, Features::default()),
        };
        let grid_positions: Vec<[u32; 3]> = patch
            .positions
            .iter()
            .map(|&p| self.grid.quantize(p))
            .collect();
        let patch_ref = PatchRef {
            grid_positions: &grid_positions,
            colors: (!patch.colors.is_empty()).then_some(&patch.colors[..]),
            normals: (!patch.normals.is_empty()).then_some(&patch.normals[..]),
            original_ids: &patch.ids,
            indices: &patch.indices,
            shift,
            texture: texture.map(|t| (&t.uvs[..], &[][..])),
        };
        let (blob, encoded_vertices, border) =
            codec::encode_with_border(&patch_ref, self.options.zstd_level);
        let encoded_vertices = encoded_vertices as u32;
        let blob_offset = self.blobs.append(&blob)?;
        Ok(Stored {
            raw_offset,
            raw_len: raw.len() as u32,
            blob_offset,
            blob_len: blob.len() as u32,
            blob_crc: crc32fast::hash(&blob),
            triangles: patch.triangle_count() as u32,
            vertices: patch.ids.len() as u32,
            bounds: sphere_of_points(patch.positions.iter()),
            cone: normal_cone(&patch.positions, &patch.indices),
            outline: outline(patch, border.as_deref()),
            tex_offset,
            tex_len,
            encoded_vertices,
            features,
        })
    }

    /// A stored patch's atlas; with `covered`, the texels its bake sampled too (only the
    /// JPEG measures read them: resampling a coarser patch does not).
    fn load_atlas(&self, node: u32, covered: bool) -> io::Result<Option<PatchTexture>> {
        let n = &self.nodes[node as usize];
        if n.tex_len == 0 {
            return Ok(None);
        }
        atlas_from_bytes(
            &self.atlases.read(n.tex_offset, n.tex_len as usize)?,
            covered,
        )
        .map(Some)
    }

    /// Original IDs of a stored patch (the head of its scratch record), without the rest.
    fn load_ids(&self, node: u32) -> io::Result<Vec<u32>> {
        let n = &self.nodes[node as usize];
        let bytes = self.raw.read(
            n.raw_offset + BuildPatch::IDS_OFFSET,
            n.vertices as usize * 4,
        )?;
        Ok(bytemuck::pod_collect_to_vec(&bytes))
    }

    fn load(&self, node: u32) -> io::Result<BuildPatch> {
        let n = &self.nodes[node as usize];
        BuildPatch::from_bytes(&self.raw.read(n.raw_offset, n.raw_len as usize)?)
    }

    fn push_node(
        &mut self,
        s: &Stored,
        level: u32,
        lod_sphere: Sphere,
        errors: GroupErrors,
        producer: u32,
    ) -> u32 {
        let id = self.nodes.len() as u32;
        self.nodes.push(Node {
            raw_offset: s.raw_offset,
            raw_len: s.raw_len,
            blob_offset: s.blob_offset,
            blob_len: s.blob_len,
            blob_crc: s.blob_crc,
            triangles: s.triangles,
            vertices: s.vertices,
            level,
            bounds: s.bounds,
            cone: s.cone,
            lod_sphere,
            lod_error: errors.stored,
            geometric_error: errors.geometric,
            producer,
            parent_sphere: lod_sphere,
            parent_error: f32::INFINITY,
            member_of: NO_GROUP,
            tex_offset: s.tex_offset,
            tex_len: s.tex_len,
            encoded_vertices: s.encoded_vertices,
            features: s.features,
        });
        id
    }

    /// Steps 2 and 3: spatial buckets, then feature-following leaf patches per bucket; also
    /// each bucket's surface segments, gathered for the merge that follows.
    fn leaves(
        &mut self,
        ingested: &mut Ingested,
        scratch: &Path,
        threads: usize,
    ) -> Result<(Vec<PoolItem>, Collector), BuildError> {
        let tris = ingested.triangle_count as usize;
        // Bucket size depends on the input and the budget only, never on the thread count, so
        // a build gives the same file on every machine. ~300 bytes of working memory per
        // triangle while partitioning; at most BUCKET_WORKERS buckets are in memory at once.
        let by_memory = self.options.memory_budget * 2 / 5 / (BUCKET_WORKERS * 300);
        let for_parallelism = (tris / 12).max(self.options.max_patch_triangles * 16);
        let bucket_max = by_memory
            .min(for_parallelism)
            .min(BUCKET_TRIANGLES)
            .max(self.options.max_patch_triangles * 4);
        // Each sampled vertex stands for `tris / samples` triangles.
        let per_sample = tris as f64 / ingested.sample.len().max(1) as f64;
        let kd = KdSplit::build(&mut ingested.sample, per_sample, bucket_max);
        let buckets = write_buckets(
            &ingested.faces_path,
            ingested.face_uvs_path.as_deref(),
            ingested.positions.as_slice(),
            &kd,
            scratch,
            self.options.memory_budget / 16,
        )?;
        let _ = std::fs::remove_file(&ingested.faces_path);
        if let Some(path) = &ingested.face_uvs_path {
            let _ = std::fs::remove_file(path);
        }
        ingested.positions.release();
        self.progress.stage("partitioning", buckets.len() as u64);
        let segments = Collector::new(
            scratch,
            ingested.positions.len(),
            buckets.len(),
            self.options.memory_budget,
        )?;

        let arrays = &*ingested;
        let positions = arrays.positions.as_slice();
        let normals = arrays.normals.as_slice();
        let colors = arrays.colors.as_ref().map(|c| c.as_slice());
        let textures = &arrays.textures[..];
        let max = self.options.max_patch_triangles;
        let this = &*self;
        let workers = rayon::ThreadPoolBuilder::new()
            .num_threads(threads.min(BUCKET_WORKERS))
            .build()
            .map_err(|e| BuildError::Io(io::Error::other(e.to_string())))?;
        let results: Vec<Result<Vec<Stored>, BuildError>> = workers.install(|| {
            // One job a bucket (and below, a group), so an idle thread can take any that
            // is left: rayon otherwise folds a run of them on one thread once it stops
            // splitting, and at the end of the leaves and of the first level one core sat idle
            // for a quarter to a third of a second while the other worked through such a run.
            buckets
                .par_iter()
                .with_max_len(1)
                .enumerate()
                .map(|(index, bucket)| {
                    if this.progress.cancelled() {
                        return Err(BuildError::Cancelled);
                    }
                    let (faces, face_uvs) = read_bucket(bucket, this.textured)?;
                    let _ = std::fs::remove_file(&bucket.path);
                    let mesh = bucket_mesh(&faces, positions, normals, colors);
                    drop(faces);
                    segments.add(index, &mesh)?;
                    // Spilled vertex arrays give back the pages this bucket touched.
                    arrays.positions.release();
                    arrays.normals.release();
                    if let Some(c) = &arrays.colors {
                        c.release();
                    }
                    let patches = split_tracked(&mesh, &mesh.indices, max);
                    let stored = patches
                        .iter()
                        .map(|(p, tris)| {
                            let texture = this.textured.then(|| {
                                let faces: Vec<TexturedFace> = tris
                                    .iter()
                                    .map(|&t| {
                                        face_uvs
                                            .get(t as usize)
                                            .copied()
                                            .unwrap_or(TexturedFace::NONE)
                                    })
                                    .collect();
                                leaf_atlas(p, &faces, textures)
                            });
                            this.store(p, 0, texture.as_ref())
                        })
                        .collect::<io::Result<Vec<_>>>()?;
                    this.progress.advance(1);
                    Ok(stored)
                })
                .collect()
        });
        let mut pool = Vec::new();
        for r in results {
            for s in r? {
                // Leaves are the scan itself (on the grid: within `grid.max_error()` of it).
                let exact = GroupErrors {
                    geometric: 0.0,
                    stored: 0.0,
                };
                let node = self.push_node(&s, 0, s.bounds, exact, NO_GROUP);
                pool.push(PoolItem {
                    node,
                    outline: s.outline,
                });
            }
        }
        self.raw.flush()?;
        self.atlases.flush()?;
        Ok((pool, segments))
    }

    /// Step 4: grouping and simplification, level by level, until a handful of roots remain.
    fn levels(
        &mut self,
        mut pool: Vec<PoolItem>,
        vertex_count: usize,
    ) -> Result<Vec<u32>, BuildError> {
        let max = self.options.max_patch_triangles;
        let mut group_size = self.options.group_size;
        let mut round = 0u32;
        // How many patches of the current pool hold each vertex (saturating).
        let mut uses = vec![0u8; vertex_count];
        while pool.len() > 1 {
            round += 1;
            uses.fill(0);
            for item in &pool {
                for id in self.load_ids(item.node)? {
                    let u = &mut uses[id as usize];
                    *u = u.saturating_add(1);
                }
            }
            let outlines: Vec<PatchOutline> = pool
                .iter_mut()
                .map(|p| PatchOutline {
                    points: std::mem::take(&mut p.outline.points),
                })
                .collect();
            let grouping = group_patches(&outlines, group_size);
            for (item, o) in pool.iter_mut().zip(outlines) {
                item.outline = o;
            }
            self.progress
                .stage(&format!("simplifying level {round}"), grouping.len() as u64);
            let pool_tris: u64 = pool
                .iter()
                .map(|p| self.nodes[p.node as usize].triangles as u64)
                .sum();

            let this = &*self;
            let pool_ref = &pool;
            let uses = &uses;
            let results: Vec<Result<GroupOutcome, BuildError>> = grouping
                .par_iter()
                .with_max_len(1)
                .map(|members| {
                    if this.progress.cancelled() {
                        return Err(BuildError::Cancelled);
                    }
                    let patches = members
                        .iter()
                        .map(|&m| this.load(pool_ref[m].node))
                        .collect::<io::Result<Vec<_>>>()?;
                    let refs: Vec<&BuildPatch> = patches.iter().collect();
                    let merged = merge(&refs);
                    // A vertex used by more pool patches than group members holding it is
                    // shared with a patch outside the group.
                    let shared_outside: Vec<bool> = merged
                        .patch
                        .ids
                        .iter()
                        .zip(&merged.holders)
                        .map(|(&id, &holders)| uses[id as usize] > holders)
                        .collect();
                    let maps = Maps {
                        color: this.textured,
                        normals: this.options.normal_maps,
                    };
                    let member_atlases = if maps.color || maps.normals {
                        members
                            .iter()
                            .map(|&m| this.load_atlas(pool_ref[m].node, false))
                            .collect::<io::Result<Vec<_>>>()?
                    } else {
                        members.iter().map(|_| None).collect()
                    };
                    let outcome = match simplify_group(
                        &merged,
                        &shared_outside,
                        max,
                        this.options.simplifier,
                    ) {
                        None => None,
                        Some(step) => {
                            // Triangle inequality: the unquantised products are within
                            // `distance` of the unquantised members, which are within their
                            // geometric error of the scan. Decoding adds the quantisation of
                            // this node only: every vertex is within `max_error()` of its grid
                            // point, and coarse interiors add their rounding at `shift`.
                            let member_error = members
                                .iter()
                                .map(|&m| this.nodes[pool_ref[m].node as usize].geometric_error)
                                .fold(0.0f32, f32::max);
                            let geometric = member_error + step.distance;
                            let shift = this.grid.shift_for_error(geometric);
                            let mut quantisation = this.grid.max_error();
                            if shift > 0 {
                                quantisation += this.grid.max_error_at(shift);
                            }
                            let errors = GroupErrors {
                                geometric,
                                stored: (geometric as f64 + quantisation) as f32,
                            };
                            let texel = if maps.normals {
                                let density = this.options.normal_map_density.clamp(0.1, 16.0);
                                errors.stored.min(mean_edge(&step.products) / density)
                            } else {
                                errors.stored
                            };
                            let textures = coarse_atlases(
                                &step.products,
                                &patches,
                                &member_atlases,
                                texel,
                                maps,
                            );
                            let stored = step
                                .products
                                .iter()
                                .zip(&textures)
                                .map(|(p, t)| this.store(p, shift, t.as_ref()))
                                .collect::<io::Result<Vec<_>>>()?;
                            Some((errors, stored))
                        }
                    };
                    this.progress.advance(1);
                    Ok(outcome)
                })
                .collect();

            let mut items: Vec<Option<PoolItem>> = pool.into_iter().map(Some).collect();
            let mut next = Vec::new();
            let mut progressed = false;
            for (members, result) in grouping.iter().zip(results) {
                let member_items: Vec<PoolItem> =
                    members.iter().filter_map(|&m| items[m].take()).collect();
                match result? {
                    None => next.extend(member_items),
                    Some((errors, products)) => {
                        let error = errors.stored;
                        progressed = true;
                        let member_nodes: Vec<u32> = member_items.iter().map(|i| i.node).collect();
                        let g = self.groups.len() as u32;
                        let mut sphere = self.nodes[member_nodes[0] as usize].lod_sphere;
                        let mut level = 0;
                        for &m in &member_nodes {
                            let n = &self.nodes[m as usize];
                            sphere = merge_spheres(merge_spheres(sphere, n.lod_sphere), n.bounds);
                            level = level.max(n.level);
                        }
                        for &m in &member_nodes {
                            let n = &mut self.nodes[m as usize];
                            n.member_of = g;
                            n.parent_sphere = sphere;
                            n.parent_error = error;
                        }
                        let mut product_nodes = Vec::with_capacity(products.len());
                        for s in products {
                            let node = self.push_node(&s, level + 1, sphere, errors, g);
                            product_nodes.push(node);
                            next.push(PoolItem {
                                node,
                                outline: s.outline,
                            });
                        }
                        self.groups.push(Group {
                            sphere,
                            error,
                            level,
                            members: member_nodes,
                            products: product_nodes,
                        });
                    }
                }
            }
            self.raw.flush()?;
            self.atlases.flush()?;
            let next_tris: u64 = next
                .iter()
                .map(|p| self.nodes[p.node as usize].triangles as u64)
                .sum();
            tracing::debug!(
                round,
                patches = next.len(),
                triangles = next_tris,
                group_size,
                "level done"
            );
            pool = next;
            if !progressed {
                if group_size >= pool.len() {
                    break;
                }
                group_size *= 2;
            } else if next_tris as f64 > pool_tris as f64 * 0.9 && group_size < 64 {
                // Locked borders are holding the level back: larger groups lock less.
                group_size *= 2;
            }
        }
        Ok(pool.into_iter().map(|p| p.node).collect())
    }

    /// Step 5a (textured scans): every fragment's quality from its features among its level's
    /// ([`fragment_quality`]), and its image (WebP at JPEG's error, [`webp_match`], or JPEG)
    /// put in its patch's blob. The blobs move to a new scratch file.
    fn place_atlases(&mut self) -> Result<TextureReport, BuildError> {
        self.blobs.flush()?;
        self.atlases.flush()?;
        // Fragment qualities are chosen among the colour atlases (every atlas of a textured
        // scan; an untextured scan's hold normal maps alone).
        let textured: Vec<usize> = (0..self.nodes.len())
            .filter(|&i| self.textured && self.nodes[i].tex_len > 0)
            .collect();
        let levels: Vec<u32> = textured.iter().map(|&i| self.nodes[i].level).collect();
        let features: Vec<Features> = textured.iter().map(|&i| self.nodes[i].features).collect();
        let (n, gamma) = fragment_quality::normalised(&levels, &features);
        // Per node: its quality and whether it is featured.
        let mut quality: Vec<Option<(u8, bool)>> = vec![None; self.nodes.len()];
        for (k, &i) in textured.iter().enumerate() {
            let q = fragment_quality::quality(
                n[k],
                gamma[k],
                self.options.texture_quality,
                self.options.texture_spread,
            );
            quality[i] = Some((q, n[k] >= gamma[k]));
        }
        self.progress.stage(ATLAS_STAGE, self.nodes.len() as u64);
        // WebP at JPEG's error, measured on a sample of the atlases ([`webp_match`]).
        let webp = if self.options.atlas_codec == AtlasCodec::Webp && !textured.is_empty() {
            Some(self.match_webp(&textured, &quality)?)
        } else {
            None
        };
        let webp_offset = webp.and_then(|m| m.offset);
        let placed = ScratchFile::create(&self.scratch.join("patches.placed"))?;
        let mut report = TextureReport::default();
        let mut quality_sum = 0u64;
        let (mut q_min, mut q_max) = (u8::MAX, 0u8);
        let all: Vec<usize> = (0..self.nodes.len()).collect();
        for chunk in all.chunks(64) {
            if self.progress.cancelled() {
                return Err(BuildError::Cancelled);
            }
            let this = &*self;
            type Placed = (Vec<u8>, Option<TextureBytes>, Option<usize>);
            let done: Vec<io::Result<Placed>> = chunk
                .par_iter()
                .map(|&i| {
                    let n = &this.nodes[i];
                    let blob = this.blobs.read(n.blob_offset, n.blob_len as usize)?;
                    let Some(atlas) = this.load_atlas(i as u32, this.options.measure_textures)?
                    else {
                        return Ok((blob, None, None));
                    };
                    let color = match (quality[i], &atlas.image) {
                        (Some((q, _)), Some(image)) => Some(match webp_offset {
                            Some(o) => atlas::encode_webp(image, f32::from(q) + o),
                            None => atlas::encode_jpeg(image, q),
                        }),
                        _ => None,
                    };
                    let normals = atlas
                        .normals
                        .as_ref()
                        .map(|n| atlas::encode_normal_jpeg(n, NORMAL_MAP_QUALITY));
                    let blob = codec::with_images(&blob, color.as_deref(), normals.as_deref())
                        .map_err(|e| io::Error::new(io::ErrorKind::InvalidData, e))?;
                    // Bytes as stored: without the tables and headers the blob leaves out.
                    let saved = color.as_ref().map_or(0, |encoded| {
                        encoded.len().saturating_sub(codec::stored_image_len(&blob)) as u64
                    });
                    let measured = match (&color, &atlas.image) {
                        (Some(encoded), Some(image)) => {
                            let mut m = measure_atlas(
                                image,
                                &atlas.uvs,
                                &atlas.covered,
                                encoded,
                                n.features.covered_texels,
                                this.options.measure_textures,
                            )?;
                            m.image_bytes -= saved;
                            m.header_bytes -= saved;
                            Some(m)
                        }
                        _ => None,
                    };
                    let normal_bytes = normals.map(|n| n.len() - saved as usize);
                    Ok((blob, measured, normal_bytes))
                })
                .collect();
            for (&i, result) in chunk.iter().zip(done) {
                let (blob, measured, normal_bytes) = result?;
                if let Some(b) = normal_bytes {
                    self.normal_map_bytes.maps += 1;
                    self.normal_map_bytes.jpeg_bytes += b as u64;
                }
                let n = &mut self.nodes[i];
                n.blob_offset = placed.append(&blob)?;
                n.blob_len = blob.len() as u32;
                n.blob_crc = crc32fast::hash(&blob);
                if let (Some(m), Some((q, featured))) = (measured, quality[i]) {
                    let class = if featured {
                        &mut report.featured
                    } else {
                        &mut report.plain
                    };
                    *class = class.plus(&m);
                    if self.nodes[i].level == 0 {
                        report.leaves = report.leaves.plus(&m);
                    }
                    quality_sum += u64::from(q);
                    q_min = q_min.min(q);
                    q_max = q_max.max(q);
                }
                self.progress.advance(1);
            }
        }
        placed.flush()?;
        self.blobs = placed;
        let fragments = report.featured.fragments + report.plain.fragments;
        report.quality = (
            q_min.min(q_max),
            quality_sum as f32 / fragments.max(1) as f32,
            q_max,
        );
        report.webp = webp;
        Ok(report)
    }

    /// [`webp_match::match_jpeg`] on an even sample of the colour atlases (`textured`, in
    /// node order), each at its fragment's quality.
    fn match_webp(
        &self,
        textured: &[usize],
        quality: &[Option<(u8, bool)>],
    ) -> io::Result<webp_match::Match> {
        let mut picked = Vec::new();
        for k in webp_match::sample_indices(textured.len()) {
            let i = textured[k];
            if let (Some(atlas), Some((q, _))) = (self.load_atlas(i as u32, true)?, quality[i])
                && let Some(image) = atlas.image
            {
                let (w, h) = (image.width() as usize, image.height() as usize);
                let covered = fragment_quality::covered_or_found(&atlas.covered, w, h, &atlas.uvs)
                    .into_owned();
                picked.push((image, covered, q));
            }
        }
        let samples: Vec<webp_match::Sample> = picked
            .iter()
            .map(|(image, covered, q)| webp_match::Sample {
                image,
                covered,
                quality: *q,
            })
            .collect();
        Ok(webp_match::match_jpeg(&samples))
    }

    /// Step 5: tables and blobs in locality order.
    fn write(
        &mut self,
        output: &Path,
        import: &ImportStats,
        roots: &[u32],
    ) -> Result<u64, BuildError> {
        self.blobs.flush()?;
        self.progress.stage("writing", self.nodes.len() as u64);
        let (lo, hi) = self.bbox();
        let order = locality_order(&self.nodes, lo, hi);
        let mut new_id = vec![0u32; self.nodes.len()];
        for (new, &old) in order.iter().enumerate() {
            new_id[old as usize] = new as u32;
        }
        let mut offset = 0u64;
        let records: Vec<NodeRecord> = order
            .iter()
            .map(|&old| {
                let n = &self.nodes[old as usize];
                let r = NodeRecord {
                    blob_offset: offset,
                    blob_len: n.blob_len,
                    blob_crc: n.blob_crc,
                    triangle_count: n.triangles,
                    vertex_count: n.encoded_vertices,
                    level: n.level,
                    bounds: n.bounds,
                    cone: n.cone,
                    lod_sphere: n.lod_sphere,
                    lod_error: n.lod_error,
                    parent_error: n.parent_error,
                    parent_sphere: n.parent_sphere,
                    producer: n.producer,
                    member_of: n.member_of,
                    ..bytemuck::Zeroable::zeroed()
                };
                offset += n.blob_len as u64;
                r
            })
            .collect();
        let mut links = Vec::new();
        let groups: Vec<GroupRecord> = self
            .groups
            .iter()
            .map(|g| {
                let members_first = links.len() as u32;
                links.extend(g.members.iter().map(|&m| new_id[m as usize]));
                let products_first = links.len() as u32;
                links.extend(g.products.iter().map(|&p| new_id[p as usize]));
                GroupRecord {
                    sphere: g.sphere,
                    error: g.error,
                    level: g.level,
                    members_first,
                    members_count: g.members.len() as u32,
                    products_first,
                    products_count: g.products.len() as u32,
                    _pad: [0; 2],
                }
            })
            .collect();
        let mut flags = HAS_NORMALS;
        if import.has_colors {
            flags |= HAS_COLORS;
        }
        if self.textured {
            flags |= HAS_TEXTURE;
        }
        if self.normal_map_bytes.maps > 0 {
            flags |= HAS_NORMAL_MAPS;
        }
        if self.options.vertex_order == VertexOrder::Morton {
            flags |= MORTON_VERTEX_ORDER;
        }
        let header = Header {
            flags,
            level_count: self.nodes.iter().map(|n| n.level).max().unwrap_or(0) + 1,
            input_vertex_count: import.vertices,
            input_triangle_count: import.triangles,
            bbox_min: lo,
            bbox_max: hi,
            grid_origin: self.grid.origin,
            grid_step: self.grid.step,
            max_patch_triangles: self.options.max_patch_triangles as u32,
            root_count: roots.len() as u32,
            ..bytemuck::Zeroable::zeroed()
        };
        let nodes = &self.nodes;
        let blobs = &self.blobs;
        let progress = self.progress;
        let written = TableWriter {
            header,
            nodes: &records,
            groups: &groups,
            links: &links,
        }
        .write(output, offset, |out| {
            for &old in &order {
                let n = &nodes[old as usize];
                out.write_all(&blobs.read(n.blob_offset, n.blob_len as usize)?)?;
                progress.advance(1);
            }
            Ok(())
        })?;
        Ok(written)
    }
}

/// One fragment's bytes, covered texels (counted with its features) and, when `measure`, JPEG
/// error over those texels.
fn measure_atlas(
    image: &mesh::Texture,
    uvs: &[[f32; 2]],
    covered: &[bool],
    encoded: &[u8],
    covered_texels: u64,
    measure: bool,
) -> io::Result<TextureBytes> {
    let mut bytes = TextureBytes {
        fragments: 1,
        covered_texels,
        image_bytes: encoded.len() as u64,
        header_bytes: atlas::header_len(encoded) as u64,
        ..TextureBytes::default()
    };
    if measure {
        let (w, h) = (image.width() as usize, image.height() as usize);
        // The texels the bake sampled (as the features counted them), else those inside the
        // triangles.
        let covered = fragment_quality::covered_or_found(covered, w, h, uvs);
        let back = mesh::Texture::decode(encoded).map_err(io::Error::other)?;
        let ssim = fragment_quality::ssim_map(image, &back)
            .ok_or_else(|| io::Error::other("the atlas image decodes to another size"))?;
        for (((&c, a), b), s) in covered
            .iter()
            .zip(image.texels())
            .zip(back.texels())
            .zip(ssim)
        {
            if c {
                bytes.ssim_sum += f64::from(s);
                bytes.squared_error += fragment_quality::rgb_squared_error(*a, *b);
                bytes.samples += 3;
            }
        }
    }
    Ok(bytes)
}

/// A leaf's atlas, cut from the scan's textures at their own resolution.
fn leaf_atlas(
    patch: &BuildPatch,
    faces: &[TexturedFace],
    textures: &[SourceTexture],
) -> PatchTexture {
    let texel = atlas::source_texel_size(&patch.positions, &patch.indices, faces, textures)
        .unwrap_or_else(|| fallback_texel_size(patch));
    let layout = planar_chart::best_layout(&patch.positions, &patch.indices, texel);
    let source = SourceColors {
        indices: &patch.indices,
        colors: &patch.colors,
        faces,
        textures,
    };
    atlas::bake(
        &layout,
        &source,
        false,
        Maps {
            color: true,
            normals: false,
        },
    )
}

/// Mean edge length of the patches' triangles (infinite for none).
fn mean_edge(patches: &[BuildPatch]) -> f32 {
    let (mut sum, mut n) = (0f64, 0u64);
    for p in patches {
        let v = |i: u32| glam::Vec3::from(p.positions[i as usize]);
        for t in p.indices.chunks_exact(3) {
            sum += f64::from(
                v(t[0]).distance(v(t[1])) + v(t[1]).distance(v(t[2])) + v(t[2]).distance(v(t[0])),
            );
            n += 3;
        }
    }
    if n == 0 {
        f32::INFINITY
    } else {
        (sum / n as f64) as f32
    }
}

/// Texel size of a patch without source texture: about eight texels per triangle.
fn fallback_texel_size(patch: &BuildPatch) -> f32 {
    let p = |i: u32| glam::Vec3::from(patch.positions[i as usize]);
    let area: f32 = patch
        .indices
        .chunks_exact(3)
        .map(|t| (p(t[1]) - p(t[0])).cross(p(t[2]) - p(t[0])).length() * 0.5)
        .sum();
    (area / patch.triangle_count().max(1) as f32 / 8.0)
        .sqrt()
        .max(1e-12)
}

/// Atlases of a group's products, resampled from its members': colour where the members
/// have it (`maps.color`: none unless every member has), normal maps where `maps.normals`
/// (from the members' normal maps, or their vertex normals where they have none: leaves).
/// Texels are `texel` large (about the products' error: a patch is drawn while its error is
/// at most a pixel) but never finer than the members'.
fn coarse_atlases(
    products: &[BuildPatch],
    members: &[BuildPatch],
    member_atlases: &[Option<PatchTexture>],
    texel: f32,
    maps: Maps,
) -> Vec<Option<PatchTexture>> {
    let maps = Maps {
        color: maps.color
            && member_atlases.len() == members.len()
            && member_atlases
                .iter()
                .all(|a| a.as_ref().is_some_and(|a| a.image.is_some())),
        normals: maps.normals,
    };
    if !maps.color && !maps.normals {
        return products.iter().map(|_| None).collect();
    }
    let finest = member_atlases
        .iter()
        .flatten()
        .map(|a| a.texel_size)
        .fold(f32::INFINITY, f32::min);
    // (Members without atlas, leaves of an untextured scan, set no floor.)
    let texel = if finest.is_finite() {
        texel.max(finest)
    } else {
        texel
    };
    // A member without normal map (a leaf) shades with the normals its decoder computes from
    // its triangles (`codec`: area-weighted, as every client does inside a patch).
    let computed: Vec<Vec<[f32; 3]>> = members
        .iter()
        .enumerate()
        .map(|(i, m)| {
            let mapped = member_atlases
                .get(i)
                .is_some_and(|a| a.as_ref().is_some_and(|a| a.normals.is_some()));
            if maps.normals && !mapped {
                codec::computed_normals(&m.positions, &m.indices)
            } else {
                Vec::new()
            }
        })
        .collect();
    let finer: Vec<FinerPatch> = members
        .iter()
        .zip(&computed)
        .enumerate()
        .map(|(i, (m, normals))| FinerPatch {
            positions: &m.positions,
            indices: &m.indices,
            normals,
            atlas: member_atlases.get(i).and_then(Option::as_ref),
        })
        .collect();
    let surface = FinerSurface::new(&finer);
    products
        .iter()
        .map(|p| {
            let layout = planar_chart::best_layout(&p.positions, &p.indices, texel);
            let source = Resampled {
                positions: &p.positions,
                indices: &p.indices,
                finer: &surface,
                last: Default::default(),
                normals: maps.normals,
            };
            Some(atlas::bake(&layout, &source, true, maps))
        })
        .collect()
}

/// Scratch form of an atlas (native layout; never leaves the build machine): width, height,
/// texel size, corner count, which images (bit 0 colour, bit 1 normals), then their texels
/// and the corners' coordinates.
fn atlas_to_bytes(t: &PatchTexture) -> Vec<u8> {
    let images = [&t.image, &t.normals];
    let first = images.iter().find_map(|i| i.as_ref());
    let (w, h) = first.map_or((0, 0), |i| (i.width(), i.height()));
    let texels = w as usize * h as usize * 4;
    let mut out = Vec::with_capacity(20 + 2 * texels + t.uvs.len() * 8);
    out.extend_from_slice(&w.to_le_bytes());
    out.extend_from_slice(&h.to_le_bytes());
    out.extend_from_slice(&t.texel_size.to_le_bytes());
    out.extend_from_slice(&(t.uvs.len() as u32).to_le_bytes());
    let covered = t.covered.len() == w as usize * h as usize && w * h > 0;
    let which = u32::from(t.image.is_some())
        | (u32::from(t.normals.is_some()) << 1)
        | (u32::from(covered) << 2);
    out.extend_from_slice(&which.to_le_bytes());
    for image in images.into_iter().flatten() {
        out.extend_from_slice(bytemuck::cast_slice(image.texels()));
    }
    out.extend_from_slice(bytemuck::cast_slice(&t.uvs));
    if covered {
        // The texels the bake sampled, a bit each: what the fragment's measures count over.
        out.extend(
            t.covered
                .chunks(8)
                .map(|c| c.iter().rev().fold(0u8, |b, &f| (b << 1) | u8::from(f))),
        );
    }
    out
}

fn atlas_from_bytes(bytes: &[u8], with_covered: bool) -> io::Result<PatchTexture> {
    let bad = || io::Error::new(io::ErrorKind::InvalidData, "corrupt scratch atlas");
    let word = |i: usize| -> io::Result<u32> {
        let b = bytes.get(i * 4..i * 4 + 4).ok_or_else(bad)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    };
    let (w, h) = (word(0)?, word(1)?);
    let texel_size = f32::from_bits(word(2)?);
    let n = word(3)? as usize;
    let which = word(4)?;
    let size = w as usize * h as usize * 4;
    let mut at = 20;
    let mut image = |present: bool| -> io::Result<Option<mesh::Texture>> {
        if !present {
            return Ok(None);
        }
        let texels = bytes.get(at..at + size).ok_or_else(bad)?;
        at += size;
        mesh::Texture::from_texels(w, h, bytemuck::pod_collect_to_vec(texels))
            .ok_or_else(bad)
            .map(Some)
    };
    let color = image(which & 1 != 0)?;
    let normals = image(which & 2 != 0)?;
    let uvs = bytes.get(at..at + n * 8).ok_or_else(bad)?;
    at += n * 8;
    let texels = w as usize * h as usize;
    let covered = if with_covered && which & 4 != 0 {
        let bits = bytes.get(at..at + texels.div_ceil(8)).ok_or_else(bad)?;
        (0..texels)
            .map(|i| bits[i / 8] >> (i % 8) & 1 != 0)
            .collect()
    } else {
        Vec::new()
    };
    Ok(PatchTexture {
        image: color,
        normals,
        uvs: bytemuck::pod_collect_to_vec(uvs),
        texel_size,
        covered,
    })
}

/// Gathers a bucket's faces into a compact mesh (local indices, original IDs kept).
fn bucket_mesh(
    faces: &[[u32; 3]],
    positions: &[[f32; 3]],
    normals: &[[f32; 3]],
    colors: Option<&[[u8; 4]]>,
) -> BuildPatch {
    let mut ids: Vec<u32> = faces.iter().flatten().copied().collect();
    ids.sort_unstable();
    ids.dedup();
    let mut mesh = BuildPatch {
        positions: ids.iter().map(|&i| positions[i as usize]).collect(),
        normals: ids.iter().map(|&i| normals[i as usize]).collect(),
        colors: colors
            .map(|c| ids.iter().map(|&i| c[i as usize]).collect())
            .unwrap_or_default(),
        ..Default::default()
    };
    mesh.indices = faces
        .iter()
        .flatten()
        .map(|i| ids.binary_search(i).unwrap_or(0) as u32)
        .collect();
    mesh.ids = ids;
    mesh
}

/// Moves a finished file from the scratch directory to `to` (renamed when on the same file
/// system, else copied under a temporary name and renamed).
fn place(from: &Path, to: &Path) -> io::Result<()> {
    if std::fs::rename(from, to).is_ok() {
        return Ok(());
    }
    let tmp = super::format::temp_path(to);
    std::fs::copy(from, &tmp)?;
    std::fs::rename(&tmp, to).inspect_err(|_| {
        let _ = std::fs::remove_file(&tmp);
    })
}

/// Border vertices (or a few samples when there is no border) for grouping; `border` marks
/// them where the encoder found them already (the same vertices: debug builds check).
fn outline(patch: &BuildPatch, border: Option<&[bool]>) -> PatchOutline {
    let counted = || {
        let mut on_border = vec![false; patch.ids.len()];
        for (a, b) in patch.local_border_edges() {
            on_border[a as usize] = true;
            on_border[b as usize] = true;
        }
        on_border
    };
    let on_border: std::borrow::Cow<'_, [bool]> = match border {
        Some(b) => {
            debug_assert_eq!(b, &counted()[..], "the encoder's border is the patch's");
            b.into()
        }
        None => counted().into(),
    };
    let mut points: Vec<(u32, [f32; 3])> = on_border
        .iter()
        .enumerate()
        .filter(|&(_, &b)| b)
        .map(|(v, _)| (patch.ids[v], patch.positions[v]))
        .collect();
    points.sort_unstable_by_key(|&(id, _)| id);
    if points.is_empty() {
        let step = (patch.ids.len() / 8).max(1);
        points = (0..patch.ids.len())
            .step_by(step)
            .map(|i| (patch.ids[i], patch.positions[i]))
            .collect();
    }
    PatchOutline { points }
}

/// Quantisation grid: a sixth of the mean edge (within 2^11..2^24 steps across the model);
/// the leaf-level position error is then at most 0.15 mean edges, below scanner noise and
/// comparable to Nexus' default (a tenth of the node error).
fn choose_grid(ingested: &Ingested) -> Grid {
    let (lo, hi) = ingested.bbox;
    let extent = (hi - lo).max_element().max(f32::MIN_POSITIVE) as f64;
    let mut step = if ingested.mean_edge > 0.0 {
        ingested.mean_edge / 6.0
    } else {
        extent / 65536.0
    };
    step = step.clamp(extent / (1u64 << 24) as f64, extent / (1u64 << 11) as f64);
    if step.is_nan() || step <= 0.0 || step.is_infinite() {
        step = 1e-6;
    }
    Grid {
        origin: [lo.x as f64, lo.y as f64, lo.z as f64],
        step,
    }
}

/// Node order in the file: coarse levels first, then Morton order of patch centres, so a view's
/// patches are near each other and the coarse start of any session is one contiguous range.
fn locality_order(nodes: &[Node], lo: [f32; 3], hi: [f32; 3]) -> Vec<u32> {
    let scale: [f32; 3] = std::array::from_fn(|k| {
        let e = hi[k] - lo[k];
        if e > 0.0 {
            ((1u32 << MORTON_BITS) - 1) as f32 / e
        } else {
            0.0
        }
    });
    let mut keyed: Vec<(u32, u64, u32)> = nodes
        .iter()
        .enumerate()
        .map(|(i, n)| {
            let q: [u32; 3] = std::array::from_fn(|k| {
                ((n.bounds[k] - lo[k]) * scale[k]).clamp(0.0, ((1u32 << MORTON_BITS) - 1) as f32)
                    as u32
            });
            (u32::MAX - n.level, morton3(q), i as u32)
        })
        .collect();
    keyed.sort_unstable();
    keyed.into_iter().map(|k| k.2).collect()
}

/// The Morton code of a point quantised to [`MORTON_BITS`] bits per axis (higher bits are
/// ignored): its coordinates' bits interleaved, x lowest, so points near each other get near
/// codes (Morton, "A computer oriented geodetic data base", IBM 1966).
pub fn morton3(q: [u32; 3]) -> u64 {
    fn spread(mut x: u64) -> u64 {
        x &= 0x1f_ffff;
        x = (x | x << 32) & 0x1f_0000_0000_ffff;
        x = (x | x << 16) & 0x1f_0000_ff00_00ff;
        x = (x | x << 8) & 0x100f_00f0_0f00_f00f;
        x = (x | x << 4) & 0x10c3_0c30_c30c_30c3;
        x = (x | x << 2) & 0x1249_2492_4924_9249;
        x
    }
    spread(q[0] as u64) | spread(q[1] as u64) << 1 | spread(q[2] as u64) << 2
}

/// Bits per axis of [`morton3`] (3 × 21 = 63 bits of code).
pub const MORTON_BITS: u32 = 21;

/// Peak resident set size of this process (Linux `VmHWM`).
pub fn peak_rss_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

#[cfg(test)]
mod morton_tests {
    use super::*;

    #[test]
    fn morton3_interleaves_the_bits_of_the_three_axes() {
        let naive = |q: [u32; 3]| {
            (0..MORTON_BITS).fold(0u64, |r, b| {
                (0..3).fold(r, |r, k| r | ((q[k] as u64 >> b) & 1) << (3 * b + k as u32))
            })
        };
        for q in [
            [0, 0, 0],
            [1, 0, 0],
            [0, 1, 0],
            [0, 0, 1],
            [5, 2, 7],
            [0x1f_ffff, 0, 0x15_5555],
            [0x1f_ffff; 3],
        ] {
            assert_eq!(morton3(q), naive(q), "{q:?}");
        }
        // Bits above the 21st are ignored.
        assert_eq!(morton3([1 << 21 | 3, 0, 0]), morton3([3, 0, 0]));
    }
}
