//! `audit_log`: who changed what, when. Written inside the transaction of every state change.

use serde::Serialize;
use sqlx::FromRow;
use utoipa::ToSchema;

use super::{Db, Page, Result, Tx};

/// One audit entry.
#[derive(Debug, Clone, Serialize, FromRow, ToSchema)]
pub struct AuditEntry {
    /// Id.
    pub id: i64,
    /// Acting user (none for CLI actions).
    pub user_id: Option<i64>,
    /// Action, e.g. `content.update`.
    pub action: String,
    /// Kind of entity changed.
    pub entity: String,
    /// Id of the entity changed.
    pub entity_id: Option<i64>,
    /// Details of the action (JSON, its fields depend on the action).
    #[serde(serialize_with = "as_json")]
    #[schema(value_type = Object)]
    pub details: String,
    /// Time.
    #[schema(format = DateTime)]
    pub created_at: String,
}

/// Records an action in the current transaction.
pub async fn record(
    tx: &mut Tx,
    user_id: Option<i64>,
    action: &str,
    entity: &str,
    entity_id: Option<i64>,
    details: serde_json::Value,
) -> Result<()> {
    sqlx::query(
        "INSERT INTO audit_log (user_id, action, entity, entity_id, details, created_at)
         VALUES (?, ?, ?, ?, ?, ?)",
    )
    .bind(user_id)
    .bind(action)
    .bind(entity)
    .bind(entity_id)
    .bind(details.to_string())
    .bind(crate::now_rfc3339())
    .execute(&mut **tx)
    .await?;
    Ok(())
}

/// Latest entries first, optionally for one entity.
pub async fn list(db: &Db, entity: Option<(&str, i64)>, page: Page) -> Result<Vec<AuditEntry>> {
    let rows =
        match entity {
            Some((kind, id)) => sqlx::query_as::<_, AuditEntry>(
                "SELECT id, user_id, action, entity, entity_id, details, created_at FROM audit_log
                 WHERE entity = ? AND entity_id = ? ORDER BY id DESC LIMIT ? OFFSET ?",
            )
            .bind(kind)
            .bind(id)
            .bind(page.limit)
            .bind(page.offset)
            .fetch_all(&db.read)
            .await?,
            None => sqlx::query_as::<_, AuditEntry>(
                "SELECT id, user_id, action, entity, entity_id, details, created_at FROM audit_log
                 ORDER BY id DESC LIMIT ? OFFSET ?",
            )
            .bind(page.limit)
            .bind(page.offset)
            .fetch_all(&db.read)
            .await?,
        };
    Ok(rows)
}

fn as_json<S: serde::Serializer>(details: &str, s: S) -> std::result::Result<S::Ok, S::Error> {
    let value: serde_json::Value = serde_json::from_str(details).unwrap_or(serde_json::Value::Null);
    value.serialize(s)
}
