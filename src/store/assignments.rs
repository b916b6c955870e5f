//! `assignments`: the "Assigned Information" of system paper §2.1.2 — which contents are
//! attached to which parts (many-to-many), in an order per part.

use serde::Serialize;
use sqlx::FromRow;
use utoipa::ToSchema;

use super::{Db, Result, StoreError, Tx};

/// A content as assigned to a part.
#[derive(Debug, Clone, Serialize, FromRow, ToSchema)]
pub struct AssignedContent {
    /// Content id.
    pub id: i64,
    /// Assignment id.
    pub assignment_id: i64,
    /// Part id.
    pub part_id: i64,
    /// Position in the part's list (1-based).
    pub position: i64,
    /// Content title.
    pub title: String,
    /// Content caption.
    pub caption: String,
    /// Content thumbnail.
    pub thumbnail_attachment_id: Option<i64>,
    /// Current revision of the content.
    pub current_revision: i64,
    /// Last change of the content.
    #[schema(format = DateTime)]
    pub updated_at: String,
}

/// A part a content is assigned to.
#[derive(Debug, Clone, Serialize, FromRow, ToSchema)]
pub struct AssignedPart {
    /// Part id.
    pub id: i64,
    /// Assignment id.
    pub assignment_id: i64,
    /// Model id.
    pub model_id: i64,
    /// Model title.
    pub model_title: String,
    /// The part's name as every page shows it: the title of the first information assigned to
    /// it.
    pub part_title: String,
    /// Part kind.
    #[schema(value_type = crate::store::parts::PartKind)]
    pub kind: String,
    /// Position of the content in the part's list.
    pub position: i64,
    /// Part thumbnail (rendered by the server).
    pub thumbnail_attachment_id: Option<i64>,
    /// The part's camera as stored (JSON); see [`AssignedPart::camera`].
    #[serde(skip)]
    pub camera_json: Option<String>,
}

impl AssignedPart {
    /// The part's camera (its best view unless a client set one).
    pub fn camera(&self) -> Option<super::parts::Camera> {
        self.camera_json
            .as_deref()
            .and_then(|c| serde_json::from_str(c).ok())
    }
}

async fn ensure_part(tx: &mut Tx, part_id: i64) -> Result<()> {
    let found: Option<i64> = sqlx::query_scalar("SELECT id FROM parts WHERE id = ?")
        .bind(part_id)
        .fetch_optional(&mut **tx)
        .await?;
    found.map(|_| ()).ok_or(StoreError::NotFound("part"))
}

/// Contents assigned to a part, in order.
pub async fn contents_for_part(db: &Db, part_id: i64) -> Result<Vec<AssignedContent>> {
    let found: Option<i64> = sqlx::query_scalar("SELECT id FROM parts WHERE id = ?")
        .bind(part_id)
        .fetch_optional(&db.read)
        .await?;
    if found.is_none() {
        return Err(StoreError::NotFound("part"));
    }
    Ok(sqlx::query_as::<_, AssignedContent>(
        "SELECT c.id, a.id AS assignment_id, a.part_id, a.position, c.title, c.caption,
         c.thumbnail_attachment_id, c.current_revision, c.updated_at
         FROM assignments a JOIN contents c ON c.id = a.content_id
         WHERE a.part_id = ? ORDER BY a.position, a.id",
    )
    .bind(part_id)
    .fetch_all(&db.read)
    .await?)
}

/// Parts a content is assigned to.
pub async fn parts_for_content(db: &Db, content_id: i64) -> Result<Vec<AssignedPart>> {
    Ok(sqlx::query_as::<_, AssignedPart>(
        "SELECT p.id, a.id AS assignment_id, p.model_id, m.title AS model_title,
         (SELECT c.title FROM assignments f JOIN contents c ON c.id = f.content_id
          WHERE f.part_id = p.id ORDER BY f.position, f.id LIMIT 1) AS part_title,
         p.kind, a.position, p.thumbnail_attachment_id, p.camera AS camera_json
         FROM assignments a JOIN parts p ON p.id = a.part_id JOIN models m ON m.id = p.model_id
         WHERE a.content_id = ? ORDER BY m.id, p.id",
    )
    .bind(content_id)
    .fetch_all(&db.read)
    .await?)
}

async fn renumber(tx: &mut Tx, part_id: i64, order: &[i64]) -> Result<()> {
    for (i, content_id) in order.iter().enumerate() {
        sqlx::query("UPDATE assignments SET position = ? WHERE part_id = ? AND content_id = ?")
            .bind(i as i64 + 1)
            .bind(part_id)
            .bind(content_id)
            .execute(&mut **tx)
            .await?;
    }
    Ok(())
}

async fn order_tx(tx: &mut Tx, part_id: i64) -> Result<Vec<i64>> {
    Ok(sqlx::query_scalar(
        "SELECT content_id FROM assignments WHERE part_id = ? ORDER BY position, id",
    )
    .bind(part_id)
    .fetch_all(&mut **tx)
    .await?)
}

/// Assigns a content to a part at `position` (1-based; default: last).
pub async fn assign(
    db: &Db,
    part_id: i64,
    content_id: i64,
    position: Option<i64>,
    user_id: i64,
) -> Result<()> {
    let mut tx = db.begin().await?;
    ensure_part(&mut tx, part_id).await?;
    let mut order = order_tx(&mut tx, part_id).await?;
    sqlx::query(
        "INSERT INTO assignments (part_id, content_id, position, created_by, created_at)
         VALUES (?, ?, ?, ?, ?)",
    )
    .bind(part_id)
    .bind(content_id)
    .bind(order.len() as i64 + 1)
    .bind(user_id)
    .bind(crate::now_rfc3339())
    .execute(&mut *tx)
    .await
    .map_err(|e| {
        StoreError::map_constraint(
            e,
            "content is already assigned to this part",
            "content does not exist",
        )
    })?;
    let at = position
        .map(|p| (p.max(1) - 1) as usize)
        .unwrap_or(order.len())
        .min(order.len());
    order.insert(at, content_id);
    renumber(&mut tx, part_id, &order).await?;
    super::changes::push(&mut tx, content_id).await?;
    super::audit::record(
        &mut tx,
        Some(user_id),
        "assignment.create",
        "part",
        Some(part_id),
        serde_json::json!({"content_id": content_id, "position": at + 1}),
    )
    .await?;
    tx.commit().await?;
    Ok(())
}

/// Removes a content from a part.
pub async fn unassign(db: &Db, part_id: i64, content_id: i64, user_id: i64) -> Result<()> {
    let mut tx = db.begin().await?;
    ensure_part(&mut tx, part_id).await?;
    let n = sqlx::query("DELETE FROM assignments WHERE part_id = ? AND content_id = ?")
        .bind(part_id)
        .bind(content_id)
        .execute(&mut *tx)
        .await?
        .rows_affected();
    if n == 0 {
        return Err(StoreError::NotFound("assignment"));
    }
    let order = order_tx(&mut tx, part_id).await?;
    renumber(&mut tx, part_id, &order).await?;
    super::changes::push(&mut tx, content_id).await?;
    super::audit::record(
        &mut tx,
        Some(user_id),
        "assignment.delete",
        "part",
        Some(part_id),
        serde_json::json!({"content_id": content_id}),
    )
    .await?;
    tx.commit().await?;
    Ok(())
}

/// Sets the order of a part's contents; `content_ids` must name each assigned content once.
pub async fn reorder(db: &Db, part_id: i64, content_ids: &[i64], user_id: i64) -> Result<()> {
    let mut tx = db.begin().await?;
    ensure_part(&mut tx, part_id).await?;
    let mut current = order_tx(&mut tx, part_id).await?;
    let mut wanted = content_ids.to_vec();
    current.sort_unstable();
    wanted.sort_unstable();
    if current != wanted {
        return Err(StoreError::Invalid(
            "content_ids must list every content assigned to the part exactly once".into(),
        ));
    }
    renumber(&mut tx, part_id, content_ids).await?;
    super::audit::record(
        &mut tx,
        Some(user_id),
        "assignment.reorder",
        "part",
        Some(part_id),
        serde_json::json!({"content_ids": content_ids}),
    )
    .await?;
    tx.commit().await?;
    Ok(())
}
