//! Typed HTTP errors. API routes answer JSON `{"error": "..."}` with a 4xx status for every
//! client mistake (a 500 only for a real server fault, with a generic message); pages answer
//! an HTML error page, or a redirect to `/login` when no one is logged in.

use actix_web::http::StatusCode;
use actix_web::http::header::{self, ContentType};
use actix_web::{HttpRequest, HttpResponse, ResponseError};
use askama::Template;
use serde::Serialize;
use utoipa::ToSchema;

use super::layout::Layout;
use crate::app::AppError;
use crate::search::SearchError;
use crate::store::StoreError;
use crate::store::contents::{ContentEdit, Revision};
use crate::wiki::merge::Merged;

/// The 409 body of a content save based on a stale revision: the three versions and their
/// three-way merge.
#[derive(Debug, Serialize, ToSchema)]
pub struct EditConflict {
    /// What went wrong, for people.
    pub error: String,
    /// The revision the rejected save was based on.
    pub base_revision: i64,
    /// The number of the current revision.
    pub current_revision: i64,
    /// The revision the rejected save was based on, in full (the common base of the merge;
    /// `null` when that number names no revision).
    pub base: Option<Revision>,
    /// The current revision in full ("theirs").
    pub current: Revision,
    /// The rejected edit ("yours"); `null` for a revert.
    pub yours: Option<ContentEdit>,
    /// The three-way merge of yours and theirs against the base: with `conflicts` 0 the
    /// merged text to save (on `current_revision`); otherwise the overlaps are between
    /// `<<<<<<< yours` / `=======` / `>>>>>>> theirs` markers, to resolve. `null` for a revert
    /// or without a base.
    pub merged: Option<Merged>,
}

/// An error of an API route.
#[derive(Debug)]
pub enum ApiError {
    /// 400: malformed or invalid input.
    BadRequest(String),
    /// 401: no valid session.
    Unauthorized,
    /// 401: login with a wrong user name or password.
    BadCredentials,
    /// 403: not allowed (role or CSRF).
    Forbidden(String),
    /// 404: no such thing.
    NotFound(String),
    /// 405: method not allowed on this path.
    MethodNotAllowed,
    /// 409: conflicts with the current state.
    Conflict(String),
    /// 409: a content save on a stale revision; carries both versions.
    StaleRevision {
        /// Revision the save was based on.
        base: i64,
        /// The current revision ("theirs").
        current: Box<Revision>,
        /// The rejected edit ("yours").
        yours: Option<Box<ContentEdit>>,
        /// The base revision, when known.
        base_text: Option<Box<Revision>>,
        /// The three-way merge, when there is a base and an edit.
        merged: Option<Box<Merged>>,
    },
    /// 413: body too large.
    PayloadTooLarge(String),
    /// 415: wrong content type.
    UnsupportedMediaType(String),
    /// 429: too many attempts (failed logins); with `Retry-After`.
    TooManyRequests {
        /// Why.
        message: String,
        /// Seconds until an attempt is heard again.
        retry_after: u64,
    },
    /// 503: the service cannot answer now (render queue full, no GPU adapter); with
    /// `Retry-After` when retrying later may work.
    Unavailable {
        /// Why.
        message: String,
        /// Suggested delay in seconds.
        retry_after: Option<u64>,
    },
    /// 500: server fault (details are logged, not shown).
    Internal(String),
}

impl ApiError {
    /// 400 with a message.
    pub fn bad(msg: impl Into<String>) -> ApiError {
        ApiError::BadRequest(msg.into())
    }

    /// 500, logging `err`.
    pub fn internal(err: impl std::fmt::Display) -> ApiError {
        tracing::error!(error = %err, "internal error");
        ApiError::Internal(err.to_string())
    }

    /// Seconds for a `Retry-After` header, if the error has one.
    pub fn retry_after(&self) -> Option<u64> {
        match self {
            ApiError::Unavailable { retry_after, .. } => *retry_after,
            ApiError::TooManyRequests { retry_after, .. } => Some(*retry_after),
            _ => None,
        }
    }

    /// The message shown to the client.
    pub fn message(&self) -> String {
        match self {
            ApiError::BadRequest(m)
            | ApiError::Forbidden(m)
            | ApiError::NotFound(m)
            | ApiError::Conflict(m)
            | ApiError::PayloadTooLarge(m)
            | ApiError::UnsupportedMediaType(m)
            | ApiError::TooManyRequests { message: m, .. }
            | ApiError::Unavailable { message: m, .. } => m.clone(),
            ApiError::Unauthorized => "authentication required: log in first".into(),
            ApiError::BadCredentials => "invalid username or password".into(),
            ApiError::MethodNotAllowed => "method not allowed on this path".into(),
            ApiError::StaleRevision { base, current, .. } => format!(
                "edit conflict: your edit is based on revision {base} but the current revision \
                 is {}; merge your changes into the current text and save again",
                current.number
            ),
            ApiError::Internal(_) => "internal server error".into(),
        }
    }
}

impl std::fmt::Display for ApiError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message())
    }
}

impl ResponseError for ApiError {
    fn status_code(&self) -> StatusCode {
        match self {
            ApiError::BadRequest(_) => StatusCode::BAD_REQUEST,
            ApiError::Unauthorized | ApiError::BadCredentials => StatusCode::UNAUTHORIZED,
            ApiError::Forbidden(_) => StatusCode::FORBIDDEN,
            ApiError::NotFound(_) => StatusCode::NOT_FOUND,
            ApiError::MethodNotAllowed => StatusCode::METHOD_NOT_ALLOWED,
            ApiError::Conflict(_) | ApiError::StaleRevision { .. } => StatusCode::CONFLICT,
            ApiError::PayloadTooLarge(_) => StatusCode::PAYLOAD_TOO_LARGE,
            ApiError::UnsupportedMediaType(_) => StatusCode::UNSUPPORTED_MEDIA_TYPE,
            ApiError::TooManyRequests { .. } => StatusCode::TOO_MANY_REQUESTS,
            ApiError::Unavailable { .. } => StatusCode::SERVICE_UNAVAILABLE,
            ApiError::Internal(_) => StatusCode::INTERNAL_SERVER_ERROR,
        }
    }

    fn error_response(&self) -> HttpResponse {
        let mut resp = HttpResponse::build(self.status_code());
        resp.insert_header((header::CACHE_CONTROL, "no-store"));
        if let Some(secs) = self.retry_after() {
            resp.insert_header((header::RETRY_AFTER, secs.to_string()));
        }
        if matches!(self, ApiError::Unauthorized) {
            resp.insert_header((header::WWW_AUTHENTICATE, "Cookie realm=\"meshwiki\""));
        }
        match self {
            ApiError::StaleRevision {
                base,
                current,
                yours,
                base_text,
                merged,
            } => resp.json(EditConflict {
                error: self.message(),
                base_revision: *base,
                current_revision: current.number,
                base: base_text.as_deref().cloned(),
                current: Revision::clone(current),
                yours: yours.as_deref().cloned(),
                merged: merged.as_deref().cloned(),
            }),
            _ => resp.json(super::openapi::ErrorBody {
                error: self.message(),
            }),
        }
    }
}

impl From<AppError> for ApiError {
    fn from(e: AppError) -> ApiError {
        match e {
            AppError::NotFound(m) => ApiError::NotFound(m),
            AppError::Invalid(m) => ApiError::BadRequest(m),
            AppError::Forbidden(m) => ApiError::Forbidden(m),
            AppError::Conflict(m) => ApiError::Conflict(m),
            AppError::UnsupportedMedia(m) => ApiError::UnsupportedMediaType(m),
            AppError::TooLarge(m) => ApiError::PayloadTooLarge(m),
            AppError::EditConflict(c) => {
                let c = *c;
                ApiError::StaleRevision {
                    base: c.base_number,
                    current: Box::new(c.theirs),
                    yours: Some(Box::new(c.yours)),
                    base_text: c.base.map(Box::new),
                    merged: c.merged.map(Box::new),
                }
            }
            AppError::Store(e) => e.into(),
            AppError::Render(e) => e.into(),
            AppError::Unavailable(message) => ApiError::Unavailable {
                message,
                retry_after: None,
            },
            AppError::Internal(m) => ApiError::Internal(m),
        }
    }
}

impl From<AppError> for PageError {
    fn from(e: AppError) -> PageError {
        PageError::Api(e.into())
    }
}

impl From<StoreError> for ApiError {
    fn from(e: StoreError) -> ApiError {
        match e {
            StoreError::NotFound(what) => ApiError::NotFound(format!("{what} not found")),
            StoreError::Conflict(m) => ApiError::Conflict(m),
            StoreError::Invalid(m) => ApiError::BadRequest(m),
            StoreError::StaleRevision { base, current } => ApiError::StaleRevision {
                base,
                current,
                yours: None,
                base_text: None,
                merged: None,
            },
            e @ (StoreError::Db(_) | StoreError::Migrate(_)) => ApiError::internal(e),
        }
    }
}

impl From<SearchError> for ApiError {
    fn from(e: SearchError) -> ApiError {
        match e {
            SearchError::Store(s) => s.into(),
            other => ApiError::internal(other),
        }
    }
}

impl From<askama::Error> for ApiError {
    fn from(e: askama::Error) -> ApiError {
        ApiError::internal(format!("template: {e}"))
    }
}

impl From<std::io::Error> for ApiError {
    fn from(e: std::io::Error) -> ApiError {
        ApiError::internal(format!("I/O: {e}"))
    }
}

/// An error of a page route: rendered as HTML, or a redirect to the login page.
#[derive(Debug)]
pub enum PageError {
    /// Not logged in: redirect to `/login?next=...`.
    Login(String),
    /// Any other error, shown as an HTML page with its status.
    Api(ApiError),
}

impl From<ApiError> for PageError {
    fn from(e: ApiError) -> PageError {
        match e {
            ApiError::Unauthorized => PageError::Login("/".into()),
            e => PageError::Api(e),
        }
    }
}

impl From<StoreError> for PageError {
    fn from(e: StoreError) -> PageError {
        PageError::Api(e.into())
    }
}

impl From<SearchError> for PageError {
    fn from(e: SearchError) -> PageError {
        PageError::Api(e.into())
    }
}

impl From<askama::Error> for PageError {
    fn from(e: askama::Error) -> PageError {
        PageError::Api(e.into())
    }
}

impl std::fmt::Display for PageError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            PageError::Login(_) => f.write_str("login required"),
            PageError::Api(e) => e.fmt(f),
        }
    }
}

/// An HTML error page: the status and its message in the site's layout (the navigation of the
/// visitor's session, which [`crate::web::pages::error_pages`] fills in).
#[derive(Template)]
#[template(path = "error.html")]
pub struct ErrorPage<'a> {
    /// Layout (anonymous until the middleware knows the session).
    pub layout: Layout,
    /// Status code.
    pub status: u16,
    /// Its reason phrase.
    pub reason: &'a str,
    /// What went wrong.
    pub message: String,
}

/// Marks a response as an HTML error page, for [`crate::web::pages::error_pages`].
#[derive(Debug, Clone)]
pub struct ErrorPageInfo {
    /// What went wrong.
    pub message: String,
}

impl ResponseError for PageError {
    fn status_code(&self) -> StatusCode {
        match self {
            PageError::Login(_) => StatusCode::SEE_OTHER,
            PageError::Api(e) => e.status_code(),
        }
    }

    fn error_response(&self) -> HttpResponse {
        match self {
            PageError::Login(next) => HttpResponse::SeeOther()
                .insert_header((header::LOCATION, login_url(next)))
                .finish(),
            PageError::Api(e) => {
                let status = e.status_code();
                let reason = status.canonical_reason().unwrap_or("Error");
                let page = ErrorPage {
                    layout: Layout::anonymous(format!("{} {reason}", status.as_u16())),
                    status: status.as_u16(),
                    reason,
                    message: e.message(),
                };
                let mut resp = HttpResponse::build(status);
                if let Some(secs) = e.retry_after() {
                    resp.insert_header((header::RETRY_AFTER, secs.to_string()));
                }
                let mut resp = match page.render() {
                    Ok(html) => resp.content_type(ContentType::html()).body(html),
                    Err(_) => resp.body(e.message()),
                };
                resp.extensions_mut().insert(ErrorPageInfo {
                    message: e.message(),
                });
                resp
            }
        }
    }
}

/// `/login?next=<path>` for a local path (anything else falls back to `/`).
pub fn login_url(next: &str) -> String {
    format!("/login?next={}", encode_component(safe_next(next)))
}

/// `next` if it is a same-origin absolute path, else `/`.
///
/// Browsers drop tabs and newlines from URLs and read a backslash as `/`, so `/<TAB>/evil.example`
/// or `/<BACKSLASH>evil.example` would become the scheme-relative `//evil.example`: only printable ASCII
/// without spaces or backslashes passes, starting with one `/` (never `//`). Such a value is
/// also always a valid `Location` header.
pub fn safe_next(next: &str) -> &str {
    let printable = next.bytes().all(|b| b.is_ascii_graphic() && b != b'\\');
    if printable && next.starts_with('/') && !next.starts_with("//") {
        next
    } else {
        "/"
    }
}

/// Percent-encodes a URL query component.
pub fn encode_component(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for b in s.bytes() {
        if b.is_ascii_alphanumeric() || matches!(b, b'-' | b'_' | b'.' | b'~' | b'/') {
            out.push(b as char);
        } else {
            out.push_str(&format!("%{b:02X}"));
        }
    }
    out
}

/// Maps JSON body extractor errors to 400/413/415 JSON errors.
pub fn json_error(err: actix_web::error::JsonPayloadError, _req: &HttpRequest) -> actix_web::Error {
    use actix_web::error::JsonPayloadError as E;
    match err {
        E::OverflowKnownLength { limit, .. } | E::Overflow { limit } => {
            ApiError::PayloadTooLarge(format!("JSON body larger than {limit} bytes"))
        }
        E::ContentType => {
            ApiError::UnsupportedMediaType("expected Content-Type: application/json".into())
        }
        E::Deserialize(e) => ApiError::bad(format!("invalid JSON body: {e}")),
        other => ApiError::bad(format!("cannot read JSON body: {other}")),
    }
    .into()
}

/// Maps path extractor errors to 400 JSON errors.
pub fn path_error(err: actix_web::error::PathError, _req: &HttpRequest) -> actix_web::Error {
    ApiError::bad(format!("invalid path parameter: {err}")).into()
}

/// Maps query-string extractor errors to 400 JSON errors.
pub fn query_error(
    err: actix_web::error::QueryPayloadError,
    _req: &HttpRequest,
) -> actix_web::Error {
    ApiError::bad(format!("invalid query string: {err}")).into()
}

/// Maps form body extractor errors to 400/413 errors.
pub fn form_error(err: actix_web::error::UrlencodedError, _req: &HttpRequest) -> actix_web::Error {
    use actix_web::error::UrlencodedError as E;
    let e = match err {
        E::Overflow { limit, .. } => {
            ApiError::PayloadTooLarge(format!("form body larger than {limit} bytes"))
        }
        E::ContentType => ApiError::UnsupportedMediaType(
            "expected Content-Type: application/x-www-form-urlencoded".into(),
        ),
        other => ApiError::bad(format!("invalid form: {other}")),
    };
    PageError::Api(e).into()
}
