//! Checkpoints: the state of a run at a window boundary, in one file.
//!
//! Layout (all integers little-endian):
//!
//! ```text
//! offset  size  field
//!      0     8  magic "WEFTCKPT"
//!      8     4  format version (FORMAT_VERSION)
//!     12     4  reserved, 0
//!     16     8  payload length in bytes
//!     24    16  XXH3-128 of the payload
//!     40     …  payload: zstd(postcard(Checkpoint))
//! ```
//!
//! The checksum covers the compressed payload, so a flipped or missing byte
//! anywhere is reported as corruption before anything is decoded. Files are
//! written to a temporary name and renamed ([`crate::write_atomic`]), so the
//! previous checkpoint survives any failure of the write. The state is keyed by
//! input ids only: a checkpoint resumes on any partition, thread or rank count.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use thiserror::Error;
use weft_sim::EngineState;

const MAGIC: &[u8; 8] = b"WEFTCKPT";
/// Version of the file layout and of [`Checkpoint`]'s encoding.
pub const FORMAT_VERSION: u32 = 1;
const HEADER: usize = 40;

/// Where the output files of a run stood when the checkpoint was taken, so a
/// resumed run can cut them back and continue them byte for byte.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct OutputCursors {
    /// Index of the next frame to write.
    pub next_frame: u64,
    /// Lengths of the line files at the checkpoint.
    pub stats_bytes: u64,
    pub timing_bytes: u64,
    pub frames_bytes: u64,
}

/// Everything needed to continue a run bit-identically.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Checkpoint {
    /// The weft version that wrote it.
    pub weft_version: String,
    pub scene_name: String,
    /// Fingerprint of the scene with its overrides (end time excluded) and of
    /// the world built from it; a resume refuses a scene that differs.
    pub scene_hash: String,
    pub engine: EngineState,
    pub cursors: OutputCursors,
    /// Wall-clock seconds the run had used (summed over resumed parts).
    pub wall_seconds: f64,
}

/// A checkpoint could not be read or written.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum CheckpointError {
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: not a weft checkpoint (bad magic bytes)", path.display())]
    NotACheckpoint { path: PathBuf },
    #[error(
        "{}: checkpoint format version {found}, this weft reads version {FORMAT_VERSION}",
        path.display()
    )]
    Version { path: PathBuf, found: u32 },
    #[error("{}: checkpoint is corrupt: {what}", path.display())]
    Corrupt { path: PathBuf, what: String },
    #[error("{}: cannot encode the checkpoint: {what}", path.display())]
    Encode { path: PathBuf, what: String },
    #[error(transparent)]
    Write(#[from] crate::IoError),
}

/// Encodes `ck` into the file layout above.
pub fn encode_checkpoint(ck: &Checkpoint) -> Result<Vec<u8>, String> {
    let raw = postcard::to_allocvec(ck).map_err(|e| e.to_string())?;
    // Level 3: fast, and positions of nearby vertices compress well enough.
    let payload = zstd::bulk::compress(&raw, 3).map_err(|e| e.to_string())?;
    let mut out = Vec::with_capacity(HEADER + payload.len());
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    out.extend_from_slice(&0u32.to_le_bytes());
    out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    out.extend_from_slice(&xxhash_rust::xxh3::xxh3_128(&payload).to_le_bytes());
    out.extend_from_slice(&payload);
    Ok(out)
}

/// Decodes a checkpoint file's bytes; `path` names it in errors.
pub fn decode_checkpoint(bytes: &[u8], path: &Path) -> Result<Checkpoint, CheckpointError> {
    let corrupt = |what: String| CheckpointError::Corrupt {
        path: path.to_path_buf(),
        what,
    };
    if bytes.len() < 8 || &bytes[..8] != MAGIC {
        return Err(CheckpointError::NotACheckpoint {
            path: path.to_path_buf(),
        });
    }
    if bytes.len() < HEADER {
        return Err(corrupt(format!(
            "the file ends after {} bytes, inside the {HEADER}-byte header",
            bytes.len()
        )));
    }
    let u32_at = |o: usize| u32::from_le_bytes(bytes[o..o + 4].try_into().unwrap());
    let version = u32_at(8);
    if version != FORMAT_VERSION {
        return Err(CheckpointError::Version {
            path: path.to_path_buf(),
            found: version,
        });
    }
    let len = u64::from_le_bytes(bytes[16..24].try_into().unwrap());
    let sum = u128::from_le_bytes(bytes[24..40].try_into().unwrap());
    let payload = &bytes[HEADER..];
    if payload.len() as u64 != len {
        return Err(corrupt(format!(
            "the header announces {len} payload bytes, the file holds {} (truncated or appended to)",
            payload.len()
        )));
    }
    if xxhash_rust::xxh3::xxh3_128(payload) != sum {
        return Err(corrupt(
            "checksum mismatch (the payload was altered)".into(),
        ));
    }
    // The checksum matched, so a failure below means a writer bug or a
    // deliberately forged file; report it all the same, never panic.
    let raw = zstd::stream::decode_all(payload).map_err(|e| corrupt(format!("zstd: {e}")))?;
    postcard::from_bytes(&raw).map_err(|e| corrupt(format!("decoding: {e}")))
}

/// Writes `ck` to `path` atomically. `before_rename` runs after the data are
/// in the temporary file and before it replaces `path` (a crash there must
/// leave the previous checkpoint intact; tests inject one).
pub fn write_checkpoint(
    path: &Path,
    ck: &Checkpoint,
    before_rename: impl FnOnce(),
) -> Result<(), CheckpointError> {
    let bytes = encode_checkpoint(ck).map_err(|what| CheckpointError::Encode {
        path: path.to_path_buf(),
        what,
    })?;
    crate::atomic::write_atomic_then(path, &bytes, before_rename)?;
    Ok(())
}

/// Reads and verifies the checkpoint at `path`.
pub fn read_checkpoint(path: &Path) -> Result<Checkpoint, CheckpointError> {
    let bytes = std::fs::read(path).map_err(|e| CheckpointError::Io {
        path: path.to_path_buf(),
        source: e,
    })?;
    decode_checkpoint(&bytes, path)
}
