//! Full-text search over contents with tantivy: title, caption, body (as plain text),
//! attachment names and the titles of the models a content is assigned to. Ranked (BM25,
//! title and caption boosted), with highlighted snippets and an optional model filter.
//!
//! Consistency with the database: every change that affects a search document appends to
//! the `search_changes` feed in its own transaction. [`SearchIndex::sync`] applies the feed
//! after the sequence stored as the payload of the last tantivy commit, commits, and reloads
//! the reader; request handlers await it before answering, so a committed edit is
//! searchable by the next request. After a crash the payload is behind the feed and
//! [`SearchIndex::open`] catches up on start-up. [`SearchIndex::rebuild`] re-creates
//! everything (`meshwiki reindex`).

use std::path::Path;
use std::sync::{Arc, Mutex};

use serde::Serialize;
use tantivy::collector::{Count, TopDocs};
use tantivy::query::{BooleanQuery, Occur, Query, QueryParser, TermQuery};
use tantivy::schema::{
    FAST, Field, INDEXED, IndexRecordOption, STORED, Schema, TextFieldIndexing, TextOptions, Value,
};
use tantivy::snippet::SnippetGenerator;
use tantivy::tokenizer::{
    AsciiFoldingFilter, Language, LowerCaser, RemoveLongFilter, SimpleTokenizer, Stemmer,
    TextAnalyzer,
};
use tantivy::{Index, IndexReader, IndexWriter, ReloadPolicy, TantivyDocument, Term};
use utoipa::ToSchema;

use crate::store::contents::SearchSource;
use crate::store::{self, Db, StoreError};

/// Bumped whenever the schema or analysis changes: an index of another version is rebuilt.
const SCHEMA_VERSION: u32 = 1;
const TOKENIZER: &str = "meshwiki";
const WRITER_HEAP: usize = 64 * 1024 * 1024;
const BATCH: i64 = 10_000;

/// Errors of the search index.
#[derive(Debug, thiserror::Error)]
pub enum SearchError {
    /// tantivy failed.
    #[error("search index error: {0}")]
    Tantivy(#[from] tantivy::TantivyError),
    /// The database failed.
    #[error(transparent)]
    Store(#[from] StoreError),
    /// File system error.
    #[error("search index I/O error: {0}")]
    Io(#[from] std::io::Error),
    /// A background task failed.
    #[error("search task failed: {0}")]
    Task(String),
}

#[derive(Clone, Copy)]
struct Fields {
    id: Field,
    title: Field,
    caption: Field,
    body: Field,
    attachments: Field,
    models: Field,
    model_id: Field,
}

fn schema() -> (Schema, Fields) {
    let mut b = Schema::builder();
    let text = |stored: bool| {
        let o = TextOptions::default().set_indexing_options(
            TextFieldIndexing::default()
                .set_tokenizer(TOKENIZER)
                .set_index_option(IndexRecordOption::WithFreqsAndPositions),
        );
        if stored { o.set_stored() } else { o }
    };
    let fields = Fields {
        id: b.add_u64_field("id", INDEXED | STORED | FAST),
        title: b.add_text_field("title", text(true)),
        caption: b.add_text_field("caption", text(true)),
        body: b.add_text_field("body", text(true)),
        attachments: b.add_text_field("attachments", text(false)),
        models: b.add_text_field("models", text(false)),
        model_id: b.add_u64_field("model_id", INDEXED),
    };
    (b.build(), fields)
}

fn analyzer() -> TextAnalyzer {
    TextAnalyzer::builder(SimpleTokenizer::default())
        .filter(RemoveLongFilter::limit(40))
        .filter(LowerCaser)
        .filter(AsciiFoldingFilter)
        .filter(Stemmer::new(Language::English))
        .build()
}

#[derive(Serialize, serde::Deserialize)]
struct Payload {
    v: u32,
    seq: i64,
}

/// One search result.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct SearchHit {
    /// Content id.
    pub id: i64,
    /// Title.
    pub title: String,
    /// Title as HTML with matches in `<b>` (escaped, safe to embed).
    pub title_html: String,
    /// Caption.
    pub caption: String,
    /// Excerpt of the body as HTML with matches in `<b>` (escaped, safe to embed); the start
    /// of the caption or body when the body has no match.
    pub snippet_html: String,
    /// BM25 score (higher is better).
    pub score: f32,
}

/// A page of search results.
#[derive(Debug, Clone, Serialize)]
pub struct SearchResults {
    /// Number of matching contents.
    pub total: usize,
    /// The requested page of hits, best first.
    pub hits: Vec<SearchHit>,
}

struct Inner {
    index: Index,
    reader: IndexReader,
    writer: Mutex<IndexWriter>,
    fields: Fields,
    /// Highest change sequence applied; the lock also serialises index writers.
    indexed: tokio::sync::Mutex<i64>,
}

/// The search index, cheap to clone and share.
#[derive(Clone)]
pub struct SearchIndex {
    inner: Arc<Inner>,
}

impl std::fmt::Debug for SearchIndex {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SearchIndex").finish_non_exhaustive()
    }
}

fn to_document(fields: &Fields, src: &SearchSource) -> TantivyDocument {
    let mut doc = TantivyDocument::default();
    doc.add_u64(fields.id, src.id as u64);
    doc.add_text(fields.title, &src.title);
    doc.add_text(fields.caption, &src.caption);
    doc.add_text(fields.body, crate::wiki::markdown::plain_text(&src.body));
    for name in &src.attachment_names {
        doc.add_text(fields.attachments, name);
    }
    for (id, title) in &src.models {
        doc.add_u64(fields.model_id, *id as u64);
        doc.add_text(fields.models, title);
    }
    doc
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl SearchIndex {
    /// Opens the index in `dir` (creating it, or re-creating it when its schema is outdated)
    /// and brings it up to date with the database: a full rebuild for a new index, otherwise
    /// the changes committed after the index's last commit.
    pub async fn open(dir: &Path, db: &Db) -> Result<SearchIndex, SearchError> {
        let dir = dir.to_path_buf();
        let (index, seq) = tokio::task::spawn_blocking(move || open_index(&dir))
            .await
            .map_err(|e| SearchError::Task(e.to_string()))??;
        let (_, fields) = schema();
        let writer: IndexWriter = index.writer(WRITER_HEAP)?;
        let reader = index
            .reader_builder()
            .reload_policy(ReloadPolicy::Manual)
            .try_into()?;
        let this = SearchIndex {
            inner: Arc::new(Inner {
                index,
                reader,
                writer: Mutex::new(writer),
                fields,
                indexed: tokio::sync::Mutex::new(seq.unwrap_or(0)),
            }),
        };
        match seq {
            None => {
                let n = this.rebuild(db).await?;
                tracing::info!(documents = n, "search index built");
            }
            Some(_) => {
                let n = this.sync(db).await?;
                if n > 0 {
                    tracing::info!(documents = n, "search index caught up");
                }
                let head = *this.inner.indexed.lock().await;
                store::changes::prune(db, head).await?;
            }
        }
        Ok(this)
    }

    /// Applies every change committed after the last indexed one, commits and reloads the
    /// reader. Returns the number of contents re-indexed.
    pub async fn sync(&self, db: &Db) -> Result<usize, SearchError> {
        let mut indexed = self.inner.indexed.lock().await;
        let mut total = 0;
        loop {
            let changes = store::changes::since(db, *indexed, BATCH).await?;
            let Some(&(max_seq, _)) = changes.last() else {
                break;
            };
            let mut ids: Vec<i64> = changes.iter().map(|c| c.1).collect();
            ids.sort_unstable();
            ids.dedup();
            let sources = store::contents::search_sources(db, Some(&ids)).await?;
            let inner = self.inner.clone();
            let n = ids.len();
            tokio::task::spawn_blocking(move || inner.apply(Some(&ids), &sources, max_seq))
                .await
                .map_err(|e| SearchError::Task(e.to_string()))??;
            *indexed = max_seq;
            total += n;
            if (changes.len() as i64) < BATCH {
                break;
            }
        }
        Ok(total)
    }

    /// Re-creates the index from every content in the database. Returns the number of
    /// documents indexed.
    pub async fn rebuild(&self, db: &Db) -> Result<usize, SearchError> {
        let mut indexed = self.inner.indexed.lock().await;
        // Changes after `head` are applied by the next sync even if `sources` saw them.
        let head = store::changes::head(db).await?;
        let sources = store::contents::search_sources(db, None).await?;
        let n = sources.len();
        let inner = self.inner.clone();
        tokio::task::spawn_blocking(move || inner.apply(None, &sources, head))
            .await
            .map_err(|e| SearchError::Task(e.to_string()))??;
        *indexed = head;
        store::changes::prune(db, head).await?;
        Ok(n)
    }

    /// Searches `query` (tantivy query syntax, parsed leniently; words are ANDed), among the
    /// contents assigned to one of `models` when given (an empty list finds nothing).
    /// Blocking: call from a blocking context.
    pub fn search(
        &self,
        query: &str,
        models: Option<&[i64]>,
        limit: usize,
        offset: usize,
    ) -> Result<SearchResults, SearchError> {
        let inner = &self.inner;
        let f = inner.fields;
        if query.trim().is_empty() || models.is_some_and(|m| m.is_empty()) {
            return Ok(SearchResults {
                total: 0,
                hits: Vec::new(),
            });
        }
        let mut parser = QueryParser::for_index(
            &inner.index,
            vec![f.title, f.caption, f.body, f.attachments, f.models],
        );
        parser.set_conjunction_by_default();
        parser.set_field_boost(f.title, 3.0);
        parser.set_field_boost(f.caption, 2.0);
        parser.set_field_boost(f.models, 1.5);
        let (text_query, _errors) = parser.parse_query_lenient(query);
        let query: Box<dyn Query> = match models {
            Some(ms) => {
                let any_model: Vec<(Occur, Box<dyn Query>)> = ms
                    .iter()
                    .map(|m| {
                        let term = Term::from_field_u64(f.model_id, (*m).max(0) as u64);
                        let q: Box<dyn Query> =
                            Box::new(TermQuery::new(term, IndexRecordOption::Basic));
                        (Occur::Should, q)
                    })
                    .collect();
                Box::new(BooleanQuery::new(vec![
                    (Occur::Must, text_query.box_clone()),
                    (Occur::Must, Box::new(BooleanQuery::new(any_model))),
                ]))
            }
            None => text_query.box_clone(),
        };
        let searcher = inner.reader.searcher();
        let (top, total) = searcher.search(
            &query,
            &(
                TopDocs::with_limit(limit.max(1))
                    .and_offset(offset)
                    .order_by_score(),
                Count,
            ),
        )?;
        let mut body_snippets = SnippetGenerator::create(&searcher, &*query, f.body)?;
        body_snippets.set_max_num_chars(240);
        let mut title_snippets = SnippetGenerator::create(&searcher, &*query, f.title)?;
        title_snippets.set_max_num_chars(400);
        let mut hits = Vec::with_capacity(top.len());
        for (score, addr) in top {
            let doc: TantivyDocument = searcher.doc(addr)?;
            let text = |field: Field| {
                doc.get_first(field)
                    .and_then(|v| v.as_str())
                    .unwrap_or_default()
                    .to_string()
            };
            let id = doc
                .get_first(f.id)
                .and_then(|v| v.as_u64())
                .unwrap_or_default() as i64;
            let title = text(f.title);
            let caption = text(f.caption);
            let title_html = whole_highlighted(&title, &title_snippets.snippet(&title));
            let mut snippet_html = body_snippets.snippet_from_doc(&doc).to_html();
            if snippet_html.is_empty() {
                let body = text(f.body);
                let start: String = if caption.is_empty() {
                    body.chars().take(240).collect()
                } else {
                    caption.chars().take(240).collect()
                };
                snippet_html = crate::wiki::diff::escape(&start);
            }
            hits.push(SearchHit {
                id,
                title,
                title_html,
                caption,
                snippet_html,
                score,
            });
        }
        Ok(SearchResults { total, hits })
    }

    /// Number of documents visible to searches.
    pub fn num_docs(&self) -> u64 {
        self.inner.reader.searcher().num_docs()
    }

    /// Highest change sequence applied.
    pub async fn indexed_seq(&self) -> i64 {
        *self.inner.indexed.lock().await
    }
}

impl Inner {
    /// Replaces the documents of `ids` (all documents with `None`) by `sources`, commits
    /// with `seq` as payload and reloads the reader.
    fn apply(
        &self,
        ids: Option<&[i64]>,
        sources: &[SearchSource],
        seq: i64,
    ) -> Result<(), SearchError> {
        let mut writer = lock(&self.writer);
        let result = (|| -> Result<(), SearchError> {
            match ids {
                None => {
                    writer.delete_all_documents()?;
                }
                Some(ids) => {
                    for id in ids {
                        writer.delete_term(Term::from_field_u64(self.fields.id, *id as u64));
                    }
                }
            }
            for src in sources {
                writer.add_document(to_document(&self.fields, src))?;
            }
            let mut commit = writer.prepare_commit()?;
            let payload = serde_json::to_string(&Payload {
                v: SCHEMA_VERSION,
                seq,
            })
            .unwrap_or_default();
            commit.set_payload(&payload);
            commit.commit()?;
            Ok(())
        })();
        if result.is_err() {
            let _ = writer.rollback();
        }
        result?;
        self.reader.reload()?;
        Ok(())
    }
}

/// Opens or creates the index; returns it with the sequence of its last commit, or `None`
/// when it must be (re)built from scratch.
fn open_index(dir: &Path) -> Result<(Index, Option<i64>), SearchError> {
    let (schema, _) = schema();
    std::fs::create_dir_all(dir)?;
    let existing = if dir.join("meta.json").exists() {
        match Index::open_in_dir(dir) {
            Ok(index) if index.schema() == schema => Some(index),
            Ok(_) => {
                tracing::warn!("search index schema changed: rebuilding");
                None
            }
            Err(e) => {
                tracing::warn!(error = %e, "search index unreadable: rebuilding");
                None
            }
        }
    } else {
        None
    };
    let (index, seq) = match existing {
        Some(index) => {
            let payload = index
                .load_metas()?
                .payload
                .and_then(|p| serde_json::from_str::<Payload>(&p).ok());
            let seq = payload.filter(|p| p.v == SCHEMA_VERSION).map(|p| p.seq);
            (index, seq)
        }
        None => {
            // Start from an empty directory: remove whatever an old index left.
            for entry in std::fs::read_dir(dir)? {
                let path = entry?.path();
                if path.is_dir() {
                    std::fs::remove_dir_all(&path)?;
                } else {
                    std::fs::remove_file(&path)?;
                }
            }
            (Index::create_in_dir(dir, schema)?, None)
        }
    };
    index.tokenizers().register(TOKENIZER, analyzer());
    Ok((index, seq))
}

/// All of `text` as HTML, with the snippet's matches in `<b>`: a snippet's fragment ends at
/// its last match ("Lion paw (<b>north</b>" for "Lion paw (north)"), which is right for a
/// body excerpt but not for a title, which is shown whole.
fn whole_highlighted(text: &str, snippet: &tantivy::snippet::Snippet) -> String {
    use crate::wiki::diff::escape;
    let base = snippet.fragment_range().start;
    let mut ranges: Vec<std::ops::Range<usize>> = snippet
        .highlighted()
        .iter()
        .map(|r| base + r.start..base + r.end)
        .filter(|r| r.start < r.end && r.end <= text.len())
        .filter(|r| text.is_char_boundary(r.start) && text.is_char_boundary(r.end))
        .collect();
    ranges.sort_by_key(|r| r.start);
    let mut html = String::with_capacity(text.len() + 7 * ranges.len());
    let mut at = 0;
    for r in ranges {
        if r.end <= at {
            continue;
        }
        let start = r.start.max(at);
        html.push_str(&escape(&text[at..start]));
        html.push_str("<b>");
        html.push_str(&escape(&text[start..r.end]));
        html.push_str("</b>");
        at = r.end;
    }
    html.push_str(&escape(&text[at..]));
    html
}
