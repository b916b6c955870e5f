//! Sessions, roles and CSRF.
//!
//! * [`Auth`] (API routes): needs a valid session cookie (else 401 JSON); on every
//!   state-changing method it also needs the session's CSRF token in the `X-CSRF-Token`
//!   header and, when the browser sends one, a same-origin `Origin` (else 403).
//! * [`PageAuth`] (page routes, GET): a session or a redirect to `/login`.
//! * [`PageForm`] (page routes, POST): a session plus a URL-encoded form whose hidden
//!   `csrf_token` field must match the session's (else 403).

use std::future::Future;
use std::net::IpAddr;
use std::pin::Pin;

use actix_web::cookie::{Cookie, SameSite};
use actix_web::dev::Payload;
use actix_web::http::header;
use actix_web::{FromRequest, HttpMessage, HttpRequest, web};
use serde::de::DeserializeOwned;

use super::AppState;
use super::error::{ApiError, PageError};
use crate::store::sessions::{self, Session};
use crate::store::users::{self, Role, User};
use crate::store::{Db, visibility};

/// Name of the session cookie.
pub const SESSION_COOKIE: &str = "meshwiki_session";
/// Header carrying the CSRF token on API requests.
pub const CSRF_HEADER: &str = "x-csrf-token";

/// Compares two strings in time independent of where they differ.
pub fn constant_time_eq(a: &str, b: &str) -> bool {
    let (a, b) = (a.as_bytes(), b.as_bytes());
    if a.len() != b.len() {
        return false;
    }
    a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

/// The session cookie for `token`, valid for `ttl_secs`.
pub fn session_cookie(token: &str, ttl_secs: i64, secure: bool) -> Cookie<'static> {
    Cookie::build(SESSION_COOKIE, token.to_string())
        .path("/")
        .http_only(true)
        .same_site(SameSite::Lax)
        .secure(secure)
        .max_age(actix_web::cookie::time::Duration::seconds(ttl_secs))
        .finish()
}

/// A cookie that removes the session cookie.
pub fn removal_cookie(secure: bool) -> Cookie<'static> {
    let mut c = session_cookie("", 0, secure);
    c.make_removal();
    c
}

fn state(req: &HttpRequest) -> Result<web::Data<AppState>, ApiError> {
    req.app_data::<web::Data<AppState>>()
        .cloned()
        .ok_or_else(|| ApiError::internal("application state missing"))
}

/// The live session of the request, if any.
pub async fn current_session(req: &HttpRequest) -> Result<Option<Session>, ApiError> {
    if let Some(s) = req.extensions().get::<Session>() {
        return Ok(Some(s.clone()));
    }
    let Some(cookie) = req.cookie(SESSION_COOKIE) else {
        return Ok(None);
    };
    let state = state(req)?;
    let session = sessions::lookup(&state.db, cookie.value()).await?;
    if let Some(s) = &session {
        req.extensions_mut().insert(s.clone());
    }
    Ok(session)
}

/// Refuses a state-changing request whose `Origin` names another host.
pub fn check_origin(req: &HttpRequest) -> Result<(), ApiError> {
    let Some(origin) = req.headers().get(header::ORIGIN) else {
        return Ok(());
    };
    let origin = origin.to_str().unwrap_or("null");
    let host = req.connection_info().host().to_ascii_lowercase();
    let origin_host = origin
        .split_once("://")
        .map(|(_, h)| h)
        .unwrap_or("")
        .trim_end_matches('/')
        .to_ascii_lowercase();
    if origin_host == host {
        Ok(())
    } else {
        Err(ApiError::Forbidden(format!(
            "cross-origin request from {origin} refused"
        )))
    }
}

/// The client's address: the connection's peer or, when the peer is a trusted reverse proxy,
/// the last address of `X-Forwarded-For` that is not itself a trusted proxy. Never a header
/// from an untrusted peer (anyone can send one).
pub fn client_addr(req: &HttpRequest, trusted: &[IpAddr]) -> IpAddr {
    let peer = req
        .peer_addr()
        .map(|a| a.ip())
        .unwrap_or(IpAddr::V6(std::net::Ipv6Addr::UNSPECIFIED));
    if !trusted.contains(&peer) {
        return peer;
    }
    let forwarded = req
        .headers()
        .get_all("x-forwarded-for")
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(','))
        .filter_map(|a| a.trim().parse::<IpAddr>().ok())
        .collect::<Vec<_>>();
    forwarded
        .into_iter()
        .rev()
        .find(|a| !trusted.contains(a))
        .unwrap_or(peer)
}

/// One login attempt, for the API and the login form alike: refused with 429 while this
/// account from this address (or this address) is backing off ([`crate::throttle`]), else the
/// password is checked; every failure is logged, and every checked one audited.
pub async fn attempt_login(
    req: &HttpRequest,
    state: &AppState,
    username: &str,
    password: &str,
) -> Result<User, ApiError> {
    let addr = client_addr(req, &state.settings.trusted_proxies);
    let now = std::time::Instant::now();
    // The name as logged and audited: bounded, and without control characters (no forged
    // log lines).
    let shown: String = username
        .chars()
        .map(|c| if c.is_control() { '?' } else { c })
        .take(64)
        .collect();
    if let Err(left) = state.logins.check(username, addr, now) {
        let secs = left.as_secs_f64().ceil().max(1.0) as u64;
        // Logged, not audited: a refused attempt checks nothing, and one database write per
        // refusal would let a flood of them load the writer.
        tracing::warn!(user = %shown, %addr, retry_after = secs, "login refused: too many failures");
        return Err(ApiError::TooManyRequests {
            message: format!("too many failed logins: try again in {secs} s"),
            retry_after: secs,
        });
    }
    let user = if username.len() <= 256 && password.len() <= 4096 {
        users::authenticate(&state.db, username, password).await?
    } else {
        None
    };
    match user {
        Some(user) => {
            state.logins.succeeded(username, addr);
            Ok(user)
        }
        None => {
            let f = state
                .logins
                .failed(username, addr, std::time::Instant::now());
            tracing::warn!(
                user = %shown,
                %addr,
                failures = f.pair_failures,
                address_failures = f.address_failures,
                blocked_secs = f.blocked_for.map(|d| d.as_secs()),
                "failed login"
            );
            let account = match users::by_name(&state.db, username).await {
                Ok(u) => u.map(|u| u.id),
                Err(_) => None,
            };
            if let Err(e) =
                sessions::record_failed_login(&state.db, account, &shown, &addr.to_string()).await
            {
                tracing::error!(error = %e, "cannot audit a failed login");
            }
            Err(ApiError::BadCredentials)
        }
    }
}

/// Role check shared by the extractors.
fn require(user: &User, role: Role) -> Result<(), ApiError> {
    if user.role >= role {
        Ok(())
    } else {
        Err(ApiError::Forbidden(format!(
            "this needs the {role} role; you are {}",
            user.role
        )))
    }
}

/// An authenticated API request (CSRF-checked on state-changing methods).
#[derive(Debug, Clone)]
pub struct Auth(pub Session);

impl Auth {
    /// The logged-in user.
    pub fn user(&self) -> &User {
        &self.0.user
    }

    /// The logged-in user's id.
    pub fn id(&self) -> i64 {
        self.0.user.id
    }

    /// 403 unless the user has at least `role`.
    pub fn require(&self, role: Role) -> Result<(), ApiError> {
        require(&self.0.user, role)
    }
}

impl FromRequest for Auth {
    type Error = ApiError;
    type Future = Pin<Box<dyn Future<Output = Result<Auth, ApiError>>>>;

    fn from_request(req: &HttpRequest, _: &mut Payload) -> Self::Future {
        let req = req.clone();
        Box::pin(async move {
            let session = current_session(&req).await?.ok_or(ApiError::Unauthorized)?;
            if !req.method().is_safe() {
                check_origin(&req)?;
                let sent = req
                    .headers()
                    .get(CSRF_HEADER)
                    .and_then(|v| v.to_str().ok())
                    .unwrap_or("");
                if !constant_time_eq(sent, &session.csrf_token) {
                    return Err(ApiError::Forbidden(
                        "missing or invalid CSRF token: send the session's csrf_token in the \
                         X-CSRF-Token header"
                            .into(),
                    ));
                }
            }
            Ok(Auth(session))
        })
    }
}

/// A read that anonymous visitors may make where the model is public
/// ([`crate::store::visibility`]): the session when there is one (CSRF-checked like
/// [`Auth`]), else `None`. Each handler asks for what it reads ([`Reader::model`], …): with a
/// session everything is readable; without one only what hangs on a public model, else 401.
#[derive(Debug, Clone)]
pub struct Reader(pub Option<Auth>);

impl Reader {
    /// Whether the request has no session.
    pub fn is_anonymous(&self) -> bool {
        self.0.is_none()
    }

    /// The logged-in user, if any.
    pub fn user(&self) -> Option<&User> {
        self.0.as_ref().map(Auth::user)
    }

    /// 401 for an anonymous visitor unless `public` holds.
    fn allow(&self, public: bool) -> Result<(), ApiError> {
        if self.0.is_some() || public {
            Ok(())
        } else {
            Err(ApiError::Unauthorized)
        }
    }

    /// Model `id` may be read.
    pub async fn model(&self, db: &Db, id: i64) -> Result<(), ApiError> {
        match self.0 {
            Some(_) => Ok(()),
            None => self.allow(visibility::model(db, id).await?),
        }
    }

    /// Part `id` may be read.
    pub async fn part(&self, db: &Db, id: i64) -> Result<(), ApiError> {
        match self.0 {
            Some(_) => Ok(()),
            None => self.allow(visibility::part(db, id).await?),
        }
    }

    /// Content `id` may be read.
    pub async fn content(&self, db: &Db, id: i64) -> Result<(), ApiError> {
        match self.0 {
            Some(_) => Ok(()),
            None => self.allow(visibility::content(db, id).await?),
        }
    }

    /// Attachment `id` may be read.
    pub async fn attachment(&self, db: &Db, id: i64) -> Result<(), ApiError> {
        match self.0 {
            Some(_) => Ok(()),
            None => self.allow(visibility::attachment(db, id).await?),
        }
    }
}

impl FromRequest for Reader {
    type Error = ApiError;
    type Future = Pin<Box<dyn Future<Output = Result<Reader, ApiError>>>>;

    fn from_request(req: &HttpRequest, payload: &mut Payload) -> Self::Future {
        let auth = Auth::from_request(req, payload);
        Box::pin(async move {
            match auth.await {
                Ok(a) => Ok(Reader(Some(a))),
                Err(ApiError::Unauthorized) => Ok(Reader(None)),
                Err(e) => Err(e),
            }
        })
    }
}

/// A page that anonymous visitors may open where the model is public: the session when there
/// is one; without one, handlers check what they show and send the visitor to `/login`
/// otherwise ([`PageReader::login`]).
#[derive(Debug, Clone)]
pub struct PageReader {
    /// The session, if any.
    pub auth: Option<PageAuth>,
    next: String,
}

impl PageReader {
    /// The redirect to the login page (back to this page afterwards).
    pub fn login(&self) -> PageError {
        PageError::Login(self.next.clone())
    }

    /// Unless there is a session or `public` holds, the redirect to the login page.
    pub fn allow(&self, public: bool) -> Result<(), PageError> {
        if self.auth.is_some() || public {
            Ok(())
        } else {
            Err(self.login())
        }
    }
}

impl FromRequest for PageReader {
    type Error = PageError;
    type Future = Pin<Box<dyn Future<Output = Result<PageReader, PageError>>>>;

    fn from_request(req: &HttpRequest, _: &mut Payload) -> Self::Future {
        let req = req.clone();
        Box::pin(async move {
            let auth = current_session(&req).await?.map(PageAuth);
            Ok(PageReader {
                auth,
                next: next_of(&req),
            })
        })
    }
}

/// An authenticated page request; without a session, a redirect to `/login`.
#[derive(Debug, Clone)]
pub struct PageAuth(pub Session);

impl PageAuth {
    /// The logged-in user.
    pub fn user(&self) -> &User {
        &self.0.user
    }

    /// The logged-in user's id.
    pub fn id(&self) -> i64 {
        self.0.user.id
    }

    /// The session's CSRF token (for hidden form fields).
    pub fn csrf(&self) -> &str {
        &self.0.csrf_token
    }

    /// 403 page unless the user has at least `role`.
    pub fn require(&self, role: Role) -> Result<(), PageError> {
        Ok(require(&self.0.user, role)?)
    }

    /// 403 unless `token` is the session's CSRF token.
    pub fn check_csrf(&self, token: &str) -> Result<(), PageError> {
        if constant_time_eq(token, &self.0.csrf_token) {
            Ok(())
        } else {
            Err(PageError::Api(ApiError::Forbidden(
                "missing or invalid CSRF token: reload the page and try again".into(),
            )))
        }
    }
}

fn next_of(req: &HttpRequest) -> String {
    if req.method() == actix_web::http::Method::GET {
        req.uri()
            .path_and_query()
            .map(|p| p.as_str().to_string())
            .unwrap_or_else(|| "/".into())
    } else {
        "/".into()
    }
}

impl FromRequest for PageAuth {
    type Error = PageError;
    type Future = Pin<Box<dyn Future<Output = Result<PageAuth, PageError>>>>;

    fn from_request(req: &HttpRequest, _: &mut Payload) -> Self::Future {
        let req = req.clone();
        Box::pin(async move {
            match current_session(&req).await? {
                Some(s) => Ok(PageAuth(s)),
                None => Err(PageError::Login(next_of(&req))),
            }
        })
    }
}

/// A form that carries the hidden `csrf_token` field.
pub trait CsrfForm {
    /// The submitted CSRF token.
    fn csrf_token(&self) -> &str;
}

/// A CSRF-checked form post from a logged-in user.
#[derive(Debug)]
pub struct PageForm<T> {
    /// The session.
    pub auth: PageAuth,
    /// The form.
    pub form: T,
}

impl<T: DeserializeOwned + CsrfForm + 'static> FromRequest for PageForm<T> {
    type Error = PageError;
    type Future = Pin<Box<dyn Future<Output = Result<PageForm<T>, PageError>>>>;

    fn from_request(req: &HttpRequest, payload: &mut Payload) -> Self::Future {
        let req = req.clone();
        let form = web::Form::<T>::from_request(&req, payload);
        Box::pin(async move {
            let session = current_session(&req)
                .await?
                .ok_or_else(|| PageError::Login(next_of(&req)))?;
            let auth = PageAuth(session);
            check_origin(&req)?;
            let form = form
                .await
                .map_err(|e| PageError::Api(ApiError::bad(format!("invalid form: {e}"))))?;
            auth.check_csrf(form.csrf_token())?;
            Ok(PageForm {
                auth,
                form: form.into_inner(),
            })
        })
    }
}
