//! Contents: validating and saving an edit. An edit made on a revision that is no longer the
//! current one is merged three-way with what was saved since ([`crate::wiki::merge`]): a clean
//! merge can be saved at once (the page does, as wikis do), and a conflict comes back with the
//! three versions and the merge, its overlaps between markers, for a person to resolve.

use super::{App, AppError};
use crate::app::events::{Event, EventKind};
use crate::store::StoreError;
use crate::store::contents::{self, Content, ContentEdit, Revision};
use crate::wiki::merge::{self, Fields, Merged};

/// How many times a clean merge is retried when yet another save lands meanwhile.
const MERGE_ATTEMPTS: usize = 4;

/// An edit based on a stale revision that was not saved.
#[derive(Debug, Clone)]
pub struct EditConflict {
    /// Number of the revision the edit was based on.
    pub base_number: i64,
    /// That revision (absent when the number names none).
    pub base: Option<Revision>,
    /// The current revision ("theirs").
    pub theirs: Revision,
    /// The rejected edit ("yours").
    pub yours: ContentEdit,
    /// The three-way merge of yours and theirs against the base (absent without a base).
    pub merged: Option<Merged>,
}

/// What to do with a clean merge of a stale edit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OnStale {
    /// Report it (the API: the client decides).
    Report,
    /// Save it (the page, as MediaWiki does); conflicts are still reported.
    SaveCleanMerge,
}

/// A saved edit.
#[derive(Debug, Clone)]
pub struct Saved {
    /// The content as saved.
    pub content: Content,
    /// The revision the edit was merged with, when it was based on an older one.
    pub merged_with: Option<Revision>,
}

impl App {
    /// Checks an edit against the limits, and that it holds no unresolved conflict marker.
    pub fn validate_edit(&self, edit: &ContentEdit) -> Result<(), AppError> {
        let l = &self.settings.limits;
        edit.validate(l.title_chars, l.body_bytes)?;
        for (field, text) in [
            ("title", &edit.title),
            ("caption", &edit.caption),
            ("body", &edit.body),
        ] {
            if merge::has_conflict_markers(text) {
                return Err(AppError::invalid(format!(
                    "the {field} still holds an edit conflict (<<<<<<< … ======= … >>>>>>>): \
                     keep what should stay and remove the markers"
                )));
            }
        }
        Ok(())
    }

    /// Saves `edit` of content `id`, made on revision `base`, as a new revision by `user_id`
    /// (`thumbnail`: `Some` changes it). A stale base is merged three-way with the current
    /// revision: with [`OnStale::SaveCleanMerge`] a clean merge is saved, anything else is
    /// [`AppError::EditConflict`].
    pub async fn save_content(
        &self,
        user_id: i64,
        id: i64,
        base: i64,
        edit: &ContentEdit,
        thumbnail: Option<Option<i64>>,
        on_stale: OnStale,
    ) -> Result<Saved, AppError> {
        self.validate_edit(edit)?;
        let (mut base, mut edit) = (base, edit.clone());
        let mut merged_with = None;
        for _ in 0..MERGE_ATTEMPTS {
            match contents::update(&self.db, id, base, &edit, thumbnail, user_id).await {
                Ok(content) => {
                    self.sync_search().await;
                    self.events
                        .publish(Event::content(EventKind::ContentUpdated, content.id));
                    return Ok(Saved {
                        content,
                        merged_with,
                    });
                }
                Err(StoreError::StaleRevision {
                    base: stale,
                    current,
                }) => {
                    let conflict = self.conflict(id, stale, *current, &edit).await?;
                    match (&conflict.merged, on_stale) {
                        (Some(m), OnStale::SaveCleanMerge) if m.is_clean() => {
                            edit = ContentEdit {
                                title: m.title.clone(),
                                caption: m.caption.clone(),
                                body: m.body.clone(),
                                comment: edit.comment.clone(),
                            };
                            base = conflict.theirs.number;
                            merged_with = Some(conflict.theirs);
                        }
                        _ => return Err(AppError::EditConflict(Box::new(conflict))),
                    }
                }
                Err(e) => return Err(e.into()),
            }
        }
        Err(AppError::Conflict(format!(
            "content {id} keeps changing: {MERGE_ATTEMPTS} saves landed while merging; try again"
        )))
    }

    /// The conflict of `yours` (made on revision `base`) with the current revision `theirs`.
    pub async fn conflict(
        &self,
        id: i64,
        base: i64,
        theirs: Revision,
        yours: &ContentEdit,
    ) -> Result<EditConflict, AppError> {
        let base_rev = match contents::revision(&self.db, id, base).await {
            Ok(r) => Some(r),
            Err(StoreError::NotFound(_)) => None,
            Err(e) => return Err(e.into()),
        };
        let merged = base_rev.as_ref().map(|b| {
            merge::merge(
                Fields {
                    title: &b.title,
                    caption: &b.caption,
                    body: &b.body,
                },
                Fields {
                    title: yours.title.trim(),
                    caption: &yours.caption,
                    body: &yours.body,
                },
                Fields {
                    title: &theirs.title,
                    caption: &theirs.caption,
                    body: &theirs.body,
                },
            )
        });
        Ok(EditConflict {
            base_number: base,
            base: base_rev,
            theirs,
            yours: yours.clone(),
            merged,
        })
    }
}
