//! Three-way merge of concurrent edits of a content, as wikis do (MediaWiki's edit conflict
//! resolution, diff3): an edit made on revision `base` while a colleague saved `theirs` is
//! merged line by line against the common base (diffy's diff3 merge). Changes to different
//! lines combine on their own; a line both changed differently is a *conflict*, kept with both
//! versions between markers for a person to resolve — never decided for either side.
//!
//! Markers in the body, one per line as `git merge-file` writes them:
//!
//! ```text
//! <<<<<<< yours
//! your lines
//! =======
//! their lines
//! >>>>>>> theirs
//! ```
//!
//! Single-line fields (title, caption) take the changed side when only one side changed; when
//! both changed them differently the field holds `<<<<<<< yours: … ======= theirs: … >>>>>>>`.
//! A text still holding a marker is refused on save ([`has_conflict_markers`]).

use serde::Serialize;
use utoipa::ToSchema;

/// Start of a conflict.
pub const START: &str = "<<<<<<<";
/// Between the two versions of a conflict.
pub const MIDDLE: &str = "=======";
/// End of a conflict.
pub const END: &str = ">>>>>>>";

/// The merge of two concurrent edits of a content.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, ToSchema)]
pub struct Merged {
    /// Merged title (with markers when both changed it differently).
    pub title: String,
    /// Merged caption (likewise).
    pub caption: String,
    /// Merged Markdown body, conflicts between markers.
    pub body: String,
    /// Number of conflicts left to resolve (0: the merge is clean).
    pub conflicts: usize,
}

impl Merged {
    /// Whether the edits combined without a conflict.
    pub fn is_clean(&self) -> bool {
        self.conflicts == 0
    }
}

/// One version of the three fields.
#[derive(Debug, Clone, Copy)]
pub struct Fields<'a> {
    /// Title.
    pub title: &'a str,
    /// Caption.
    pub caption: &'a str,
    /// Markdown body.
    pub body: &'a str,
}

/// Merges `yours` (made on `base`) with `theirs` (saved since on top of `base`).
pub fn merge(base: Fields<'_>, yours: Fields<'_>, theirs: Fields<'_>) -> Merged {
    let (title, t) = merge_line(base.title, yours.title, theirs.title);
    let (caption, c) = merge_line(base.caption, yours.caption, theirs.caption);
    let (body, b) = merge_text(base.body, yours.body, theirs.body);
    Merged {
        title,
        caption,
        body,
        conflicts: t + c + b,
    }
}

/// Line-by-line three-way merge of a multi-line text: the merged text and its number of
/// conflicts.
pub fn merge_text(base: &str, yours: &str, theirs: &str) -> (String, usize) {
    if yours == theirs || theirs == base {
        return (yours.to_string(), 0);
    }
    if yours == base {
        return (theirs.to_string(), 0);
    }
    // diffy works on lines: the texts as the browser sends them (CRLF) become LF first, so a
    // line ending is never a difference.
    let (base, yours, theirs) = (lf(base), lf(yours), lf(theirs));
    let mut options = diffy::MergeOptions::new();
    options
        .set_conflict_style(diffy::ConflictStyle::Merge)
        .set_incomplete_hunk_style(diffy::IncompleteHunkStyle::Git);
    match options.merge(&base, &yours, &theirs) {
        Ok(text) => (text, 0),
        Err(marked) => {
            // diffy labels the sides "ours" and "theirs": here "ours" is the person saving.
            let mut conflicts = 0;
            let mut out = String::with_capacity(marked.len());
            for line in marked.split_inclusive('\n') {
                let (text, newline) = match line.strip_suffix('\n') {
                    Some(t) => (t, "\n"),
                    None => (line, ""),
                };
                if text == "<<<<<<< ours" {
                    conflicts += 1;
                    out.push_str(START);
                    out.push_str(" yours");
                } else {
                    out.push_str(text);
                }
                out.push_str(newline);
            }
            (out, conflicts.max(1))
        }
    }
}

/// Three-way merge of a single-line field: the changed side when only one side changed, else
/// both between markers on one line.
pub fn merge_line(base: &str, yours: &str, theirs: &str) -> (String, usize) {
    if yours == theirs || theirs == base {
        (yours.to_string(), 0)
    } else if yours == base {
        (theirs.to_string(), 0)
    } else {
        (
            format!("{START} yours: {yours} {MIDDLE} theirs: {theirs} {END}"),
            1,
        )
    }
}

/// Whether `text` still holds a conflict marker of [`merge`] (a single-line field's, or a
/// body line starting with one).
pub fn has_conflict_markers(text: &str) -> bool {
    text.contains(&format!("{START} yours"))
        || text
            .lines()
            .any(|l| l.starts_with(START) || l == MIDDLE || l.starts_with(&format!("{END} theirs")))
}

fn lf(s: &str) -> String {
    s.replace("\r\n", "\n")
}

#[cfg(test)]
mod tests {
    use super::*;

    const BASE: &str =
        "# Apse\n\nThe apse was rebuilt in 1420.\n\nIts vault is painted.\n\nThe altar is lost.\n";

    #[test]
    fn edits_of_different_lines_combine() {
        let theirs = BASE.replace("in 1420.", "in 1420, as recorded during the May survey.");
        let yours = BASE.replace("is painted.", "is painted with stars.");
        let (merged, conflicts) = merge_text(BASE, &yours, &theirs);
        assert_eq!(conflicts, 0);
        assert!(merged.contains("during the May survey"), "{merged}");
        assert!(merged.contains("painted with stars"), "{merged}");
        assert!(!has_conflict_markers(&merged));
    }

    #[test]
    fn an_overlap_is_a_conflict_with_both_versions() {
        let theirs = BASE.replace("The altar is lost.", "The altar was moved to the museum.");
        let yours = BASE.replace("The altar is lost.", "The altar burnt in 1944.");
        let (merged, conflicts) = merge_text(BASE, &yours, &theirs);
        assert_eq!(conflicts, 1);
        let start = merged.find("<<<<<<< yours\n").expect("start marker");
        let middle = merged.find("\n=======\n").expect("middle marker");
        let end = merged.find("\n>>>>>>> theirs").expect("end marker");
        assert!(start < middle && middle < end);
        assert!(merged[start..middle].contains("burnt in 1944"));
        assert!(merged[middle..end].contains("moved to the museum"));
        // What both kept is outside the conflict, once.
        assert_eq!(merged.matches("The apse was rebuilt in 1420.").count(), 1);
        assert!(has_conflict_markers(&merged));
    }

    #[test]
    fn one_sided_and_identical_changes_are_taken_as_they_are() {
        let changed = BASE.replace("1420", "1421");
        assert_eq!(merge_text(BASE, BASE, &changed), (changed.clone(), 0));
        assert_eq!(merge_text(BASE, &changed, BASE), (changed.clone(), 0));
        assert_eq!(merge_text(BASE, &changed, &changed), (changed.clone(), 0));
        // Line endings are not differences.
        let crlf = BASE.replace('\n', "\r\n").replace("painted", "gilded");
        let theirs = BASE.replace("lost", "found");
        let (merged, conflicts) = merge_text(BASE, &crlf, &theirs);
        assert_eq!(conflicts, 0, "{merged}");
        assert!(merged.contains("gilded") && merged.contains("found"));
    }

    #[test]
    fn texts_without_a_final_newline_merge_and_conflict_on_whole_lines() {
        let (merged, conflicts) = merge_text("a\nb\nc\nd", "a\nB\nc\nd", "a\nb\nc\nD");
        assert_eq!((merged.as_str(), conflicts), ("a\nB\nc\nD", 0));
        // Changes of adjacent lines overlap (as in diff3 and git): the person decides.
        assert_eq!(merge_text("a\nb\nc", "a\nB\nc", "a\nb\nC").1, 1);
        let (merged, conflicts) = merge_text("a\nb", "a\nyours", "a\ntheirs");
        assert_eq!(conflicts, 1);
        assert!(merged.lines().any(|l| l == "======="), "{merged}");
        assert!(merged.lines().any(|l| l == "yours") && merged.lines().any(|l| l == "theirs"));
    }

    #[test]
    fn fields_merge_on_their_own() {
        let base = Fields {
            title: "Apse",
            caption: "East end",
            body: BASE,
        };
        let yours = Fields {
            title: "Apse",
            caption: "East end of the nave",
            body: BASE,
        };
        let theirs = Fields {
            title: "The apse",
            caption: "East end",
            body: BASE,
        };
        let m = merge(base, yours, theirs);
        assert!(m.is_clean());
        assert_eq!(
            (m.title.as_str(), m.caption.as_str()),
            ("The apse", "East end of the nave")
        );
        let both = Fields {
            title: "Chancel",
            ..yours
        };
        let m = merge(base, both, theirs);
        assert_eq!(m.conflicts, 1);
        assert_eq!(
            m.title,
            "<<<<<<< yours: Chancel ======= theirs: The apse >>>>>>>"
        );
        assert!(has_conflict_markers(&m.title));
        assert!(!has_conflict_markers("a title with <<< arrows"));
    }
}
