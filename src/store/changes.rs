//! `search_changes`: the change feed that keeps the search index in step with the database.
//! A row names a content whose search document must be rebuilt; rows are appended in the
//! same transaction as the change, so a committed change is never lost to the index.

use super::{Db, Result, Tx};

/// Queues content `content_id` for re-indexing.
pub async fn push(tx: &mut Tx, content_id: i64) -> Result<()> {
    sqlx::query("INSERT INTO search_changes (content_id) VALUES (?)")
        .bind(content_id)
        .execute(&mut **tx)
        .await?;
    Ok(())
}

/// Queues every content assigned to a part of model `model_id`.
pub async fn push_model(tx: &mut Tx, model_id: i64) -> Result<()> {
    sqlx::query(
        "INSERT INTO search_changes (content_id)
         SELECT DISTINCT a.content_id FROM assignments a JOIN parts p ON p.id = a.part_id
         WHERE p.model_id = ?",
    )
    .bind(model_id)
    .execute(&mut **tx)
    .await?;
    Ok(())
}

/// Queues every content assigned to part `part_id`.
pub async fn push_part(tx: &mut Tx, part_id: i64) -> Result<()> {
    sqlx::query(
        "INSERT INTO search_changes (content_id)
         SELECT DISTINCT content_id FROM assignments WHERE part_id = ?",
    )
    .bind(part_id)
    .execute(&mut **tx)
    .await?;
    Ok(())
}

/// Queues every content that holds attachment `attachment_id`.
pub async fn push_attachment(tx: &mut Tx, attachment_id: i64) -> Result<()> {
    sqlx::query(
        "INSERT INTO search_changes (content_id)
         SELECT DISTINCT content_id FROM content_attachments WHERE attachment_id = ?",
    )
    .bind(attachment_id)
    .execute(&mut **tx)
    .await?;
    Ok(())
}

/// Changes after `seq`, oldest first, at most `limit`: `(seq, content_id)`.
pub async fn since(db: &Db, seq: i64, limit: i64) -> Result<Vec<(i64, i64)>> {
    Ok(sqlx::query_as(
        "SELECT seq, content_id FROM search_changes WHERE seq > ? ORDER BY seq LIMIT ?",
    )
    .bind(seq)
    .bind(limit)
    .fetch_all(&db.read)
    .await?)
}

/// Highest sequence number written so far (0 when none).
pub async fn head(db: &Db) -> Result<i64> {
    Ok(
        sqlx::query_scalar::<_, Option<i64>>("SELECT MAX(seq) FROM search_changes")
            .fetch_one(&db.read)
            .await?
            .unwrap_or(0),
    )
}

/// Drops applied changes up to and excluding `seq` (the newest row is kept so the sequence
/// stays monotonic on every database).
pub async fn prune(db: &Db, seq: i64) -> Result<()> {
    let mut tx = db.begin().await?;
    sqlx::query("DELETE FROM search_changes WHERE seq < ?")
        .bind(seq)
        .execute(&mut *tx)
        .await?;
    tx.commit().await?;
    Ok(())
}
