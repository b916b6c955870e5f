//! The server crate's layers (docs/ARCHITECTURE.md): every module of `src/` names what it
//! uses as `crate::…` (or, in the binary, `meshwiki::…`); this reads those paths from the
//! source and checks that they point only downwards: web/cli → app → jobs → render, search,
//! seed → store, blobs → config, uploads, throttle, wiki. Within `web`, the pages may use the
//! API modules, never the other way round.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// Rank of each top-level module: a module may use only modules of a lower rank (and
/// itself). A new module must be placed here.
const LAYERS: &[(&str, u8)] = &[
    ("cli", 6),
    ("web", 5),
    ("app", 4),
    ("jobs", 3),
    ("render", 2),
    ("search", 2),
    ("seed", 2),
    ("terminal", 4),
    ("store", 1),
    ("blobs", 1),
    ("config", 0),
    ("uploads", 0),
    ("upload_sessions", 0),
    ("throttle", 0),
    ("wiki", 0),
];

/// Within `web`: the pages (HTML) sit above the API modules and the shared plumbing.
const WEB_LAYERS: &[(&str, u8)] = &[("pages", 1)];

fn rank(table: &[(&str, u8)], module: &str) -> Option<u8> {
    table.iter().find(|(m, _)| *m == module).map(|(_, r)| *r)
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).expect("reading src/") {
        let path = entry.expect("reading src/").path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The source without comments and string literals (so doc links and messages do not count).
fn code_only(src: &str) -> String {
    let b = src.as_bytes();
    let mut out = String::with_capacity(src.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'/' && b.get(i + 1) == Some(&b'/') {
            while i < b.len() && b[i] != b'\n' {
                i += 1;
            }
        } else if b[i] == b'/' && b.get(i + 1) == Some(&b'*') {
            let mut depth = 0;
            while i < b.len() {
                if b[i] == b'/' && b.get(i + 1) == Some(&b'*') {
                    depth += 1;
                    i += 2;
                } else if b[i] == b'*' && b.get(i + 1) == Some(&b'/') {
                    depth -= 1;
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    i += 1;
                }
            }
        } else if b[i] == b'"' {
            // A plain string; raw strings (r"…", r#"…"#) hold no `crate::` paths here.
            i += 1;
            while i < b.len() && b[i] != b'"' {
                if b[i] == b'\\' {
                    i += 1;
                }
                i += 1;
            }
            i += 1;
            out.push_str("\"\"");
        } else if b[i] == b'\'' && b.get(i + 2) == Some(&b'\'') {
            // A character literal such as '"' or '{'.
            i += 3;
        } else if b[i] == b'\'' && b.get(i + 1) == Some(&b'\\') {
            i += 2;
            while i < b.len() && b[i] != b'\'' {
                i += 1;
            }
            i += 1;
        } else {
            let start = i;
            while i < b.len() && !matches!(b[i], b'/' | b'"' | b'\'') {
                i += 1;
            }
            if i == start {
                out.push(b[i] as char);
                i += 1;
            } else {
                out.push_str(&src[start..i]);
            }
        }
    }
    out
}

fn ident_at(s: &str) -> &str {
    let end = s
        .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
        .unwrap_or(s.len());
    &s[..end]
}

/// The first path segments after each `prefix` (`crate::` or `meshwiki::`), including every
/// item of a `prefix{a::…, b}` group.
fn used_roots(code: &str, prefix: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    let mut rest = code;
    while let Some(at) = rest.find(prefix) {
        let before = rest[..at].chars().next_back();
        rest = &rest[at + prefix.len()..];
        if before.is_some_and(|c| c.is_ascii_alphanumeric() || c == '_' || c == ':') {
            continue;
        }
        let t = rest.trim_start();
        if let Some(group) = t.strip_prefix('{') {
            // Items at depth 1 of the group.
            let mut depth = 1;
            let mut item_start = true;
            for (i, c) in group.char_indices() {
                match c {
                    '{' => depth += 1,
                    '}' => {
                        depth -= 1;
                        if depth == 0 {
                            break;
                        }
                    }
                    ',' if depth == 1 => item_start = true,
                    c if depth == 1 && item_start && !c.is_whitespace() => {
                        item_start = false;
                        let id = ident_at(&group[i..]);
                        if !id.is_empty() {
                            out.insert(id.to_string());
                        }
                    }
                    _ => {}
                }
            }
        } else {
            let id = ident_at(t);
            if !id.is_empty() {
                out.insert(id.to_string());
            }
        }
    }
    out
}

/// The modules `lib.rs` declares.
fn crate_modules(src: &Path) -> BTreeSet<String> {
    let lib = std::fs::read_to_string(src.join("lib.rs")).expect("reading src/lib.rs");
    code_only(&lib)
        .lines()
        .filter_map(|l| {
            let l = l.trim();
            let l = l.strip_prefix("pub ").unwrap_or(l);
            l.strip_prefix("mod ")
                .map(|m| m.trim_end_matches(';').trim().to_string())
        })
        .collect()
}

#[test]
fn layers_point_downwards() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let src = root.join("src");
    let modules = crate_modules(&src);
    for m in &modules {
        assert!(
            rank(LAYERS, m).is_some(),
            "src/lib.rs declares `{m}`, which tests/server/layers.rs does not place in a layer"
        );
    }
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    files.sort();
    let mut violations = Vec::new();
    let mut checked = 0;
    for file in &files {
        let rel = file.strip_prefix(&src).expect("under src/");
        let parts: Vec<String> = rel
            .components()
            .map(|c| c.as_os_str().to_string_lossy().into_owned())
            .collect();
        let first = parts[0].trim_end_matches(".rs");
        let (module, prefix) = match first {
            "lib" => continue,
            "main" | "cli" => ("cli", "meshwiki::"),
            m => (m, "crate::"),
        };
        let own = rank(LAYERS, module).unwrap_or_else(|| {
            panic!("{} is in no layer of tests/server/layers.rs", rel.display())
        });
        let code = code_only(&std::fs::read_to_string(file).expect("reading a source file"));
        let used = used_roots(&code, prefix);
        checked += 1;
        for u in &used {
            if u == module || !modules.contains(u.as_str()) {
                continue; // itself, or an item of the crate root (`now_rfc3339`, `Settings`)
            }
            let theirs = rank(LAYERS, u).unwrap_or(u8::MAX);
            if theirs >= own {
                violations.push(format!("{} ({module}) uses {u}", rel.display()));
            }
        }
        // Inside web: which submodule this file belongs to, and which it uses via `super::`
        // or `crate::web::`.
        if module == "web" && parts.len() > 1 {
            let sub = parts[1].trim_end_matches(".rs");
            let own = rank(WEB_LAYERS, sub).unwrap_or(0);
            let mut used = used_roots(&code, "crate::web::");
            if parts.len() == 2 {
                used.extend(used_roots(&code, "super::"));
            } else {
                used.extend(used_roots(&code, "super::super::"));
            }
            for u in used {
                if u != sub && rank(WEB_LAYERS, &u).unwrap_or(0) > own {
                    violations.push(format!("{} (web::{sub}) uses web::{u}", rel.display()));
                }
            }
        }
    }
    assert!(checked > 50, "only {checked} source files were read");
    assert!(
        violations.is_empty(),
        "imports that point upwards (see docs/ARCHITECTURE.md):\n{}",
        violations.join("\n")
    );
}

#[test]
fn the_reader_finds_paths_in_groups_and_ignores_comments() {
    let code = code_only(
        "use crate::{store::{self, Db}, web::events};\n// crate::jobs in a comment\n\
         let s = \"crate::render\"; let c = '\"'; x = crate::app::f(); y = notcrate::seed;",
    );
    let used = used_roots(&code, "crate::");
    let expected: BTreeSet<String> = ["app", "store", "web"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    assert_eq!(used, expected);
}
