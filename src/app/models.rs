//! The model registry: the one opener and cache of models' `.mwlod` files, shared by patch
//! serving, rendering, selection and part views, with the one readiness check ("the model is
//! ready and its file is a plain path under the data directory").
//!
//! An open model maps its file once; the engine's [`RenderModel`] wraps the same mapping, so
//! the renderer's patch cache is keyed by it. Entries are checked against the file on disk
//! (device, inode, size, modification time) on every use, so a rebuilt model is reopened;
//! they are dropped on delete and when a build of the model finishes, and the least recently
//! used beyond [`REGISTRY_SIZE`] is closed. Whenever an entry goes, its patches leave the
//! render cache. Memory maps of replaced files stay valid until the last user drops them.

use std::collections::HashMap;
use std::path::{Component, Path, PathBuf};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::{Instant, SystemTime};

use meshwiki_engine::lod::{LodFile, sparse};
use meshwiki_engine::render::{RenderModel, open_segments};

use super::AppError;
use crate::render::RenderService;
use crate::store::Db;
use crate::store::models::{self, ModelStatus};

/// Open models kept at most.
pub const REGISTRY_SIZE: usize = 32;

/// What a model is opened for: the wording of "not ready" depends on it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Purpose {
    /// Streaming its hierarchy and patches.
    Serve,
    /// Server-side rendering.
    Render,
    /// Region selection.
    Select,
}

/// Identity of a file on disk.
#[derive(Debug, Clone, PartialEq, Eq)]
struct FileKey {
    path: PathBuf,
    len: u64,
    modified: Option<SystemTime>,
    dev: u64,
    ino: u64,
}

impl FileKey {
    fn of(path: &Path, m: &std::fs::Metadata) -> FileKey {
        #[cfg(unix)]
        let (dev, ino) = {
            use std::os::unix::fs::MetadataExt;
            (m.dev(), m.ino())
        };
        #[cfg(not(unix))]
        let (dev, ino) = (0, 0);
        FileKey {
            path: path.to_path_buf(),
            len: m.len(),
            modified: m.modified().ok(),
            dev,
            ino,
        }
    }
}

/// An open model: its mapped hierarchy, the renderer's handle on it, its ETag and (once asked
/// for) the JSON of its hierarchy.
pub struct OpenModel {
    /// Model id.
    pub id: i64,
    /// The mapped file.
    pub lod: Arc<LodFile>,
    /// The renderer's model (the same mapping).
    pub render: RenderModel,
    /// Quoted ETag of the whole file (header checksum and size).
    pub etag: String,
    /// Path of the file.
    pub path: PathBuf,
    /// The hierarchy as JSON (`docs/FORMAT.md`), encoded on first request.
    pub json: OnceLock<bytes::Bytes>,
    /// Object-space error of the model's sparse mesh (`lod::sparse`): what a model whose
    /// geometry stays on the server serves to everyone but admins.
    pub sparse_error: f32,
}

impl OpenModel {
    /// Whether node `node` is in the sparse mesh or coarser (false for a node that does not
    /// exist).
    pub fn within_sparse(&self, node: u32) -> bool {
        self.lod
            .node(node)
            .is_ok_and(|n| sparse::within_sparse(n, self.sparse_error))
    }
}

impl std::fmt::Debug for OpenModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OpenModel")
            .field("id", &self.id)
            .field("path", &self.path)
            .finish()
    }
}

struct Entry {
    key: FileKey,
    open: Arc<OpenModel>,
    used: Instant,
}

/// Open models by id (see the module documentation). Cheap to clone.
#[derive(Clone)]
pub struct ModelRegistry {
    inner: Arc<Mutex<HashMap<i64, Entry>>>,
    data_dir: PathBuf,
    render: RenderService,
}

impl std::fmt::Debug for ModelRegistry {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ModelRegistry")
            .field("open", &self.lock().len())
            .finish()
    }
}

/// The path of a model's LOD file if `relative` is a plain path of at least two components
/// (`models/…`) under `data_dir`; never anything a row could point outside with.
pub fn lod_file(data_dir: &Path, relative: &str) -> Option<PathBuf> {
    let p = Path::new(relative);
    (p.components().count() >= 2 && p.components().all(|c| matches!(c, Component::Normal(_))))
        .then(|| data_dir.join(p))
}

impl ModelRegistry {
    /// An empty registry of the models under `data_dir`, whose patches `render` caches.
    pub fn new(data_dir: PathBuf, render: RenderService) -> ModelRegistry {
        ModelRegistry {
            inner: Arc::default(),
            data_dir,
            render,
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<i64, Entry>> {
        self.inner.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn drop_from_render_cache(&self, open: &OpenModel) {
        if let Ok(r) = self.render.renderer() {
            r.forget(&open.render);
        }
    }

    /// Closes a model (deleted or rebuilt): it is reopened on next use and its patches leave
    /// the render cache.
    pub fn forget(&self, model_id: i64) {
        let old = self.lock().remove(&model_id);
        if let Some(old) = old {
            self.drop_from_render_cache(&old.open);
        }
    }

    /// The LOD file of a ready model: [`AppError::NotFound`] for an unknown model,
    /// [`AppError::Conflict`] while it is not ready (pending, building, failed) or has no
    /// plain file path.
    pub async fn ready_path(
        &self,
        db: &Db,
        model_id: i64,
        purpose: Purpose,
    ) -> Result<PathBuf, AppError> {
        let model = models::get(db, model_id).await?;
        let status = model.status.as_str();
        match (model.status, purpose) {
            (ModelStatus::Ready, _) => {}
            (ModelStatus::Pending | ModelStatus::Building, Purpose::Serve) => {
                return Err(AppError::Conflict(format!(
                    "model {model_id} is {status}: its LOD hierarchy is not built yet; try \
                     again when its status is ready"
                )));
            }
            (ModelStatus::Pending | ModelStatus::Building, Purpose::Render) => {
                return Err(AppError::Conflict(format!(
                    "model {model_id} is {status}: it can be rendered once its status is ready"
                )));
            }
            (ModelStatus::Pending | ModelStatus::Building, Purpose::Select) => {
                return Err(AppError::Conflict(format!(
                    "model {model_id} is {status}: regions can be selected once its status is \
                     ready"
                )));
            }
            (ModelStatus::Failed, purpose) => {
                let why = model.error.as_deref().unwrap_or("unknown error");
                return Err(AppError::Conflict(match purpose {
                    Purpose::Serve => {
                        format!("model {model_id} has no LOD hierarchy: its build failed: {why}")
                    }
                    Purpose::Render => {
                        format!("model {model_id} cannot be rendered: its build failed: {why}")
                    }
                    Purpose::Select => {
                        format!("model {model_id} cannot be selected on: its build failed")
                    }
                }));
            }
        }
        model
            .lod_path
            .as_deref()
            .and_then(|rel| lod_file(&self.data_dir, rel))
            .ok_or_else(|| AppError::Conflict(format!("model {model_id} has no LOD file")))
    }

    /// The open model of a ready model (see [`ModelRegistry::ready_path`] for the errors).
    pub async fn open(
        &self,
        db: &Db,
        model_id: i64,
        purpose: Purpose,
    ) -> Result<Arc<OpenModel>, AppError> {
        let path = self.ready_path(db, model_id, purpose).await?;
        let meta = tokio::fs::metadata(&path)
            .await
            .map_err(|e| AppError::internal(format!("LOD file {} missing: {e}", path.display())))?;
        let key = FileKey::of(&path, &meta);
        if let Some(e) = self.lock().get_mut(&model_id)
            && e.key == key
        {
            e.used = Instant::now();
            return Ok(e.open.clone());
        }
        let opened = path.clone();
        let (lod, segments, sparse_error) = tokio::task::spawn_blocking(move || {
            LodFile::open(&opened).map(|lod| {
                let budget = sparse::sparse_budget(lod.header().input_triangle_count);
                let sparse_error = sparse::sparse_error(lod.nodes(), budget);
                (lod, open_segments(&opened), sparse_error)
            })
        })
        .await
        .map_err(AppError::internal)?
        .map_err(|e| AppError::internal(format!("LOD file unreadable: {e}")))?;
        let lod = Arc::new(lod);
        let h = lod.header();
        let open = Arc::new(OpenModel {
            id: model_id,
            etag: format!("\"{:08x}-{:x}\"", h.header_crc, lod.bytes().len()),
            render: RenderModel::new(lod.clone()).with_segments(segments),
            lod,
            path,
            json: OnceLock::new(),
            sparse_error,
        });
        let mut dropped = Vec::new();
        {
            let mut m = self.lock();
            if let Some(old) = m.remove(&model_id) {
                dropped.push(old.open);
            }
            while m.len() >= REGISTRY_SIZE {
                let Some(oldest) = m.iter().min_by_key(|(_, e)| e.used).map(|(k, _)| *k) else {
                    break;
                };
                if let Some(old) = m.remove(&oldest) {
                    dropped.push(old.open);
                }
            }
            m.insert(
                model_id,
                Entry {
                    key,
                    open: open.clone(),
                    used: Instant::now(),
                },
            );
        }
        for old in &dropped {
            self.drop_from_render_cache(old);
        }
        Ok(open)
    }

    /// Ids of the models open now (tests and diagnostics).
    pub fn open_ids(&self) -> Vec<i64> {
        let mut ids: Vec<i64> = self.lock().keys().copied().collect();
        ids.sort_unstable();
        ids
    }
}

impl super::App {
    /// Deletes model `id` (by `user_id`) with its parts and assignments (contents stay): a build
    /// still running stops first and leaves nothing behind; the registry forgets the model, its
    /// LOD file is removed, and so are its repository's images no other model uses.
    pub async fn delete_model(&self, user_id: i64, id: i64) -> Result<models::Model, AppError> {
        self.jobs.cancel_for_model(id, Some(user_id)).await?;
        let images = crate::store::lumigraph::model_blobs(&self.db, id).await?;
        let model = models::delete(&self.db, id, user_id).await?;
        self.jobs.remove_unused_images(images).await;
        self.models.forget(model.id);
        self.sync_search().await;
        if let Some(lod) = &model.lod_path {
            remove_model_file(&self.settings.data_dir, lod).await;
        }
        Ok(model)
    }
}

/// Removes a model's LOD file (or directory) if `relative` is a plain path inside `models/`
/// of the data directory; anything else is left alone.
async fn remove_model_file(data_dir: &Path, relative: &str) {
    let rel = Path::new(relative);
    let plain = rel.components().all(|c| matches!(c, Component::Normal(_)));
    if !plain || !rel.starts_with("models") || rel.components().count() < 2 {
        tracing::warn!(path = relative, "not removing LOD path outside models/");
        return;
    }
    let path = data_dir.join(rel);
    let p = path.clone();
    let result = tokio::task::spawn_blocking(move || {
        // The surface segments beside it go with it.
        let segments = meshwiki_engine::segment::path_for(&p);
        if segments != p {
            crate::remove_file_or_dir(&segments)?;
        }
        crate::remove_file_or_dir(&p)
    })
    .await
    .unwrap_or_else(|e| Err(std::io::Error::other(e)));
    if let Err(e) = result {
        tracing::warn!(path = %path.display(), error = %e, "cannot remove LOD file");
    }
}
