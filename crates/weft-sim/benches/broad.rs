//! Broad-phase wall time on a folded 50k-triangle grid with trajectories:
//! `Serial` against a small scoped-thread executor with 1 and 2 threads
//! (weft-sim cannot use weft-par's `Threads`; `weft bench` times the real one
//! inside whole windows), with all triangles in one tree and grouped as 64
//! and 256 partitions would be (contiguous runs: rows of the grid).
//!
//! `cargo bench -p weft-sim --bench broad`

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::Instant;

use glam::DVec3;
use weft_geom::shapes::grid;
use weft_sim::broad::BroadPhase;
use weft_sim::trajectory::Trajectories;
use weft_sim::{Executor, Serial};

/// `n` scoped threads taking chunks / map items from a shared queue.
struct Scoped(usize);

impl Executor for Scoped {
    fn for_each_chunk<T: Send>(
        &self,
        data: &mut [T],
        bounds: &[usize],
        task: &(dyn Fn(usize, &mut [T]) + Sync),
    ) {
        let chunks = weft_sim::executor::split_chunks(data, bounds);
        let queue = Mutex::new(chunks.into_iter());
        std::thread::scope(|s| {
            for _ in 0..self.0 {
                s.spawn(|| loop {
                    let next = queue.lock().unwrap().next();
                    match next {
                        Some((k, chunk)) => task(k, chunk),
                        None => break,
                    }
                });
            }
        });
    }

    fn map<R: Send>(&self, n: usize, f: &(dyn Fn(usize) -> R + Sync)) -> Vec<R> {
        let next = AtomicUsize::new(0);
        let mut parts: Vec<Vec<(usize, R)>> = std::thread::scope(|s| {
            let handles: Vec<_> = (0..self.0)
                .map(|_| {
                    s.spawn(|| {
                        let mut out = Vec::new();
                        loop {
                            let i = next.fetch_add(1, Ordering::Relaxed);
                            if i >= n {
                                break out;
                            }
                            out.push((i, f(i)));
                        }
                    })
                })
                .collect();
            handles.into_iter().map(|h| h.join().unwrap()).collect()
        });
        let mut all: Vec<(usize, R)> = parts.drain(..).flatten().collect();
        all.sort_unstable_by_key(|(i, _)| *i);
        all.into_iter().map(|(_, r)| r).collect()
    }

    fn name(&self) -> String {
        format!("scoped({})", self.0)
    }
}

/// A `res × res` grid folded over itself with noise and `steps` breakpoints
/// per vertex (every vertex moves at every step).
fn folded(res: usize, steps: u64) -> (Vec<[u32; 3]>, Vec<f64>, Trajectories, f64) {
    let mesh = grid(DVec3::ZERO, DVec3::X, DVec3::Y, [1.0, 1.0], [res, res]);
    let h = 1.0 / (res - 1) as f64;
    let mut s = 1u64;
    let mut rnd = move || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    let x: Vec<DVec3> = mesh
        .positions
        .iter()
        .map(|p| {
            let q = if p.x > 0.0 {
                DVec3::new(-p.x, p.y, 0.5 * h + 0.2 * p.x * p.x)
            } else {
                *p
            };
            q + DVec3::new(rnd(), rnd(), rnd()) * 0.2 * h
        })
        .collect();
    let mut traj = Trajectories::new(x.len(), usize::MAX);
    traj.begin(0, &x);
    for k in 1..=steps {
        for (i, p) in x.iter().enumerate() {
            let d = DVec3::new(rnd(), rnd(), rnd()) * 0.05 * h * k as f64;
            traj.record(i, 64 * k, *p + d).unwrap();
        }
    }
    let inv_mass = vec![1.0; x.len()];
    (mesh.triangles, inv_mass, traj, 0.25 * h)
}

fn time<E: Executor>(
    exec: &E,
    groups: usize,
    tris: &[[u32; 3]],
    m: &[f64],
    traj: &Trajectories,
    inflate: f64,
) {
    let labels: Vec<u32> = (0..tris.len())
        .map(|t| (t * groups / tris.len()) as u32)
        .collect();
    let mut bp = BroadPhase::grouped(&labels);
    let mut n = bp
        .candidates_on(exec, tris, m, traj, inflate)
        .unwrap()
        .len();
    let mut best = f64::INFINITY;
    for _ in 0..7 {
        let t = Instant::now();
        n = bp
            .candidates_on(exec, tris, m, traj, inflate)
            .unwrap()
            .len();
        best = best.min(t.elapsed().as_secs_f64());
    }
    println!(
        "{:>10}, {groups:>3} groups: {:8.2} ms (best of 7, warm workspace; {} pairs, {} hull pairs, {} candidates)",
        exec.name(),
        best * 1e3,
        bp.last_pairs,
        bp.last_group_pairs.len(),
        n
    );
}

/// Serial stage times, from the public pieces (not the broad phase itself).
fn stages(tris: &[[u32; 3]], m: &[f64], traj: &Trajectories, inflate: f64) {
    use weft_geom::bvh::Bvh;
    use weft_geom::dop::Dop26;
    use weft_sim::broad::{primitives_overlap, stencils_of_pair};
    let t = Instant::now();
    let vd: Vec<Dop26> = (0..traj.len())
        .map(|i| Dop26::from_points(traj.of(i).points.iter().copied()))
        .collect();
    let td: Vec<Dop26> = tris
        .iter()
        .map(|t| {
            let mut d = vd[t[0] as usize];
            d.merge(&vd[t[1] as usize]);
            d.merge(&vd[t[2] as usize]);
            d.inflate(inflate);
            d
        })
        .collect();
    let t_dops = t.elapsed().as_secs_f64();
    let mut bvh = Bvh::build(&td);
    let t = Instant::now();
    bvh.refit(&td);
    let t_refit = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let mut pairs = Vec::new();
    bvh.self_overlaps(|a, b| pairs.push((a, b)));
    let t_trav = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let mut keys = Vec::new();
    for &(a, b) in &pairs {
        stencils_of_pair(tris[a as usize], tris[b as usize], m, &mut keys);
    }
    let t_gen = t.elapsed().as_secs_f64();
    let raw = keys.len();
    let t = Instant::now();
    keys.sort_unstable();
    keys.dedup();
    let t_sort = t.elapsed().as_secs_f64();
    let unique = keys.len();
    let t = Instant::now();
    keys.retain(|k| primitives_overlap(&vd, k, inflate));
    let t_filter = t.elapsed().as_secs_f64();
    println!(
        "serial stages (ms): dops {:.1}, refit {:.1}, traversal {:.1}, stencils {:.1} ({raw} keys), \
         sort+dedup {:.1} ({unique} unique), filter {:.1} ({} left)",
        t_dops * 1e3,
        t_refit * 1e3,
        t_trav * 1e3,
        t_gen * 1e3,
        t_sort * 1e3,
        t_filter * 1e3,
        keys.len()
    );
}

fn main() {
    let (tris, m, traj, inflate) = folded(160, 3);
    println!(
        "broad phase: {} triangles, {} vertices, {} breakpoints",
        tris.len(),
        traj.len(),
        traj.breakpoints()
    );
    stages(&tris, &m, &traj, inflate);
    for groups in [1, 64, 256] {
        time(&Serial, groups, &tris, &m, &traj, inflate);
        time(&Scoped(1), groups, &tris, &m, &traj, inflate);
        time(&Scoped(2), groups, &tris, &m, &traj, inflate);
    }
}
