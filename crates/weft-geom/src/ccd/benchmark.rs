//! Reader and runner for the public CCD benchmarks (`shared/data/ccd`).
//!
//! Two layouts are recognized while walking a root folder recursively (in
//! sorted, deterministic order):
//!
//! * **wang2021** (Wang et al. 2021): `<scene>/{vertex-face,edge-edge}/data_*.csv`,
//!   8 rows per query (`x0..x3` at t = 0, then at t = 1), 7 integer columns per
//!   row: numerator/denominator of x, y, z and the 0/1 ground truth (equal on
//!   all 8 rows). One [`BenchFolder`] per `vertex-face` / `edge-edge` folder.
//! * **belgrod2023** (Belgrod et al. 2023): `<scene>/queries/<step>{vf,ee}.csv`
//!   with 6 columns (no truth) and the truth in
//!   `<scene>/mma_bool/<step>{vf,ee}_mma_bool.json` (a JSON array of booleans,
//!   one per query). One [`BenchFolder`] per csv file.
//!
//! Coordinates are big-integer fractions; each is converted **exactly** to an
//! `f64` (an error names file and line when it is not exactly representable).
//! Queries are linear motions from t = 0 to t = 1, answered with
//! [`super::linear_proximity`].

use std::path::{Path, PathBuf};
use std::time::Instant;

use num_bigint::BigInt;
use num_rational::BigRational;
use num_traits::{One, Signed, ToPrimitive, Zero};
use serde::Serialize;
use weft_core::{DVec3, StencilKind};

use super::{linear_proximity, CcdStats};

/// One CCD query: linear motion from `start` (t = 0) to `end` (t = 1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CcdQuery {
    /// vertex–face or edge–edge.
    pub kind: StencilKind,
    /// positions at t = 0 (VF: `[p, a, b, c]`, EE: `[p0, p1, q0, q1]`).
    pub start: [DVec3; 4],
    /// positions at t = 1.
    pub end: [DVec3; 4],
    /// ground truth: the primitives touch or cross at some t in [0, 1].
    pub truth: bool,
}

/// The queries of one benchmark folder (wang2021) or file (belgrod2023), all
/// of one kind.
#[derive(Clone, Debug)]
pub struct BenchFolder {
    /// the `vertex-face`/`edge-edge` folder or the belgrod query csv file.
    pub path: PathBuf,
    /// the queries in file order.
    pub queries: Vec<CcdQuery>,
}

/// Errors while reading benchmark data.
///
/// When it occurs: the path does not exist or cannot be read, or a file is
/// malformed. How to handle it: the message names the file (and line); fix or
/// remove that file, or point the reader at the right folder.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CcdDataError {
    /// a file or folder could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// the path.
        path: PathBuf,
        /// the cause.
        source: std::io::Error,
    },
    /// a file's content is malformed.
    #[error("{path}:{line}: {message}")]
    Malformed {
        /// the file.
        path: PathBuf,
        /// 1-based line (0 when the problem is not on one line).
        line: usize,
        /// what is wrong.
        message: String,
    },
    /// no benchmark data under the root.
    #[error("no CCD benchmark data (wang2021 or belgrod2023 layout) found under {0}")]
    NoData(PathBuf),
}

fn malformed(path: &Path, line: usize, message: impl Into<String>) -> CcdDataError {
    CcdDataError::Malformed {
        path: path.to_path_buf(),
        line,
        message: message.into(),
    }
}

fn io_err(path: &Path, source: std::io::Error) -> CcdDataError {
    CcdDataError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Loads every benchmark folder under `root` (or `root` itself when it is
/// one), in sorted path order.
pub fn load_benchmark(root: &Path) -> Result<Vec<BenchFolder>, CcdDataError> {
    let meta = std::fs::metadata(root).map_err(|e| io_err(root, e))?;
    let mut out = Vec::new();
    if meta.is_file() {
        load_belgrod_file(root, &mut out)?;
    } else {
        walk(root, &mut out)?;
    }
    if out.is_empty() {
        return Err(CcdDataError::NoData(root.to_path_buf()));
    }
    Ok(out)
}

fn sorted_entries(dir: &Path) -> Result<Vec<PathBuf>, CcdDataError> {
    let mut v = Vec::new();
    for e in std::fs::read_dir(dir).map_err(|e| io_err(dir, e))? {
        v.push(e.map_err(|e| io_err(dir, e))?.path());
    }
    v.sort();
    Ok(v)
}

fn walk(dir: &Path, out: &mut Vec<BenchFolder>) -> Result<(), CcdDataError> {
    let name = dir.file_name().and_then(|s| s.to_str()).unwrap_or("");
    let entries = sorted_entries(dir)?;
    let wang_kind = match name {
        "vertex-face" => Some(StencilKind::VertexFace),
        "edge-edge" => Some(StencilKind::EdgeEdge),
        _ => None,
    };
    if let Some(kind) = wang_kind {
        let mut queries = Vec::new();
        for f in &entries {
            let fname = f.file_name().and_then(|s| s.to_str()).unwrap_or("");
            if f.is_file() && fname.starts_with("data_") && fname.ends_with(".csv") {
                parse_wang_csv(f, kind, &mut queries)?;
            }
        }
        if !queries.is_empty() {
            out.push(BenchFolder {
                path: dir.to_path_buf(),
                queries,
            });
        }
    }
    if name == "queries" {
        for f in &entries {
            if f.is_file() && f.extension().and_then(|s| s.to_str()) == Some("csv") {
                load_belgrod_file(f, out)?;
            }
        }
    }
    for e in &entries {
        if e.is_dir() {
            walk(e, out)?;
        }
    }
    Ok(())
}

/// Loads one belgrod query csv (`<scene>/queries/<step>{vf,ee}.csv`) with its
/// truth file; files whose name does not end in `vf`/`ee` are skipped.
fn load_belgrod_file(f: &Path, out: &mut Vec<BenchFolder>) -> Result<(), CcdDataError> {
    let stem = f.file_stem().and_then(|s| s.to_str()).unwrap_or("");
    let kind = if stem.ends_with("vf") {
        StencilKind::VertexFace
    } else if stem.ends_with("ee") {
        StencilKind::EdgeEdge
    } else {
        return Ok(());
    };
    let scene = f.parent().and_then(Path::parent).unwrap_or(Path::new("."));
    let truth_path = scene.join("mma_bool").join(format!("{stem}_mma_bool.json"));
    let truth_text = std::fs::read_to_string(&truth_path).map_err(|e| io_err(&truth_path, e))?;
    let truth: Vec<bool> = serde_json::from_str(&truth_text).map_err(|e| {
        malformed(
            &truth_path,
            e.line(),
            format!("expected a JSON array of booleans: {e}"),
        )
    })?;
    let rows = parse_rows(f, 6)?;
    if rows.len() != truth.len() * 8 {
        return Err(malformed(
            f,
            0,
            format!(
                "{} rows but {} truth values in {} (expected 8 rows per query)",
                rows.len(),
                truth.len(),
                truth_path.display()
            ),
        ));
    }
    let queries = rows
        .chunks_exact(8)
        .zip(truth)
        .map(|(q, truth)| CcdQuery {
            kind,
            start: std::array::from_fn(|i| q[i].0),
            end: std::array::from_fn(|i| q[i + 4].0),
            truth,
        })
        .collect();
    out.push(BenchFolder {
        path: f.to_path_buf(),
        queries,
    });
    Ok(())
}

fn parse_wang_csv(
    f: &Path,
    kind: StencilKind,
    queries: &mut Vec<CcdQuery>,
) -> Result<(), CcdDataError> {
    let rows = parse_rows(f, 7)?;
    if rows.len() % 8 != 0 {
        return Err(malformed(
            f,
            0,
            format!("{} rows is not a multiple of 8", rows.len()),
        ));
    }
    for q in rows.chunks_exact(8) {
        let bit = q[0].1;
        if let Some(r) = q.iter().find(|r| r.1 != bit) {
            return Err(malformed(
                f,
                r.2,
                "ground-truth bit differs within one query",
            ));
        }
        queries.push(CcdQuery {
            kind,
            start: std::array::from_fn(|i| q[i].0),
            end: std::array::from_fn(|i| q[i + 4].0),
            truth: bit,
        });
    }
    Ok(())
}

/// Parses the non-empty lines of a csv with `cols` integer columns into
/// (point, truth bit, line number); the bit is `false` for 6 columns.
fn parse_rows(f: &Path, cols: usize) -> Result<Vec<(DVec3, bool, usize)>, CcdDataError> {
    let text = std::fs::read_to_string(f).map_err(|e| io_err(f, e))?;
    let mut rows = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let ln = i + 1;
        let line = line.trim();
        if line.is_empty() {
            continue;
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        if fields.len() != cols {
            return Err(malformed(
                f,
                ln,
                format!("expected {cols} columns, found {}", fields.len()),
            ));
        }
        let mut ints = Vec::with_capacity(cols);
        for s in &fields {
            let v: BigInt = s
                .parse()
                .map_err(|_| malformed(f, ln, format!("not an integer: {s:?}")))?;
            ints.push(v);
        }
        let mut c = [0.0; 3];
        for k in 0..3 {
            c[k] = exact_f64(&ints[2 * k], &ints[2 * k + 1])
                .map_err(|m| malformed(f, ln, format!("coordinate {k}: {m}")))?;
        }
        let bit = if cols == 7 {
            if ints[6].is_zero() {
                false
            } else if ints[6].is_one() {
                true
            } else {
                return Err(malformed(f, ln, "ground truth must be 0 or 1"));
            }
        } else {
            false
        };
        rows.push((DVec3::new(c[0], c[1], c[2]), bit, ln));
    }
    Ok(rows)
}

/// The `f64` equal to `num / den`, or an error when it is not exactly
/// representable (or `den` is zero).
pub fn exact_f64(num: &BigInt, den: &BigInt) -> Result<f64, String> {
    if den.is_zero() {
        return Err("zero denominator".into());
    }
    let r = BigRational::new(num.clone(), den.clone());
    let not_exact = || format!("{num}/{den} is not exactly representable as an f64");
    // Reduced denominator must be 2^k, reduced numerator an odd m times 2^z
    // with m < 2^53.
    let d = r.denom();
    let k = d.bits() - 1;
    if d != &(BigInt::one() << k) {
        return Err(not_exact());
    }
    let n = r.numer().abs();
    if n.is_zero() {
        return Ok(0.0);
    }
    let z = n.trailing_zeros().unwrap_or(0);
    let m = &n >> z;
    if m.bits() > 53 {
        return Err(not_exact());
    }
    let mut v = m.to_f64().ok_or_else(not_exact)?;
    let mut e = z as i64 - k as i64;
    // Scale by powers of two in exact steps (exact as long as the value stays
    // normal; verified below).
    while e > 0 {
        let s = e.min(512);
        v *= 2f64.powi(s as i32);
        e -= s;
    }
    while e < 0 {
        let s = (-e).min(512);
        v *= 2f64.powi(-(s as i32));
        e += s;
    }
    if r.is_negative() {
        v = -v;
    }
    if BigRational::from_float(v).as_ref() == Some(&r) {
        Ok(v)
    } else {
        Err(not_exact())
    }
}

/// Timing and accuracy figures of a set of queries.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct BenchSummary {
    /// number of queries.
    pub queries: u64,
    /// truth "yes" answered "no" (must be 0).
    pub false_negatives: u64,
    /// truth "no" answered "yes".
    pub false_positives: u64,
    /// mean wall-clock time per query (ns).
    pub ns_per_query: f64,
    /// median time per query (ns).
    pub median_ns: f64,
    /// slowest query (ns).
    pub max_ns: f64,
    /// narrow-phase counters over these queries.
    pub stats: CcdStats,
}

impl BenchSummary {
    fn from_samples(times: &mut [u64], fneg: u64, fpos: u64, stats: CcdStats) -> BenchSummary {
        times.sort_unstable();
        let n = times.len();
        let mean = if n == 0 {
            0.0
        } else {
            times.iter().map(|&t| t as f64).sum::<f64>() / n as f64
        };
        let median = match n {
            0 => 0.0,
            _ if n % 2 == 1 => times[n / 2] as f64,
            _ => 0.5 * (times[n / 2 - 1] as f64 + times[n / 2] as f64),
        };
        BenchSummary {
            queries: n as u64,
            false_negatives: fneg,
            false_positives: fpos,
            ns_per_query: mean,
            median_ns: median,
            max_ns: times.last().copied().unwrap_or(0) as f64,
            stats,
        }
    }
}

/// Figures of one [`BenchFolder`].
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FolderReport {
    /// the folder (or belgrod csv file).
    pub path: String,
    /// `"vertex-face"`, `"edge-edge"` or `"mixed"`.
    pub kind: String,
    /// its figures.
    #[serde(flatten)]
    pub summary: BenchSummary,
}

/// Result of [`run_benchmark`].
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct BenchReport {
    /// the `eta` used.
    pub eta: f64,
    /// one entry per folder, in input order.
    pub folders: Vec<FolderReport>,
    /// all vertex–face queries.
    pub vertex_face: BenchSummary,
    /// all edge–edge queries.
    pub edge_edge: BenchSummary,
    /// all queries.
    pub total: BenchSummary,
}

impl BenchReport {
    /// Pretty JSON of the whole report.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).unwrap_or_else(|e| format!("{{\"error\":\"{e}\"}}"))
    }

    /// A plain-text table (one line per folder, then the totals).
    pub fn to_table(&self) -> String {
        let mut s = format!(
            "{:<60} {:>7} {:>4} {:>5} {:>11} {:>11} {:>11}\n",
            "folder", "queries", "FN", "FP", "mean ns", "median ns", "max ns"
        );
        let line = |s: &mut String, name: &str, b: &BenchSummary| {
            s.push_str(&format!(
                "{:<60} {:>7} {:>4} {:>5} {:>11.0} {:>11.0} {:>11.0}\n",
                name,
                b.queries,
                b.false_negatives,
                b.false_positives,
                b.ns_per_query,
                b.median_ns,
                b.max_ns
            ));
        };
        for f in &self.folders {
            line(&mut s, &f.path, &f.summary);
        }
        line(&mut s, "all vertex-face", &self.vertex_face);
        line(&mut s, "all edge-edge", &self.edge_edge);
        line(&mut s, "all", &self.total);
        s
    }
}

fn kind_name(kind: StencilKind) -> &'static str {
    match kind {
        StencilKind::VertexFace => "vertex-face",
        StencilKind::EdgeEdge => "edge-edge",
    }
}

/// Runs every query of `folders` once with [`linear_proximity`] at separation
/// `eta`, timing each query with [`Instant`] (parsing excluded).
pub fn run_benchmark(folders: &[BenchFolder], eta: f64) -> BenchReport {
    run_benchmark_repeated(folders, eta, 1)
}

/// As [`run_benchmark`], but each query runs `repeats` times (at least once)
/// back to back and its time is the fastest run: this filters out preemption
/// by other processes, which otherwise dominates `max_ns` on a busy machine.
/// The answer of every run is the same (the predicate is deterministic); the
/// counters are those of the first run.
pub fn run_benchmark_repeated(folders: &[BenchFolder], eta: f64, repeats: u32) -> BenchReport {
    let mut all: [(Vec<u64>, u64, u64, CcdStats); 2] = Default::default();
    let mut reports = Vec::with_capacity(folders.len());
    for folder in folders {
        let mut times = Vec::with_capacity(folder.queries.len());
        let (mut fneg, mut fpos) = (0, 0);
        let mut stats = CcdStats::default();
        for q in &folder.queries {
            let mut qs = CcdStats::default();
            let t = Instant::now();
            let yes = linear_proximity(q.kind, &q.start, &q.end, eta, &mut qs);
            let mut ns = t.elapsed().as_nanos().min(u64::MAX as u128) as u64;
            for _ in 1..repeats {
                let mut scratch = CcdStats::default();
                let t = Instant::now();
                let again = linear_proximity(q.kind, &q.start, &q.end, eta, &mut scratch);
                ns = ns.min(t.elapsed().as_nanos().min(u64::MAX as u128) as u64);
                debug_assert_eq!(again, yes);
            }
            times.push(ns);
            let slot = &mut all[matches!(q.kind, StencilKind::EdgeEdge) as usize];
            slot.0.push(ns);
            slot.3.merge(&qs);
            stats.merge(&qs);
            if q.truth && !yes {
                fneg += 1;
                slot.1 += 1;
            }
            if !q.truth && yes {
                fpos += 1;
                slot.2 += 1;
            }
        }
        let kind = match folder.queries.first() {
            Some(q0) if folder.queries.iter().all(|q| q.kind == q0.kind) => kind_name(q0.kind),
            Some(_) => "mixed",
            None => "empty",
        };
        reports.push(FolderReport {
            path: folder.path.display().to_string(),
            kind: kind.to_string(),
            summary: BenchSummary::from_samples(&mut times, fneg, fpos, stats),
        });
    }
    let mut total_times: Vec<u64> = all[0].0.iter().chain(all[1].0.iter()).copied().collect();
    let mut total_stats = all[0].3;
    total_stats.merge(&all[1].3);
    let total = BenchSummary::from_samples(
        &mut total_times,
        all[0].1 + all[1].1,
        all[0].2 + all[1].2,
        total_stats,
    );
    let [vf, ee] = all;
    let (mut vft, vfn, vfp, vfs) = vf;
    let (mut eet, een, eep, ees) = ee;
    BenchReport {
        eta,
        folders: reports,
        vertex_face: BenchSummary::from_samples(&mut vft, vfn, vfp, vfs),
        edge_edge: BenchSummary::from_samples(&mut eet, een, eep, ees),
        total,
    }
}
