//! The network mode of the system paper (§5): a model's Grid-Lumigraph image repository —
//! its description, its build (a background job, `crate::jobs::lumigraph`), its images — and
//! the rule of who may read a model's geometry (`geometry_access`).

use std::path::PathBuf;

use glam::Vec3;
use meshwiki_engine::lumigraph::{DIRECTIONS, Grid, grid, image};
use serde::Serialize;
use utoipa::ToSchema;

use super::AppError;
use super::models::Purpose;
use crate::jobs::lumigraph::{DEFAULT_GRID, DEFAULT_SIZE};
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
    /// Distance between neighbouring grid points.
    pub spacing: Option<f32>,
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
        let (mut viewing_box, mut spacing, mut sparse) = (None, None, None);
        if model.status == ModelStatus::Ready {
            let open = self.models.open(&self.db, model_id, Purpose::Serve).await?;
            let h = open.lod.header();
            if let Ok(g) = Grid::new(Vec3::from(h.bbox_min), Vec3::from(h.bbox_max), points, size) {
                viewing_box = Some(ViewingBox {
                    min: g.min.to_array(),
                    side: g.side,
                });
                spacing = Some(g.spacing());
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

    /// Image `(x, y, z, d)` of model `model_id`'s repository: 404 for a key outside the grid,
    /// an image not rendered yet, or (with `version`) a repository built by another job.
    pub async fn lumigraph_image(
        &self,
        model_id: i64,
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
        grid::check_key(repo.grid, key).map_err(|e| AppError::NotFound(e.to_string()))?;
        let [x, y, z, d] = key;
        match lumigraph::entry(&self.db, model_id, key).await? {
            None => Err(AppError::NotFound(format!(
                "image ({x}, {y}, {z}, {d}) is not rendered yet (the repository is {})",
                repo.status.as_str()
            ))),
            Some(Entry::Empty | Entry::Inside) => Ok(LumigraphImage::Empty),
            Some(Entry::Image { sha256, .. }) => {
                let path = self.settings.lumigraph_path(&sha256).ok_or_else(|| {
                    AppError::internal(format!("malformed image address {sha256}"))
                })?;
                Ok(LumigraphImage::Image { path, sha256 })
            }
        }
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
