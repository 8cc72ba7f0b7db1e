//! The one error type of weft-render: every variant names the file it is
//! about, and parse errors name the line.

use std::fmt;
use std::path::PathBuf;
use thiserror::Error;

/// Rendering a run or plotting its diagnostics failed.
///
/// When this error occurs: a run folder or stats file is missing or malformed,
/// a frame cannot be read, an output cannot be written, an option is out of
/// range, or ffmpeg was asked for and failed. How to handle it: the `Display`
/// output is meant for the user as is (`file:line: message`); fix the named
/// file or option and run again.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum RenderError {
    /// The operating system refused a read, write, rename or process start.
    /// (The cause is part of the message rather than a `source()`, so
    /// printing the error chain does not repeat it.)
    #[error("{}: {error}", path.display())]
    Io {
        path: PathBuf,
        error: std::io::Error,
    },
    /// A run-folder or stats file is malformed; `line` is 1-based.
    #[error("{}{}: {message}", path.display(), Line(*line))]
    Format {
        path: PathBuf,
        line: Option<usize>,
        message: String,
    },
    /// A frame listed in `frames.jsonl` could not be read (`error` names the
    /// frame file and the place in it).
    #[error("frame {frame}: {error}")]
    Frame { frame: u64, error: weft_io::IoError },
    /// An image or animation encoder failed on the named output.
    #[error("{}: cannot encode: {message}", path.display())]
    Encode { path: PathBuf, message: String },
    /// ffmpeg is missing (and MP4 was asked for explicitly) or it failed.
    #[error("ffmpeg ({program}): {message}")]
    Video { program: String, message: String },
    /// An option is out of range (size, stride, frame rate, camera).
    #[error("invalid render option: {0}")]
    Option(String),
}

impl RenderError {
    pub(crate) fn io(path: impl Into<PathBuf>, error: std::io::Error) -> Self {
        Self::Io {
            path: path.into(),
            error,
        }
    }

    pub(crate) fn format(path: impl Into<PathBuf>, line: Option<usize>, message: String) -> Self {
        Self::Format {
            path: path.into(),
            line,
            message,
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
