//! `sessions`: login sessions. Only the SHA-256 of the session token is stored; each session
//! has its own CSRF token.

use super::users::User;
use super::{Db, Result};

/// A live session joined with its user.
#[derive(Debug, Clone)]
pub struct Session {
    /// Session id.
    pub id: i64,
    /// CSRF token of the session.
    pub csrf_token: String,
    /// Expiry in Unix seconds.
    pub expires_at: i64,
    /// The logged-in user.
    pub user: User,
}

/// A newly created session: the cookie token (only ever shown here) and the CSRF token.
#[derive(Debug, Clone)]
pub struct NewSession {
    /// Value of the session cookie.
    pub token: String,
    /// CSRF token.
    pub csrf_token: String,
    /// Expiry in Unix seconds.
    pub expires_at: i64,
}

/// Creates a session for `user_id` valid for `ttl_secs`, and drops expired sessions.
pub async fn create(db: &Db, user_id: i64, ttl_secs: i64) -> Result<NewSession> {
    let token = crate::random_hex(32);
    let csrf_token = crate::random_hex(32);
    let now = crate::now_unix();
    let expires_at = now.saturating_add(ttl_secs);
    let mut tx = db.begin().await?;
    sqlx::query("DELETE FROM sessions WHERE expires_at <= ?")
        .bind(now)
        .execute(&mut *tx)
        .await?;
    sqlx::query(
        "INSERT INTO sessions (token_hash, user_id, csrf_token, created_at, expires_at)
         VALUES (?, ?, ?, ?, ?)",
    )
    .bind(crate::sha256_hex(token.as_bytes()))
    .bind(user_id)
    .bind(&csrf_token)
    .bind(crate::now_rfc3339())
    .bind(expires_at)
    .execute(&mut *tx)
    .await?;
    super::audit::record(
        &mut tx,
        Some(user_id),
        "session.create",
        "user",
        Some(user_id),
        serde_json::json!({}),
    )
    .await?;
    tx.commit().await?;
    Ok(NewSession {
        token,
        csrf_token,
        expires_at,
    })
}

/// Records a failed login in the audit log: the account when it exists (`user_id`), the name
/// tried and the client address. The password is never recorded.
pub async fn record_failed_login(
    db: &Db,
    user_id: Option<i64>,
    username: &str,
    address: &str,
) -> Result<()> {
    let mut tx = db.begin().await?;
    let name: String = username.chars().take(64).collect();
    super::audit::record(
        &mut tx,
        None,
        "session.login_failed",
        "user",
        user_id,
        serde_json::json!({ "username": name, "address": address }),
    )
    .await?;
    tx.commit().await?;
    Ok(())
}

/// The live session for a cookie token, if any (expired sessions and disabled users: none).
pub async fn lookup(db: &Db, token: &str) -> Result<Option<Session>> {
    if token.len() != 64 {
        return Ok(None);
    }
    let row: Option<(i64, String, i64, i64)> = sqlx::query_as(
        "SELECT s.id, s.csrf_token, s.expires_at, s.user_id FROM sessions s
         JOIN users u ON u.id = s.user_id
         WHERE s.token_hash = ? AND s.expires_at > ? AND u.disabled = 0",
    )
    .bind(crate::sha256_hex(token.as_bytes()))
    .bind(crate::now_unix())
    .fetch_optional(&db.read)
    .await?;
    let Some((id, csrf_token, expires_at, user_id)) = row else {
        return Ok(None);
    };
    let user = super::users::get(db, user_id).await?;
    Ok(Some(Session {
        id,
        csrf_token,
        expires_at,
        user,
    }))
}

/// Ends a session.
pub async fn delete(db: &Db, id: i64, user_id: i64) -> Result<()> {
    let mut tx = db.begin().await?;
    sqlx::query("DELETE FROM sessions WHERE id = ?")
        .bind(id)
        .execute(&mut *tx)
        .await?;
    super::audit::record(
        &mut tx,
        Some(user_id),
        "session.delete",
        "user",
        Some(user_id),
        serde_json::json!({}),
    )
    .await?;
    tx.commit().await?;
    Ok(())
}
