//! `contents` and `content_revisions`: the "Information Contents" of system paper §2.1.2 as
//! wiki pages. Every save names the revision it is based on and appends a full revision;
//! a save on a stale base fails with [`StoreError::StaleRevision`] (never a lost update).

use std::collections::HashMap;

use serde::{Deserialize, Serialize};
use sqlx::FromRow;
use utoipa::ToSchema;

use super::{Db, Page, Result, StoreError, Tx};

/// A content (wiki page) at its current revision.
#[derive(Debug, Clone, Serialize, FromRow, ToSchema)]
pub struct Content {
    /// Id.
    pub id: i64,
    /// Title.
    pub title: String,
    /// Short caption (plain text).
    pub caption: String,
    /// Body (Markdown).
    pub body: String,
    /// Thumbnail attachment.
    pub thumbnail_attachment_id: Option<i64>,
    /// Number of the current revision.
    pub current_revision: i64,
    /// Creator.
    pub created_by: i64,
    /// Creation time.
    #[schema(format = DateTime)]
    pub created_at: String,
    /// Time of the current revision.
    #[schema(format = DateTime)]
    pub updated_at: String,
}

/// A revision, in full.
#[derive(Debug, Clone, Serialize, FromRow, ToSchema)]
pub struct Revision {
    /// Id of the revision row.
    pub id: i64,
    /// Content it belongs to.
    pub content_id: i64,
    /// Revision number (1, 2, ...).
    pub number: i64,
    /// Title at this revision.
    pub title: String,
    /// Caption at this revision.
    pub caption: String,
    /// Body at this revision.
    pub body: String,
    /// Author's user id.
    pub author_id: i64,
    /// Author's user name.
    pub author: String,
    /// Edit comment.
    pub comment: String,
    /// Time of the save.
    #[schema(format = DateTime)]
    pub created_at: String,
}

/// A revision without its text (history lists).
#[derive(Debug, Clone, Serialize, FromRow, ToSchema)]
pub struct RevisionSummary {
    /// Id of the revision row.
    pub id: i64,
    /// Revision number.
    pub number: i64,
    /// Title at this revision.
    pub title: String,
    /// Author's user id.
    pub author_id: i64,
    /// Author's user name.
    pub author: String,
    /// Edit comment.
    pub comment: String,
    /// Size of the body in bytes.
    pub body_bytes: i64,
    /// Time of the save.
    #[schema(format = DateTime)]
    pub created_at: String,
}

/// The editable text of a content.
#[derive(Debug, Clone, Default, Serialize, Deserialize, ToSchema)]
pub struct ContentEdit {
    /// Title (required).
    pub title: String,
    /// Caption.
    #[serde(default)]
    pub caption: String,
    /// Markdown body.
    #[serde(default)]
    pub body: String,
    /// Edit comment.
    #[serde(default)]
    pub comment: String,
}

impl ContentEdit {
    /// Checks lengths: title 1–`max_title` characters, caption up to 1,000 characters,
    /// body up to `max_body` bytes, comment up to 500 characters.
    pub fn validate(&self, max_title: usize, max_body: usize) -> Result<()> {
        let title = self.title.trim().chars().count();
        if title == 0 || title > max_title {
            return Err(StoreError::Invalid(format!(
                "title must be 1 to {max_title} characters"
            )));
        }
        if self.caption.chars().count() > 1000 {
            return Err(StoreError::Invalid(
                "caption must be at most 1000 characters".into(),
            ));
        }
        if self.body.len() > max_body {
            return Err(StoreError::Invalid(format!(
                "body must be at most {max_body} bytes"
            )));
        }
        if self.comment.chars().count() > 500 {
            return Err(StoreError::Invalid(
                "comment must be at most 500 characters".into(),
            ));
        }
        Ok(())
    }
}

const COLUMNS: &str = "id, title, caption, body, thumbnail_attachment_id, current_revision, \
    created_by, created_at, updated_at";

async fn insert_revision(
    tx: &mut Tx,
    content_id: i64,
    number: i64,
    edit: &ContentEdit,
    user_id: i64,
    now: &str,
) -> Result<()> {
    sqlx::query(
        "INSERT INTO content_revisions (content_id, number, title, caption, body, author_id,
         comment, created_at) VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
    )
    .bind(content_id)
    .bind(number)
    .bind(edit.title.trim())
    .bind(&edit.caption)
    .bind(&edit.body)
    .bind(user_id)
    .bind(&edit.comment)
    .bind(now)
    .execute(&mut **tx)
    .await?;
    Ok(())
}

/// Creates a content with revision 1.
pub async fn create(
    db: &Db,
    edit: &ContentEdit,
    thumbnail_attachment_id: Option<i64>,
    user_id: i64,
) -> Result<Content> {
    let mut tx = db.begin().await?;
    let content = create_tx(&mut tx, edit, thumbnail_attachment_id, user_id).await?;
    tx.commit().await?;
    Ok(content)
}

/// [`create`] inside an open transaction.
pub async fn create_tx(
    tx: &mut Tx,
    edit: &ContentEdit,
    thumbnail_attachment_id: Option<i64>,
    user_id: i64,
) -> Result<Content> {
    let now = crate::now_rfc3339();
    let id: i64 = sqlx::query_scalar(
        "INSERT INTO contents (title, caption, body, thumbnail_attachment_id, current_revision,
         created_by, created_at, updated_at) VALUES (?, ?, ?, ?, 1, ?, ?, ?) RETURNING id",
    )
    .bind(edit.title.trim())
    .bind(&edit.caption)
    .bind(&edit.body)
    .bind(thumbnail_attachment_id)
    .bind(user_id)
    .bind(&now)
    .bind(&now)
    .fetch_one(&mut **tx)
    .await
    .map_err(|e| StoreError::map_constraint(e, "", "thumbnail attachment does not exist"))?;
    insert_revision(tx, id, 1, edit, user_id, &now).await?;
    super::changes::push(tx, id).await?;
    super::audit::record(
        tx,
        Some(user_id),
        "content.create",
        "content",
        Some(id),
        serde_json::json!({"title": edit.title.trim(), "revision": 1}),
    )
    .await?;
    get_tx(tx, id).await
}

async fn get_tx(tx: &mut Tx, id: i64) -> Result<Content> {
    sqlx::query_as::<_, Content>(sqlx::AssertSqlSafe(format!(
        "SELECT {COLUMNS} FROM contents WHERE id = ?"
    )))
    .bind(id)
    .fetch_optional(&mut **tx)
    .await?
    .ok_or(StoreError::NotFound("content"))
}

/// A content by id.
pub async fn get(db: &Db, id: i64) -> Result<Content> {
    sqlx::query_as::<_, Content>(sqlx::AssertSqlSafe(format!(
        "SELECT {COLUMNS} FROM contents WHERE id = ?"
    )))
    .bind(id)
    .fetch_optional(&db.read)
    .await?
    .ok_or(StoreError::NotFound("content"))
}

/// Contents, most recently changed first.
pub async fn list(db: &Db, page: Page) -> Result<Vec<Content>> {
    Ok(sqlx::query_as::<_, Content>(sqlx::AssertSqlSafe(format!(
        "SELECT {COLUMNS} FROM contents ORDER BY updated_at DESC, id DESC LIMIT ? OFFSET ?"
    )))
    .bind(page.limit)
    .bind(page.offset)
    .fetch_all(&db.read)
    .await?)
}

/// Number of contents.
pub async fn count(db: &Db) -> Result<i64> {
    Ok(sqlx::query_scalar("SELECT COUNT(*) FROM contents")
        .fetch_one(&db.read)
        .await?)
}

async fn current_revision_tx(tx: &mut Tx, id: i64) -> Result<Revision> {
    sqlx::query_as::<_, Revision>(
        "SELECT r.id, r.content_id, r.number, r.title, r.caption, r.body, r.author_id,
         u.username AS author, r.comment, r.created_at
         FROM contents c JOIN content_revisions r ON r.content_id = c.id AND r.number = c.current_revision
         JOIN users u ON u.id = r.author_id WHERE c.id = ?",
    )
    .bind(id)
    .fetch_optional(&mut **tx)
    .await?
    .ok_or(StoreError::NotFound("content"))
}

/// Saves a new revision of content `id` based on revision `base`. Fails with
/// [`StoreError::StaleRevision`] (carrying the current revision) when `base` is not current.
/// `thumbnail`: `None` leaves it, `Some(x)` sets it.
pub async fn update(
    db: &Db,
    id: i64,
    base: i64,
    edit: &ContentEdit,
    thumbnail: Option<Option<i64>>,
    user_id: i64,
) -> Result<Content> {
    let mut tx = db.begin().await?;
    let current = current_revision_tx(&mut tx, id).await?;
    if current.number != base {
        return Err(StoreError::StaleRevision {
            base,
            current: Box::new(current),
        });
    }
    let number = current.number + 1;
    let now = crate::now_rfc3339();
    insert_revision(&mut tx, id, number, edit, user_id, &now).await?;
    sqlx::query(
        "UPDATE contents SET title = ?, caption = ?, body = ?, current_revision = ?, updated_at = ?
         WHERE id = ?",
    )
    .bind(edit.title.trim())
    .bind(&edit.caption)
    .bind(&edit.body)
    .bind(number)
    .bind(&now)
    .bind(id)
    .execute(&mut *tx)
    .await?;
    if let Some(t) = thumbnail {
        sqlx::query("UPDATE contents SET thumbnail_attachment_id = ? WHERE id = ?")
            .bind(t)
            .bind(id)
            .execute(&mut *tx)
            .await
            .map_err(|e| {
                StoreError::map_constraint(e, "", "thumbnail attachment does not exist")
            })?;
    }
    super::changes::push(&mut tx, id).await?;
    super::audit::record(
        &mut tx,
        Some(user_id),
        "content.update",
        "content",
        Some(id),
        serde_json::json!({"revision": number, "base": base, "comment": edit.comment}),
    )
    .await?;
    let content = get_tx(&mut tx, id).await?;
    tx.commit().await?;
    Ok(content)
}

/// Saves a copy of revision `number` as a new revision. With `base`, fails like [`update`]
/// when `base` is not current.
pub async fn revert(
    db: &Db,
    id: i64,
    number: i64,
    base: Option<i64>,
    comment: Option<&str>,
    user_id: i64,
) -> Result<Content> {
    let old = revision(db, id, number).await?;
    let current = get(db, id).await?;
    let edit = ContentEdit {
        title: old.title,
        caption: old.caption,
        body: old.body,
        comment: comment
            .map(str::to_string)
            .unwrap_or_else(|| format!("Reverted to revision {number}")),
    };
    if edit.comment.chars().count() > 500 {
        return Err(StoreError::Invalid(
            "comment must be at most 500 characters".into(),
        ));
    }
    update(
        db,
        id,
        base.unwrap_or(current.current_revision),
        &edit,
        None,
        user_id,
    )
    .await
}

/// History of content `id`, newest first.
pub async fn revisions(db: &Db, id: i64) -> Result<Vec<RevisionSummary>> {
    get(db, id).await?;
    Ok(sqlx::query_as::<_, RevisionSummary>(
        "SELECT r.id, r.number, r.title, r.author_id, u.username AS author, r.comment,
         LENGTH(CAST(r.body AS BLOB)) AS body_bytes, r.created_at
         FROM content_revisions r JOIN users u ON u.id = r.author_id
         WHERE r.content_id = ? ORDER BY r.number DESC",
    )
    .bind(id)
    .fetch_all(&db.read)
    .await?)
}

/// Revision `number` of content `id`.
pub async fn revision(db: &Db, id: i64, number: i64) -> Result<Revision> {
    sqlx::query_as::<_, Revision>(
        "SELECT r.id, r.content_id, r.number, r.title, r.caption, r.body, r.author_id,
         u.username AS author, r.comment, r.created_at
         FROM content_revisions r JOIN users u ON u.id = r.author_id
         WHERE r.content_id = ? AND r.number = ?",
    )
    .bind(id)
    .bind(number)
    .fetch_optional(&db.read)
    .await?
    .ok_or(StoreError::NotFound("revision"))
}

/// Deletes a content with its revisions, assignments and attachment links.
pub async fn delete(db: &Db, id: i64, user_id: i64) -> Result<()> {
    let mut tx = db.begin().await?;
    let content = get_tx(&mut tx, id).await?;
    sqlx::query("DELETE FROM contents WHERE id = ?")
        .bind(id)
        .execute(&mut *tx)
        .await?;
    super::changes::push(&mut tx, id).await?;
    super::audit::record(
        &mut tx,
        Some(user_id),
        "content.delete",
        "content",
        Some(id),
        serde_json::json!({"title": content.title, "revision": content.current_revision}),
    )
    .await?;
    tx.commit().await?;
    Ok(())
}

/// Everything the search index holds about one content.
#[derive(Debug, Clone, Default)]
pub struct SearchSource {
    /// Content id.
    pub id: i64,
    /// Title.
    pub title: String,
    /// Caption.
    pub caption: String,
    /// Markdown body.
    pub body: String,
    /// Original names of its attachments.
    pub attachment_names: Vec<String>,
    /// Models it is assigned to (through parts): id and title.
    pub models: Vec<(i64, String)>,
}

/// Search sources of the given contents (missing ids are skipped), or of every content.
pub async fn search_sources(db: &Db, ids: Option<&[i64]>) -> Result<Vec<SearchSource>> {
    let mut out: Vec<SearchSource> = Vec::new();
    match ids {
        None => {
            let rows: Vec<(i64, String, String, String)> =
                sqlx::query_as("SELECT id, title, caption, body FROM contents ORDER BY id")
                    .fetch_all(&db.read)
                    .await?;
            let mut attachments: HashMap<i64, Vec<String>> = HashMap::new();
            let names: Vec<(i64, String)> = sqlx::query_as(
                "SELECT ca.content_id, a.original_name FROM content_attachments ca
                 JOIN attachments a ON a.id = ca.attachment_id ORDER BY ca.content_id, ca.position",
            )
            .fetch_all(&db.read)
            .await?;
            for (cid, name) in names {
                attachments.entry(cid).or_default().push(name);
            }
            let mut models: HashMap<i64, Vec<(i64, String)>> = HashMap::new();
            let rows_m: Vec<(i64, i64, String)> = sqlx::query_as(
                "SELECT DISTINCT a.content_id, m.id, m.title FROM assignments a
                 JOIN parts p ON p.id = a.part_id JOIN models m ON m.id = p.model_id",
            )
            .fetch_all(&db.read)
            .await?;
            for (cid, mid, title) in rows_m {
                models.entry(cid).or_default().push((mid, title));
            }
            for (id, title, caption, body) in rows {
                out.push(SearchSource {
                    id,
                    title,
                    caption,
                    body,
                    attachment_names: attachments.remove(&id).unwrap_or_default(),
                    models: models.remove(&id).unwrap_or_default(),
                });
            }
        }
        Some(ids) => {
            for chunk in ids.chunks(400) {
                out.extend(search_sources_chunk(db, chunk).await?);
            }
        }
    }
    Ok(out)
}

async fn search_sources_chunk(db: &Db, ids: &[i64]) -> Result<Vec<SearchSource>> {
    fn in_list(
        prefix: &'static str,
        ids: &[i64],
        suffix: &str,
    ) -> sqlx::QueryBuilder<sqlx::Sqlite> {
        let mut qb = sqlx::QueryBuilder::new(prefix);
        let mut sep = qb.separated(", ");
        for id in ids {
            sep.push_bind(*id);
        }
        sep.push_unseparated(") ");
        qb.push(suffix);
        qb
    }
    let rows: Vec<(i64, String, String, String)> = in_list(
        "SELECT id, title, caption, body FROM contents WHERE id IN (",
        ids,
        "",
    )
    .build_query_as()
    .fetch_all(&db.read)
    .await?;
    let names: Vec<(i64, String)> = in_list(
        "SELECT ca.content_id, a.original_name FROM content_attachments ca
         JOIN attachments a ON a.id = ca.attachment_id WHERE ca.content_id IN (",
        ids,
        "ORDER BY ca.content_id, ca.position",
    )
    .build_query_as()
    .fetch_all(&db.read)
    .await?;
    let rows_m: Vec<(i64, i64, String)> = in_list(
        "SELECT DISTINCT a.content_id, m.id, m.title FROM assignments a
         JOIN parts p ON p.id = a.part_id JOIN models m ON m.id = p.model_id WHERE a.content_id IN (",
        ids,
        "",
    )
    .build_query_as()
    .fetch_all(&db.read)
    .await?;
    let mut by_id: HashMap<i64, SearchSource> = rows
        .into_iter()
        .map(|(id, title, caption, body)| {
            (
                id,
                SearchSource {
                    id,
                    title,
                    caption,
                    body,
                    ..Default::default()
                },
            )
        })
        .collect();
    for (cid, name) in names {
        if let Some(s) = by_id.get_mut(&cid) {
            s.attachment_names.push(name);
        }
    }
    for (cid, mid, title) in rows_m {
        if let Some(s) = by_id.get_mut(&cid) {
            s.models.push((mid, title));
        }
    }
    let mut out: Vec<SearchSource> = by_id.into_values().collect();
    out.sort_by_key(|s| s.id);
    Ok(out)
}
