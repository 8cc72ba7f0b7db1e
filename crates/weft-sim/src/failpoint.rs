//! Deterministic crash points, for testing that a run resumed from its last
//! checkpoint is bit-identical to one that never stopped.
//!
//! `WEFT_FAILPOINT=NAME@N` makes the process exit at once with code
//! [`EXIT_CODE`] — no destructors, no buffered output flushed, as in a crash —
//! the `N`-th time (counted by the caller: a window index, a rollback count, a
//! checkpoint number) the point `NAME` is reached. Unset, a point costs one
//! cached lookup. The points weft defines:
//!
//! | name | where | `N` |
//! |---|---|---|
//! | `mid-window` | after the first event batch of a window's first pass | window index |
//! | `mid-rollback` | just after a rollback restored the window start | rollbacks so far in the run, this one included |
//! | `checkpoint-rename` | a checkpoint is written to its temporary file, not yet renamed | checkpoints written by this process, this one included |
//! | `interrupt-after-rollback` | (does not exit) sets the engine's interrupt flag just after a rollback, as a signal arriving then would | rollbacks so far in the run, this one included |

use std::sync::OnceLock;

/// Exit status of a process stopped at a failpoint.
pub const EXIT_CODE: i32 = 86;

fn configured() -> Option<&'static (String, u64)> {
    static CONFIG: OnceLock<Option<(String, u64)>> = OnceLock::new();
    CONFIG
        .get_or_init(|| {
            let spec = std::env::var("WEFT_FAILPOINT").ok()?;
            let (name, n) = spec.split_once('@')?;
            Some((name.to_string(), n.trim().parse().ok()?))
        })
        .as_ref()
}

/// Exits the process if `WEFT_FAILPOINT` names `name@n`.
#[inline]
pub fn hit(name: &str, n: u64) {
    if triggered(name, n) {
        eprintln!("weft: failpoint {name}@{n} reached; exiting as if crashed");
        std::process::exit(EXIT_CODE);
    }
}

/// Whether `WEFT_FAILPOINT` names `name@n` (for points that act, not exit).
#[inline]
pub fn triggered(name: &str, n: u64) -> bool {
    configured().is_some_and(|(point, at)| point == name && *at == n)
}
