//! Scan uploads: the one way a received scan reaches the build queue ([`App::submit_scan`]:
//! a `.zip` unpacked, the scan picked among its files), and resumable upload sessions
//! ([`crate::upload_sessions`]: opened with the list of files, filled chunk by chunk, then
//! finished into a build with [`App::finish_upload`]).

use std::time::Duration;

use meshwiki_engine::lod::VertexOrder;
use meshwiki_engine::lod::segsimplify::Simplifier;
use serde::Deserialize;
use utoipa::ToSchema;

use super::{App, AppError};
use crate::jobs::archive::{self, ReceivedFile};
use crate::jobs::{MAX_SCAN_FILES, SCAN_EXTENSIONS, UploadTarget, companion_path, scan_extension};
use crate::store::jobs::{Job, JobOptions};
use crate::store::models::{Model, NewModel};
use crate::upload_sessions::{SessionError, SessionFile, SessionState};
use crate::uploads::TempUpload;

/// Build options the uploader of a scan may choose; the server keeps its memory budget and
/// threads. Every field is optional: the server's default where absent.
#[derive(Debug, Clone, Default, PartialEq, Eq, Deserialize, ToSchema)]
pub struct BuildChoices {
    /// How the levels are simplified: `quadric` (edge collapses, the default) or `segments`
    /// (the mesh-segmentation paper's segment-driven vertex removal).
    #[serde(default)]
    pub simplifier: Option<Simplifier>,
    /// Triangle budget of every patch (256–65536; default the server's, 4096 unless
    /// configured): smaller patches refine more finely and cost more requests.
    #[serde(default)]
    pub patch_triangles: Option<u32>,
    /// JPEG quality (1–100) of a textured scan's atlases, the mean of each level's (default 85).
    #[serde(default)]
    pub texture_quality: Option<u8>,
    /// How far an atlas' quality moves with the density of features of its patch (0–50; 0:
    /// every atlas the same quality; default 10).
    #[serde(default)]
    pub texture_spread: Option<u8>,
    /// Bake a normal map into every coarse patch (default off: on the scans measured they
    /// cost more bytes than the finer geometry for the same image; `meshwiki-bench normals`).
    #[serde(default)]
    pub normal_maps: Option<bool>,
    /// How the model's vertices are numbered: `morton` (the default: by the Morton code of
    /// their positions, smaller files) or `source` (ids are the scan file's vertex indices,
    /// for tools that relate parts to the file).
    #[serde(default)]
    pub vertex_order: Option<VertexOrder>,
}

/// Smallest patch triangle budget an upload may ask for.
pub const MIN_PATCH_TRIANGLES: u32 = 256;
/// Largest patch triangle budget (the engine's limit).
pub const MAX_PATCH_TRIANGLES: u32 = 1 << 16;
/// Largest texture spread an upload may ask for.
pub const MAX_TEXTURE_SPREAD: u8 = 50;

impl BuildChoices {
    /// The job options these choices make, or why they cannot be built.
    pub fn job_options(&self) -> Result<JobOptions, AppError> {
        if let Some(n) = self.patch_triangles
            && !(MIN_PATCH_TRIANGLES..=MAX_PATCH_TRIANGLES).contains(&n)
        {
            return Err(AppError::invalid(format!(
                "patch_triangles must be {MIN_PATCH_TRIANGLES} to {MAX_PATCH_TRIANGLES}, not {n}"
            )));
        }
        if let Some(q) = self.texture_quality
            && !(1..=100).contains(&q)
        {
            return Err(AppError::invalid(format!(
                "texture_quality must be 1 to 100, not {q}"
            )));
        }
        if let Some(s) = self.texture_spread
            && s > MAX_TEXTURE_SPREAD
        {
            return Err(AppError::invalid(format!(
                "texture_spread must be 0 to {MAX_TEXTURE_SPREAD}, not {s}"
            )));
        }
        Ok(JobOptions {
            simplifier: self.simplifier,
            max_patch_triangles: self.patch_triangles,
            texture_quality: self.texture_quality,
            texture_spread: self.texture_spread,
            normal_maps: self.normal_maps,
            vertex_order: self.vertex_order,
            ..JobOptions::default()
        })
    }
}

/// The model a scan is for.
#[derive(Debug, Clone)]
pub enum ScanFor {
    /// A new model (its source name is the scan's).
    New {
        /// Title (checked by the caller).
        title: String,
        /// Description (Markdown).
        description: String,
    },
    /// An existing model without a built scan: a retry.
    Existing(i64),
}

impl From<SessionError> for AppError {
    fn from(e: SessionError) -> AppError {
        match e {
            SessionError::NotFound(_) => AppError::NotFound(e.to_string()),
            SessionError::Invalid(_) | SessionError::Incomplete(_) => {
                AppError::Invalid(e.to_string())
            }
            SessionError::Offset { .. } | SessionError::Busy => AppError::Conflict(e.to_string()),
            SessionError::TooLarge(m) => AppError::TooLarge(m),
            SessionError::Io(e) => AppError::internal(e),
        }
    }
}

impl App {
    /// Queues the build of a received scan: `files` as uploaded (one scan and the files it
    /// refers to, or one `.zip` of them), for a new or an existing model, built with the
    /// uploader's `choices` (refused with a message when out of range).
    pub async fn submit_scan(
        &self,
        files: Vec<ReceivedFile>,
        target: ScanFor,
        choices: &BuildChoices,
        user: i64,
    ) -> Result<(Model, Job), AppError> {
        let options = choices.job_options()?;
        if let ScanFor::Existing(id) = target {
            // Before unpacking anything: a model that cannot take a scan is refused at once.
            let model = crate::store::models::get(&self.db, id).await?;
            crate::store::jobs::check_takes_scan(&model)?;
        }
        let dir = self.settings.uploads_dir();
        let limit = self.settings.build.upload_bytes;
        let scan = tokio::task::spawn_blocking(move || archive::assemble(files, &dir, limit))
            .await
            .map_err(AppError::internal)??;
        let new;
        let target = match target {
            ScanFor::New { title, description } => {
                new = NewModel {
                    title,
                    description: description.replace("\r\n", "\n"),
                    source_name: scan.display_name.clone(),
                };
                UploadTarget::New(&new)
            }
            ScanFor::Existing(id) => UploadTarget::Existing(id),
        };
        Ok(self.jobs.submit_upload(scan, target, options, user).await?)
    }

    /// Opens a resumable upload of `files` (relative paths and sizes): one scan with the files
    /// it refers to, or one `.zip`. Refused at once when the list cannot make a scan, so no
    /// gigabyte is sent in vain.
    pub async fn open_upload(
        &self,
        user: i64,
        files: Vec<SessionFile>,
    ) -> Result<SessionState, AppError> {
        if files.len() > MAX_SCAN_FILES {
            return Err(AppError::invalid(format!(
                "upload at most {MAX_SCAN_FILES} files: the scan and the files it refers to"
            )));
        }
        let mut checked = Vec::with_capacity(files.len());
        for f in files {
            let path = companion_path(&f.path).ok_or_else(|| {
                AppError::invalid(format!(
                    "{:?} is not a plain relative file name",
                    f.path
                        .chars()
                        .filter(|c| !c.is_control())
                        .take(100)
                        .collect::<String>()
                ))
            })?;
            if checked.iter().any(|c: &SessionFile| c.path == path) {
                return Err(AppError::invalid(format!("{path} is listed twice")));
            }
            checked.push(SessionFile { path, size: f.size });
        }
        let zip = checked.len() == 1 && archive::is_zip(&checked[0].path);
        let scans = checked
            .iter()
            .filter(|f| scan_extension(&f.path).is_some())
            .count();
        if !zip && scans != 1 {
            return Err(AppError::invalid(if scans == 0 {
                format!(
                    "none of the files is a scan: one must end in {SCAN_EXTENSIONS} (or upload one .zip)"
                )
            } else {
                "upload one scan at a time (with the files it refers to)".to_string()
            }));
        }
        Ok(self
            .uploads
            .create(user, checked, self.settings.build.upload_bytes)
            .await?)
    }

    /// Finishes a complete upload session: its files become the scan of a build, and the
    /// session is gone.
    pub async fn finish_upload(
        &self,
        user: i64,
        id: &str,
        target: ScanFor,
        choices: &BuildChoices,
    ) -> Result<(Model, Job), AppError> {
        // Refused before the session is taken: the files stay for a corrected request.
        choices.job_options()?;
        if let ScanFor::Existing(model_id) = target {
            let model = crate::store::models::get(&self.db, model_id).await?;
            crate::store::jobs::check_takes_scan(&model)?;
        }
        let taken = self.uploads.take(id, user).await?;
        let dir = self.settings.uploads_dir();
        let files = tokio::task::spawn_blocking(move || -> std::io::Result<Vec<ReceivedFile>> {
            let mut files = Vec::with_capacity(taken.files.len());
            for (relative, path, bytes) in &taken.files {
                let temp = TempUpload::new(&dir);
                std::fs::rename(path, temp.path())?;
                files.push(ReceivedFile {
                    relative: relative.clone(),
                    temp,
                    bytes: *bytes,
                });
            }
            drop(taken);
            Ok(files)
        })
        .await
        .map_err(AppError::internal)?
        .map_err(AppError::internal)?;
        self.submit_scan(files, target, choices, user).await
    }

    /// Removes upload sessions idle for longer than their lifetime, now and every `every`.
    pub(super) fn sweep_uploads(&self, every: Duration) {
        let sessions = self.uploads.clone();
        tokio::spawn(async move {
            loop {
                let s = sessions.clone();
                let removed = tokio::task::spawn_blocking(move || s.sweep())
                    .await
                    .unwrap_or_default();
                for p in removed {
                    tracing::info!(path = %p.display(), "removed an abandoned upload session");
                }
                tokio::time::sleep(every).await;
            }
        });
    }
}
