//! Receiving uploads, for every route that takes them (attachments, scan uploads, selection
//! masks): text fields under one budget per form, and file bodies streamed to a guarded
//! temporary file in `uploads/` ([`crate::uploads::TempUpload`]), never held in memory.

use std::collections::HashMap;
use std::path::Path;

use actix_multipart::Field;
use futures_util::{Stream, StreamExt};
use sha2::Digest;
use tokio::io::AsyncWriteExt;

use super::ApiError;
use crate::uploads::TempUpload;

/// Most text (non-file) fields in one form.
pub const MAX_TEXT_FIELDS: usize = 32;
/// Most bytes of all text fields of one form together.
pub const MAX_TEXT_BYTES: usize = 256 * 1024;

/// A multipart error as a 400.
pub fn multipart_error(e: actix_multipart::MultipartError) -> ApiError {
    ApiError::bad(format!("invalid multipart upload: {e}"))
}

/// The text fields of a form, read under a count and size budget: a form may not make the
/// server buffer more than [`MAX_TEXT_BYTES`] in [`MAX_TEXT_FIELDS`] fields (413 past either).
#[derive(Debug, Default)]
pub struct TextFields {
    values: HashMap<String, String>,
    count: usize,
    bytes: usize,
}

impl TextFields {
    /// No fields yet.
    pub fn new() -> TextFields {
        TextFields::default()
    }

    /// Reads `field` (named `name`) as text of at most `max_field` bytes (400 when longer),
    /// counting it against the form's budget. A repeated name keeps the last value.
    pub async fn read(
        &mut self,
        name: String,
        field: &mut Field,
        max_field: usize,
    ) -> Result<(), ApiError> {
        self.count += 1;
        if self.count > MAX_TEXT_FIELDS {
            return Err(ApiError::PayloadTooLarge(format!(
                "a form has at most {MAX_TEXT_FIELDS} text fields"
            )));
        }
        let mut value = Vec::new();
        while let Some(chunk) = field.next().await {
            let chunk = chunk.map_err(multipart_error)?;
            self.bytes += chunk.len();
            if self.bytes > MAX_TEXT_BYTES {
                return Err(ApiError::PayloadTooLarge(format!(
                    "the form's text fields are larger than {MAX_TEXT_BYTES} bytes together"
                )));
            }
            value.extend_from_slice(&chunk);
            if value.len() > max_field {
                return Err(ApiError::bad(format!(
                    "form field {name:?} is longer than {max_field} bytes"
                )));
            }
        }
        self.values
            .insert(name, String::from_utf8_lossy(&value).into_owned());
        Ok(())
    }

    /// A field's value.
    pub fn get(&self, name: &str) -> Option<&str> {
        self.values.get(name).map(String::as_str)
    }

    /// Takes a field's value out.
    pub fn remove(&mut self, name: &str) -> Option<String> {
        self.values.remove(name)
    }
}

/// A body received into a temporary file.
#[derive(Debug)]
pub struct Spooled {
    /// The file (removed when dropped, unless persisted).
    pub temp: TempUpload,
    /// Its length.
    pub bytes: u64,
    /// SHA-256 of the bytes, when asked for.
    pub sha256: Option<String>,
}

/// Streams `body` into a new temporary file in `dir`, at most `limit` bytes (`too_large()`
/// past that), hashing it when `hash`, and syncs it. On any error the file is removed.
pub async fn spool<S>(
    dir: &Path,
    mut body: S,
    limit: u64,
    hash: bool,
    too_large: impl Fn() -> ApiError,
) -> Result<Spooled, ApiError>
where
    S: Stream<Item = Result<actix_web::web::Bytes, ApiError>> + Unpin,
{
    let temp = TempUpload::new(dir);
    let file = tokio::fs::File::create(temp.path()).await?;
    let mut out = tokio::io::BufWriter::with_capacity(1 << 20, file);
    let mut hasher = hash.then(sha2::Sha256::new);
    let mut bytes: u64 = 0;
    while let Some(chunk) = body.next().await {
        let chunk = chunk?;
        bytes += chunk.len() as u64;
        if bytes > limit {
            return Err(too_large());
        }
        if let Some(h) = &mut hasher {
            h.update(&chunk);
        }
        out.write_all(&chunk).await?;
    }
    out.flush().await?;
    let file = out.into_inner();
    file.sync_all().await?;
    drop(file);
    Ok(Spooled {
        temp,
        bytes,
        sha256: hasher.map(|h| crate::hex(&h.finalize())),
    })
}
