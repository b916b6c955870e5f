//! `part_revisions`: the history of parts (the wiki promise: every change is kept). Every
//! write of a part — through a selection or `/api/v1/parts`, created, edited or deleted — goes
//! through `parts`' one writer, which appends a row here in the same transaction: the part's
//! state after the change (kind, centre, vertex set, camera), its author, time and comment,
//! and the selection tool and view when a selection made it.

use roaring::RoaringBitmap;
use serde::Serialize;
use sqlx::Row;
use utoipa::ToSchema;

use super::parts::{Camera, PartKind, Provenance, serialize_vertex_set};
use super::{Db, Result, StoreError, Tx};

/// One revision of a part (without its vertex set, which
/// `/api/v1/parts/{id}/revisions/{number}/vertices` serves).
#[derive(Debug, Clone, Serialize, ToSchema)]
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
    /// The view the selection was made from (a `ViewCamera`: eye, target, up, fovy,
    /// width, height).
    #[schema(value_type = Option<Object>)]
    pub view: Option<serde_json::Value>,
    /// Camera at this revision.
    pub camera: Option<Camera>,
    /// The author's comment.
    pub comment: Option<String>,
    /// Author.
    pub author_id: Option<i64>,
    /// Author's user name.
    pub author: Option<String>,
    /// Time.
    #[schema(format = DateTime)]
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
    /// Camera (JSON).
    pub camera: Option<&'a str>,
}

/// Appends a revision of a part in the current transaction; returns its number.
pub(super) async fn record_tx(
    tx: &mut Tx,
    s: &Snapshot<'_>,
    action: &str,
    prov: &Provenance,
) -> Result<i64> {
    let number: i64 = sqlx::query_scalar(
        "SELECT COALESCE(MAX(number), 0) + 1 FROM part_revisions WHERE part_id = ?",
    )
    .bind(s.part_id)
    .fetch_one(&mut **tx)
    .await?;
    sqlx::query(
        "INSERT INTO part_revisions (part_id, model_id, number, action, tool, kind, center_x,
         center_y, center_z, vertex_count, vertex_set, view, camera, comment, author_id,
         created_at)
         VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
    )
    .bind(s.part_id)
    .bind(s.model_id)
    .bind(number)
    .bind(action)
    .bind(prov.tool.as_deref())
    .bind(s.kind)
    .bind(s.center[0])
    .bind(s.center[1])
    .bind(s.center[2])
    .bind(s.vertex_count)
    .bind(s.vertex_set)
    .bind(prov.view.as_ref().map(|v| v.to_string()))
    .bind(s.camera)
    .bind(prov.comment.as_deref().filter(|c| !c.trim().is_empty()))
    .bind(prov.user_id)
    .bind(crate::now_rfc3339())
    .execute(&mut **tx)
    .await?;
    Ok(number)
}

/// A part's revisions, oldest first.
pub async fn list(db: &Db, part_id: i64) -> Result<Vec<PartRevision>> {
    let rows = sqlx::query(
        "SELECT r.number, r.part_id, r.model_id, r.action, r.tool, r.kind, r.center_x,
         r.center_y, r.center_z, r.vertex_count, r.view, r.camera, r.comment, r.author_id,
         u.username, r.created_at
         FROM part_revisions r LEFT JOIN users u ON u.id = r.author_id
         WHERE r.part_id = ? ORDER BY r.number",
    )
    .bind(part_id)
    .fetch_all(&db.read)
    .await?;
    rows.iter()
        .map(|r| {
            let view: Option<String> = r.try_get("view")?;
            let camera: Option<String> = r.try_get("camera")?;
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
                camera: camera.and_then(|c| serde_json::from_str(&c).ok()),
                comment: r.try_get("comment")?,
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
        Some(None) => Ok(serialize_vertex_set(&RoaringBitmap::new())),
    }
}
