//! `/search`: the search page (query, model filter, ranked hits with snippets).

use actix_web::{HttpResponse, web};
use askama::Template;

use super::{Layout, render};
use crate::store::Page;
use crate::store::models::{self, Model};
use crate::web::auth::PageReader;
use crate::web::search::{HitView, SearchQuery, run, with_part_links};
use crate::web::{AppState, PageError};

/// Mounts the page.
pub fn configure(cfg: &mut web::ServiceConfig) {
    cfg.service(crate::web::resource("/search").route(web::get().to(search)));
}

#[derive(Template)]
#[template(path = "search.html")]
struct SearchPage {
    layout: Layout,
    q: String,
    model: i64,
    models: Vec<Model>,
    hits: Vec<HitView>,
    total: usize,
    searched: bool,
    offset: usize,
    prev: Option<usize>,
    next: Option<usize>,
}

async fn search(
    state: web::Data<AppState>,
    reader: PageReader,
    q: web::Query<SearchQuery>,
) -> Result<HttpResponse, PageError> {
    let q = q.into_inner();
    let anonymous = reader.auth.is_none();
    // Anonymous visitors search the public models (and no page without one).
    let page = Page::new(Some(1000), None);
    let models = if anonymous {
        models::list_public(&state.db, page).await?
    } else {
        models::list(&state.db, page).await?
    };
    reader.allow(!models.is_empty())?;
    let searchable = match crate::web::search::searchable(&state, anonymous, q.model).await {
        Ok(s) => s,
        Err(crate::web::ApiError::Unauthorized) => return Err(reader.login()),
        Err(e) => return Err(e.into()),
    };
    let searched = !q.q.trim().is_empty();
    let limit = 20;
    let offset = q.offset.unwrap_or(0).min(10_000);
    let results = run(
        &state,
        &SearchQuery {
            q: q.q.clone(),
            model: q.model,
            limit: Some(limit),
            offset: Some(offset),
        },
        searchable.clone(),
    )
    .await?;
    let shown = if anonymous {
        searchable.as_deref()
    } else {
        None
    };
    let hits = with_part_links(&state, results.hits, &q.q, shown).await?;
    let title = if searched {
        format!("Search: {}", q.q)
    } else {
        "Search".into()
    };
    render(&SearchPage {
        layout: match &reader.auth {
            Some(auth) => Layout::new(auth, title),
            None => Layout::anonymous(title),
        },
        model: q.model.unwrap_or(0),
        prev: (offset > 0).then(|| offset.saturating_sub(limit)),
        next: (offset + limit < results.total).then_some(offset + limit),
        q: q.q,
        models,
        total: results.total,
        hits,
        searched,
        offset,
    })
}
