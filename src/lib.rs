//! meshwiki: a knowledge server that attaches wiki information to regions of huge 3D scans.
//!
//! The server crate: the application layer ([`app`], where use cases are orchestrated), the
//! relational store ([`store`]), full-text search ([`search`]), wiki rendering ([`wiki`]),
//! background LOD builds ([`jobs`]), server-side rendering ([`render`]) and the HTTP layer
//! ([`web`]). Geometry lives in `meshwiki-engine`. Dependencies point downwards only (see
//! `docs/ARCHITECTURE.md`).

pub mod app;
pub mod blobs;
pub mod config;
pub mod jobs;
pub mod render;
pub mod search;
pub mod seed;
pub mod store;
pub mod terminal;
pub mod throttle;
pub mod upload_sessions;
pub mod uploads;
pub mod web;
pub mod wiki;

pub use config::Settings;

/// Current time as an RFC 3339 UTC string with millisecond precision (the format of every
/// timestamp column).
pub fn now_rfc3339() -> String {
    let now = time::OffsetDateTime::now_utc();
    let format = time::macros::format_description!(
        "[year]-[month]-[day]T[hour]:[minute]:[second].[subsecond digits:3]Z"
    );
    now.format(&format)
        .unwrap_or_else(|_| now.unix_timestamp().to_string())
}

/// Removes a file, or a folder with everything in it; a missing one is fine.
pub fn remove_file_or_dir(path: &std::path::Path) -> std::io::Result<()> {
    let result = match std::fs::symlink_metadata(path) {
        Ok(m) if m.is_dir() => std::fs::remove_dir_all(path),
        Ok(_) => std::fs::remove_file(path),
        Err(e) => Err(e),
    };
    match result {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        other => other,
    }
}

/// Current time in Unix seconds.
pub fn now_unix() -> i64 {
    time::OffsetDateTime::now_utc().unix_timestamp()
}

/// `n` random bytes from the operating system, hex-encoded.
pub fn random_hex(n: usize) -> String {
    let mut buf = vec![0u8; n];
    // The OS random source failing is not recoverable for a security token.
    getrandom::fill(&mut buf).expect("operating system random source unavailable");
    hex(&buf)
}

/// Lower-case hex encoding.
pub fn hex(bytes: &[u8]) -> String {
    const DIGITS: &[u8; 16] = b"0123456789abcdef";
    let mut s = String::with_capacity(bytes.len() * 2);
    for b in bytes {
        s.push(DIGITS[(b >> 4) as usize] as char);
        s.push(DIGITS[(b & 15) as usize] as char);
    }
    s
}

/// SHA-256 of `data`, hex-encoded.
pub fn sha256_hex(data: &[u8]) -> String {
    use sha2::Digest;
    hex(&sha2::Sha256::digest(data))
}
