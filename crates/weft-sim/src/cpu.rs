//! CPU time, as the counted evidence of parallel runs: what a rank's work
//! costs, apart from wall time (which oversubscribed ranks share) and apart
//! from the time it spends polling for its peers.
//!
//! A rank that is a process of its own (one process, or an MPI rank) counts
//! the CPU of all its threads ([`process_seconds`]); ranks simulated as
//! threads of one process count their own thread's ([`thread_seconds`]:
//! exact with one thread per rank).

/// CPU seconds the calling thread has used.
pub fn thread_seconds() -> f64 {
    cpu_time::ThreadTime::try_now().map_or(0.0, |t| t.as_duration().as_secs_f64())
}

/// CPU seconds every thread of this process has used.
pub fn process_seconds() -> f64 {
    cpu_time::ProcessTime::try_now().map_or(0.0, |t| t.as_duration().as_secs_f64())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Work advances both clocks by about its length; sleeping advances
    /// neither much.
    #[test]
    fn clocks_count_work_not_sleep() {
        let (t0, p0) = (thread_seconds(), process_seconds());
        std::thread::sleep(std::time::Duration::from_millis(50));
        let (t1, p1) = (thread_seconds(), process_seconds());
        assert!(t1 - t0 < 0.02, "{}", t1 - t0);
        assert!(p1 >= p0);
        let start = std::time::Instant::now();
        let mut x = 1u64;
        // Work until the thread clock says 60 ms (on a loaded machine
        // that takes longer than 60 ms of wall time).
        while thread_seconds() - t1 < 0.06 && start.elapsed().as_secs_f64() < 10.0 {
            x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
        }
        let (t2, p2) = (thread_seconds(), process_seconds());
        assert!(t2 - t1 > 0.05 && p2 - p1 > 0.05, "{} {}", t2 - t1, p2 - p1);
    }
}
