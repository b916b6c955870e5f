//! Line diff with word-level emphasis between two texts (any two revisions), rendered as an
//! HTML table, plus a unified diff for scripts.

use similar::{ChangeTag, TextDiff};

/// A rendered diff.
#[derive(Debug, Clone, Default, serde::Serialize, utoipa::ToSchema)]
#[schema(as = TextDiff)]
pub struct Diff {
    /// HTML table (`<table class="diff">`), escaped and safe to embed.
    pub html: String,
    /// Unified diff text.
    pub unified: String,
    /// Lines added.
    pub added: usize,
    /// Lines removed.
    pub removed: usize,
}

/// Escapes text for HTML.
pub fn escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

/// Diffs `old` against `new` by lines, emphasising changed words inside changed lines;
/// `context` unchanged lines are kept around each change.
pub fn diff(old: &str, new: &str, context: usize) -> Diff {
    let text = TextDiff::configure()
        .algorithm(similar::Algorithm::Patience)
        .timeout(std::time::Duration::from_secs(2))
        .diff_lines(old, new);
    let mut html = String::from("<table class=\"diff\"><tbody>");
    let (mut added, mut removed) = (0, 0);
    let groups = text.grouped_ops(context);
    if groups.is_empty() {
        html.push_str("<tr class=\"diff-same\"><td colspan=\"3\">No differences.</td></tr>");
    }
    for (i, group) in groups.iter().enumerate() {
        if i > 0 {
            html.push_str("<tr class=\"diff-gap\"><td></td><td></td><td>…</td></tr>");
        }
        for op in group {
            for change in text.iter_inline_changes(op) {
                let (class, sign) = match change.tag() {
                    ChangeTag::Delete => {
                        removed += 1;
                        ("diff-del", "−")
                    }
                    ChangeTag::Insert => {
                        added += 1;
                        ("diff-ins", "+")
                    }
                    ChangeTag::Equal => ("diff-ctx", " "),
                };
                let num = |n: Option<usize>| n.map(|n| (n + 1).to_string()).unwrap_or_default();
                html.push_str(&format!(
                    "<tr class=\"{class}\"><td class=\"ln\">{}</td><td class=\"ln\">{}</td><td class=\"code\"><span class=\"sign\">{sign}</span>",
                    num(change.old_index()),
                    num(change.new_index()),
                ));
                for (emphasized, value) in change.iter_strings_lossy() {
                    let value = value.trim_end_matches(['\n', '\r']);
                    if emphasized {
                        html.push_str("<mark>");
                        html.push_str(&escape(value));
                        html.push_str("</mark>");
                    } else {
                        html.push_str(&escape(value));
                    }
                }
                html.push_str("</td></tr>");
            }
        }
    }
    html.push_str("</tbody></table>");
    let unified = text
        .unified_diff()
        .context_radius(context)
        .header("old", "new")
        .to_string();
    Diff {
        html,
        unified,
        added,
        removed,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn marks_changed_words_and_escapes() {
        let d = diff("a <b>\nsame\nold word\n", "a <b>\nsame\nnew word\n", 3);
        assert_eq!((d.added, d.removed), (1, 1));
        assert!(d.html.contains("<mark>old</mark>"), "{}", d.html);
        assert!(d.html.contains("<mark>new</mark>"), "{}", d.html);
        assert!(d.html.contains("a &lt;b&gt;"));
        assert!(d.unified.contains("-old word"));
    }

    #[test]
    fn identical_texts() {
        let d = diff("x\n", "x\n", 3);
        assert!(d.html.contains("No differences"));
        assert_eq!((d.added, d.removed), (0, 0));
    }
}
