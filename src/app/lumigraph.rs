//! The network mode of the system paper (§5): a model's Grid-Lumigraph image repository —
//! its description, its build (a background job, `crate::jobs::lumigraph`), its images — and
//! the rule of who may read a model's geometry (`geometry_access`).

use std::path::PathBuf;

use glam::Vec3;
use meshwiki_engine::lumigraph::{DIRECTIONS, Grid, grid, image, sample};
use serde::Serialize;
use utoipa::ToSchema;

use super::AppError;
use super::models::Purpose;
use crate::blobs::{self, Bucket};
use crate::jobs::lumigraph::{DEFAULT_GRID, DEFAULT_SIZE, QUALITY};
use crate::store::jobs::Job;
use crate::store::lumigraph::{self, Counts, Entry, LumigraphStatus};
use crate::store::models::{self, GeometryAccess, ModelStatus};
use crate::store::users::{Role, User};

/// Media type of a repository image (`docs/FORMAT.md`, "Lumigraph image").
pub const IMAGE_MEDIA_TYPE: &str = "application/vnd.meshwiki.lumigraph-image";

/// The viewing box: a cube, `min` its minimum corner, `side` its side.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct ViewingBox {
    /// Minimum corner x, y, z.
    pub min: [f32; 3],
    /// Side length.
    pub side: f32,
}

/// One of the six view directions of every grid point (index = `d`).
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct ImageDirection {
    /// Unit view direction.
    pub forward: [f32; 3],
    /// Unit up vector of the image.
    pub up: [f32; 3],
}

/// The sparse mesh: the patches a model whose geometry stays on the server serves to all.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct SparseMesh {
    /// Object-space error of the sparse mesh: a patch whose `parent_error` exceeds it is in
    /// the sparse mesh or coarser.
    pub error: f32,
}

/// A model's image repository as clients read it (`GET /api/v1/models/{id}/lumigraph`).
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct LumigraphDescription {
    /// The model.
    pub model_id: i64,
    /// `none`, `queued`, `building`, `ready` or `failed`.
    pub status: LumigraphStatus,
    /// Grid points per axis (none without a repository).
    pub grid: Option<u32>,
    /// Image side in pixels.
    pub size: Option<u32>,
    /// Side of each image's depth section in pixels.
    pub depth_size: Option<u32>,
    /// The viewing box the grid spans corner to corner (none until the model is ready).
    #[serde(rename = "box")]
    pub viewing_box: Option<ViewingBox>,
    /// Distance between neighbouring grid points (of level 0).
    pub spacing: Option<f32>,
    /// Finest refinement level: level `l` has `(grid - 1) * 2^l + 1` points per axis, a
    /// spacing of `spacing / 2^l`, and keeps only its points within `refine_margin` of its
    /// spacing of the model's bounding box (`model_box`); its images are rendered on first
    /// request. Level 0 is the grid itself.
    pub levels: u32,
    /// See `levels`.
    pub refine_margin: f32,
    /// The model's bounding box, minimum and maximum corner (none until the model is ready).
    pub model_box: Option<[[f32; 3]; 2]>,
    /// Field of view of every image, degrees (square images).
    pub fov_deg: f32,
    /// The six directions, `d` = 0..5.
    pub directions: Vec<ImageDirection>,
    /// Media types of the images served.
    pub encodings: Vec<String>,
    /// What is recorded so far.
    pub counts: Counts,
    /// The job that builds (built) the repository.
    pub job_id: Option<i64>,
    /// Why the build failed.
    pub message: Option<String>,
    /// Render time of the repository so far, seconds.
    pub seconds: f64,
    /// Who may read the model's geometry.
    pub geometry_access: GeometryAccess,
    /// The sparse mesh (none until the model is ready).
    pub sparse: Option<SparseMesh>,
}

/// What a repository key holds.
#[derive(Debug, Clone)]
pub enum LumigraphImage {
    /// The image file, its SHA-256 (the ETag) and size.
    Image {
        /// The file.
        path: PathBuf,
        /// Its SHA-256.
        sha256: String,
    },
    /// The image shows nothing, or its grid point lies inside the object.
    Empty,
}

/// How much of a model's geometry a reader may obtain.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum GeometryGrant {
    /// Everything.
    Full,
    /// Patches in the sparse mesh or coarser: those whose parent error exceeds this.
    Sparse(f32),
}

fn is_admin(user: Option<&User>) -> bool {
    user.is_some_and(|u| u.role == Role::Admin)
}

impl super::App {
    /// The description of model `model_id`'s repository.
    pub async fn lumigraph(&self, model_id: i64) -> Result<LumigraphDescription, AppError> {
        let model = models::get(&self.db, model_id).await?;
        let repo = lumigraph::get(&self.db, model_id).await?;
        let counts = lumigraph::counts(&self.db, model_id).await?;
        let (points, size) = repo
            .as_ref()
            .map_or((DEFAULT_GRID, DEFAULT_SIZE), |r| (r.grid, r.size));
        let (mut viewing_box, mut spacing, mut sparse, mut model_box) = (None, None, None, None);
        if model.status == ModelStatus::Ready {
            let open = self.models.open(&self.db, model_id, Purpose::Serve).await?;
            let h = open.lod.header();
            if let Ok(g) = Grid::new(Vec3::from(h.bbox_min), Vec3::from(h.bbox_max), points, size) {
                viewing_box = Some(ViewingBox {
                    min: g.min.to_array(),
                    side: g.side,
                });
                spacing = Some(g.spacing());
                model_box = Some([g.model[0].to_array(), g.model[1].to_array()]);
            }
            sparse = Some(SparseMesh {
                error: open.sparse_error,
            });
        }
        Ok(LumigraphDescription {
            model_id,
            status: repo.as_ref().map_or(LumigraphStatus::None, |r| r.status),
            grid: repo.as_ref().map(|r| r.grid),
            size: repo.as_ref().map(|r| r.size),
            depth_size: repo.as_ref().map(|r| image::depth_side(r.size)),
            viewing_box: repo.as_ref().and(viewing_box),
            spacing: repo.as_ref().and(spacing),
            levels: grid::MAX_LEVEL,
            refine_margin: grid::REFINE_MARGIN,
            model_box: repo.as_ref().and(model_box),
            fov_deg: 90.0,
            directions: DIRECTIONS
                .iter()
                .map(|d| ImageDirection {
                    forward: d.forward,
                    up: d.up,
                })
                .collect(),
            encodings: vec![IMAGE_MEDIA_TYPE.to_string()],
            counts,
            job_id: repo.as_ref().and_then(|r| r.job_id),
            message: repo.as_ref().and_then(|r| r.message.clone()),
            seconds: repo.as_ref().map_or(0.0, |r| r.seconds),
            geometry_access: model.geometry_access,
            sparse,
        })
    }

    /// Queues the build of model `model_id`'s repository (admins only; defaults: a
    /// [`DEFAULT_GRID`]³ grid of [`DEFAULT_SIZE`]² images), replacing the one it has.
    pub async fn start_lumigraph(
        &self,
        user: &User,
        model_id: i64,
        grid: Option<u32>,
        size: Option<u32>,
    ) -> Result<(LumigraphDescription, Job), AppError> {
        if user.role != Role::Admin {
            return Err(AppError::Forbidden(
                "only admins build image repositories".into(),
            ));
        }
        let (grid, size) = (grid.unwrap_or(DEFAULT_GRID), size.unwrap_or(DEFAULT_SIZE));
        // (`submit_lumigraph` checks the request.)
        let (_, job) = self
            .jobs
            .submit_lumigraph(model_id, grid, size, user.id)
            .await?;
        Ok((self.lumigraph(model_id).await?, job))
    }

    /// Image `(x, y, z, d)` of refinement level `level` of model `model_id`'s repository
    /// (level 0: the grid the build renders). 404 for a key outside the grid or a finer
    /// level's point away from the model, an image of level 0 not rendered yet, or (with
    /// `version`) a repository built by another job. An image of a finer level is rendered
    /// the first time it is asked for, once the repository is ready, and stored like the
    /// others (`engine/src/lumigraph/grid.rs`, "Refinement levels").
    pub async fn lumigraph_image(
        &self,
        model_id: i64,
        level: u32,
        key: [u32; 4],
        version: Option<i64>,
    ) -> Result<LumigraphImage, AppError> {
        let repo = lumigraph::get(&self.db, model_id).await?.ok_or_else(|| {
            AppError::NotFound(format!("model {model_id} has no image repository"))
        })?;
        if let Some(v) = version
            && repo.job_id != Some(v)
        {
            return Err(AppError::NotFound(format!(
                "version {v} of model {model_id}'s image repository is gone (the current one is \
                 {})",
                repo.job_id.map_or("none".to_string(), |c| c.to_string())
            )));
        }
        grid::check_key(repo.grid, level, key).map_err(|e| AppError::NotFound(e.to_string()))?;
        let [x, y, z, d] = key;
        let (level, [x, y, z]) = Grid::canonical(level, [x, y, z]);
        let key = [x, y, z, d];
        let entry = match lumigraph::entry(&self.db, model_id, level, key).await? {
            Some(e) => e,
            None if level == 0 || repo.status != LumigraphStatus::Ready => {
                return Err(AppError::NotFound(format!(
                    "image ({x}, {y}, {z}, {d}) of level {level} is not rendered yet (the \
                     repository is {})",
                    repo.status.as_str()
                )));
            }
            None => self.render_refined(model_id, &repo, level, key).await?,
        };
        match entry {
            Entry::Empty | Entry::Inside => Ok(LumigraphImage::Empty),
            Entry::Image { sha256, .. } => {
                let path = self.settings.lumigraph_path(&sha256).ok_or_else(|| {
                    AppError::internal(format!("malformed image address {sha256}"))
                })?;
                Ok(LumigraphImage::Image { path, sha256 })
            }
        }
    }

    /// Renders, stores and records image `key` of refinement level `level` (> 0) of ready
    /// repository `repo`; 404 when the point is not kept by its level, or when the
    /// repository was rebuilt meanwhile.
    async fn render_refined(
        &self,
        model_id: i64,
        repo: &lumigraph::Lumigraph,
        level: u32,
        key: [u32; 4],
    ) -> Result<Entry, AppError> {
        let job_id = repo.job_id.ok_or_else(|| {
            AppError::NotFound(format!("model {model_id}'s image repository has no build"))
        })?;
        let open = self.models.open(&self.db, model_id, Purpose::Serve).await?;
        let lod = open.lod.clone();
        let h = lod.header();
        let g = Grid::new(
            Vec3::from(h.bbox_min),
            Vec3::from(h.bbox_max),
            repo.grid,
            repo.size,
        )
        .map_err(|e| AppError::NotFound(e.to_string()))?;
        g.check_level_key(level, key)
            .map_err(|e| AppError::NotFound(e.to_string()))?;
        // Any reader can have images rendered: their storage is capped per model.
        let cap = self.settings.limits.refined_image_bytes;
        let stored = lumigraph::refined_bytes(&self.db, model_id).await?;
        if stored as u64 >= cap {
            tracing::warn!(
                model_id,
                stored,
                cap,
                "refined repository images at their storage cap: not rendering more"
            );
            return Err(AppError::Unavailable(format!(
                "model {model_id}'s refined repository images have reached their storage cap \
                 ({stored} of {cap} bytes): image ({}, {}, {}, {}) of level {level} is not \
                 rendered; coarser levels are served (an admin may raise \
                 MESHWIKI_REFINED_IMAGES_CAP or rebuild the repository)",
                key[0], key[1], key[2], key[3]
            )));
        }
        let with_albedo = lod.has_colors() || lod.has_texture();
        let service = self.render.clone();
        let ticket = service.admit(sample::frame_bytes(&g)).await?;
        let (model, settings) = (open.render.clone(), self.settings.clone());
        let (rendered, _hold) = service
            .run(ticket, move |r| -> Result<Entry, String> {
                let image = sample::sample_image(r, &model, &g, level, key, with_albedo, QUALITY)
                    .map_err(|e| e.to_string())?;
                let Some(bytes) = image else {
                    return Ok(Entry::Empty);
                };
                let sha256 = blobs::write_bytes_to(&settings, Bucket::Lumigraph, &bytes)
                    .map_err(|e| format!("cannot store an image: {e}"))?;
                Ok(Entry::Image {
                    sha256,
                    bytes: bytes.len() as i64,
                })
            })
            .await?;
        let entry = rendered.map_err(|msg| {
            AppError::internal(format!(
                "rendering image {key:?} of level {level} of model {model_id} failed: {msg}"
            ))
        })?;
        // A concurrent request may have recorded the key first: what is recorded is served.
        lumigraph::record_refined(&self.db, model_id, job_id, level, key, entry)
            .await?
            .ok_or_else(|| {
                AppError::NotFound(format!(
                    "model {model_id}'s image repository was rebuilt meanwhile"
                ))
            })
    }

    /// How much of model `model_id`'s geometry `user` (none: an anonymous visitor) may
    /// obtain: all of it, unless the model keeps its geometry on the server
    /// (`geometry_access` = `sparse`) and the reader is not an admin.
    pub async fn geometry_grant(
        &self,
        user: Option<&User>,
        model_id: i64,
    ) -> Result<GeometryGrant, AppError> {
        let model = models::get(&self.db, model_id).await?;
        if model.geometry_access == GeometryAccess::Full || is_admin(user) {
            return Ok(GeometryGrant::Full);
        }
        let open = self.models.open(&self.db, model_id, Purpose::Serve).await?;
        Ok(GeometryGrant::Sparse(open.sparse_error))
    }

    /// [`AppError::Forbidden`] unless `user` may obtain model `model_id`'s full-resolution
    /// geometry (the LOD file, exports, depth and id buffers).
    pub async fn require_full_geometry(
        &self,
        user: Option<&User>,
        model_id: i64,
        what: &str,
    ) -> Result<(), AppError> {
        match self.geometry_grant(user, model_id).await? {
            GeometryGrant::Full => Ok(()),
            GeometryGrant::Sparse(_) => Err(sparse_refusal(model_id, what)),
        }
    }
}

/// The refusal of geometry finer than the sparse mesh.
pub fn sparse_refusal(model_id: i64, what: &str) -> AppError {
    AppError::Forbidden(format!(
        "model {model_id} keeps its geometry on the server (geometry_access = sparse): {what} \
         is for admins only; view it image-based (GET /api/v1/models/{model_id}/lumigraph)"
    ))
}
