//! Server-rendered pages (askama templates in `templates/`), readable without JavaScript.
//! Every form post carries the session's CSRF token in a hidden `csrf_token` field.

pub mod account;
pub mod admin;
pub mod contents;
pub mod jobs;
pub mod models;
pub mod search;

/// Template filters shared by the pages (each page module brings `filters` into scope).
pub mod filters {
    /// An RFC 3339 time as people read it, `2026-12-02 16:43 UTC` (the exact value stays in
    /// the `<time datetime>` attribute); anything else as it is.
    #[askama::filter_fn]
    pub fn when(value: &dyn std::fmt::Display, _: &dyn askama::Values) -> askama::Result<String> {
        Ok(super::readable_time(&value.to_string()))
    }

    /// A count with thousands separators: `1,234,567`.
    #[askama::filter_fn]
    pub fn count(value: &dyn std::fmt::Display, _: &dyn askama::Values) -> askama::Result<String> {
        Ok(super::grouped(&value.to_string()))
    }
}

/// `2026-12-02T16:43:05Z` (or with fractions or an offset) → `2026-12-02 16:43 UTC`.
fn readable_time(s: &str) -> String {
    let b = s.as_bytes();
    let shaped = b.len() >= 17
        && b[4] == b'-'
        && b[7] == b'-'
        && b[10] == b'T'
        && b[13] == b':'
        && s.is_char_boundary(16);
    if !shaped {
        return s.to_string();
    }
    let zone = if s.ends_with('Z') || s.ends_with("+00:00") {
        " UTC".to_string()
    } else {
        match s.rfind(['+', '-']) {
            Some(i) if i > 16 => format!(" {}", &s[i..]),
            _ => String::new(),
        }
    };
    format!("{} {}{zone}", &s[..10], &s[11..16])
}

/// Digits grouped by three with commas (a leading `-` kept); anything else as it is.
fn grouped(s: &str) -> String {
    let (sign, digits) = match s.strip_prefix('-') {
        Some(d) => ("-", d),
        None => ("", s),
    };
    if digits.is_empty() || !digits.bytes().all(|c| c.is_ascii_digit()) {
        return s.to_string();
    }
    let mut out = String::with_capacity(digits.len() + digits.len() / 3 + 1);
    for (i, c) in digits.chars().enumerate() {
        if i > 0 && (digits.len() - i) % 3 == 0 {
            out.push(',');
        }
        out.push(c);
    }
    format!("{sign}{out}")
}

use actix_web::http::StatusCode;
use actix_web::http::header::{self, ContentType};
use actix_web::{HttpResponse, web};
use askama::Template;
use serde::Deserialize;

use actix_web::body::{BoxBody, MessageBody};
use actix_web::dev::{ServiceRequest, ServiceResponse};
use actix_web::middleware::Next;

use super::PageError;
use super::auth::CsrfForm;
use super::error::{ErrorPage, ErrorPageInfo};

pub use super::layout::{Layout, UserInfo};

/// A form with only the CSRF field.
#[derive(Debug, Deserialize)]
pub struct CsrfOnly {
    /// CSRF token.
    #[serde(default)]
    pub csrf_token: String,
}

impl CsrfForm for CsrfOnly {
    fn csrf_token(&self) -> &str {
        &self.csrf_token
    }
}

/// Renders a template as a 200 HTML response.
pub fn render<T: Template>(t: &T) -> Result<HttpResponse, PageError> {
    render_status(StatusCode::OK, t)
}

/// Renders a template as an HTML response with `status`.
pub fn render_status<T: Template>(status: StatusCode, t: &T) -> Result<HttpResponse, PageError> {
    Ok(HttpResponse::build(status)
        .content_type(ContentType::html())
        .body(t.render()?))
}

/// 303 See Other to `to`.
pub fn redirect(to: &str) -> HttpResponse {
    HttpResponse::SeeOther()
        .insert_header((header::LOCATION, to.to_string()))
        .finish()
}

/// Normalises form text: CRLF → LF.
pub fn lf(s: &str) -> String {
    s.replace("\r\n", "\n")
}

/// Gives HTML error pages (403, 404, 409…, rendered by [`PageError`] without knowing who asks)
/// the navigation of the visitor's session, so an error never strands anyone outside the site.
pub async fn error_pages(
    req: ServiceRequest,
    next: Next<impl MessageBody + 'static>,
) -> Result<ServiceResponse<BoxBody>, actix_web::Error> {
    let res = next.call(req).await?;
    let Some(info) = res.response().extensions().get::<ErrorPageInfo>().cloned() else {
        return Ok(res.map_into_boxed_body());
    };
    let session = super::auth::current_session(res.request())
        .await
        .ok()
        .flatten();
    let Some(session) = session else {
        return Ok(res.map_into_boxed_body());
    };
    let status = res.status();
    let reason = status.canonical_reason().unwrap_or("Error");
    let page = ErrorPage {
        layout: Layout::of_session(&session, format!("{} {reason}", status.as_u16())),
        status: status.as_u16(),
        reason,
        message: info.message,
    };
    let Ok(html) = page.render() else {
        return Ok(res.map_into_boxed_body());
    };
    Ok(res.map_body(|_, _| BoxBody::new(html)))
}

async fn home() -> HttpResponse {
    redirect("/models")
}

/// Mounts every page.
pub fn configure(cfg: &mut web::ServiceConfig) {
    cfg.service(super::resource("/").route(web::get().to(home)));
    account::configure(cfg);
    models::configure(cfg);
    contents::configure(cfg);
    search::configure(cfg);
    admin::configure(cfg);
    jobs::configure(cfg);
}

#[cfg(test)]
mod filter_tests {
    #[test]
    fn times_and_counts_read_as_people_read_them() {
        assert_eq!(
            super::readable_time("2026-12-02T16:43:05Z"),
            "2026-12-02 16:43 UTC"
        );
        assert_eq!(
            super::readable_time("2026-12-02T16:43:05.123+02:00"),
            "2026-12-02 16:43 +02:00"
        );
        assert_eq!(super::readable_time("yesterday"), "yesterday");
        assert_eq!(super::grouped("1234567"), "1,234,567");
        assert_eq!(super::grouped("-1000"), "-1,000");
        assert_eq!(super::grouped("999"), "999");
        assert_eq!(super::grouped("12a"), "12a");
    }
}
