//! `attachments` and `content_attachments`: files stored content-addressed by SHA-256 and
//! linked, in order, to contents. The file itself lives in the data directory; this table
//! keeps its hash, media type, size and the (display-only) original name.

use serde::Serialize;
use sqlx::FromRow;
use utoipa::ToSchema;

use super::{Db, Result, StoreError, Tx};

/// An attachment.
#[derive(Debug, Clone, Serialize, FromRow, ToSchema)]
pub struct Attachment {
    /// Id.
    pub id: i64,
    /// SHA-256 of the file (hex).
    pub sha256: String,
    /// Media type.
    pub media_type: String,
    /// Size in bytes.
    pub size: i64,
    /// Name given by the uploader (display only, never a path).
    pub original_name: String,
    /// Uploader.
    pub uploaded_by: i64,
    /// Upload time.
    #[schema(format = DateTime)]
    pub created_at: String,
}

/// A received file to record.
#[derive(Debug, Clone)]
pub struct NewAttachment {
    /// SHA-256 (hex).
    pub sha256: String,
    /// Media type.
    pub media_type: String,
    /// Size in bytes.
    pub size: i64,
    /// Sanitised original name.
    pub original_name: String,
}

const COLUMNS: &str = "id, sha256, media_type, size, original_name, uploaded_by, created_at";

/// Records an attachment and, with `content_id`, links it at the end of that content's list.
pub async fn create(
    db: &Db,
    new: &NewAttachment,
    content_id: Option<i64>,
    user_id: i64,
) -> Result<Attachment> {
    let mut tx = db.begin().await?;
    let id: i64 = sqlx::query_scalar(
        "INSERT INTO attachments (sha256, media_type, size, original_name, uploaded_by, created_at)
         VALUES (?, ?, ?, ?, ?, ?) RETURNING id",
    )
    .bind(&new.sha256)
    .bind(&new.media_type)
    .bind(new.size)
    .bind(&new.original_name)
    .bind(user_id)
    .bind(crate::now_rfc3339())
    .fetch_one(&mut *tx)
    .await?;
    super::audit::record(
        &mut tx,
        Some(user_id),
        "attachment.create",
        "attachment",
        Some(id),
        serde_json::json!({"sha256": new.sha256, "size": new.size, "name": new.original_name}),
    )
    .await?;
    if let Some(cid) = content_id {
        link_tx(&mut tx, cid, id, user_id).await?;
    }
    let a = get_tx(&mut tx, id).await?;
    tx.commit().await?;
    Ok(a)
}

async fn get_tx(tx: &mut Tx, id: i64) -> Result<Attachment> {
    sqlx::query_as::<_, Attachment>(sqlx::AssertSqlSafe(format!(
        "SELECT {COLUMNS} FROM attachments WHERE id = ?"
    )))
    .bind(id)
    .fetch_optional(&mut **tx)
    .await?
    .ok_or(StoreError::NotFound("attachment"))
}

/// An attachment by id.
pub async fn get(db: &Db, id: i64) -> Result<Attachment> {
    sqlx::query_as::<_, Attachment>(sqlx::AssertSqlSafe(format!(
        "SELECT {COLUMNS} FROM attachments WHERE id = ?"
    )))
    .bind(id)
    .fetch_optional(&db.read)
    .await?
    .ok_or(StoreError::NotFound("attachment"))
}

async fn link_tx(tx: &mut Tx, content_id: i64, attachment_id: i64, user_id: i64) -> Result<()> {
    let exists: Option<i64> = sqlx::query_scalar("SELECT id FROM contents WHERE id = ?")
        .bind(content_id)
        .fetch_optional(&mut **tx)
        .await?;
    if exists.is_none() {
        return Err(StoreError::NotFound("content"));
    }
    sqlx::query(
        "INSERT INTO content_attachments (content_id, attachment_id, position)
         VALUES (?, ?, (SELECT COALESCE(MAX(position), 0) + 1 FROM content_attachments
                        WHERE content_id = ?))",
    )
    .bind(content_id)
    .bind(attachment_id)
    .bind(content_id)
    .execute(&mut **tx)
    .await
    .map_err(|e| {
        StoreError::map_constraint(
            e,
            "attachment is already linked to this content",
            "attachment does not exist",
        )
    })?;
    super::changes::push(tx, content_id).await?;
    super::audit::record(
        tx,
        Some(user_id),
        "content.attach",
        "content",
        Some(content_id),
        serde_json::json!({"attachment_id": attachment_id}),
    )
    .await
}

/// Links an existing attachment to the end of a content's list.
pub async fn link(db: &Db, content_id: i64, attachment_id: i64, user_id: i64) -> Result<()> {
    let mut tx = db.begin().await?;
    link_tx(&mut tx, content_id, attachment_id, user_id).await?;
    tx.commit().await?;
    Ok(())
}

/// Removes an attachment from a content (the file stays for other references).
pub async fn unlink(db: &Db, content_id: i64, attachment_id: i64, user_id: i64) -> Result<()> {
    let mut tx = db.begin().await?;
    let n =
        sqlx::query("DELETE FROM content_attachments WHERE content_id = ? AND attachment_id = ?")
            .bind(content_id)
            .bind(attachment_id)
            .execute(&mut *tx)
            .await?
            .rows_affected();
    if n == 0 {
        return Err(StoreError::NotFound("attachment link"));
    }
    super::changes::push(&mut tx, content_id).await?;
    super::audit::record(
        &mut tx,
        Some(user_id),
        "content.detach",
        "content",
        Some(content_id),
        serde_json::json!({"attachment_id": attachment_id}),
    )
    .await?;
    tx.commit().await?;
    Ok(())
}

/// Attachments of a content, in order.
pub async fn list_for_content(db: &Db, content_id: i64) -> Result<Vec<Attachment>> {
    Ok(sqlx::query_as::<_, Attachment>(
        "SELECT a.id, a.sha256, a.media_type, a.size, a.original_name, a.uploaded_by, a.created_at
         FROM content_attachments ca JOIN attachments a ON a.id = ca.attachment_id
         WHERE ca.content_id = ? ORDER BY ca.position, a.id",
    )
    .bind(content_id)
    .fetch_all(&db.read)
    .await?)
}
