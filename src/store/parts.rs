//! `parts`: the "Identified Part" of system paper §2.1.2 — a point or region on a model, with
//! its centre, a reference to its vertex set (a serialised `RoaringBitmap` of original vertex
//! ids) and a preferred camera.

use roaring::RoaringBitmap;
use serde::{Deserialize, Serialize};
use sqlx::Row;
use sqlx::sqlite::SqliteRow;

use super::models::double_option;
use super::{Db, Result, StoreError, Tx};

/// Kind of part.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, sqlx::Type)]
#[serde(rename_all = "lowercase")]
#[sqlx(rename_all = "lowercase")]
pub enum PartKind {
    /// A picked point.
    Point,
    /// A selected region.
    Region,
}

impl PartKind {
    /// Name as stored.
    pub fn as_str(self) -> &'static str {
        match self {
            PartKind::Point => "point",
            PartKind::Region => "region",
        }
    }
}

/// Preferred view of a part.
///
/// A part created without a camera gets its *best view* from the server (`auto: true`,
/// `crate::render::views`), recomputed whenever its vertex set changes; a camera given by a
/// client (`auto` is then always false) is kept until a client changes it, and `null` in a
/// patch hands the part back to the server's best view.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Camera {
    /// Eye position.
    pub eye: [f64; 3],
    /// Point looked at.
    pub target: [f64; 3],
    /// Up vector.
    pub up: [f64; 3],
    /// Vertical field of view in degrees.
    pub fovy: f64,
    /// Computed by the server (best view) rather than given by a client.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub auto: bool,
}

impl Camera {
    fn validate(&self) -> Result<()> {
        let finite = self
            .eye
            .iter()
            .chain(&self.target)
            .chain(&self.up)
            .all(|v| v.is_finite());
        if !(finite && self.fovy > 0.0 && self.fovy < 180.0) {
            return Err(StoreError::Invalid(
                "camera needs finite eye/target/up and 0 < fovy < 180".into(),
            ));
        }
        if self.up.iter().all(|v| *v == 0.0) {
            return Err(StoreError::Invalid("camera up vector is zero".into()));
        }
        Ok(())
    }
}

/// An identified part.
#[derive(Debug, Clone, Serialize)]
pub struct Part {
    /// Id.
    pub id: i64,
    /// Model it lies on.
    pub model_id: i64,
    /// Point or region.
    pub kind: PartKind,
    /// Centre (model coordinates).
    pub center: [f64; 3],
    /// Number of vertices in its vertex set.
    pub vertex_count: i64,
    /// Preferred camera.
    pub camera: Option<Camera>,
    /// Thumbnail attachment.
    pub thumbnail_attachment_id: Option<i64>,
    /// Creator.
    pub created_by: i64,
    /// Creation time.
    pub created_at: String,
    /// Last change.
    pub updated_at: String,
}

const COLUMNS: &str = "id, model_id, kind, center_x, center_y, center_z, vertex_count, camera, \
    thumbnail_attachment_id, created_by, created_at, updated_at";

fn from_row(r: &SqliteRow) -> std::result::Result<Part, sqlx::Error> {
    let camera: Option<String> = r.try_get("camera")?;
    Ok(Part {
        id: r.try_get("id")?,
        model_id: r.try_get("model_id")?,
        kind: r.try_get("kind")?,
        center: [
            r.try_get("center_x")?,
            r.try_get("center_y")?,
            r.try_get("center_z")?,
        ],
        vertex_count: r.try_get("vertex_count")?,
        camera: camera.and_then(|c| serde_json::from_str(&c).ok()),
        thumbnail_attachment_id: r.try_get("thumbnail_attachment_id")?,
        created_by: r.try_get("created_by")?,
        created_at: r.try_get("created_at")?,
        updated_at: r.try_get("updated_at")?,
    })
}

/// Fields of a new part.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NewPart {
    /// Point or region.
    pub kind: PartKind,
    /// Centre.
    pub center: [f64; 3],
    /// Preferred camera.
    #[serde(default)]
    pub camera: Option<Camera>,
    /// Original vertex ids of the region (required for regions, optional for points).
    #[serde(default)]
    pub vertex_ids: Option<Vec<u32>>,
    /// Thumbnail attachment.
    #[serde(default)]
    pub thumbnail_attachment_id: Option<i64>,
}

/// Changes to a part; `None` leaves a field as it is.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PartPatch {
    /// New kind.
    pub kind: Option<PartKind>,
    /// New centre.
    pub center: Option<[f64; 3]>,
    /// New camera (`null` clears it).
    #[serde(default, with = "double_option")]
    pub camera: Option<Option<Camera>>,
    /// New vertex set.
    pub vertex_ids: Option<Vec<u32>>,
    /// New thumbnail (`null` clears it).
    #[serde(default, with = "double_option")]
    pub thumbnail_attachment_id: Option<Option<i64>>,
}

fn validate_center(c: &[f64; 3]) -> Result<()> {
    if c.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(StoreError::Invalid(
            "center must be three finite numbers".into(),
        ))
    }
}

/// Builds the vertex set, checking ids against the model's vertex count (when known).
fn vertex_set(ids: &[u32], model_vertices: i64, limit: usize) -> Result<RoaringBitmap> {
    if ids.len() > limit {
        return Err(StoreError::Invalid(format!(
            "a part may hold at most {limit} vertices"
        )));
    }
    let set: RoaringBitmap = ids.iter().copied().collect();
    if model_vertices > 0
        && let Some(max) = set.max()
        && i64::from(max) >= model_vertices
    {
        return Err(StoreError::Invalid(format!(
            "vertex id {max} is out of range: the model has {model_vertices} vertices"
        )));
    }
    Ok(set)
}

fn serialize_set(set: &RoaringBitmap) -> Vec<u8> {
    let mut out = Vec::with_capacity(set.serialized_size());
    // Writing into a Vec cannot fail.
    let _ = set.serialize_into(&mut out);
    out
}

async fn model_vertices(tx: &mut Tx, model_id: i64) -> Result<i64> {
    sqlx::query_scalar("SELECT vertex_count FROM models WHERE id = ?")
        .bind(model_id)
        .fetch_optional(&mut **tx)
        .await?
        .ok_or(StoreError::NotFound("model"))
}

/// Creates a part on model `model_id`.
pub async fn create(
    db: &Db,
    model_id: i64,
    new: &NewPart,
    user_id: i64,
    max_vertices: usize,
) -> Result<Part> {
    validate_center(&new.center)?;
    if let Some(c) = &new.camera {
        c.validate()?;
    }
    let ids = new.vertex_ids.as_deref().unwrap_or(&[]);
    if new.kind == PartKind::Region && ids.is_empty() {
        return Err(StoreError::Invalid(
            "a region part needs a non-empty vertex_ids array".into(),
        ));
    }
    let mut tx = db.begin().await?;
    let model_vertices = model_vertices(&mut tx, model_id).await?;
    let set = vertex_set(ids, model_vertices, max_vertices)?;
    let blob = (!set.is_empty()).then(|| serialize_set(&set));
    let camera = new
        .camera
        .map(|c| serde_json::to_string(&Camera { auto: false, ..c }).unwrap_or_default());
    let now = crate::now_rfc3339();
    let id: i64 = sqlx::query_scalar(
        "INSERT INTO parts (model_id, kind, center_x, center_y, center_z, vertex_count, vertex_set,
         camera, thumbnail_attachment_id, created_by, created_at, updated_at)
         VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?) RETURNING id",
    )
    .bind(model_id)
    .bind(new.kind)
    .bind(new.center[0])
    .bind(new.center[1])
    .bind(new.center[2])
    .bind(set.len() as i64)
    .bind(blob)
    .bind(camera)
    .bind(new.thumbnail_attachment_id)
    .bind(user_id)
    .bind(&now)
    .bind(&now)
    .fetch_one(&mut *tx)
    .await
    .map_err(|e| StoreError::map_constraint(e, "", "thumbnail attachment does not exist"))?;
    super::audit::record(
        &mut tx,
        Some(user_id),
        "part.create",
        "part",
        Some(id),
        serde_json::json!({"model_id": model_id, "kind": new.kind, "vertex_count": set.len()}),
    )
    .await?;
    let part = get_tx(&mut tx, id).await?;
    tx.commit().await?;
    Ok(part)
}

async fn get_tx(tx: &mut Tx, id: i64) -> Result<Part> {
    let row = sqlx::query(sqlx::AssertSqlSafe(format!(
        "SELECT {COLUMNS} FROM parts WHERE id = ?"
    )))
    .bind(id)
    .fetch_optional(&mut **tx)
    .await?
    .ok_or(StoreError::NotFound("part"))?;
    Ok(from_row(&row)?)
}

/// A part by id.
pub async fn get(db: &Db, id: i64) -> Result<Part> {
    let row = sqlx::query(sqlx::AssertSqlSafe(format!(
        "SELECT {COLUMNS} FROM parts WHERE id = ?"
    )))
    .bind(id)
    .fetch_optional(&db.read)
    .await?
    .ok_or(StoreError::NotFound("part"))?;
    Ok(from_row(&row)?)
}

/// Parts of a model, oldest first.
pub async fn list_for_model(db: &Db, model_id: i64) -> Result<Vec<Part>> {
    let rows = sqlx::query(sqlx::AssertSqlSafe(format!(
        "SELECT {COLUMNS} FROM parts WHERE model_id = ? ORDER BY id"
    )))
    .bind(model_id)
    .fetch_all(&db.read)
    .await?;
    Ok(rows
        .iter()
        .map(from_row)
        .collect::<std::result::Result<_, _>>()?)
}

/// The serialised vertex set of a part (empty bitmap when it has none).
pub async fn vertices(db: &Db, id: i64) -> Result<Vec<u8>> {
    let blob: Option<Option<Vec<u8>>> =
        sqlx::query_scalar("SELECT vertex_set FROM parts WHERE id = ?")
            .bind(id)
            .fetch_optional(&db.read)
            .await?;
    match blob {
        None => Err(StoreError::NotFound("part")),
        Some(Some(b)) => Ok(b),
        Some(None) => Ok(serialize_set(&RoaringBitmap::new())),
    }
}

/// Applies `patch` to part `id`.
pub async fn update(
    db: &Db,
    id: i64,
    patch: &PartPatch,
    user_id: i64,
    max_vertices: usize,
) -> Result<Part> {
    if let Some(c) = &patch.center {
        validate_center(c)?;
    }
    if let Some(Some(c)) = &patch.camera {
        c.validate()?;
    }
    let mut tx = db.begin().await?;
    let mut part = get_tx(&mut tx, id).await?;
    if let Some(k) = patch.kind {
        part.kind = k;
    }
    if let Some(c) = patch.center {
        part.center = c;
    }
    if let Some(c) = patch.camera {
        part.camera = c.map(|c| Camera { auto: false, ..c });
    }
    if let Some(t) = patch.thumbnail_attachment_id {
        part.thumbnail_attachment_id = t;
    }
    if let Some(ids) = &patch.vertex_ids {
        // A new region gets a new best view (unless its camera came from a client) and a new
        // thumbnail (unless this patch sets one); the server renders them in the background.
        if patch.camera.is_none() && part.camera.is_some_and(|c| c.auto) {
            part.camera = None;
        }
        if patch.thumbnail_attachment_id.is_none() {
            part.thumbnail_attachment_id = None;
        }
        let model_vertices = model_vertices(&mut tx, part.model_id).await?;
        let set = vertex_set(ids, model_vertices, max_vertices)?;
        part.vertex_count = set.len() as i64;
        sqlx::query("UPDATE parts SET vertex_set = ?, vertex_count = ? WHERE id = ?")
            .bind((!set.is_empty()).then(|| serialize_set(&set)))
            .bind(part.vertex_count)
            .bind(id)
            .execute(&mut *tx)
            .await?;
    }
    if part.kind == PartKind::Region && part.vertex_count == 0 {
        return Err(StoreError::Invalid(
            "a region part needs a non-empty vertex set".into(),
        ));
    }
    part.updated_at = crate::now_rfc3339();
    sqlx::query(
        "UPDATE parts SET kind = ?, center_x = ?, center_y = ?, center_z = ?, camera = ?,
         thumbnail_attachment_id = ?, updated_at = ? WHERE id = ?",
    )
    .bind(part.kind)
    .bind(part.center[0])
    .bind(part.center[1])
    .bind(part.center[2])
    .bind(
        part.camera
            .map(|c| serde_json::to_string(&c).unwrap_or_default()),
    )
    .bind(part.thumbnail_attachment_id)
    .bind(&part.updated_at)
    .bind(id)
    .execute(&mut *tx)
    .await
    .map_err(|e| StoreError::map_constraint(e, "", "thumbnail attachment does not exist"))?;
    super::audit::record(
        &mut tx,
        Some(user_id),
        "part.update",
        "part",
        Some(id),
        serde_json::json!({
            "kind": patch.kind,
            "center": patch.center,
            "vertices_changed": patch.vertex_ids.is_some(),
        }),
    )
    .await?;
    tx.commit().await?;
    Ok(part)
}

/// Deletes a part and its assignments (the contents stay).
pub async fn delete(db: &Db, id: i64, user_id: i64) -> Result<()> {
    let mut tx = db.begin().await?;
    let part = get_tx(&mut tx, id).await?;
    super::changes::push_part(&mut tx, id).await?;
    sqlx::query("DELETE FROM parts WHERE id = ?")
        .bind(id)
        .execute(&mut *tx)
        .await?;
    super::audit::record(
        &mut tx,
        Some(user_id),
        "part.delete",
        "part",
        Some(id),
        serde_json::json!({"model_id": part.model_id}),
    )
    .await?;
    tx.commit().await?;
    Ok(())
}

/// Parts that lack a camera or a thumbnail, on ready models (all of them, or those of
/// `model_id`): the work list of the server's best views and thumbnails.
pub async fn needing_views(db: &Db, model_id: Option<i64>) -> Result<Vec<i64>> {
    Ok(sqlx::query_scalar(
        "SELECT p.id FROM parts p JOIN models m ON m.id = p.model_id
         WHERE m.status = 'ready' AND (p.camera IS NULL OR p.thumbnail_attachment_id IS NULL)
         AND (? IS NULL OR p.model_id = ?) ORDER BY p.id",
    )
    .bind(model_id)
    .bind(model_id)
    .fetch_all(&db.read)
    .await?)
}

/// The stored vertex set of a part as it is in the database (`None` when it has none), for
/// [`set_generated_view`]; `NotFound` for an unknown part.
pub async fn vertex_set_raw(db: &Db, id: i64) -> Result<Option<Vec<u8>>> {
    let blob: Option<Option<Vec<u8>>> =
        sqlx::query_scalar("SELECT vertex_set FROM parts WHERE id = ?")
            .bind(id)
            .fetch_optional(&db.read)
            .await?;
    blob.ok_or(StoreError::NotFound("part"))
}

/// Model and vertex-set size in bytes of part `id`, `None` when there is no such part.
pub async fn model_and_set_size(db: &Db, id: i64) -> Result<Option<(i64, i64)>> {
    Ok(sqlx::query_as::<_, (i64, i64)>(
        "SELECT model_id, COALESCE(length(vertex_set), 0) FROM parts WHERE id = ?",
    )
    .bind(id)
    .fetch_optional(&db.read)
    .await?)
}

/// Stores a server-computed camera (`auto` is set) and thumbnail where the part has none,
/// provided its vertex set is still `vertex_set` (else it changed meanwhile and the work is
/// stale). Returns whether the part was updated. `updated_at` is left alone: it versions
/// edits (selections check it), and these views are derived from the part, not edits.
pub async fn set_generated_view(
    db: &Db,
    id: i64,
    camera: Option<&Camera>,
    thumbnail_attachment_id: Option<i64>,
    vertex_set: Option<&[u8]>,
) -> Result<bool> {
    let camera =
        camera.map(|c| serde_json::to_string(&Camera { auto: true, ..*c }).unwrap_or_default());
    let mut tx = db.begin().await?;
    let n = sqlx::query(
        "UPDATE parts SET camera = COALESCE(camera, ?),
         thumbnail_attachment_id = COALESCE(thumbnail_attachment_id, ?)
         WHERE id = ? AND vertex_set IS ?
         AND ((camera IS NULL AND ? IS NOT NULL) OR (thumbnail_attachment_id IS NULL AND ? IS NOT NULL))",
    )
    .bind(&camera)
    .bind(thumbnail_attachment_id)
    .bind(id)
    .bind(vertex_set)
    .bind(&camera)
    .bind(thumbnail_attachment_id)
    .execute(&mut *tx)
    .await
    .map_err(|e| StoreError::map_constraint(e, "", "thumbnail attachment does not exist"))?
    .rows_affected();
    tx.commit().await?;
    Ok(n > 0)
}
