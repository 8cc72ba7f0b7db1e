//! Output files of previews: written beside their final name and renamed into
//! place, so a reader sees the old file or the new one. Unlike
//! [`weft_io::write_atomic`] nothing is fsynced: previews are cheap to redo,
//! and a sync per frame would dominate the time of a short render.

use crate::error::RenderError;
use std::path::{Path, PathBuf};

/// Writes a file through a temporary sibling and renames it into place when
/// finished, so a reader never sees a half-written preview.
pub(crate) struct TempOutput {
    pub tmp: PathBuf,
    pub path: PathBuf,
}

impl TempOutput {
    pub fn new(path: &Path) -> TempOutput {
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let tmp = path.with_file_name(format!(".{name}.{}.tmp", std::process::id()));
        TempOutput {
            tmp,
            path: path.to_path_buf(),
        }
    }

    pub fn commit(self) -> Result<PathBuf, RenderError> {
        std::fs::rename(&self.tmp, &self.path).map_err(|e| RenderError::io(&self.path, e))?;
        Ok(self.path.clone())
    }
}

impl Drop for TempOutput {
    fn drop(&mut self) {
        // After a successful rename this finds nothing to remove.
        let _ = std::fs::remove_file(&self.tmp);
    }
}

/// Replaces `path` with `bytes` (temporary sibling, then rename).
pub(crate) fn write_replacing(path: &Path, bytes: &[u8]) -> Result<(), RenderError> {
    let out = TempOutput::new(path);
    std::fs::write(&out.tmp, bytes).map_err(|e| RenderError::io(path, e))?;
    out.commit().map(|_| ())
}
