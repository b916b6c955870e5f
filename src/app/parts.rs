//! Parts: every create, edit and delete — through a selection or `/api/v1/parts` — goes
//! through here to the store's one writer (`store::parts`), so each is a revision with its
//! author, time and comment (`/api/v1/parts/{id}/revisions`), an audit entry, and an event
//! for live viewers; a deletion also brings the search index up to date. A part without a
//! camera or thumbnail gets them from the part views in the background.

use super::events::{Event, EventKind};
use super::{App, AppError};
use crate::store::parts::{
    self, Action, NewPart, Part, PartPatch, PartState, Provenance, apply_patch, state_of_new,
};

impl App {
    /// Creates a part from the API's fields (an editor's).
    pub async fn create_part(
        &self,
        user_id: i64,
        model_id: i64,
        new: &NewPart,
    ) -> Result<Part, AppError> {
        let limit = self.settings.limits.part_vertices;
        let state = state_of_new(new, limit)?;
        let prov = Provenance::by(user_id, new.comment.clone());
        self.create_part_with(model_id, &state, &prov).await
    }

    /// Creates a part in `state` and announces it.
    pub async fn create_part_with(
        &self,
        model_id: i64,
        state: &PartState,
        prov: &Provenance,
    ) -> Result<Part, AppError> {
        let limit = self.settings.limits.part_vertices;
        let part = parts::create(&self.db, model_id, state, prov, limit).await?;
        self.events
            .publish(Event::part(EventKind::PartCreated, part.model_id, part.id));
        Ok(part)
    }

    /// Applies an API patch to part `id` (an editor's).
    pub async fn edit_part(
        &self,
        user_id: i64,
        id: i64,
        patch: &PartPatch,
    ) -> Result<Part, AppError> {
        let limit = self.settings.limits.part_vertices;
        let prov = Provenance::by(user_id, patch.comment.clone());
        self.change_part(
            id,
            Action::Edit,
            |s| apply_patch(s, patch, limit),
            None,
            &prov,
        )
        .await
    }

    /// Changes part `id` by `change` (see `store::parts::update`) and announces it.
    pub async fn change_part(
        &self,
        id: i64,
        action: Action,
        change: impl FnOnce(&mut PartState) -> crate::store::Result<()>,
        expected_updated_at: Option<&str>,
        prov: &Provenance,
    ) -> Result<Part, AppError> {
        let limit = self.settings.limits.part_vertices;
        let part = parts::update(
            &self.db,
            id,
            action,
            change,
            expected_updated_at,
            prov,
            limit,
        )
        .await?;
        self.events
            .publish(Event::part(EventKind::PartUpdated, part.model_id, part.id));
        Ok(part)
    }

    /// Deletes part `id` (its assignments go, its contents and history stay).
    pub async fn delete_part(
        &self,
        user_id: i64,
        id: i64,
        comment: Option<String>,
    ) -> Result<Part, AppError> {
        let part = parts::delete(&self.db, id, &Provenance::by(user_id, comment)).await?;
        self.sync_search().await;
        self.events
            .publish(Event::part(EventKind::PartDeleted, part.model_id, id));
        Ok(part)
    }
}
