//! What every page's layout (`templates/base.html`) shows: the title, the logged-in user and
//! the CSRF token of the page's forms. Error pages use it too (`error.rs`, and the
//! [`super::pages`] middleware that gives them the visitor's navigation).

use super::auth::PageAuth;
use crate::store::sessions::Session;
use crate::store::users::Role;

/// The logged-in user as the layout shows it.
#[derive(Debug, Clone)]
pub struct UserInfo {
    /// Id.
    pub id: i64,
    /// User name.
    pub username: String,
    /// Role name.
    pub role: String,
    /// Admin?
    pub is_admin: bool,
    /// Editor or admin?
    pub can_edit: bool,
}

/// What the base layout needs.
#[derive(Debug, Clone)]
pub struct Layout {
    /// Page title.
    pub title: String,
    /// Logged-in user.
    pub user: Option<UserInfo>,
    /// CSRF token for forms.
    pub csrf: String,
}

impl Layout {
    /// Layout for a logged-in page.
    pub fn new(auth: &PageAuth, title: impl Into<String>) -> Layout {
        Layout::of_session(&auth.0, title)
    }

    /// Layout for `session`'s user.
    pub fn of_session(session: &Session, title: impl Into<String>) -> Layout {
        let u = &session.user;
        Layout {
            title: title.into(),
            user: Some(UserInfo {
                id: u.id,
                username: u.username.clone(),
                role: u.role.to_string(),
                is_admin: u.role >= Role::Admin,
                can_edit: u.role >= Role::Editor,
            }),
            csrf: session.csrf_token.clone(),
        }
    }

    /// Layout for a page without a session.
    pub fn anonymous(title: impl Into<String>) -> Layout {
        Layout {
            title: title.into(),
            user: None,
            csrf: String::new(),
        }
    }

    /// Whether the user may edit.
    pub fn can_edit(&self) -> bool {
        self.user.as_ref().is_some_and(|u| u.can_edit)
    }
}
