//! Demo data for `meshwiki demo`: a few wiki contents with Markdown, several revisions and
//! an image attachment, created once on an empty database ([`seed_demo`]); and, once the
//! generated demo relief is built, a region part on its sun disk with a content assigned
//! ([`seed_demo_model`]).

use std::io::Cursor;
use std::path::Path;

use crate::config::Settings;
use crate::store::attachments::{self, NewAttachment};
use crate::store::contents::{self, ContentEdit};
use crate::store::{Db, StoreError};

/// Errors while seeding.
#[derive(Debug, thiserror::Error)]
pub enum SeedError {
    /// The database failed.
    #[error(transparent)]
    Store(#[from] StoreError),
    /// Writing the attachment failed.
    #[error("cannot write demo attachment: {0}")]
    Io(#[from] std::io::Error),
    /// Encoding the demo image failed.
    #[error("cannot encode demo image: {0}")]
    Image(#[from] image::ImageError),
    /// The demo model's LOD file could not be read.
    #[error("cannot read the demo model: {0}")]
    Lod(String),
}

fn edit(title: &str, caption: &str, body: &str, comment: &str) -> ContentEdit {
    ContentEdit {
        title: title.into(),
        caption: caption.into(),
        body: body.into(),
        comment: comment.into(),
    }
}

/// A small PNG (a stone-coloured gradient with a few "incised" lines).
fn demo_png() -> Result<Vec<u8>, image::ImageError> {
    let img = image::RgbImage::from_fn(160, 96, |x, y| {
        let incised = (y % 24 == 12 && x > 16 && x < 144) || (x % 40 == 20 && y > 8 && y < 88);
        let base = 150 + ((x + y) % 40) as u8;
        if incised {
            image::Rgb([base / 3, base / 3, base / 3 + 10])
        } else {
            image::Rgb([base, base - 10, base - 30])
        }
    });
    let mut out = Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png)?;
    Ok(out.into_inner())
}

/// Seeds demo contents authored by `user_id` if the database holds no contents yet.
/// Returns whether anything was created. The caller syncs the search index afterwards.
pub async fn seed_demo(db: &Db, settings: &Settings, user_id: i64) -> Result<bool, SeedError> {
    if contents::count(db).await? > 0 {
        return Ok(false);
    }
    let welcome = contents::create(
        db,
        &edit(
            "Welcome to meshwiki",
            "What this server is and how to use it",
            "# Welcome\n\nmeshwiki attaches *wiki information* to regions of huge 3D scans.\n\n\
             - **Models** are scans.\n- **Parts** are points or regions selected on a model.\n\
             - **Contents** are wiki pages like this one, assigned to parts.\n\n\
             Every save keeps a revision: see the history, compare any two revisions, revert.\n",
            "First version",
        ),
        None,
        user_id,
    )
    .await?;
    contents::update(
        db,
        welcome.id,
        welcome.current_revision,
        &edit(
            "Welcome to meshwiki",
            "What this server is and how to use it",
            "# Welcome\n\nmeshwiki attaches *wiki information* to regions of huge 3D scans of \
             cultural heritage.\n\n\
             - **Models** are scans.\n- **Parts** are points or regions selected on a model.\n\
             - **Contents** are wiki pages like this one, assigned to parts.\n\n\
             Every save keeps a revision: see the history, compare any two revisions, revert.\n\n\
             ## Searching\n\nUse the search box: words are combined with AND, `\"a phrase\"` \
             matches exactly and `-word` excludes.\n",
            "Explain search",
        ),
        None,
        user_id,
    )
    .await?;

    let lion = contents::create(
        db,
        &edit(
            "Bronze lion, left fore paw",
            "Casting seam and later repair",
            "The left fore paw shows a **casting seam** running along the outer toe.\n\n\
             | Feature | Depth (mm) |\n|---|---|\n| Seam | 0.4 |\n| Repair patch | 1.2 |\n\n\
             The repair patch is a later addition, visible as a change in patina.\n",
            "Observations from the 2023 survey",
        ),
        None,
        user_id,
    )
    .await?;
    contents::update(
        db,
        lion.id,
        lion.current_revision,
        &edit(
            "Bronze lion, left fore paw",
            "Casting seam and later repair",
            "The left fore paw shows a **casting seam** running along the outer toe.\n\n\
             | Feature | Depth (mm) |\n|---|---|\n| Seam | 0.4 |\n| Repair patch | 1.5 |\n\n\
             The repair patch is a later addition, visible as a change in patina and in the \
             scan's surface roughness.\n\n> Measured again with the calibrated probe.\n",
            "Corrected the patch depth",
        ),
        None,
        user_id,
    )
    .await?;

    let png = demo_png()?;
    let sha256 = {
        let settings = settings.clone();
        let png = png.clone();
        tokio::task::spawn_blocking(move || crate::blobs::write_bytes(&settings, &png))
            .await
            .map_err(|e| std::io::Error::other(e.to_string()))??
    };
    let inscription = contents::create(
        db,
        &edit(
            "Inscription on the base",
            "Rubbing and transcription",
            "A short inscription runs along the front of the base.\n",
            "Stub",
        ),
        None,
        user_id,
    )
    .await?;
    let attachment = attachments::create(
        db,
        &NewAttachment {
            sha256,
            media_type: "image/png".into(),
            size: png.len() as i64,
            original_name: "inscription-rubbing.png".into(),
        },
        Some(inscription.id),
        user_id,
    )
    .await?;
    contents::update(
        db,
        inscription.id,
        inscription.current_revision,
        &edit(
            "Inscription on the base",
            "Rubbing and transcription",
            &format!(
                "A short inscription runs along the front of the base.\n\n\
                 ![Rubbing of the inscription](/api/v1/attachments/{}/download)\n\n\
                 Transcription (tentative): *\"given by the guild of bronze founders\"*.\n",
                attachment.id
            ),
            "Add rubbing and transcription",
        ),
        Some(Some(attachment.id)),
        user_id,
    )
    .await?;

    contents::create(
        db,
        &edit(
            "Scanning notes",
            "How the scans were captured",
            "## Capture\n\n1. Structured-light scanner, 0.1 mm point spacing.\n\
             2. 412 overlapping range images, aligned and merged.\n\n\
             ## Known gaps\n\nThe underside of the base could not be reached; holes there \
             were filled during merging.\n",
            "",
        ),
        None,
        user_id,
    )
    .await?;
    Ok(true)
}

/// Centre (x, y) and radius of the sun disk of the generated relief (`mesh::synth`).
const SUN: ([f64; 2], f64) = ([0.0, -0.08], 0.115);

/// Original ids and centre of the vertices of the relief's sun disk, from the leaves.
fn sun_disk(lod_path: &Path) -> Result<(Vec<u32>, [f64; 3]), SeedError> {
    use meshwiki_engine::lod::LodFile;
    let lod = LodFile::open(lod_path).map_err(|e| SeedError::Lod(e.to_string()))?;
    let ([cx, cy], r) = SUN;
    let mut ids = Vec::new();
    let mut sum = [0.0f64; 3];
    for (i, n) in lod.nodes().iter().enumerate() {
        let b = n.bounds;
        let d = ((b[0] as f64 - cx).powi(2) + (b[1] as f64 - cy).powi(2)).sqrt();
        if n.level != 0 || d > r + b[3] as f64 {
            continue;
        }
        let p = lod
            .patch(i as u32)
            .map_err(|e| SeedError::Lod(e.to_string()))?;
        for (q, &id) in p.positions.iter().zip(&p.original_ids) {
            if (q[0] as f64 - cx).powi(2) + (q[1] as f64 - cy).powi(2) <= r * r {
                ids.push(id);
                for (acc, &c) in sum.iter_mut().zip(q) {
                    *acc += c as f64;
                }
            }
        }
    }
    ids.sort_unstable();
    ids.dedup();
    let n = ids.len().max(1) as f64;
    Ok((ids, sum.map(|s| s / n)))
}

/// Seeds the built demo relief (model `model_id`, LOD file at `lod_path`) with a region part
/// on its sun disk and a content assigned to it, unless the model has parts already.
/// Returns whether anything was created; the caller syncs the search index afterwards.
pub async fn seed_demo_model(
    db: &Db,
    settings: &Settings,
    model_id: i64,
    lod_path: &Path,
    user_id: i64,
) -> Result<bool, SeedError> {
    use crate::store::{assignments, parts};
    if !parts::list_for_model(db, model_id).await?.is_empty() {
        return Ok(false);
    }
    let path = lod_path.to_path_buf();
    let (ids, center) = tokio::task::spawn_blocking(move || sun_disk(&path))
        .await
        .map_err(|e| SeedError::Lod(e.to_string()))??;
    if ids.is_empty() {
        return Ok(false);
    }
    let part = parts::create(
        db,
        model_id,
        &parts::PartState {
            kind: parts::PartKind::Region,
            center,
            camera: Some(parts::Camera {
                eye: [center[0], center[1] - 0.25, center[2] + 0.6],
                target: center,
                up: [0.0, 1.0, 0.0],
                fovy: 40.0,
                auto: false,
            }),
            vertices: ids.into_iter().collect(),
            thumbnail_attachment_id: None,
        },
        &parts::Provenance::by(user_id, Some("Seeded with the demo model".into())),
        settings.limits.part_vertices,
    )
    .await?;
    let content = contents::create(
        db,
        &edit(
            "Sun disk with rays",
            "Central motif of the demo relief",
            "The **sun disk** in the lower centre of the panel is carved in low relief, with \
             sixteen rays fading into the ground.\n\n\
             - Remnants of *red ochre* survive in the disk.\n\
             - The rays are worn smooth towards their tips.\n\n\
             This region was selected on the generated demo scan: open the model to see it \
             highlighted, or select another region and assign information to it.\n",
            "Seeded with the demo model",
        ),
        None,
        user_id,
    )
    .await?;
    assignments::assign(db, part.id, content.id, None, user_id).await?;
    Ok(true)
}
