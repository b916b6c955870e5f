//! `part_revisions`: the history of parts' geometry (issue 6: "every change is in the
//! history"), and the writes of the selection tools — a confirmed selection creates a part or
//! replaces, grows or trims a part's vertex set — each in one transaction with its revision row
//! and its audit entry.

use roaring::RoaringBitmap;
use serde::Serialize;
use sqlx::Row;

use super::parts::{self, Part, PartKind};
use super::{Db, Result, StoreError, Tx};

/// One revision of a part (without its vertex set).
#[derive(Debug, Clone, Serialize)]
pub struct PartRevision {
    /// Revision number (1 = creation).
    pub number: i64,
    /// Part.
    pub part_id: i64,
    /// Model.
    pub model_id: i64,
    /// `create`, `replace`, `add`, `subtract`, `edit` or `delete`.
    pub action: String,
    /// Selection tool, if a selection made the change.
    pub tool: Option<String>,
    /// Kind at this revision.
    pub kind: PartKind,
    /// Centre at this revision.
    pub center: [f64; 3],
    /// Vertices at this revision.
    pub vertex_count: i64,
    /// The view the selection was made from.
    pub view: Option<serde_json::Value>,
    /// Author.
    pub author_id: Option<i64>,
    /// Author's user name.
    pub author: Option<String>,
    /// Time.
    pub created_at: String,
}

/// The state of a part to record.
#[derive(Debug, Clone, Copy)]
pub struct Snapshot<'a> {
    /// Part.
    pub part_id: i64,
    /// Model.
    pub model_id: i64,
    /// Kind.
    pub kind: PartKind,
    /// Centre.
    pub center: [f64; 3],
    /// Vertex count.
    pub vertex_count: i64,
    /// Serialised vertex set.
    pub vertex_set: Option<&'a [u8]>,
}

/// Appends a revision of a part in the current transaction; returns its number.
pub async fn record_tx(
    tx: &mut Tx,
    s: &Snapshot<'_>,
    action: &str,
    tool: Option<&str>,
    view: Option<&serde_json::Value>,
    user_id: Option<i64>,
) -> Result<i64> {
    let number: i64 = sqlx::query_scalar(
        "SELECT COALESCE(MAX(number), 0) + 1 FROM part_revisions WHERE part_id = ?",
    )
    .bind(s.part_id)
    .fetch_one(&mut **tx)
    .await?;
    sqlx::query(
        "INSERT INTO part_revisions (part_id, model_id, number, action, tool, kind, center_x,
         center_y, center_z, vertex_count, vertex_set, view, author_id, created_at)
         VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
    )
    .bind(s.part_id)
    .bind(s.model_id)
    .bind(number)
    .bind(action)
    .bind(tool)
    .bind(s.kind)
    .bind(s.center[0])
    .bind(s.center[1])
    .bind(s.center[2])
    .bind(s.vertex_count)
    .bind(s.vertex_set)
    .bind(view.map(|v| v.to_string()))
    .bind(user_id)
    .bind(crate::now_rfc3339())
    .execute(&mut **tx)
    .await?;
    Ok(number)
}

/// A part's revisions, oldest first.
pub async fn list(db: &Db, part_id: i64) -> Result<Vec<PartRevision>> {
    let rows = sqlx::query(
        "SELECT r.number, r.part_id, r.model_id, r.action, r.tool, r.kind, r.center_x,
         r.center_y, r.center_z, r.vertex_count, r.view, r.author_id, u.username, r.created_at
         FROM part_revisions r LEFT JOIN users u ON u.id = r.author_id
         WHERE r.part_id = ? ORDER BY r.number",
    )
    .bind(part_id)
    .fetch_all(&db.read)
    .await?;
    rows.iter()
        .map(|r| {
            let view: Option<String> = r.try_get("view")?;
            Ok(PartRevision {
                number: r.try_get("number")?,
                part_id: r.try_get("part_id")?,
                model_id: r.try_get("model_id")?,
                action: r.try_get("action")?,
                tool: r.try_get("tool")?,
                kind: r.try_get("kind")?,
                center: [
                    r.try_get("center_x")?,
                    r.try_get("center_y")?,
                    r.try_get("center_z")?,
                ],
                vertex_count: r.try_get("vertex_count")?,
                view: view.and_then(|v| serde_json::from_str(&v).ok()),
                author_id: r.try_get("author_id")?,
                author: r.try_get("username")?,
                created_at: r.try_get("created_at")?,
            })
        })
        .collect::<std::result::Result<_, sqlx::Error>>()
        .map_err(StoreError::from)
}

/// The serialised vertex set of revision `number` of a part (an empty set when it had none).
pub async fn vertices(db: &Db, part_id: i64, number: i64) -> Result<Vec<u8>> {
    let blob: Option<Option<Vec<u8>>> = sqlx::query_scalar(
        "SELECT vertex_set FROM part_revisions WHERE part_id = ? AND number = ?",
    )
    .bind(part_id)
    .bind(number)
    .fetch_optional(&db.read)
    .await?;
    match blob {
        None => Err(StoreError::NotFound("part revision")),
        Some(Some(b)) => Ok(b),
        Some(None) => Ok(serialize(&RoaringBitmap::new())),
    }
}

/// Serialised form of a vertex set (RoaringBitmap's portable format, as `parts` stores it).
pub fn serialize(set: &RoaringBitmap) -> Vec<u8> {
    let mut out = Vec::with_capacity(set.serialized_size());
    // Writing into a Vec cannot fail.
    let _ = set.serialize_into(&mut out);
    out
}

/// A confirmed selection to write.
#[derive(Debug, Clone)]
pub struct SelectionWrite<'a> {
    /// Point or region.
    pub kind: PartKind,
    /// Centre (an anchor on the surface).
    pub center: [f64; 3],
    /// The vertex set.
    pub set: &'a RoaringBitmap,
    /// Tool that made it.
    pub tool: &'a str,
    /// `create` for a new part; `replace`, `add` or `subtract` for an edit.
    pub action: &'a str,
    /// The view it was made from.
    pub view: Option<serde_json::Value>,
}

async fn check_set(tx: &mut Tx, model_id: i64, set: &RoaringBitmap, limit: usize) -> Result<()> {
    if set.len() > limit as u64 {
        return Err(StoreError::Invalid(format!(
            "a part may hold at most {limit} vertices; this selection has {}",
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

fn validate(w: &SelectionWrite<'_>) -> Result<()> {
    if !w.center.iter().all(|v| v.is_finite()) {
        return Err(StoreError::Invalid(
            "the selection has no finite centre".into(),
        ));
    }
    if w.kind == PartKind::Region && w.set.is_empty() {
        return Err(StoreError::Invalid(
            "the selection is empty: a region part needs at least one vertex".into(),
        ));
    }
    Ok(())
}

/// Creates a part from a confirmed selection (revision 1, audit `part.create`). The part has
/// no camera and no thumbnail: the server's best view and thumbnail follow (render views).
pub async fn create_part(
    db: &Db,
    model_id: i64,
    w: &SelectionWrite<'_>,
    user_id: i64,
    max_vertices: usize,
) -> Result<Part> {
    validate(w)?;
    let mut tx = db.begin().await?;
    check_set(&mut tx, model_id, w.set, max_vertices).await?;
    let blob = (!w.set.is_empty()).then(|| serialize(w.set));
    let now = crate::now_rfc3339();
    let id: i64 = sqlx::query_scalar(
        "INSERT INTO parts (model_id, kind, center_x, center_y, center_z, vertex_count, vertex_set,
         camera, thumbnail_attachment_id, created_by, created_at, updated_at)
         VALUES (?, ?, ?, ?, ?, ?, ?, NULL, NULL, ?, ?, ?) RETURNING id",
    )
    .bind(model_id)
    .bind(w.kind)
    .bind(w.center[0])
    .bind(w.center[1])
    .bind(w.center[2])
    .bind(w.set.len() as i64)
    .bind(&blob)
    .bind(user_id)
    .bind(&now)
    .bind(&now)
    .fetch_one(&mut *tx)
    .await?;
    let snapshot = Snapshot {
        part_id: id,
        model_id,
        kind: w.kind,
        center: w.center,
        vertex_count: w.set.len() as i64,
        vertex_set: blob.as_deref(),
    };
    record_tx(
        &mut tx,
        &snapshot,
        "create",
        Some(w.tool),
        w.view.as_ref(),
        Some(user_id),
    )
    .await?;
    super::audit::record(
        &mut tx,
        Some(user_id),
        "part.create",
        "part",
        Some(id),
        serde_json::json!({"model_id": model_id, "kind": w.kind, "vertex_count": w.set.len(),
                           "tool": w.tool}),
    )
    .await?;
    tx.commit().await?;
    parts::get(db, id).await
}

/// Replaces the vertex set of part `part_id` by a confirmed selection (`w.action`: replace,
/// add or subtract), provided the part is unchanged since `expected_updated_at` (else
/// [`StoreError::Conflict`]: someone edited it meanwhile). A server-computed camera and the
/// thumbnail are cleared so the server renders them again for the new region.
pub async fn update_part(
    db: &Db,
    part_id: i64,
    w: &SelectionWrite<'_>,
    expected_updated_at: &str,
    user_id: i64,
    max_vertices: usize,
) -> Result<Part> {
    validate(w)?;
    let mut tx = db.begin().await?;
    let row = sqlx::query("SELECT model_id, updated_at, camera FROM parts WHERE id = ?")
        .bind(part_id)
        .fetch_optional(&mut *tx)
        .await?
        .ok_or(StoreError::NotFound("part"))?;
    let model_id: i64 = row.try_get("model_id")?;
    let updated_at: String = row.try_get("updated_at")?;
    let camera: Option<String> = row.try_get("camera")?;
    if updated_at != expected_updated_at {
        return Err(StoreError::Conflict(format!(
            "part {part_id} changed since this selection was made (at {updated_at}); select \
             again on its current state"
        )));
    }
    check_set(&mut tx, model_id, w.set, max_vertices).await?;
    let auto_camera = camera
        .as_deref()
        .and_then(|c| serde_json::from_str::<parts::Camera>(c).ok())
        .is_some_and(|c| c.auto);
    let blob = (!w.set.is_empty()).then(|| serialize(w.set));
    sqlx::query(
        "UPDATE parts SET kind = ?, center_x = ?, center_y = ?, center_z = ?, vertex_count = ?,
         vertex_set = ?, camera = CASE WHEN ? THEN NULL ELSE camera END,
         thumbnail_attachment_id = NULL, updated_at = ? WHERE id = ?",
    )
    .bind(w.kind)
    .bind(w.center[0])
    .bind(w.center[1])
    .bind(w.center[2])
    .bind(w.set.len() as i64)
    .bind(&blob)
    .bind(auto_camera)
    .bind(crate::now_rfc3339())
    .bind(part_id)
    .execute(&mut *tx)
    .await?;
    let snapshot = Snapshot {
        part_id,
        model_id,
        kind: w.kind,
        center: w.center,
        vertex_count: w.set.len() as i64,
        vertex_set: blob.as_deref(),
    };
    record_tx(
        &mut tx,
        &snapshot,
        w.action,
        Some(w.tool),
        w.view.as_ref(),
        Some(user_id),
    )
    .await?;
    super::audit::record(
        &mut tx,
        Some(user_id),
        "part.update",
        "part",
        Some(part_id),
        serde_json::json!({"vertices_changed": true, "vertex_count": w.set.len(),
                           "tool": w.tool, "mode": w.action}),
    )
    .await?;
    tx.commit().await?;
    parts::get(db, part_id).await
}

/// Records a revision of `part` as it is now (API writes: `create`, `edit`, `delete`).
pub async fn record_part_tx(
    tx: &mut Tx,
    part: &Part,
    vertex_set: Option<&[u8]>,
    action: &str,
    user_id: i64,
) -> Result<()> {
    let snapshot = Snapshot {
        part_id: part.id,
        model_id: part.model_id,
        kind: part.kind,
        center: part.center,
        vertex_count: part.vertex_count,
        vertex_set,
    };
    record_tx(tx, &snapshot, action, None, None, Some(user_id)).await?;
    Ok(())
}
