//! The JSON-lines files a run appends to (`frames.jsonl`, `stats.jsonl`,
//! `timing.jsonl`), read also while the run is still writing them: a run
//! appends one line per frame or window, so the last line may be cut off
//! mid-write. Only a whole line (one that ends in a newline) that does not
//! parse is an error.

use crate::error::RenderError;
use serde::de::DeserializeOwned;
use std::path::Path;

/// The records of a JSON-lines file.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct JsonLines<T> {
    /// Each record with its (1-based) line number, in file order; blank lines
    /// are skipped.
    pub records: Vec<(usize, T)>,
    /// The (1-based) number of the last line when it was skipped as
    /// incomplete: no newline at its end and not a whole record.
    pub incomplete_last_line: Option<usize>,
}

impl<T> JsonLines<T> {
    /// The records without their line numbers.
    pub fn into_records(self) -> Vec<T> {
        self.records.into_iter().map(|(_, r)| r).collect()
    }
}

/// Reads and parses the JSON-lines file `path` (see [`parse`]).
pub(crate) fn read<T: DeserializeOwned>(
    path: &Path,
    what: &str,
) -> Result<JsonLines<T>, RenderError> {
    let text = std::fs::read_to_string(path).map_err(|e| RenderError::io(path, e))?;
    parse(path, &text, what)
}

/// Parses `text`, the contents of `path`, one `T` per non-blank line. A last
/// line without a newline that does not parse is skipped and noted; any
/// other line that does not parse is an error naming the file and the line
/// (`malformed {what}: …`).
pub(crate) fn parse<T: DeserializeOwned>(
    path: &Path,
    text: &str,
    what: &str,
) -> Result<JsonLines<T>, RenderError> {
    let mut records = Vec::new();
    let mut incomplete_last_line = None;
    let count = text.lines().count();
    for (i, line) in text.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        match serde_json::from_str(line) {
            Ok(record) => records.push((i + 1, record)),
            Err(_) if i + 1 == count && !text.ends_with('\n') => {
                incomplete_last_line = Some(i + 1);
            }
            Err(e) => {
                return Err(RenderError::format(
                    path,
                    Some(i + 1),
                    format!("malformed {what}: {e}"),
                ))
            }
        }
    }
    Ok(JsonLines {
        records,
        incomplete_last_line,
    })
}

/// The warning for a skipped incomplete last line of `path`.
pub(crate) fn incomplete_warning(path: &Path, line: usize) -> String {
    format!(
        "{}:{line}: skipped an incomplete last line (is the run still writing it?)",
        path.display()
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn numbers(text: &str) -> Result<JsonLines<u32>, RenderError> {
        parse(Path::new("n.jsonl"), text, "number")
    }

    #[test]
    fn a_torn_last_line_is_skipped_and_any_other_bad_line_is_an_error() {
        let whole = numbers("1\n\n2\n").unwrap();
        assert_eq!(whole.records, vec![(1, 1), (3, 2)]);
        assert_eq!(whole.incomplete_last_line, None);

        let torn = numbers("1\n2\n{\"a").unwrap();
        assert_eq!(torn.records, vec![(1, 1), (2, 2)]);
        assert_eq!(torn.incomplete_last_line, Some(3));
        // Unterminated but whole: kept.
        let unterminated = numbers("1\n22").unwrap();
        assert_eq!(unterminated.records, vec![(1, 1), (2, 22)]);
        assert_eq!(unterminated.incomplete_last_line, None);

        let e = numbers("1\n{\"a\n").unwrap_err().to_string();
        assert!(e.contains("n.jsonl:2: malformed number"), "{e}");
        let e = numbers("x\n2").unwrap_err().to_string();
        assert!(e.contains("n.jsonl:1:"), "{e}");
    }
}
