//! Typed errors for mesh input, each naming the file and where in it.

use std::fmt;
use std::path::PathBuf;

/// Where in a file an error was found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Location {
    /// The file as a whole.
    File,
    /// A 1-based line of a text file.
    Line(u64),
    /// A 0-based byte offset of a binary file.
    Byte(u64),
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Location::File => Ok(()),
            Location::Line(n) => write!(f, ":{n}"),
            Location::Byte(n) => write!(f, ": byte {n}"),
        }
    }
}

/// What is wrong with a mesh or its file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ErrorKind {
    /// The file could not be read.
    #[error("cannot read")]
    Io(#[source] std::io::Error),
    /// The file could not be written ([`crate::io::write_mesh`]).
    #[error("cannot write")]
    Write(#[source] std::io::Error),
    /// The file holds nothing.
    #[error("the file is empty")]
    Empty,
    /// Neither the extension nor the content names a known format.
    #[error("unknown mesh format ({0}); expected .obj, .off, .ply or .stl")]
    UnknownFormat(String),
    /// A variant of a known format that is not supported.
    #[error("unsupported: {0}")]
    Unsupported(String),
    /// The file ends before the data its header announced.
    #[error("truncated: {0}")]
    Truncated(String),
    /// Text that does not parse.
    #[error("{0}")]
    Syntax(String),
    /// A face names a vertex that does not exist.
    #[error("vertex index {index} out of range ({vertices} vertices)")]
    IndexOutOfRange {
        /// The index as written in the file.
        index: i64,
        /// How many vertices there are.
        vertices: usize,
    },
    /// A face with fewer than 3 vertices.
    #[error("face with {0} vertices (at least 3 needed)")]
    FaceTooSmall(usize),
    /// A coordinate that is NaN or infinite (or overflows `f32`).
    #[error("non-finite coordinate {0}")]
    NonFinite(String),
    /// A header count that cannot be right (more elements than bytes, or more than `u32` holds).
    #[error("implausible count: {0}")]
    TooLarge(String),
}

/// A mesh input error: the file (when known), the place in it, and what is wrong.
#[derive(Debug)]
pub struct MeshError {
    /// The file, or `None` for in-memory input.
    pub path: Option<PathBuf>,
    /// Where in the file.
    pub location: Location,
    /// What is wrong.
    pub kind: ErrorKind,
}

impl MeshError {
    /// An error at a location, without a path yet (readers add it).
    #[must_use]
    pub fn new(location: Location, kind: ErrorKind) -> Self {
        Self {
            path: None,
            location,
            kind,
        }
    }

    /// An error at a 1-based line.
    #[must_use]
    pub fn at_line(line: u64, kind: ErrorKind) -> Self {
        Self::new(Location::Line(line), kind)
    }

    /// An error at a byte offset.
    #[must_use]
    pub fn at_byte(offset: u64, kind: ErrorKind) -> Self {
        Self::new(Location::Byte(offset), kind)
    }

    /// The same error, naming the file.
    #[must_use]
    pub fn with_path(mut self, path: impl Into<PathBuf>) -> Self {
        self.path = Some(path.into());
        self
    }
}

impl fmt::Display for MeshError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.path {
            Some(p) => write!(f, "{}{}: {}", p.display(), self.location, self.kind),
            None => match self.location {
                Location::File => write!(f, "{}", self.kind),
                Location::Line(n) => write!(f, "line {n}: {}", self.kind),
                Location::Byte(n) => write!(f, "byte {n}: {}", self.kind),
            },
        }
    }
}

impl std::error::Error for MeshError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match &self.kind {
            ErrorKind::Io(e) | ErrorKind::Write(e) => Some(e),
            _ => None,
        }
    }
}
