//! Wiki text: Markdown rendering with sanitising ([`markdown`]), revision diffs ([`diff`])
//! and the three-way merge of concurrent edits ([`merge`]).

pub mod diff;
pub mod markdown;
pub mod merge;
