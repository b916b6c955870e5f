//! `GET /api/v1/search?q=&model=&limit=&offset=`: ranked contents with highlighted
//! snippets; the total number of matches is in the `X-Total-Count` header.

use actix_web::{HttpResponse, web};
use serde::Deserialize;
use utoipa::{IntoParams, ToSchema};

use super::auth::Reader;
use super::{ApiError, AppState};
use crate::search::{SearchHit, SearchResults};
use crate::store::assignments;
use crate::store::visibility;

/// Mounts the route.
pub fn configure(cfg: &mut web::ServiceConfig) {
    cfg.service(super::resource("/api/v1/search").route(web::get().to(search)));
}

/// This module's operations in the OpenAPI document ([`super::openapi`]).
#[derive(utoipa::OpenApi)]
#[openapi(paths(search))]
pub(super) struct Api;

/// Search parameters.
#[derive(Debug, Default, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct SearchQuery {
    /// Query text (words are ANDed; tantivy syntax such as `"phrase"` and `-word` works; at
    /// most 1000 bytes). Empty: no hits.
    #[serde(default)]
    pub q: String,
    /// Only contents assigned to this model (empty: all).
    #[serde(default, deserialize_with = "empty_as_none")]
    pub model: Option<i64>,
    /// Hits per page (1–100, default 20).
    pub limit: Option<usize>,
    /// Hits to skip (at most 10000).
    pub offset: Option<usize>,
}

/// The models a search may look in: all (`None`) with a session; without one the public
/// models only (401 when there is none, or when a model filter names another).
pub async fn searchable(
    state: &AppState,
    anonymous: bool,
    model: Option<i64>,
) -> Result<Option<Vec<i64>>, ApiError> {
    if !anonymous {
        return Ok(model.map(|m| vec![m]));
    }
    match model {
        Some(m) if visibility::model(&state.db, m).await? => Ok(Some(vec![m])),
        Some(_) => Err(ApiError::Unauthorized),
        None => match visibility::public_models(&state.db).await? {
            // No public model: there is nothing to search without logging in.
            public if public.is_empty() => Err(ApiError::Unauthorized),
            public => Ok(Some(public)),
        },
    }
}

/// Runs a search on a blocking thread, among `models` (see [`searchable`]).
pub async fn run(
    state: &AppState,
    q: &SearchQuery,
    models: Option<Vec<i64>>,
) -> Result<SearchResults, ApiError> {
    if q.q.len() > 1000 {
        return Err(ApiError::bad("query longer than 1000 bytes"));
    }
    let search = state.search.clone();
    let text = q.q.clone();
    let (limit, offset) = (
        q.limit.unwrap_or(20).clamp(1, 100),
        q.offset.unwrap_or(0).min(10_000),
    );
    Ok(
        tokio::task::spawn_blocking(move || search.search(&text, models.as_deref(), limit, offset))
            .await
            .map_err(ApiError::internal)??,
    )
}

/// Full-text search over contents
///
/// Searches the title, caption, body, attachment names and the titles of the models a content
/// is assigned to (title and caption weigh more). Hits come best first, each with highlighted
/// snippets and the parts it is assigned to (links to their best views); the total number of
/// matches is in the `X-Total-Count` header.
#[utoipa::path(get, path = "/api/v1/search", tag = "search",
    params(SearchQuery),
    responses((status = 200, description = "Hits, best first", body = Vec<HitView>,
        headers(("X-Total-Count" = usize,
            description = "Number of matching contents, all pages together")))),
    security((), ("sessionCookie" = ["viewer"])))]
async fn search(
    state: web::Data<AppState>,
    reader: Reader,
    q: web::Query<SearchQuery>,
) -> Result<HttpResponse, ApiError> {
    let models = searchable(&state, reader.is_anonymous(), q.model).await?;
    let results = run(&state, &q, models.clone()).await?;
    // Anonymous visitors see the parts of public models only.
    let shown = if reader.is_anonymous() {
        models.as_deref()
    } else {
        None
    };
    let hits = with_part_links(&state, results.hits, &q.q, shown).await?;
    Ok(HttpResponse::Ok()
        .insert_header(("X-Total-Count", results.total.to_string()))
        .json(hits))
}

/// A part a hit is assigned to, with the link that opens the viewer on the part's best view
/// (framed, highlighted, its information open).
#[derive(Debug, Clone, serde::Serialize, ToSchema)]
pub struct PartLink {
    /// Part id.
    pub id: i64,
    /// Model id.
    pub model_id: i64,
    /// Model title.
    pub model_title: String,
    /// The part's name: the title of its first information (as the viewer's callout shows it).
    pub title: String,
    /// Part kind.
    pub kind: String,
    /// `/models/{model_id}?part={id}&q={query}`: the page opening the viewer on the part's best
    /// view (framed, highlighted, its information open with the query's words marked and the
    /// matching paragraph in view); without `&q=` outside a search.
    pub url: String,
    /// The part's thumbnail (an attachment), once rendered.
    pub thumbnail_attachment_id: Option<i64>,
    /// The part's best view (or the camera a client gave it).
    pub camera: Option<crate::store::parts::Camera>,
    /// A server-rendered image of that view with the part tinted (for clients without 3D):
    /// `GET /api/v1/models/{model_id}/render` at 640×480.
    pub image_url: Option<String>,
}

/// `GET /api/v1/models/{model_id}/render` of `camera` at 640×480 with `part` tinted.
pub fn view_image_url(model_id: i64, part: i64, camera: &crate::store::parts::Camera) -> String {
    let v = |a: &[f64; 3]| format!("{},{},{}", a[0], a[1], a[2]);
    format!(
        "/api/v1/models/{model_id}/render?eye={}&target={}&up={}&fovy={}&w=640&h=480&parts={part}",
        v(&camera.eye),
        v(&camera.target),
        v(&camera.up),
        camera.fovy
    )
}

/// A search hit with the parts it is assigned to.
#[derive(Debug, Clone, serde::Serialize, ToSchema)]
pub struct HitView {
    /// The hit.
    #[serde(flatten)]
    pub hit: SearchHit,
    /// Parts showing it, each linking to its best view.
    pub parts: Vec<PartLink>,
}

/// The best-view links of the parts content `content_id` is assigned to; `query` (the search
/// that found it, may be empty) travels in each link as `&q=`.
pub async fn part_links(
    state: &AppState,
    content_id: i64,
    query: &str,
    models: Option<&[i64]>,
) -> Result<Vec<PartLink>, ApiError> {
    let q = query.trim();
    let q = if q.is_empty() {
        String::new()
    } else {
        format!("&q={}", super::error::encode_component(q))
    };
    Ok(assignments::parts_for_content(&state.db, content_id)
        .await?
        .into_iter()
        .filter(|p| models.is_none_or(|ms| ms.contains(&p.model_id)))
        .map(|p| PartLink {
            url: format!("/models/{}?part={}{q}", p.model_id, p.id),
            camera: p.camera(),
            image_url: p.camera().map(|c| view_image_url(p.model_id, p.id, &c)),
            thumbnail_attachment_id: p.thumbnail_attachment_id,
            id: p.id,
            model_id: p.model_id,
            model_title: p.model_title,
            title: p.part_title,
            kind: p.kind,
        })
        .collect())
}

/// Adds the part links to each hit (`query`: the search that found them; `models`: the
/// models whose parts may be shown, all when `None`).
pub async fn with_part_links(
    state: &AppState,
    hits: Vec<SearchHit>,
    query: &str,
    models: Option<&[i64]>,
) -> Result<Vec<HitView>, ApiError> {
    let mut out = Vec::with_capacity(hits.len());
    for hit in hits {
        let parts = part_links(state, hit.id, query, models).await?;
        out.push(HitView { hit, parts });
    }
    Ok(out)
}

/// Deserialises an optional number where an empty string (an HTML form's "any" choice)
/// means none.
pub fn empty_as_none<'de, D>(d: D) -> Result<Option<i64>, D::Error>
where
    D: serde::Deserializer<'de>,
{
    let s: Option<String> = Option::deserialize(d)?;
    match s.as_deref().map(str::trim) {
        None | Some("") => Ok(None),
        Some(v) => v
            .parse()
            .map(Some)
            .map_err(|_| serde::de::Error::custom(format!("invalid number {v:?}"))),
    }
}
