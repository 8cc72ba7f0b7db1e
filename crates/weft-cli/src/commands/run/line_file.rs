//! A JSON-lines file a run appends to (`stats.jsonl`, `timing.jsonl`,
//! `frames.jsonl`) that only ever holds whole lines.
//!
//! Each line reaches the file in one write as soon as it is appended, so a
//! reader (`weft render DIR`, `weft plot DIR`, `tail -f`) sees a run in
//! progress line by line. A write that fails part-way (a full disk) is cut
//! back to the last whole line — truncating needs no space — so the file
//! stays readable; a resume cuts the file back to the length its checkpoint
//! recorded in any case.

use std::fs::{File, OpenOptions};
use std::io::{Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};

use super::faults;

pub struct LineFile {
    path: PathBuf,
    file: File,
    /// Bytes of whole lines in the file.
    len: u64,
    /// Lines this process appended (numbers the `write:NAME` failpoint).
    appended: u64,
    /// `write:NAME`, the failpoint of an append (named once, not per line).
    failpoint: String,
    /// The line being appended with its newline, kept between appends.
    buf: Vec<u8>,
}

impl LineFile {
    /// Creates `path` empty (replacing a file there).
    pub fn create(path: &Path) -> anyhow::Result<Self> {
        let file =
            File::create(path).with_context(|| format!("cannot create {}", path.display()))?;
        Ok(Self::new(path, file, 0))
    }

    /// Reopens `path` to append after its first `len` bytes, cutting what
    /// follows (lines written after the checkpoint that recorded `len`).
    pub fn resume(path: &Path, len: u64) -> anyhow::Result<Self> {
        let mut file = OpenOptions::new()
            .read(true)
            .write(true)
            .open(path)
            .with_context(|| format!("cannot reopen {} to continue it", path.display()))?;
        let have = file.metadata()?.len();
        if have < len {
            bail!(
                "{} holds {have} bytes but the checkpoint recorded {len}: the run folder \
                 was modified after the checkpoint, cannot continue it byte for byte",
                path.display()
            );
        }
        file.set_len(len)
            .with_context(|| format!("cannot cut {} back to its checkpoint", path.display()))?;
        file.seek(SeekFrom::End(0))?;
        Ok(Self::new(path, file, len))
    }

    fn new(path: &Path, file: File, len: u64) -> Self {
        let name = path.file_name().unwrap_or_default().to_string_lossy();
        Self {
            path: path.to_path_buf(),
            file,
            len,
            appended: 0,
            failpoint: format!("write:{name}"),
            buf: Vec::new(),
        }
    }

    /// Appends `line` and a newline, whole or not at all.
    pub fn append(&mut self, line: &str) -> anyhow::Result<()> {
        let mut bytes = std::mem::take(&mut self.buf);
        bytes.clear();
        bytes.extend_from_slice(line.as_bytes());
        bytes.push(b'\n');
        let result = self.write_line(&bytes);
        self.buf = bytes;
        result
    }

    /// Writes `bytes` (one line and its newline), cutting a partial write.
    fn write_line(&mut self, bytes: &[u8]) -> anyhow::Result<()> {
        self.appended += 1;
        let written = match faults::injected(&self.failpoint, self.appended) {
            // As a disk that fills up mid-line: half of it is on disk.
            Err(e) => self.file.write_all(&bytes[..bytes.len() / 2]).and(Err(e)),
            Ok(()) => self.file.write_all(bytes),
        };
        if let Err(e) = written {
            let cut = self
                .file
                .set_len(self.len)
                .and_then(|()| self.file.seek(SeekFrom::Start(self.len)));
            let what = match cut {
                Ok(_) => "the partial line was cut".to_string(),
                Err(c) => format!("the partial line could not be cut either: {c}"),
            };
            return Err(e)
                .with_context(|| format!("cannot write {} ({what})", self.path.display()));
        }
        self.len += bytes.len() as u64;
        Ok(())
    }

    /// Bytes of whole lines in the file.
    pub fn len(&self) -> u64 {
        self.len
    }

    /// Makes the lines so far durable (before a checkpoint records the length).
    pub fn sync(&self) -> anyhow::Result<()> {
        self.file
            .sync_data()
            .with_context(|| format!("cannot write {} to disk", self.path.display()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_reach_the_file_at_once_and_resume_cuts_later_ones() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("stats.jsonl");
        let mut f = LineFile::create(&path).unwrap();
        f.append("{\"a\":1}").unwrap();
        // Visible to another reader without a flush.
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "{\"a\":1}\n");
        let mark = f.len();
        f.append("{\"a\":2}").unwrap();
        drop(f);
        let mut f = LineFile::resume(&path, mark).unwrap();
        f.append("{\"a\":3}").unwrap();
        assert_eq!(
            std::fs::read_to_string(&path).unwrap(),
            "{\"a\":1}\n{\"a\":3}\n"
        );
        assert!(
            LineFile::resume(&path, 1000).is_err(),
            "shorter than recorded"
        );
    }
}
