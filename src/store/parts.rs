//! `parts`: the "Identified Part" of system paper §2.1.2 — a point or region on a model, with
//! its centre, a reference to its vertex set (a serialised `RoaringBitmap` of original vertex
//! ids) and a preferred camera.

use roaring::RoaringBitmap;
use serde::{Deserialize, Serialize};
use sqlx::Row;
use sqlx::sqlite::SqliteRow;
use utoipa::ToSchema;

use super::models::double_option;
use super::part_revisions::{self, Snapshot};
use super::{Db, Result, StoreError, Tx};

/// Kind of part.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, sqlx::Type, ToSchema)]
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
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, ToSchema)]
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
#[derive(Debug, Clone, Serialize, ToSchema)]
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
    #[schema(format = DateTime)]
    pub created_at: String,
    /// Last change.
    #[schema(format = DateTime)]
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
#[derive(Debug, Clone, Deserialize, ToSchema)]
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
    /// Comment of the creation, kept in the part's history.
    #[serde(default)]
    pub comment: Option<String>,
}

/// Changes to a part; `None` leaves a field as it is.
#[derive(Debug, Clone, Default, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct PartPatch {
    /// New kind.
    pub kind: Option<PartKind>,
    /// New centre.
    pub center: Option<[f64; 3]>,
    /// New camera (`null` clears it).
    #[serde(default, with = "double_option")]
    #[schema(value_type = Option<Camera>)]
    pub camera: Option<Option<Camera>>,
    /// New vertex set.
    pub vertex_ids: Option<Vec<u32>>,
    /// New thumbnail (`null` clears it).
    #[serde(default, with = "double_option")]
    #[schema(value_type = Option<i64>)]
    pub thumbnail_attachment_id: Option<Option<i64>>,
    /// Comment of the edit, kept in the part's history.
    #[serde(default)]
    pub comment: Option<String>,
}

/// Longest revision comment, in characters.
pub const MAX_COMMENT_CHARS: usize = 2000;

fn validate_center(c: &[f64; 3]) -> Result<()> {
    if c.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(StoreError::Invalid(
            "center must be three finite numbers".into(),
        ))
    }
}

/// Serialised form of a vertex set (RoaringBitmap's portable format, as parts and their
/// revisions store it and `/api/v1/parts/{id}/vertices` serves it).
pub fn serialize_vertex_set(set: &RoaringBitmap) -> Vec<u8> {
    let mut out = Vec::with_capacity(set.serialized_size());
    // Writing into a Vec cannot fail.
    let _ = set.serialize_into(&mut out);
    out
}

/// A stored vertex set (`None`: empty).
pub fn parse_vertex_set(blob: Option<&[u8]>) -> Result<RoaringBitmap> {
    match blob {
        None => Ok(RoaringBitmap::new()),
        Some(b) => RoaringBitmap::deserialize_from(b)
            .map_err(|e| StoreError::Invalid(format!("stored vertex set unreadable: {e}"))),
    }
}

/// Checks a vertex set against the part limit and the model's vertex count (when known).
async fn check_vertex_set(
    tx: &mut Tx,
    model_id: i64,
    set: &RoaringBitmap,
    limit: usize,
) -> Result<()> {
    if set.len() > limit as u64 {
        return Err(StoreError::Invalid(format!(
            "a part may hold at most {limit} vertices; this one has {}",
            set.len()
        )));
    }
    let model_vertices: i64 = sqlx::query_scalar("SELECT vertex_count FROM models WHERE id = ?")
        .bind(model_id)
        .fetch_optional(&mut **tx)
        .await?
        .ok_or(StoreError::NotFound("model"))?;
    if model_vertices > 0
        && let Some(max) = set.max()
        && i64::from(max) >= model_vertices
    {
        return Err(StoreError::Invalid(format!(
            "vertex id {max} is out of range: the model has {model_vertices} vertices"
        )));
    }
    Ok(())
}

/// A vertex set from a client's id list (at most `limit` ids before deduplication).
fn set_of_ids(ids: &[u32], limit: usize) -> Result<RoaringBitmap> {
    if ids.len() > limit {
        return Err(StoreError::Invalid(format!(
            "a part may hold at most {limit} vertices"
        )));
    }
    Ok(ids.iter().copied().collect())
}

/// What a change to a part is, for its revision.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Action {
    /// A new part.
    Create,
    /// An edit through `PATCH /api/v1/parts/{id}`.
    Edit,
    /// A selection replaced the vertex set.
    Replace,
    /// A selection grew it.
    Add,
    /// A selection trimmed it.
    Subtract,
    /// The part was deleted (the revision keeps its last state).
    Delete,
}

impl Action {
    /// Name as stored.
    pub fn as_str(self) -> &'static str {
        match self {
            Action::Create => "create",
            Action::Edit => "edit",
            Action::Replace => "replace",
            Action::Add => "add",
            Action::Subtract => "subtract",
            Action::Delete => "delete",
        }
    }
}

/// Who made a change, how, and why: every write of a part carries one, and it becomes the
/// part's revision (author, time, comment; the selection tool and view when a selection made
/// it) and its audit entry.
#[derive(Debug, Clone, Default)]
pub struct Provenance {
    /// Author.
    pub user_id: i64,
    /// The author's comment.
    pub comment: Option<String>,
    /// Selection tool (`lasso`, `markup`, `heavy_lasso`, `point`), if a selection made it.
    pub tool: Option<String>,
    /// The view the selection was made from.
    pub view: Option<serde_json::Value>,
}

impl Provenance {
    /// A change by `user_id` with an optional comment.
    pub fn by(user_id: i64, comment: Option<String>) -> Provenance {
        Provenance {
            user_id,
            comment,
            ..Provenance::default()
        }
    }

    fn validate(&self) -> Result<()> {
        if let Some(c) = &self.comment
            && c.chars().count() > MAX_COMMENT_CHARS
        {
            return Err(StoreError::Invalid(format!(
                "a comment may have at most {MAX_COMMENT_CHARS} characters"
            )));
        }
        Ok(())
    }
}

/// The full state of a part as written: the one row image every write path produces.
#[derive(Debug, Clone)]
pub struct PartState {
    /// Point or region.
    pub kind: PartKind,
    /// Centre.
    pub center: [f64; 3],
    /// Vertex set.
    pub vertices: RoaringBitmap,
    /// Preferred camera.
    pub camera: Option<Camera>,
    /// Thumbnail attachment.
    pub thumbnail_attachment_id: Option<i64>,
}

impl PartState {
    fn validate(&self) -> Result<()> {
        validate_center(&self.center)?;
        if let Some(c) = &self.camera {
            c.validate()?;
        }
        if self.kind == PartKind::Region && self.vertices.is_empty() {
            return Err(StoreError::Invalid(
                "a region part needs a non-empty vertex set".into(),
            ));
        }
        Ok(())
    }
}

fn camera_json(c: &Option<Camera>) -> Option<String> {
    c.map(|c| serde_json::to_string(&c).unwrap_or_default())
}

/// The stored form of a state's vertex set (`None` when empty) and camera (JSON).
fn row_image(state: &PartState) -> (Option<Vec<u8>>, Option<String>) {
    let blob = (!state.vertices.is_empty()).then(|| serialize_vertex_set(&state.vertices));
    (blob, camera_json(&state.camera))
}

/// Appends the revision of part `id` in `state` (`row`: its stored vertex set and camera).
async fn record_revision_tx(
    tx: &mut Tx,
    id: i64,
    model_id: i64,
    state: &PartState,
    row: (&Option<Vec<u8>>, &Option<String>),
    action: Action,
    prov: &Provenance,
) -> Result<()> {
    let snapshot = Snapshot {
        part_id: id,
        model_id,
        kind: state.kind,
        center: state.center,
        vertex_count: state.vertices.len() as i64,
        vertex_set: row.0.as_deref(),
        camera: row.1.as_deref(),
    };
    part_revisions::record_tx(tx, &snapshot, action.as_str(), prov).await?;
    Ok(())
}

/// Inserts or updates the row of a part (`id`: `None` inserts) with `state`, appends its
/// revision and its audit entry, all in `tx`. The one writer of `parts`' user-facing columns.
async fn write_tx(
    tx: &mut Tx,
    id: Option<i64>,
    model_id: i64,
    state: &PartState,
    action: Action,
    prov: &Provenance,
    limit: usize,
) -> Result<i64> {
    state.validate()?;
    prov.validate()?;
    check_vertex_set(tx, model_id, &state.vertices, limit).await?;
    let (blob, camera) = row_image(state);
    let now = crate::now_rfc3339();
    let count = state.vertices.len() as i64;
    let thumbnail_missing = "thumbnail attachment does not exist";
    let id = match id {
        None => sqlx::query_scalar(
            "INSERT INTO parts (model_id, kind, center_x, center_y, center_z, vertex_count,
             vertex_set, camera, thumbnail_attachment_id, created_by, created_at, updated_at)
             VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?) RETURNING id",
        )
        .bind(model_id)
        .bind(state.kind)
        .bind(state.center[0])
        .bind(state.center[1])
        .bind(state.center[2])
        .bind(count)
        .bind(&blob)
        .bind(&camera)
        .bind(state.thumbnail_attachment_id)
        .bind(prov.user_id)
        .bind(&now)
        .bind(&now)
        .fetch_one(&mut **tx)
        .await
        .map_err(|e| StoreError::map_constraint(e, "", thumbnail_missing))?,
        Some(id) => {
            sqlx::query(
                "UPDATE parts SET kind = ?, center_x = ?, center_y = ?, center_z = ?,
                 vertex_count = ?, vertex_set = ?, camera = ?, thumbnail_attachment_id = ?,
                 updated_at = ? WHERE id = ?",
            )
            .bind(state.kind)
            .bind(state.center[0])
            .bind(state.center[1])
            .bind(state.center[2])
            .bind(count)
            .bind(&blob)
            .bind(&camera)
            .bind(state.thumbnail_attachment_id)
            .bind(&now)
            .bind(id)
            .execute(&mut **tx)
            .await
            .map_err(|e| StoreError::map_constraint(e, "", thumbnail_missing))?;
            id
        }
    };
    record_revision_tx(tx, id, model_id, state, (&blob, &camera), action, prov).await?;
    let audit = if action == Action::Create {
        "part.create"
    } else {
        "part.update"
    };
    super::audit::record(
        tx,
        Some(prov.user_id),
        audit,
        "part",
        Some(id),
        serde_json::json!({"model_id": model_id, "kind": state.kind, "vertex_count": count,
                           "action": action.as_str(), "tool": prov.tool}),
    )
    .await?;
    Ok(id)
}

/// Creates a part on model `model_id` with `state` (revision 1). A part without a camera or
/// thumbnail gets the server's best view and thumbnail in the background.
pub async fn create(
    db: &Db,
    model_id: i64,
    state: &PartState,
    prov: &Provenance,
    max_vertices: usize,
) -> Result<Part> {
    let mut tx = db.begin().await?;
    let id = write_tx(
        &mut tx,
        None,
        model_id,
        state,
        Action::Create,
        prov,
        max_vertices,
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
        Some(None) => Ok(serialize_vertex_set(&RoaringBitmap::new())),
    }
}

/// The state of a new part from the API's fields.
pub fn state_of_new(new: &NewPart, max_vertices: usize) -> Result<PartState> {
    let ids = new.vertex_ids.as_deref().unwrap_or(&[]);
    if new.kind == PartKind::Region && ids.is_empty() {
        return Err(StoreError::Invalid(
            "a region part needs a non-empty vertex_ids array".into(),
        ));
    }
    Ok(PartState {
        kind: new.kind,
        center: new.center,
        vertices: set_of_ids(ids, max_vertices)?,
        camera: new.camera.map(|c| Camera { auto: false, ..c }),
        thumbnail_attachment_id: new.thumbnail_attachment_id,
    })
}

/// The current state of part `id` in `tx`, with its model.
async fn state_tx(tx: &mut Tx, id: i64) -> Result<(Part, PartState)> {
    let part = get_tx(tx, id).await?;
    let blob: Option<Vec<u8>> = sqlx::query_scalar("SELECT vertex_set FROM parts WHERE id = ?")
        .bind(id)
        .fetch_one(&mut **tx)
        .await?;
    let state = PartState {
        kind: part.kind,
        center: part.center,
        vertices: parse_vertex_set(blob.as_deref())?,
        camera: part.camera,
        thumbnail_attachment_id: part.thumbnail_attachment_id,
    };
    Ok((part, state))
}

/// Changes part `id`: `change` maps its current state to the new one. With
/// `expected_updated_at`, the part must be unchanged since then (else
/// [`StoreError::Conflict`]). A new vertex set drops a server-computed camera and the
/// thumbnail unless `change` set them, so the server renders them again for the new region.
pub async fn update(
    db: &Db,
    id: i64,
    action: Action,
    change: impl FnOnce(&mut PartState) -> Result<()>,
    expected_updated_at: Option<&str>,
    prov: &Provenance,
    max_vertices: usize,
) -> Result<Part> {
    let mut tx = db.begin().await?;
    let (part, before) = state_tx(&mut tx, id).await?;
    if let Some(expected) = expected_updated_at
        && part.updated_at != expected
    {
        return Err(StoreError::Conflict(format!(
            "part {id} changed since this selection was made (at {}); select again on its \
             current state",
            part.updated_at
        )));
    }
    let mut after = before.clone();
    change(&mut after)?;
    if after.vertices != before.vertices {
        if after.camera == before.camera && before.camera.is_some_and(|c| c.auto) {
            after.camera = None;
        }
        if after.thumbnail_attachment_id == before.thumbnail_attachment_id {
            after.thumbnail_attachment_id = None;
        }
    }
    write_tx(
        &mut tx,
        Some(id),
        part.model_id,
        &after,
        action,
        prov,
        max_vertices,
    )
    .await?;
    let part = get_tx(&mut tx, id).await?;
    tx.commit().await?;
    Ok(part)
}

/// Applies an API patch to `state`.
pub fn apply_patch(state: &mut PartState, patch: &PartPatch, max_vertices: usize) -> Result<()> {
    if let Some(k) = patch.kind {
        state.kind = k;
    }
    if let Some(c) = patch.center {
        state.center = c;
    }
    if let Some(c) = patch.camera {
        state.camera = c.map(|c| Camera { auto: false, ..c });
    }
    if let Some(t) = patch.thumbnail_attachment_id {
        state.thumbnail_attachment_id = t;
    }
    if let Some(ids) = &patch.vertex_ids {
        state.vertices = set_of_ids(ids, max_vertices)?;
    }
    Ok(())
}

/// Deletes a part and its assignments (the contents stay); its history keeps a `delete`
/// revision with its last state.
pub async fn delete(db: &Db, id: i64, prov: &Provenance) -> Result<Part> {
    prov.validate()?;
    let mut tx = db.begin().await?;
    let (part, state) = state_tx(&mut tx, id).await?;
    let (blob, camera) = row_image(&state);
    super::changes::push_part(&mut tx, id).await?;
    sqlx::query("DELETE FROM parts WHERE id = ?")
        .bind(id)
        .execute(&mut *tx)
        .await?;
    let row = (&blob, &camera);
    record_revision_tx(
        &mut tx,
        id,
        part.model_id,
        &state,
        row,
        Action::Delete,
        prov,
    )
    .await?;
    super::audit::record(
        &mut tx,
        Some(prov.user_id),
        "part.delete",
        "part",
        Some(id),
        serde_json::json!({"model_id": part.model_id}),
    )
    .await?;
    tx.commit().await?;
    Ok(part)
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
