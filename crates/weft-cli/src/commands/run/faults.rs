//! Injected write failures, for testing that a run whose disk fills up (or
//! whose folder turns read-only) mid-run ends `failed` and resumes from its
//! last good checkpoint.
//!
//! They ride on the engine's `WEFT_FAILPOINT=NAME@N` switch
//! (`weft_sim::failpoint`), but where its points end the process as a crash
//! would, these make the write return an error, "No space left on device", as
//! a full disk does. The points of `weft run`:
//!
//! | name | where | `N` |
//! |---|---|---|
//! | `write:stats.jsonl`, `write:timing.jsonl`, `write:frames.jsonl` | appending a line: half of it reaches the file, then the write fails | lines this process appended to the file, this one included |
//! | `write:frame` | writing a frame's files | the frame's index |
//! | `write:checkpoint` | writing a checkpoint, before its temporary file | checkpoints written by this process, this one included |
//! | `write:manifest:STATUS` (`running`, `complete`, `stopped`, `failed`) | writing the manifest with that status, before its temporary file | manifests with that status written by this process, this one included |

use std::collections::BTreeMap;
use std::io::{Error, ErrorKind};
use std::sync::Mutex;

/// Fails with "No space left on device" if `WEFT_FAILPOINT` names `name@n`.
pub fn injected(name: &str, n: u64) -> std::io::Result<()> {
    if weft_sim::failpoint::triggered(name, n) {
        return Err(Error::new(
            ErrorKind::StorageFull,
            format!("No space left on device (injected by WEFT_FAILPOINT={name}@{n})"),
        ));
    }
    Ok(())
}

/// [`injected`] for a point with no count of its own: `n` is the number of
/// calls with this `name` in this process, this one included.
pub fn injected_nth(name: &str) -> std::io::Result<()> {
    static CALLS: Mutex<BTreeMap<String, u64>> = Mutex::new(BTreeMap::new());
    let n = {
        let mut calls = CALLS.lock().unwrap_or_else(|p| p.into_inner());
        let n = calls.entry(name.to_string()).or_default();
        *n += 1;
        *n
    };
    injected(name, n)
}
