//! What anonymous visitors may read: a model marked public, and what hangs on it — its parts,
//! the contents assigned to them, and the attachments of those contents (or the thumbnails of
//! the model, its parts and those contents). Everything else needs a session. Each query says
//! only whether one thing is readable; a missing thing is not.

use super::{Db, Result};

/// Whether model `id` is public.
pub async fn model(db: &Db, id: i64) -> Result<bool> {
    exists(db, "SELECT 1 FROM models WHERE id = ?1 AND public = 1", id).await
}

/// Whether part `id` lies on a public model.
pub async fn part(db: &Db, id: i64) -> Result<bool> {
    exists(
        db,
        "SELECT 1 FROM parts p JOIN models m ON m.id = p.model_id WHERE p.id = ?1 AND m.public = 1",
        id,
    )
    .await
}

/// Whether content `id` is assigned to a part of a public model.
pub async fn content(db: &Db, id: i64) -> Result<bool> {
    exists(
        db,
        "SELECT 1 FROM assignments a JOIN parts p ON p.id = a.part_id \
         JOIN models m ON m.id = p.model_id WHERE a.content_id = ?1 AND m.public = 1",
        id,
    )
    .await
}

/// Whether attachment `id` belongs to a public model, one of its parts, or a content
/// assigned to one of its parts (attached to it, or its thumbnail).
pub async fn attachment(db: &Db, id: i64) -> Result<bool> {
    exists(
        db,
        "SELECT 1 FROM models m WHERE m.thumbnail_attachment_id = ?1 AND m.public = 1
         UNION ALL
         SELECT 1 FROM parts p JOIN models m ON m.id = p.model_id
           WHERE p.thumbnail_attachment_id = ?1 AND m.public = 1
         UNION ALL
         SELECT 1 FROM content_attachments ca JOIN assignments a ON a.content_id = ca.content_id
           JOIN parts p ON p.id = a.part_id JOIN models m ON m.id = p.model_id
           WHERE ca.attachment_id = ?1 AND m.public = 1
         UNION ALL
         SELECT 1 FROM contents c JOIN assignments a ON a.content_id = c.id
           JOIN parts p ON p.id = a.part_id JOIN models m ON m.id = p.model_id
           WHERE c.thumbnail_attachment_id = ?1 AND m.public = 1",
        id,
    )
    .await
}

/// Ids of the public models.
pub async fn public_models(db: &Db) -> Result<Vec<i64>> {
    Ok(
        sqlx::query_scalar("SELECT id FROM models WHERE public = 1 ORDER BY id")
            .fetch_all(&db.read)
            .await?,
    )
}

async fn exists(db: &Db, query: &'static str, id: i64) -> Result<bool> {
    let sql = format!("SELECT EXISTS ({query})");
    let found: i64 = sqlx::query_scalar(sqlx::AssertSqlSafe(sql))
        .bind(id)
        .fetch_one(&db.read)
        .await?;
    Ok(found != 0)
}
