//! The one error type of weft-io: every variant names the file, and parse
//! errors name the line (OBJ, PLY header and ASCII body) or the byte offset and
//! element (binary PLY).

use std::fmt;
use std::path::PathBuf;
use thiserror::Error;
use weft_core::MeshError;

/// Reading or writing a mesh file failed.
///
/// When this error occurs: the file could not be read or written, its contents
/// are malformed, or the mesh it holds is not simulable. How to handle it: the
/// `Display` output is meant for the user as is (`file:line: message`); fix the
/// named file at the named place.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum IoError {
    /// The operating system refused a read, write or rename.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The file is malformed. `line` is 1-based; binary PLY errors have no line
    /// and give the byte offset in `message` instead.
    #[error("{}{}: {message}", path.display(), Line(*line))]
    Parse {
        path: PathBuf,
        line: Option<usize>,
        message: String,
    },
    /// The file parsed but its mesh failed
    /// [`weft_core::validate`](fn@weft_core::validate). `line` is the source
    /// line of the offending triangle where the format has lines (OBJ);
    /// `message` names the elements the way the file numbers them.
    #[error("{}{}: {message}", path.display(), Line(*line))]
    Mesh {
        path: PathBuf,
        line: Option<usize>,
        /// The validation error in the mesh's 0-based ids. Not the error's
        /// `source`: `message` already says the same in the file's
        /// numbering, and a chain printer would print it a second time.
        /// Boxed: it is large, and every I/O result carries this type.
        mesh: Box<MeshError>,
        message: String,
    },
    /// The file's extension names no format weft reads.
    #[error("{}: unsupported mesh format {extension:?} (expected a .obj or .ply file)", path.display())]
    UnsupportedFormat { path: PathBuf, extension: String },
    /// A writer was given data it cannot represent in a file the readers accept
    /// (e.g. a non-finite coordinate or an index out of range).
    #[error("{}: refusing to write: {message}", path.display())]
    InvalidInput { path: PathBuf, message: String },
}

impl IoError {
    pub(crate) fn io(path: &std::path::Path, source: std::io::Error) -> Self {
        Self::Io {
            path: path.to_path_buf(),
            source,
        }
    }
}

/// Formats `:line` when a line is known, nothing otherwise.
struct Line(Option<usize>);

impl fmt::Display for Line {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.0 {
            Some(line) => write!(f, ":{line}"),
            None => Ok(()),
        }
    }
}
