//! `users`: accounts with an argon2 password hash and a role.

use serde::{Deserialize, Serialize};
use sqlx::FromRow;
use utoipa::ToSchema;

use super::{Db, Page, Result, StoreError, Tx};

/// What a user may do. Ordered: every role may do what the roles below it may.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize, sqlx::Type, ToSchema,
)]
#[serde(rename_all = "lowercase")]
#[sqlx(rename_all = "lowercase")]
pub enum Role {
    /// Reads everything.
    Viewer,
    /// Also edits contents, parts and assignments, and uploads attachments.
    Editor,
    /// Also manages users and models.
    Admin,
}

impl Role {
    /// The role's name as stored and shown.
    pub fn as_str(self) -> &'static str {
        match self {
            Role::Viewer => "viewer",
            Role::Editor => "editor",
            Role::Admin => "admin",
        }
    }

    /// Every role, lowest first.
    pub const ALL: [Role; 3] = [Role::Viewer, Role::Editor, Role::Admin];
}

impl std::str::FromStr for Role {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Role, String> {
        match s {
            "viewer" => Ok(Role::Viewer),
            "editor" => Ok(Role::Editor),
            "admin" => Ok(Role::Admin),
            other => Err(format!(
                "unknown role {other:?} (expected admin, editor or viewer)"
            )),
        }
    }
}

impl std::fmt::Display for Role {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A user account.
#[derive(Debug, Clone, Serialize, FromRow, ToSchema)]
pub struct User {
    /// Id.
    pub id: i64,
    /// Unique login name.
    pub username: String,
    /// argon2 PHC string; never serialised.
    #[serde(skip)]
    pub password_hash: String,
    /// Role.
    pub role: Role,
    /// Disabled accounts cannot log in.
    pub disabled: bool,
    /// Creation time.
    #[schema(format = DateTime)]
    pub created_at: String,
    /// Last change.
    #[schema(format = DateTime)]
    pub updated_at: String,
}

/// Hashes a password with argon2id (default parameters, random salt).
pub fn hash_password(password: &str) -> Result<String> {
    use argon2::PasswordHasher;
    argon2::Argon2::default()
        .hash_password(password.as_bytes())
        .map(|h| h.to_string())
        .map_err(|e| StoreError::Invalid(format!("cannot hash password: {e}")))
}

/// [`hash_password`] on a blocking thread (argon2 is deliberately slow).
pub async fn hash_blocking(password: &str) -> Result<String> {
    let p = password.to_string();
    tokio::task::spawn_blocking(move || hash_password(&p))
        .await
        .map_err(|e| StoreError::Invalid(format!("cannot hash password: {e}")))?
}

/// Checks `password` against an argon2 PHC string.
pub fn verify_password(password: &str, hash: &str) -> bool {
    use argon2::PasswordVerifier;
    argon2::Argon2::default()
        .verify_password(password.as_bytes(), hash)
        .is_ok()
}

/// Checks a user name: 1–64 characters of letters, digits, `.`, `_`, `-`.
pub fn validate_username(name: &str) -> Result<()> {
    if name.is_empty() || name.chars().count() > 64 {
        return Err(StoreError::Invalid(
            "username must be 1 to 64 characters".into(),
        ));
    }
    if !name
        .chars()
        .all(|c| c.is_alphanumeric() || matches!(c, '.' | '_' | '-'))
    {
        return Err(StoreError::Invalid(
            "username may only hold letters, digits, '.', '_' and '-'".into(),
        ));
    }
    Ok(())
}

/// Checks a password: 8–1024 characters.
pub fn validate_password(password: &str) -> Result<()> {
    let n = password.chars().count();
    if !(8..=1024).contains(&n) {
        return Err(StoreError::Invalid(
            "password must be 8 to 1024 characters".into(),
        ));
    }
    Ok(())
}

const COLUMNS: &str = "id, username, password_hash, role, disabled, created_at, updated_at";

/// Creates a user (the password is hashed here).
pub async fn create(
    db: &Db,
    username: &str,
    password: &str,
    role: Role,
    actor: Option<i64>,
) -> Result<User> {
    validate_username(username)?;
    validate_password(password)?;
    let hash = hash_blocking(password).await?;
    let now = crate::now_rfc3339();
    let mut tx = db.begin().await?;
    let id: i64 = sqlx::query_scalar(
        "INSERT INTO users (username, password_hash, role, disabled, created_at, updated_at)
         VALUES (?, ?, ?, 0, ?, ?) RETURNING id",
    )
    .bind(username)
    .bind(&hash)
    .bind(role)
    .bind(&now)
    .bind(&now)
    .fetch_one(&mut *tx)
    .await
    .map_err(|e| StoreError::map_constraint(e, &format!("user {username:?} already exists"), ""))?;
    super::audit::record(
        &mut tx,
        actor,
        "user.create",
        "user",
        Some(id),
        serde_json::json!({"username": username, "role": role}),
    )
    .await?;
    let user = get_tx(&mut tx, id).await?;
    tx.commit().await?;
    Ok(user)
}

/// Creates the user or, if it exists, resets its password and role and re-enables it.
pub async fn upsert(db: &Db, username: &str, password: &str, role: Role) -> Result<User> {
    if let Some(existing) = by_name(db, username).await? {
        validate_password(password)?;
        let hash = hash_blocking(password).await?;
        let mut tx = db.begin().await?;
        sqlx::query(
            "UPDATE users SET password_hash = ?, role = ?, disabled = 0, updated_at = ? WHERE id = ?",
        )
        .bind(&hash)
        .bind(role)
        .bind(crate::now_rfc3339())
        .bind(existing.id)
        .execute(&mut *tx)
        .await?;
        super::audit::record(
            &mut tx,
            None,
            "user.reset",
            "user",
            Some(existing.id),
            serde_json::json!({"username": username, "role": role}),
        )
        .await?;
        let user = get_tx(&mut tx, existing.id).await?;
        tx.commit().await?;
        Ok(user)
    } else {
        create(db, username, password, role, None).await
    }
}

async fn get_tx(tx: &mut Tx, id: i64) -> Result<User> {
    sqlx::query_as::<_, User>(sqlx::AssertSqlSafe(format!(
        "SELECT {COLUMNS} FROM users WHERE id = ?"
    )))
    .bind(id)
    .fetch_optional(&mut **tx)
    .await?
    .ok_or(StoreError::NotFound("user"))
}

/// A user by id.
pub async fn get(db: &Db, id: i64) -> Result<User> {
    sqlx::query_as::<_, User>(sqlx::AssertSqlSafe(format!(
        "SELECT {COLUMNS} FROM users WHERE id = ?"
    )))
    .bind(id)
    .fetch_optional(&db.read)
    .await?
    .ok_or(StoreError::NotFound("user"))
}

/// A user by name.
pub async fn by_name(db: &Db, username: &str) -> Result<Option<User>> {
    Ok(sqlx::query_as::<_, User>(sqlx::AssertSqlSafe(format!(
        "SELECT {COLUMNS} FROM users WHERE username = ?"
    )))
    .bind(username)
    .fetch_optional(&db.read)
    .await?)
}

/// Checks credentials; returns the user if the password matches and the account is enabled.
pub async fn authenticate(db: &Db, username: &str, password: &str) -> Result<Option<User>> {
    let user = by_name(db, username).await?;
    let password = password.to_string();
    // argon2 is deliberately slow: keep it off the async workers. Without a user, verify
    // against a fixed hash anyway so timing does not reveal which names exist.
    static DUMMY: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    let hash = user.as_ref().map(|u| u.password_hash.clone());
    let ok = tokio::task::spawn_blocking(move || {
        let hash = hash.unwrap_or_else(|| {
            DUMMY
                .get_or_init(|| hash_password("not a real password").unwrap_or_default())
                .clone()
        });
        verify_password(&password, &hash)
    })
    .await
    .unwrap_or(false);
    Ok(user.filter(|u| ok && !u.disabled))
}

/// Every user, by name.
pub async fn list(db: &Db, page: Page) -> Result<Vec<User>> {
    Ok(sqlx::query_as::<_, User>(sqlx::AssertSqlSafe(format!(
        "SELECT {COLUMNS} FROM users ORDER BY username LIMIT ? OFFSET ?"
    )))
    .bind(page.limit)
    .bind(page.offset)
    .fetch_all(&db.read)
    .await?)
}

/// Changes to a user; `None` leaves a field as it is.
#[derive(Debug, Default, Clone, Deserialize)]
pub struct UserPatch {
    /// New role.
    pub role: Option<Role>,
    /// New password.
    pub password: Option<String>,
    /// Disable (true) or re-enable (false).
    pub disabled: Option<bool>,
}

/// Applies `patch` to user `id`. Disabling a user or changing its password ends its sessions.
pub async fn update(db: &Db, id: i64, patch: &UserPatch, actor: Option<i64>) -> Result<User> {
    let hash = match &patch.password {
        Some(p) => {
            validate_password(p)?;
            Some(hash_blocking(p).await?)
        }
        None => None,
    };
    let mut tx = db.begin().await?;
    let mut user = get_tx(&mut tx, id).await?;
    if let Some(role) = patch.role {
        user.role = role;
    }
    if let Some(d) = patch.disabled {
        user.disabled = d;
    }
    if let Some(h) = &hash {
        user.password_hash = h.clone();
    }
    user.updated_at = crate::now_rfc3339();
    sqlx::query(
        "UPDATE users SET role = ?, disabled = ?, password_hash = ?, updated_at = ? WHERE id = ?",
    )
    .bind(user.role)
    .bind(user.disabled)
    .bind(&user.password_hash)
    .bind(&user.updated_at)
    .bind(id)
    .execute(&mut *tx)
    .await?;
    if user.disabled || hash.is_some() {
        sqlx::query("DELETE FROM sessions WHERE user_id = ?")
            .bind(id)
            .execute(&mut *tx)
            .await?;
    }
    super::audit::record(
        &mut tx,
        actor,
        "user.update",
        "user",
        Some(id),
        serde_json::json!({
            "role": patch.role,
            "disabled": patch.disabled,
            "password_changed": hash.is_some(),
        }),
    )
    .await?;
    tx.commit().await?;
    Ok(user)
}

/// Number of users.
pub async fn count(db: &Db) -> Result<i64> {
    Ok(sqlx::query_scalar("SELECT COUNT(*) FROM users")
        .fetch_one(&db.read)
        .await?)
}
