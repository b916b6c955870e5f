//! Import errors: they name the file, where in it, and what is wrong.

use std::fmt;
use std::path::{Path, PathBuf};

/// Where in the input an error was found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Location {
    /// The file as a whole (cannot open, unknown format).
    File,
    /// A 1-based line of a text format.
    Line(u64),
    /// A byte offset into a binary format.
    Byte(u64),
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Location::File => Ok(()),
            Location::Line(n) => write!(f, "line {n}: "),
            Location::Byte(n) => write!(f, "byte {n}: "),
        }
    }
}

/// What is wrong with the input.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ImportErrorKind {
    #[error("cannot read file: {0}")]
    Io(String),
    #[error("malformed header: {0}")]
    Header(String),
    #[error("unsupported: {0}")]
    Unsupported(String),
    #[error("truncated data: {0}")]
    Truncated(String),
    #[error("malformed data: {0}")]
    Syntax(String),
    #[error("non-finite coordinate ({0}) in vertex {1}")]
    NonFinite(String, u64),
    #[error("vertex index {index} out of range (only {count} vertices) in face {face}")]
    IndexOutOfRange { index: i64, count: u64, face: u64 },
    /// A face names a vertex beyond the count a header declared (PLY): most often the header's
    /// vertex count is smaller than the vertex data that follows it.
    #[error(
        "face {face} names vertex index {index}, but the header declares only {count} vertices \
         (line {line}): that vertex count is smaller than the vertex data, or the faces are damaged"
    )]
    BeyondDeclaredVertices {
        index: i64,
        count: u64,
        face: u64,
        line: u64,
    },
    #[error("no triangles in the file")]
    Empty,
    /// The sink refused the data (disk full, cancelled, limits).
    #[error("{0}")]
    Sink(String),
    #[error("cancelled")]
    Cancelled,
}

/// An import failure, with file and location.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ImportError {
    pub path: PathBuf,
    pub location: Location,
    pub kind: ImportErrorKind,
}

impl ImportError {
    pub fn new(path: &Path, location: Location, kind: ImportErrorKind) -> Self {
        ImportError {
            path: path.to_path_buf(),
            location,
            kind,
        }
    }

    /// An error raised by a sink, before the reader attaches file and location.
    pub fn sink(message: impl Into<String>) -> Self {
        ImportError {
            path: PathBuf::new(),
            location: Location::File,
            kind: ImportErrorKind::Sink(message.into()),
        }
    }

    /// Fills in the file path if the error came from a sink that did not know it.
    pub fn with_path(mut self, path: &Path) -> Self {
        if self.path.as_os_str().is_empty() {
            self.path = path.to_path_buf();
        }
        self
    }
}

impl fmt::Display for ImportError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let name = self
            .path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| self.path.display().to_string());
        write!(f, "{name}: {}{}", self.location, self.kind)
    }
}

impl std::error::Error for ImportError {}
