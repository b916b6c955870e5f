//! Wiki text: Markdown rendering with sanitising ([`markdown`]) and revision diffs ([`diff`]).

pub mod diff;
pub mod markdown;
