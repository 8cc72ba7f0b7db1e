//! `weft run` over ranks, end to end through the binary: ranks simulated in
//! one process (`--ranks R`) and, with the `mpi` feature, MPI ranks under
//! `mpirun`. Every rank count and thread count ends in the same `state_hash`
//! and writes the same output bytes as one process; a run stopped on one rank
//! count resumes on another; only rank 0 prints. Under MPI, bad input stops
//! every rank with one error, and a lost rank ends the run without a hang.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Output;

mod common;
use common::{resume, small_crumple};

/// The summary line of a run that reached its end — the only line: only
/// rank 0 prints.
fn summary(o: &Output) -> serde_json::Value {
    one_line(o);
    common::summary(o)
}

/// The summary line of a run stopped with a checkpoint (every rank exits 75).
fn stopped_summary(o: &Output) -> serde_json::Value {
    one_line(o);
    common::stopped_summary(o)
}

fn one_line(o: &Output) {
    let text = String::from_utf8_lossy(&o.stdout);
    assert_eq!(
        text.lines().count(),
        1,
        "one summary line (rank 0 only):\n{text}"
    );
}

/// The files a rank count must not change.
fn outputs(out: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut files = BTreeMap::new();
    for name in ["stats.jsonl", "frames.jsonl", "objects.json"] {
        files.insert(name.to_string(), std::fs::read(out.join(name)).unwrap());
    }
    for e in std::fs::read_dir(out.join("frames")).unwrap() {
        let e = e.unwrap();
        let name = format!("frames/{}", e.file_name().to_string_lossy());
        files.insert(name, std::fs::read(e.path()).unwrap());
    }
    files
}

fn run_small(out: &Path, extra: &[&str]) -> Output {
    small_crumple(out, extra, None)
        .args(["--quiet", "--no-preview"])
        .output()
        .expect("weft runs")
}

#[test]
fn simulated_ranks_give_the_same_bits_and_the_same_files() {
    let one = tempfile::tempdir().unwrap();
    let reference = summary(&run_small(one.path(), &["--threads", "1"]));
    assert!(reference["rollbacks"].as_u64().unwrap() > 0, "{reference}");
    for (ranks, threads) in [("2", "1"), ("3", "2")] {
        let dir = tempfile::tempdir().unwrap();
        let s = summary(&run_small(
            dir.path(),
            &["--ranks", ranks, "--threads", threads],
        ));
        assert_eq!(s["state_hash"], reference["state_hash"], "{ranks} ranks");
        assert_eq!(s["ranks"].to_string(), ranks, "{s}");
        assert_eq!(s["frames"], reference["frames"], "{ranks} ranks");
        assert_eq!(outputs(dir.path()), outputs(one.path()), "{ranks} ranks");
    }
}

#[test]
fn a_run_stopped_on_some_ranks_resumes_on_others() {
    let one = tempfile::tempdir().unwrap();
    let reference = summary(&run_small(one.path(), &["--threads", "1"]));
    let dir = tempfile::tempdir().unwrap();
    // Stopped after its first window on 3 ranks (they agree to stop at the
    // window boundary), continued on 2, then finished in one process.
    let s = stopped_summary(&run_small(
        dir.path(),
        &["--ranks", "3", "--threads", "1", "--stop-after", "0"],
    ));
    assert_eq!(s["stopped_by"], "stop-after", "{s}");
    stopped_summary(&resume(
        dir.path(),
        &["--ranks", "2", "--threads", "1", "--stop-after", "0"],
    ));
    let s = summary(&resume(dir.path(), &["--threads", "1"]));
    assert_eq!(s["complete"], true, "{s}");
    assert_eq!(s["state_hash"], reference["state_hash"]);
    assert_eq!(outputs(dir.path()), outputs(one.path()));
}

#[test]
fn bad_rank_counts_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let o = run_small(dir.path(), &["--ranks", "0"]);
    assert_eq!(o.status.code(), Some(2), "{o:?}");
    assert!(String::from_utf8_lossy(&o.stderr).contains("--ranks"));
}

/// MPI ranks under `mpirun` (one test at a time: the `mpi` nextest group).
#[cfg(feature = "mpi")]
mod mpi {
    use super::common::repo;
    use super::*;
    use std::process::Command;
    use std::time::{Duration, Instant};

    /// `state_hash` of the threads issue's determinism fixture, with layer
    /// prediction on (the same constant as `weft-par/tests/determinism.rs`).
    const FIXTURE_HASH: &str = "7d6870e5fb7c0e5f63f8e3af3fdaad49";
    const FIXTURE: &[&str] = &[
        "--set",
        "size=300",
        "--set",
        "time.end=0.24",
        "--set",
        "time.steps_per_window=25",
        "--set",
        "output.checkpoint_every=4",
    ];

    /// `mpirun -n ranks weft ARGS…` with what OpenMPI needs in a container,
    /// as root and with more ranks than cores.
    fn mpirun(ranks: usize) -> Command {
        mpirun_with_failpoint(ranks, None)
    }

    /// [`mpirun`] with `WEFT_FAILPOINT` set to `failpoint` on every rank.
    fn mpirun_with_failpoint(ranks: usize, failpoint: Option<&str>) -> Command {
        let mut c = Command::new("mpirun");
        c.args(["-n", &ranks.to_string(), "--bind-to", "none"])
            .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
            .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
            .env("OMPI_MCA_rmaps_base_oversubscribe", "1")
            .env("OMPI_MCA_btl_vader_single_copy_mechanism", "none")
            .env_remove("WEFT_FAILPOINT");
        if let Some(f) = failpoint {
            c.arg("-x").arg(format!("WEFT_FAILPOINT={f}"));
        }
        c.arg(env!("CARGO_BIN_EXE_weft"));
        c
    }

    /// Runs `c`, killing it after `limit`: a hang fails the test.
    fn output_within(mut c: Command, limit: Duration) -> Output {
        let child = c
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .expect("mpirun starts (is OpenMPI installed? .ci/install-mpi)");
        let id = child.id();
        let (done, wait) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            if wait.recv_timeout(limit).is_err() {
                let _ = Command::new("kill").args(["-9", &id.to_string()]).status();
            }
        });
        let started = Instant::now();
        let o = child.wait_with_output().unwrap();
        let _ = done.send(());
        assert!(
            started.elapsed() < limit,
            "mpirun hung (killed after {limit:?}):\n{}",
            String::from_utf8_lossy(&o.stderr)
        );
        o
    }

    fn run_fixture(ranks: usize, threads: usize, out: &Path, extra: &[&str]) -> Output {
        let mut c = mpirun(ranks);
        c.arg("run")
            .arg(repo().join("scenes/crumple.toml"))
            .arg("--out")
            .arg(out)
            .args(FIXTURE)
            .args(["--threads", &threads.to_string(), "--quiet", "--no-preview"])
            .args(extra);
        output_within(c, Duration::from_secs(240))
    }

    /// `weft run --resume dir` on `ranks` MPI ranks of one thread, killed
    /// after `limit`.
    fn resume_fixture(ranks: usize, dir: &Path, extra: &[&str], limit: Duration) -> Output {
        let mut c = mpirun(ranks);
        c.args(["run", "--resume"])
            .arg(dir)
            .args(["--threads", "1", "--quiet", "--no-preview"])
            .args(extra);
        output_within(c, limit)
    }

    /// The fixture's hash and one process's files on 1, 2 and 4 ranks of
    /// 1 and 2 threads (`contact.split_islands` unset: the islands split
    /// at 4 ranks only, which `stats.jsonl` does not show).
    #[test]
    fn mpi_ranks_and_threads_give_the_fixture_hash() {
        let one = tempfile::tempdir().unwrap();
        for ranks in [1, 2, 4] {
            for threads in [1, 2] {
                let dir = tempfile::tempdir().unwrap();
                let dir = if (ranks, threads) == (1, 1) {
                    &one
                } else {
                    &dir
                };
                let s = summary(&run_fixture(ranks, threads, dir.path(), &[]));
                assert_eq!(s["state_hash"], FIXTURE_HASH, "{ranks} ranks × {threads}");
                assert_eq!(s["ranks"], ranks, "{s}");
                assert_eq!(s["complete"], true);
                let label = format!("{ranks} ranks × {threads}: files");
                assert_eq!(outputs(dir.path()), outputs(one.path()), "{label}");
            }
        }
    }

    /// With `contact.split_islands` the units spread over the MPI ranks,
    /// and promotions move vertices between them (`engine/events`): the
    /// fixture's hash, and the files of one process.
    #[test]
    fn mpi_ranks_with_the_units_spread_give_the_fixture_hash() {
        let split = ["--set", "contact.split_islands=true"];
        let one = tempfile::tempdir().unwrap();
        let reference = summary(&run_fixture(1, 1, one.path(), &split));
        assert_eq!(reference["state_hash"], FIXTURE_HASH);
        let dir = tempfile::tempdir().unwrap();
        let s = summary(&run_fixture(3, 1, dir.path(), &split));
        assert_eq!(s["state_hash"], FIXTURE_HASH, "3 ranks, split");
        assert_eq!(s["complete"], true);
        assert_eq!(outputs(dir.path()), outputs(one.path()), "3 ranks, split");
    }

    #[test]
    fn mpi_run_resumes_on_another_rank_count_and_without_mpi() {
        let dir = tempfile::tempdir().unwrap();
        // Both ranks exit 75, and so does mpirun.
        stopped_summary(&run_fixture(2, 1, dir.path(), &["--stop-after", "0"]));
        let o = resume_fixture(
            4,
            dir.path(),
            &["--stop-after", "0"],
            Duration::from_secs(240),
        );
        stopped_summary(&o);
        // Then without MPI at all.
        let s = summary(&resume(dir.path(), &["--threads", "2"]));
        assert_eq!(s["complete"], true, "{s}");
        assert_eq!(s["state_hash"], FIXTURE_HASH);
    }

    #[test]
    fn mpi_bad_input_stops_every_rank_with_one_error() {
        let dir = tempfile::tempdir().unwrap();
        let o = run_fixture(3, 1, dir.path(), &["--set", "contact.no_such_key=1"]);
        assert!(!o.status.success());
        let err = String::from_utf8_lossy(&o.stderr);
        let errors = err.lines().filter(|l| l.starts_with("error:")).count();
        assert_eq!(errors, 1, "one error line:\n{err}");
        assert!(err.contains("no_such_key"), "{err}");
    }

    #[test]
    fn mpi_resume_from_a_corrupt_checkpoint_is_one_error() {
        let dir = tempfile::tempdir().unwrap();
        // Both ranks exit 75, and so does mpirun.
        stopped_summary(&run_fixture(2, 1, dir.path(), &["--stop-after", "0"]));
        let ck = dir.path().join("checkpoint.wckp");
        let mut bytes = std::fs::read(&ck).unwrap();
        let middle = bytes.len() / 2;
        bytes[middle] ^= 0xff;
        std::fs::write(&ck, bytes).unwrap();
        let o = resume_fixture(3, dir.path(), &[], Duration::from_secs(120));
        assert_eq!(o.status.code(), Some(1), "{o:?}");
        let err = String::from_utf8_lossy(&o.stderr);
        let errors = err.lines().filter(|l| l.starts_with("error:")).count();
        assert_eq!(errors, 1, "one error line:\n{err}");
        assert!(err.contains("checkpoint.wckp"), "{err}");
        assert!(!err.contains("MPI_ABORT"), "no abort needed:\n{err}");
    }

    /// An engine error is the same on every rank, so it ends the job with one
    /// error line and exit status 1, not an abort — also when rank 0 cannot
    /// record it in the manifest (the note it adds keeps the error's type).
    #[test]
    fn mpi_engine_error_the_manifest_cannot_record_is_one_error_without_abort() {
        let dir = tempfile::tempdir().unwrap();
        let mut c = mpirun_with_failpoint(2, Some("write:manifest:failed@1"));
        c.arg("run")
            .arg(repo().join("scenes/crumple.toml"))
            .arg("--out")
            .arg(dir.path())
            .args(FIXTURE)
            .args(["--set", "contact.max_rollbacks=0"])
            .args(["--threads", "1", "--quiet", "--no-preview"]);
        let o = output_within(c, Duration::from_secs(120));
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{err}");
        let errors: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
        assert_eq!(errors.len(), 1, "one error line:\n{err}");
        assert!(
            errors[0].contains("rollbacks") && errors[0].contains("manifest failed too"),
            "{err}"
        );
        assert!(!err.contains("MPI_ABORT"), "no abort needed:\n{err}");
    }

    /// Rank 1's process, found among `mpirun`'s children by its environment.
    fn rank_pid(ranks_parent: u32, rank: usize) -> Option<u32> {
        for e in std::fs::read_dir("/proc").ok()?.flatten() {
            let Ok(pid) = e.file_name().to_string_lossy().parse::<u32>() else {
                continue;
            };
            let Ok(stat) = std::fs::read_to_string(format!("/proc/{pid}/stat")) else {
                continue;
            };
            // Field 4 (after the parenthesized command) is the parent pid.
            let after = stat.rsplit_once(')').map(|(_, s)| s).unwrap_or("");
            let ppid: Option<u32> = after.split_whitespace().nth(1).and_then(|p| p.parse().ok());
            if ppid != Some(ranks_parent) {
                continue;
            }
            let env = std::fs::read(format!("/proc/{pid}/environ")).unwrap_or_default();
            let want = format!("OMPI_COMM_WORLD_RANK={rank}");
            if env.split(|&b| b == 0).any(|v| v == want.as_bytes()) {
                return Some(pid);
            }
        }
        None
    }

    #[test]
    fn mpi_lost_rank_ends_the_run_and_the_manifest_names_the_last_checkpoint() {
        let dir = tempfile::tempdir().unwrap();
        let mut c = mpirun(2);
        c.arg("run")
            .arg(repo().join("scenes/crumple.toml"))
            .arg("--out")
            .arg(dir.path())
            .args(FIXTURE)
            .args(["--set", "time.end=5", "--set", "output.checkpoint_every=2"])
            .args(["--threads", "1", "--quiet", "--no-preview"])
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped());
        let mut child = c.spawn().expect("mpirun starts");
        let manifest = dir.path().join("manifest.json");
        let started = Instant::now();
        // Wait for a checkpoint, then kill rank 1.
        loop {
            assert!(
                started.elapsed() < Duration::from_secs(120),
                "no checkpoint"
            );
            let named = std::fs::read_to_string(&manifest)
                .ok()
                .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
                .is_some_and(|m| !m["last_checkpoint"].is_null());
            if named {
                break;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        let pid = rank_pid(child.id(), 1).expect("rank 1's process");
        Command::new("kill")
            .args(["-9", &pid.to_string()])
            .status()
            .unwrap();
        let killed = Instant::now();
        let status = loop {
            if let Some(s) = child.try_wait().unwrap() {
                break s;
            }
            if killed.elapsed() > Duration::from_secs(60) {
                let _ = child.kill();
                panic!("the run hung after losing rank 1");
            }
            std::thread::sleep(Duration::from_millis(50));
        };
        assert!(!status.success());
        let m: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&manifest).unwrap()).unwrap();
        let ck = &m["last_checkpoint"];
        assert!(ck["window"].as_u64().unwrap() >= 2, "{m}");
        // The checkpoint it names is good: the run resumes from it.
        let s = summary(&resume(
            dir.path(),
            &["--set", "time.end=0.24", "--threads", "2"],
        ));
        assert_eq!(s["state_hash"], FIXTURE_HASH);
    }
}
