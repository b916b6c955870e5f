//! `models`: scans. Created empty (status `pending`) and filled in by the import pipeline
//! through [`set_status`] and [`set_stats`].

use serde::{Deserialize, Serialize};
use sqlx::Row;
use sqlx::sqlite::SqliteRow;
use utoipa::ToSchema;

use super::{Db, Page, Result, StoreError, Tx};

/// Build state of a model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, sqlx::Type, ToSchema)]
#[serde(rename_all = "lowercase")]
#[sqlx(rename_all = "lowercase")]
pub enum ModelStatus {
    /// Created, not yet imported.
    Pending,
    /// Import / LOD build running.
    Building,
    /// Ready to view.
    Ready,
    /// Import failed (see `error`).
    Failed,
}

impl ModelStatus {
    /// Name as stored.
    pub fn as_str(self) -> &'static str {
        match self {
            ModelStatus::Pending => "pending",
            ModelStatus::Building => "building",
            ModelStatus::Ready => "ready",
            ModelStatus::Failed => "failed",
        }
    }
}

/// Who may read a model's geometry.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, sqlx::Type, ToSchema,
)]
#[serde(rename_all = "lowercase")]
#[sqlx(rename_all = "lowercase")]
pub enum GeometryAccess {
    /// Everyone who may view the model streams its patches at full resolution.
    #[default]
    Full,
    /// Only admins obtain geometry finer than the sparse mesh (patches, the LOD file, exports,
    /// depth and id buffers); everyone else views the model image-based (its Grid-Lumigraph
    /// over the sparse mesh). Selection, highlights and measurements on the server still use
    /// the full-resolution scan.
    Sparse,
}

impl GeometryAccess {
    /// Name as stored.
    pub fn as_str(self) -> &'static str {
        match self {
            GeometryAccess::Full => "full",
            GeometryAccess::Sparse => "sparse",
        }
    }
}

/// Axis-aligned bounding box.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct BBox {
    /// Minimum corner (x, y, z).
    pub min: [f64; 3],
    /// Maximum corner (x, y, z).
    pub max: [f64; 3],
}

/// A scan.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct Model {
    /// Id.
    pub id: i64,
    /// Title.
    pub title: String,
    /// Description (Markdown).
    pub description: String,
    /// Name of the imported source file.
    pub source_name: String,
    /// Build state.
    pub status: ModelStatus,
    /// Vertices of the full-resolution mesh.
    pub vertex_count: i64,
    /// Triangles of the full-resolution mesh.
    pub triangle_count: i64,
    /// Bounding box, once known.
    pub bbox: Option<BBox>,
    /// LOD file, relative to the data directory.
    pub lod_path: Option<String>,
    /// Why the import failed.
    pub error: Option<String>,
    /// Thumbnail attachment.
    pub thumbnail_attachment_id: Option<i64>,
    /// Anonymous visitors may view the model, search and read the information on its parts
    /// (never edit). Set by admins.
    pub public: bool,
    /// Who may read its geometry (set by admins).
    pub geometry_access: GeometryAccess,
    /// Creator.
    pub created_by: i64,
    /// Creation time.
    #[schema(format = DateTime)]
    pub created_at: String,
    /// Last change.
    #[schema(format = DateTime)]
    pub updated_at: String,
}

const COLUMNS: &str = "id, title, description, source_name, status, vertex_count, triangle_count, \
    bbox_min_x, bbox_min_y, bbox_min_z, bbox_max_x, bbox_max_y, bbox_max_z, lod_path, error, \
    thumbnail_attachment_id, public, geometry_access, created_by, created_at, updated_at";

fn from_row(r: &SqliteRow) -> std::result::Result<Model, sqlx::Error> {
    let corners: [Option<f64>; 6] = [
        r.try_get("bbox_min_x")?,
        r.try_get("bbox_min_y")?,
        r.try_get("bbox_min_z")?,
        r.try_get("bbox_max_x")?,
        r.try_get("bbox_max_y")?,
        r.try_get("bbox_max_z")?,
    ];
    let bbox = match corners {
        [Some(a), Some(b), Some(c), Some(d), Some(e), Some(f)] => Some(BBox {
            min: [a, b, c],
            max: [d, e, f],
        }),
        _ => None,
    };
    Ok(Model {
        id: r.try_get("id")?,
        title: r.try_get("title")?,
        description: r.try_get("description")?,
        source_name: r.try_get("source_name")?,
        status: r.try_get("status")?,
        vertex_count: r.try_get("vertex_count")?,
        triangle_count: r.try_get("triangle_count")?,
        bbox,
        lod_path: r.try_get("lod_path")?,
        error: r.try_get("error")?,
        thumbnail_attachment_id: r.try_get("thumbnail_attachment_id")?,
        public: r.try_get("public")?,
        geometry_access: r.try_get("geometry_access")?,
        created_by: r.try_get("created_by")?,
        created_at: r.try_get("created_at")?,
        updated_at: r.try_get("updated_at")?,
    })
}

/// Fields of a new model.
#[derive(Debug, Clone, Default, Deserialize, ToSchema)]
pub struct NewModel {
    /// Title (required).
    pub title: String,
    /// Description.
    #[serde(default)]
    pub description: String,
    /// Source file name.
    #[serde(default)]
    pub source_name: String,
}

fn validate_title(title: &str) -> Result<()> {
    let n = title.trim().chars().count();
    if n == 0 || n > 300 {
        return Err(StoreError::Invalid(
            "title must be 1 to 300 characters".into(),
        ));
    }
    Ok(())
}

/// Creates a model record with status `pending`.
pub async fn create(db: &Db, new: &NewModel, user_id: i64) -> Result<Model> {
    let mut tx = db.begin().await?;
    let model = create_tx(&mut tx, new, user_id).await?;
    tx.commit().await?;
    Ok(model)
}

/// [`create`] inside the caller's transaction (e.g. together with its import job).
pub async fn create_tx(tx: &mut Tx, new: &NewModel, user_id: i64) -> Result<Model> {
    validate_title(&new.title)?;
    let now = crate::now_rfc3339();
    let id: i64 = sqlx::query_scalar(
        "INSERT INTO models (title, description, source_name, status, created_by, created_at, updated_at)
         VALUES (?, ?, ?, 'pending', ?, ?, ?) RETURNING id",
    )
    .bind(new.title.trim())
    .bind(&new.description)
    .bind(&new.source_name)
    .bind(user_id)
    .bind(&now)
    .bind(&now)
    .fetch_one(&mut **tx)
    .await?;
    super::audit::record(
        tx,
        Some(user_id),
        "model.create",
        "model",
        Some(id),
        serde_json::json!({"title": new.title.trim()}),
    )
    .await?;
    get_tx(tx, id).await
}

/// A model by id, inside a transaction.
pub async fn get_tx(tx: &mut Tx, id: i64) -> Result<Model> {
    let row = sqlx::query(sqlx::AssertSqlSafe(format!(
        "SELECT {COLUMNS} FROM models WHERE id = ?"
    )))
    .bind(id)
    .fetch_optional(&mut **tx)
    .await?
    .ok_or(StoreError::NotFound("model"))?;
    Ok(from_row(&row)?)
}

/// A model by id.
pub async fn get(db: &Db, id: i64) -> Result<Model> {
    let row = sqlx::query(sqlx::AssertSqlSafe(format!(
        "SELECT {COLUMNS} FROM models WHERE id = ?"
    )))
    .bind(id)
    .fetch_optional(&db.read)
    .await?
    .ok_or(StoreError::NotFound("model"))?;
    Ok(from_row(&row)?)
}

/// Models, newest first.
pub async fn list(db: &Db, page: Page) -> Result<Vec<Model>> {
    list_filtered(db, page, false).await
}

/// The public models, newest first (what anonymous visitors see).
pub async fn list_public(db: &Db, page: Page) -> Result<Vec<Model>> {
    list_filtered(db, page, true).await
}

async fn list_filtered(db: &Db, page: Page, public_only: bool) -> Result<Vec<Model>> {
    let filter = if public_only { "WHERE public = 1" } else { "" };
    let rows = sqlx::query(sqlx::AssertSqlSafe(format!(
        "SELECT {COLUMNS} FROM models {filter} ORDER BY id DESC LIMIT ? OFFSET ?"
    )))
    .bind(page.limit)
    .bind(page.offset)
    .fetch_all(&db.read)
    .await?;
    Ok(rows
        .iter()
        .map(from_row)
        .collect::<std::result::Result<_, _>>()?)
}

/// Changes to a model's descriptive fields; `None` leaves a field as it is.
#[derive(Debug, Clone, Default, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ModelPatch {
    /// New title.
    pub title: Option<String>,
    /// New description.
    pub description: Option<String>,
    /// New thumbnail (`null` clears it).
    #[serde(default, with = "double_option")]
    #[schema(value_type = Option<i64>)]
    pub thumbnail_attachment_id: Option<Option<i64>>,
    /// Public read-only access for anonymous visitors (admins only).
    #[serde(default)]
    pub public: Option<bool>,
    /// Who may read the geometry (admins only).
    #[serde(default)]
    pub geometry_access: Option<GeometryAccess>,
}

/// Serde helper telling an absent field (`None`) from an explicit `null` (`Some(None)`).
pub mod double_option {
    use serde::{Deserialize, Deserializer};

    /// Deserialises a present field, `null` included, as `Some`.
    pub fn deserialize<'de, T, D>(d: D) -> Result<Option<Option<T>>, D::Error>
    where
        T: Deserialize<'de>,
        D: Deserializer<'de>,
    {
        Ok(Some(Option::deserialize(d)?))
    }
}

/// Applies `patch`. A new title re-indexes every content assigned to the model.
pub async fn update(db: &Db, id: i64, patch: &ModelPatch, user_id: i64) -> Result<Model> {
    if let Some(t) = &patch.title {
        validate_title(t)?;
    }
    let mut tx = db.begin().await?;
    let mut model = get_tx(&mut tx, id).await?;
    let title_changed = patch
        .title
        .as_ref()
        .is_some_and(|t| t.trim() != model.title);
    if let Some(t) = &patch.title {
        model.title = t.trim().to_string();
    }
    if let Some(d) = &patch.description {
        model.description = d.clone();
    }
    if let Some(t) = patch.thumbnail_attachment_id {
        model.thumbnail_attachment_id = t;
    }
    if let Some(p) = patch.public {
        model.public = p;
    }
    if let Some(g) = patch.geometry_access {
        model.geometry_access = g;
    }
    model.updated_at = crate::now_rfc3339();
    sqlx::query(
        "UPDATE models SET title = ?, description = ?, thumbnail_attachment_id = ?, public = ?,
         geometry_access = ?, updated_at = ? WHERE id = ?",
    )
    .bind(&model.title)
    .bind(&model.description)
    .bind(model.thumbnail_attachment_id)
    .bind(model.public)
    .bind(model.geometry_access)
    .bind(&model.updated_at)
    .bind(id)
    .execute(&mut *tx)
    .await
    .map_err(|e| StoreError::map_constraint(e, "", "thumbnail attachment does not exist"))?;
    if title_changed {
        super::changes::push_model(&mut tx, id).await?;
    }
    super::audit::record(
        &mut tx,
        Some(user_id),
        "model.update",
        "model",
        Some(id),
        serde_json::json!({
            "title": patch.title,
            "description_changed": patch.description.is_some(),
            "thumbnail_attachment_id": patch.thumbnail_attachment_id,
            "public": patch.public,
            "geometry_access": patch.geometry_access,
        }),
    )
    .await?;
    tx.commit().await?;
    Ok(model)
}

/// Sets the build state (and the error message for `failed`).
pub async fn set_status(
    db: &Db,
    id: i64,
    status: ModelStatus,
    error: Option<&str>,
    user_id: Option<i64>,
) -> Result<()> {
    let mut tx = db.begin().await?;
    let n = sqlx::query("UPDATE models SET status = ?, error = ?, updated_at = ? WHERE id = ?")
        .bind(status)
        .bind(error)
        .bind(crate::now_rfc3339())
        .bind(id)
        .execute(&mut *tx)
        .await?
        .rows_affected();
    if n == 0 {
        return Err(StoreError::NotFound("model"));
    }
    super::audit::record(
        &mut tx,
        user_id,
        "model.status",
        "model",
        Some(id),
        serde_json::json!({"status": status, "error": error}),
    )
    .await?;
    tx.commit().await?;
    Ok(())
}

/// Statistics of a built model.
#[derive(Debug, Clone, Default)]
pub struct ModelStats {
    /// Source file name.
    pub source_name: Option<String>,
    /// Vertices.
    pub vertex_count: i64,
    /// Triangles.
    pub triangle_count: i64,
    /// Bounding box.
    pub bbox: Option<BBox>,
    /// LOD file relative to the data directory.
    pub lod_path: Option<String>,
}

/// Records the statistics and LOD file of a built model.
pub async fn set_stats(db: &Db, id: i64, stats: &ModelStats, user_id: Option<i64>) -> Result<()> {
    let b = stats.bbox;
    let mut tx = db.begin().await?;
    let n = sqlx::query(
        "UPDATE models SET source_name = COALESCE(?, source_name), vertex_count = ?,
         triangle_count = ?, bbox_min_x = ?, bbox_min_y = ?, bbox_min_z = ?, bbox_max_x = ?,
         bbox_max_y = ?, bbox_max_z = ?, lod_path = ?, updated_at = ? WHERE id = ?",
    )
    .bind(&stats.source_name)
    .bind(stats.vertex_count)
    .bind(stats.triangle_count)
    .bind(b.map(|b| b.min[0]))
    .bind(b.map(|b| b.min[1]))
    .bind(b.map(|b| b.min[2]))
    .bind(b.map(|b| b.max[0]))
    .bind(b.map(|b| b.max[1]))
    .bind(b.map(|b| b.max[2]))
    .bind(&stats.lod_path)
    .bind(crate::now_rfc3339())
    .bind(id)
    .execute(&mut *tx)
    .await?
    .rows_affected();
    if n == 0 {
        return Err(StoreError::NotFound("model"));
    }
    super::audit::record(
        &mut tx,
        user_id,
        "model.stats",
        "model",
        Some(id),
        serde_json::json!({
            "vertex_count": stats.vertex_count,
            "triangle_count": stats.triangle_count,
            "lod_path": stats.lod_path,
        }),
    )
    .await?;
    tx.commit().await?;
    Ok(())
}

/// Deletes a model with its parts and their assignments (contents stay). Returns the model
/// as it was, so callers can remove its files.
pub async fn delete(db: &Db, id: i64, user_id: i64) -> Result<Model> {
    let mut tx = db.begin().await?;
    let model = get_tx(&mut tx, id).await?;
    super::changes::push_model(&mut tx, id).await?;
    sqlx::query("DELETE FROM models WHERE id = ?")
        .bind(id)
        .execute(&mut *tx)
        .await?;
    super::audit::record(
        &mut tx,
        Some(user_id),
        "model.delete",
        "model",
        Some(id),
        serde_json::json!({"title": model.title}),
    )
    .await?;
    tx.commit().await?;
    Ok(model)
}
