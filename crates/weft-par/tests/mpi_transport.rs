#![cfg(feature = "mpi")]
//! `MpiTransport` on real MPI ranks.
//!
//! MPI can be initialized once per process, so each test runs twice: as the
//! parent (no `WEFT_MPI_CHILD` in the environment) it starts
//! `mpirun -n 3 THIS_TEST_BINARY --exact TEST` and checks how that ended; as
//! a child (under mpirun, `WEFT_MPI_CHILD=1`) it is one rank.

use std::path::PathBuf;
use std::process::{Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use weft_par::ranks::{MpiTransport, Transport};

const RANKS: usize = 3;
/// An mpirun still running after this is killed, and the test fails.
const TIMEOUT: Duration = Duration::from_secs(120);

fn is_child() -> bool {
    std::env::var_os("WEFT_MPI_CHILD").is_some()
}

/// How an mpirun of this binary's test `test` on [`RANKS`] ranks ended.
struct Run {
    /// `None`: it ran past [`TIMEOUT`] and was killed.
    status: Option<ExitStatus>,
    stdout: String,
    stderr: String,
}

impl Run {
    fn report(&self) -> String {
        format!(
            "mpirun: {}\n--- stdout ---\n{}\n--- stderr ---\n{}",
            match self.status {
                Some(s) => format!("{s}"),
                None => format!("killed after {TIMEOUT:?}"),
            },
            tail(&self.stdout),
            tail(&self.stderr)
        )
    }
}

fn tail(s: &str) -> &str {
    const KEEP: usize = 8000;
    if s.len() <= KEEP {
        return s;
    }
    let mut start = s.len() - KEEP;
    while !s.is_char_boundary(start) {
        start += 1;
    }
    &s[start..]
}

/// Runs this binary's test `test` on [`RANKS`] ranks under mpirun ([`mpirun_n`]).
fn mpirun(test: &str) -> Run {
    mpirun_n(test, RANKS)
}

/// Runs this binary's test `test` on `ranks` ranks under mpirun, with the
/// environment OpenMPI needs here (set for the child, whatever the caller's
/// environment has): root allowed, more ranks than cores allowed, no
/// single-copy mechanism (containers forbid it).
fn mpirun_n(test: &str, ranks: usize) -> Run {
    let exe = std::env::current_exe().expect("the test binary's path");
    let dir = std::env::temp_dir();
    let stem = format!("weft-mpi-{}-{test}", std::process::id());
    let out_path: PathBuf = dir.join(format!("{stem}.out"));
    let err_path: PathBuf = dir.join(format!("{stem}.err"));
    // Output goes to files, not pipes: a rank left behind by a killed mpirun
    // cannot keep the parent waiting for the pipe to close.
    let out = std::fs::File::create(&out_path).expect("create stdout file");
    let err = std::fs::File::create(&err_path).expect("create stderr file");
    let mpirun = std::env::var_os("WEFT_MPIRUN").unwrap_or_else(|| "mpirun".into());
    let mut child = Command::new(&mpirun)
        .args(["-n", &ranks.to_string(), "--bind-to", "none"])
        .arg(&exe)
        .args(["--exact", test, "--nocapture", "--test-threads", "1"])
        .env("WEFT_MPI_CHILD", "1")
        .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
        .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
        .env("OMPI_MCA_rmaps_base_oversubscribe", "1")
        .env("OMPI_MCA_btl_vader_single_copy_mechanism", "none")
        .env("RUST_BACKTRACE", "1")
        .stdin(Stdio::null())
        .stdout(out)
        .stderr(err)
        .spawn()
        .unwrap_or_else(|e| panic!("cannot start {mpirun:?} (is OpenMPI installed?): {e}"));

    let started = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().expect("wait for mpirun") {
            break Some(status);
        }
        if started.elapsed() > TIMEOUT {
            // SIGTERM first: mpirun then ends its ranks; SIGKILL if it won't.
            let _ = Command::new("kill")
                .args(["-TERM", &child.id().to_string()])
                .status();
            let grace = Instant::now();
            while grace.elapsed() < Duration::from_secs(10) {
                if child.try_wait().ok().flatten().is_some() {
                    break;
                }
                std::thread::sleep(Duration::from_millis(100));
            }
            let _ = child.kill();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let read = |p: &PathBuf| {
        let s = String::from_utf8_lossy(&std::fs::read(p).unwrap_or_default()).into_owned();
        let _ = std::fs::remove_file(p);
        s
    };
    Run {
        status,
        stdout: read(&out_path),
        stderr: read(&err_path),
    }
}

/// Rank `rank`'s part in round `round`: lengths differ by rank and round,
/// and over the rounds every rank sends an empty part and one of about 1 MB.
fn part(rank: usize, round: usize) -> Vec<u8> {
    let len = match (rank + round) % 5 {
        0 => 0,
        1 => 1_000_003 + rank,
        2 => 1 + 17 * round + rank,
        3 => 4096 * (rank + 1) + round,
        _ => 65_537 - rank,
    };
    (0..len)
        .map(|i| (i.wrapping_mul(31) ^ rank.wrapping_mul(97) ^ round.wrapping_mul(13)) as u8)
        .collect()
}

const ROUNDS: usize = 20;

/// The collective tests' rank count: enough for Bruck's rounds to carry
/// several blocks (`c = 1, 2, 1` over rounds `d = 1, 2, 4`).
const GATHER_RANKS: usize = 5;

/// The pieces a gather round's message is cut into in the collective
/// tests: the 1 MB parts travel in many.
const LIMIT: usize = 100_000;

/// What rank `rank` of `size` sends in one Bruck all-gather of blocks of
/// `lens[j]` bytes (rank `j`'s), messages cut at [`LIMIT`]: (messages,
/// bytes). Round `d` sends the blocks of ranks `rank .. rank + min(d, R - d)`,
/// each with its length as a `u64`; a message of `n` bytes is `n / LIMIT + 1`
/// pieces (the last one shorter, possibly empty).
fn bruck_sent(rank: usize, size: usize, lens: &[usize]) -> (u64, u64) {
    let (mut messages, mut bytes) = (0u64, 0u64);
    let mut d = 1;
    while d < size {
        let c = d.min(size - d);
        let n: usize = (0..c).map(|i| 8 + lens[(rank + i) % size]).sum();
        messages += (n / LIMIT + 1) as u64;
        bytes += n as u64;
        d *= 2;
    }
    (messages, bytes)
}

#[test]
fn all_gather_over_mpi_on_five_ranks() {
    if !is_child() {
        let run = mpirun_n("all_gather_over_mpi_on_five_ranks", GATHER_RANKS);
        assert!(run.status.is_some_and(|s| s.success()), "{}", run.report());
        for rank in 0..GATHER_RANKS {
            assert!(
                run.stdout
                    .contains(&format!("rank {rank}/{GATHER_RANKS}: {ROUNDS} rounds ok")),
                "rank {rank} did not report\n{}",
                run.report()
            );
        }
        return;
    }

    let mut transport = MpiTransport::init().expect("initialize MPI");
    assert!(
        MpiTransport::init().is_err(),
        "MPI must not initialize twice"
    );
    transport.set_message_limit(LIMIT);
    let (rank, size) = (transport.rank(), transport.size());
    assert_eq!(size, GATHER_RANKS);
    assert!(rank < size);

    let (mut messages, mut bytes) = (0u64, 0u64);
    let mut gather = |lens: &[usize], all: Vec<Vec<u8>>| {
        let sent = bruck_sent(rank, size, lens);
        messages += sent.0;
        bytes += sent.1;
        all
    };
    for round in 0..ROUNDS {
        let lens: Vec<usize> = (0..size).map(|j| part(j, round).len()).collect();
        let all = gather(
            &lens,
            transport.all_gather(part(rank, round)).expect("all_gather"),
        );
        assert_eq!(all.len(), size, "round {round}");
        for (j, got) in all.iter().enumerate() {
            let want = part(j, round);
            assert!(
                got == &want,
                "rank {rank}, round {round}: rank {j}'s part differs ({} bytes, want {})",
                got.len(),
                want.len()
            );
        }
    }
    // Every rank saw an empty part and a 1 MB one.
    assert!((0..ROUNDS).any(|r| part(rank, r).is_empty()));
    assert!((0..ROUNDS).any(|r| part(rank, r).len() > 1_000_000));

    // A round in which nobody sends a byte.
    let nothing = gather(
        &[0; GATHER_RANKS],
        transport.all_gather(Vec::new()).expect("all-empty round"),
    );
    assert_eq!(nothing, vec![Vec::<u8>::new(); size]);

    // Every round's message exactly a whole number of pieces: each ends
    // with an empty one.
    let exact = vec![LIMIT - 8; GATHER_RANKS];
    let all = gather(
        &exact,
        transport
            .all_gather(vec![rank as u8; LIMIT - 8])
            .expect("exact pieces"),
    );
    for (j, got) in all.iter().enumerate() {
        assert_eq!(got, &vec![j as u8; LIMIT - 8]);
    }

    let traffic = transport.traffic();
    assert_eq!((traffic.messages, traffic.bytes), (messages, bytes));
    assert_eq!(traffic.collectives, ROUNDS as u64 + 2);

    // From another thread too (the thread level is Serialized, not Funneled).
    let from_thread = std::thread::scope(|s| {
        s.spawn(|| transport.all_gather(vec![rank as u8; rank]))
            .join()
            .expect("all_gather thread")
    })
    .expect("all_gather from a spawned thread");
    assert_eq!(
        from_thread,
        (0..size).map(|j| vec![j as u8; j]).collect::<Vec<_>>()
    );

    transport.barrier();
    println!("rank {rank}/{size}: {ROUNDS} rounds ok");
    drop(transport);
}

/// The bytes rank `from` sends rank `to` in all-to-all round `round`.
fn message(from: usize, to: usize, round: usize) -> Vec<u8> {
    let mut bytes = part(from, round + to);
    bytes.iter_mut().for_each(|b| *b ^= to as u8);
    bytes
}

/// The words rank `from` sends rank `to` in exchange `round`: bit patterns
/// a value conversion would change (NaN payloads, a signalling NaN, signed
/// zeros, subnormals, infinities) among ordinary ones, of a length that
/// varies with the pair and the round (sometimes none).
fn words_message(from: usize, to: usize, round: usize) -> Vec<f64> {
    let special = [
        f64::from_bits(0x7ff8_0000_dead_beef),
        f64::from_bits(0x7ff0_0000_0000_0001),
        f64::from_bits(0xfff8_0000_0000_0042),
        -0.0,
        0.0,
        f64::from_bits(1),
        -f64::MIN_POSITIVE / 3.0,
        f64::INFINITY,
        f64::NEG_INFINITY,
    ];
    let len = part(from, round + to).len() / 8;
    (0..len)
        .map(|i| {
            if i % 7 == 3 {
                special[(i / 7 + from + round) % special.len()]
            } else {
                f64::from_bits((i as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ ((to as u64) << 52))
            }
        })
        .collect()
}

/// Whether two word lists hold the same bits.
fn same_bits(a: &[f64], b: &[f64]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
}

#[test]
fn exchange_over_mpi_on_three_ranks() {
    if !is_child() {
        let run = mpirun("exchange_over_mpi_on_three_ranks");
        assert!(run.status.is_some_and(|s| s.success()), "{}", run.report());
        for rank in 0..RANKS {
            assert!(
                run.stdout
                    .contains(&format!("rank {rank}/{RANKS}: {ROUNDS} exchanges ok")),
                "rank {rank} did not report\n{}",
                run.report()
            );
        }
        return;
    }

    let transport = MpiTransport::init().expect("initialize MPI");
    let (rank, size) = (transport.rank(), transport.size());
    let mut expected_bytes = 0u64;
    for round in 0..ROUNDS {
        // Even rounds: every rank to every other; odd rounds: a ring (to the
        // next rank, from the previous), as partitions' neighbours would.
        let peers: Vec<(usize, usize)> = if round % 2 == 0 {
            (0..size).filter(|&j| j != rank).map(|j| (j, j)).collect()
        } else {
            vec![((rank + 1) % size, (rank + size - 1) % size)]
        };
        let sends: Vec<(usize, Vec<f64>)> = peers
            .iter()
            .map(|&(to, _)| (to, words_message(rank, to, round)))
            .collect();
        let recvs: Vec<(usize, usize)> = peers
            .iter()
            .map(|&(_, from)| (from, words_message(from, rank, round).len()))
            .collect();
        expected_bytes += sends.iter().map(|(_, w)| 8 * w.len() as u64).sum::<u64>();
        let mut overlapped = 0;
        let got = transport
            .exchange(sends, &recvs, &mut || overlapped += 1)
            .expect("exchange");
        assert_eq!(overlapped, 1);
        for (&(from, _), words) in recvs.iter().zip(&got) {
            assert!(
                same_bits(words, &words_message(from, rank, round)),
                "rank {rank}, round {round}: the message from rank {from} differs"
            );
        }
        // A collective between exchanges must not be confused with them.
        let all = transport
            .all_gather(vec![round as u8; rank])
            .expect("all_gather");
        assert_eq!(all[(rank + 1) % size], vec![round as u8; (rank + 1) % size]);
    }
    let lens: Vec<usize> = (0..size).collect();
    let gathered = ROUNDS as u64 * bruck_sent(rank, size, &lens).1;
    let exchanged = transport.traffic().bytes - gathered;
    assert_eq!(exchanged, expected_bytes);
    transport.barrier();
    println!("rank {rank}/{size}: {ROUNDS} exchanges ok");
    drop(transport);
}

#[test]
fn all_to_all_over_mpi_on_five_ranks() {
    if !is_child() {
        let run = mpirun_n("all_to_all_over_mpi_on_five_ranks", GATHER_RANKS);
        assert!(run.status.is_some_and(|s| s.success()), "{}", run.report());
        for rank in 0..GATHER_RANKS {
            assert!(
                run.stdout.contains(&format!(
                    "rank {rank}/{GATHER_RANKS}: {ROUNDS} all-to-alls ok"
                )),
                "rank {rank} did not report\n{}",
                run.report()
            );
        }
        return;
    }

    let mut transport = MpiTransport::init().expect("initialize MPI");
    transport.set_message_limit(LIMIT);
    let (rank, size) = (transport.rank(), transport.size());
    let (mut messages, mut bytes) = (0u64, 0u64);
    for round in 0..ROUNDS {
        // Each peer its own part (empty ones too, and 1 MB ones over the
        // rounds), a head of `round % 3` words (none in some rounds), and a
        // barrier between rounds.
        let head: Vec<u64> = (0..round % 3)
            .map(|k| (100 * rank + 10 * round + k) as u64)
            .collect();
        let parts: Vec<Vec<u8>> = (0..size).map(|j| message(rank, j, round)).collect();
        for (j, p) in parts.iter().enumerate() {
            if j != rank && !p.is_empty() {
                messages += 1;
                bytes += p.len() as u64;
            }
        }
        // The gathered head blocks: a flag, the word count, the head, the
        // count of non-empty parts to others and a peer and length each.
        let blocks: Vec<usize> = (0..size)
            .map(|j| {
                let sent = (0..size)
                    .filter(|&k| k != j && !message(j, k, round).is_empty())
                    .count();
                8 * (3 + head.len() + 2 * sent)
            })
            .collect();
        let gathered = bruck_sent(rank, size, &blocks);
        messages += gathered.0;
        bytes += gathered.1;
        // Pieces of work run while the messages travel, at most the five
        // offered.
        let mut overlapped = 0;
        let mut overlap = || {
            overlapped += 1;
            overlapped < 5
        };
        let (heads, got) = (transport.all_to_all(head, parts, &mut overlap)).expect("all_to_all");
        assert!(
            overlapped <= 5,
            "rank {rank}, round {round}: {overlapped} pieces"
        );
        assert_eq!((heads.len(), got.len()), (size, size), "round {round}");
        for j in 0..size {
            let want: Vec<u64> = (0..round % 3)
                .map(|k| (100 * j + 10 * round + k) as u64)
                .collect();
            assert_eq!(
                heads[j], want,
                "rank {rank}, round {round}: rank {j}'s head"
            );
            let want = message(j, rank, round);
            assert!(
                got[j] == want,
                "rank {rank}, round {round}: rank {j}'s part differs ({} bytes, want {})",
                got[j].len(),
                want.len()
            );
        }
        transport.barrier();
    }
    let traffic = transport.traffic();
    assert_eq!((traffic.messages, traffic.bytes), (messages, bytes));
    assert_eq!(traffic.collectives, ROUNDS as u64);
    println!("rank {rank}/{size}: {ROUNDS} all-to-alls ok");
    drop(transport);
}

#[test]
fn abort_on_one_rank_ends_every_rank() {
    if !is_child() {
        let run = mpirun("abort_on_one_rank_ends_every_rank");
        let status = run
            .status
            .unwrap_or_else(|| panic!("mpirun hung after a rank aborted\n{}", run.report()));
        assert!(!status.success(), "{}", run.report());
        // OpenMPI's mpirun exits with the code the aborting rank gave.
        assert_eq!(status.code(), Some(3), "{}", run.report());
        assert!(
            !run.stdout.contains("returned after the abort"),
            "{}",
            run.report()
        );
        return;
    }

    let transport = MpiTransport::init().expect("initialize MPI");
    let rank = transport.rank();
    let all = transport.all_gather(vec![rank as u8]).expect("all_gather");
    assert_eq!(all, vec![vec![0], vec![1], vec![2]]);
    if rank == 1 {
        // Let the others get into their next collective first.
        std::thread::sleep(Duration::from_millis(300));
        transport.abort(3);
    }
    // Rank 1 never joins this one: only the abort can end it.
    let result = transport.all_gather(vec![rank as u8]);
    println!("rank {rank}: all_gather returned after the abort: {result:?}");
    std::process::exit(0);
}

#[test]
fn a_panicking_rank_ends_every_rank() {
    if !is_child() {
        let run = mpirun("a_panicking_rank_ends_every_rank");
        let status = run
            .status
            .unwrap_or_else(|| panic!("mpirun hung after a rank panicked\n{}", run.report()));
        assert!(!status.success(), "{}", run.report());
        assert!(
            run.stderr.contains("rank 2 panics on purpose"),
            "{}",
            run.report()
        );
        assert!(
            !run.stdout.contains("returned after the panic"),
            "{}",
            run.report()
        );
        return;
    }

    let transport = MpiTransport::init().expect("initialize MPI");
    let rank = transport.rank();
    transport.all_gather(vec![rank as u8]).expect("all_gather");
    if rank == 2 {
        std::thread::sleep(Duration::from_millis(300));
        // Unwinding drops the transport: that must abort every rank, not
        // finalize (which would wait for the others, who wait for rank 2).
        panic!("rank 2 panics on purpose");
    }
    let result = transport.all_gather(vec![rank as u8]);
    println!("rank {rank}: all_gather returned after the panic: {result:?}");
    std::process::exit(0);
}
