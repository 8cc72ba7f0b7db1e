//! `weft run` under `mpirun` (feature `mpi`): each process is one rank of a
//! [`Ranks`] executor over [`MpiTransport`], with `--threads` threads.
//!
//! Failure behaviour, so that no rank ever waits for one that will not come:
//!
//! * **Setup**, in two steps, each checked by every rank and then compared
//!   in one collective (if any rank failed, rank 0 prints the error, naming
//!   the rank when not all ranks saw it, and every rank exits 1): the scene,
//!   meshes, overrides and on `--resume` the manifest; then the world they
//!   build (its internal step's estimate shared by the ranks, a collective
//!   every rank reaches), on `--resume` the checkpoint, and the job (signal
//!   handlers, the progress interval).
//! * **The run**: an engine error is the same on every rank (every rank holds
//!   the same state), so rank 0 prints it and every rank exits 1. Any other
//!   error (a write that failed on rank 0, a lost peer) is printed by the rank
//!   that saw it, which then aborts the MPI job — MPI ends every rank.
//! * A **lost rank** (killed, crashed): `mpirun` ends the others; the
//!   manifest still names the last good checkpoint.

use std::process::ExitCode;

use anyhow::Context;
use weft_par::ranks::{MpiTransport, Transport};
use weft_par::{Ranks, Threads};
use weft_sim::SimError;

use super::{execute_prepared, new_job, prepare, write_trace, Prepared, RunArgs};

/// Whether this process was started by an MPI launcher (`mpirun`, `srun`).
pub fn launched() -> bool {
    [
        "OMPI_COMM_WORLD_SIZE",
        "PMI_SIZE",
        "PMIX_RANK",
        "MPI_LOCALNRANKS",
    ]
    .iter()
    .any(|v| std::env::var_os(v).is_some())
}

/// `weft run` as one MPI rank.
pub fn run(a: RunArgs) -> anyhow::Result<ExitCode> {
    if a.ranks > 1 {
        anyhow::bail!(
            "--ranks simulates ranks in one process; under mpirun the ranks are MPI's \
             (mpirun -n R weft run …)"
        );
    }
    let transport = MpiTransport::init().map_err(|e| anyhow::anyhow!("cannot start MPI: {e}"))?;
    let rank = transport.rank();
    // Everything a rank could refuse alone before the run's first collective.
    let setup = prepare(&a).and_then(|(scene, out, resume)| {
        let threads = Threads::new(a.threads).context("cannot start the worker threads")?;
        Ok((scene, out, resume, threads))
    });
    if let Some(code) = agree(&transport, &setup)? {
        return Ok(code);
    }
    let (scene, out, resume, threads) = setup?;
    // The world, whose internal step's estimate the ranks share (collective:
    // every rank builds the same world from the same scene, so they fail or
    // succeed alike), on `--resume` the checkpoint, read by every rank, and
    // the job (signal handlers, the progress interval from the environment).
    let workers = transport.size() * threads.threads();
    let prepared = {
        let ranks = Ranks::new(&transport, threads.clone());
        threads.install(|| Prepared::new(&scene, &out, resume, workers, &ranks))
    }
    .and_then(|prepared| Ok((prepared, new_job(&a, &scene, &out, resume)?)));
    if let Some(code) = agree(&transport, &prepared)? {
        return Ok(code);
    }
    let (prepared, job) = prepared?;
    let exec = Ranks::new(&transport, threads.clone());
    let result = threads.install(move || execute_prepared(job, prepared, exec));
    if let Some(path) = &a.trace {
        // One timeline per rank: rank 0 at the given path, rank r beside it.
        let path = if rank == 0 {
            path.clone()
        } else {
            path.with_extension(format!("rank{rank}.json"))
        };
        write_trace(&path, &scene.name, a.quiet || rank != 0)?;
    }
    match result {
        Ok(summary) => {
            if rank == 0 {
                println!("{}", serde_json::to_string(&summary)?);
            }
            // Every rank stopped at the same window: the same status.
            Ok(super::exit_status(&summary))
        }
        Err(e) => {
            let same_everywhere = matches!(
                e.downcast_ref::<SimError>(),
                Some(err) if !matches!(err, SimError::Ranks(_))
            );
            if same_everywhere {
                if rank == 0 {
                    eprintln!("error: {}", crate::error_text(&e));
                }
                return Ok(ExitCode::from(1));
            }
            eprintln!("error: on rank {rank}: {}", crate::error_text(&e));
            transport.abort(1)
        }
    }
}

/// **Collective.** Every rank's outcome of a step it could fail alone. When
/// any rank failed, rank 0 prints the error (naming the rank unless every
/// rank saw the same), and every rank gets the exit status 1 to end with.
fn agree<T>(
    transport: &MpiTransport,
    outcome: &anyhow::Result<T>,
) -> anyhow::Result<Option<ExitCode>> {
    let failed = (outcome.as_ref().err())
        .map(crate::error_text)
        .unwrap_or_default();
    let all = transport
        .all_gather(failed.into_bytes())
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let errors: Vec<(usize, String)> = all
        .into_iter()
        .enumerate()
        .filter(|(_, m)| !m.is_empty())
        .map(|(r, m)| (r, String::from_utf8_lossy(&m).into_owned()))
        .collect();
    let Some((r, text)) = errors.first() else {
        return Ok(None);
    };
    if transport.rank() == 0 {
        if errors.len() == transport.size() && errors.iter().all(|(_, t)| t == text) {
            eprintln!("error: {text}");
        } else {
            eprintln!("error: on rank {r}: {text}");
        }
    }
    Ok(Some(ExitCode::from(1)))
}
