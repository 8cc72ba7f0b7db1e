//! `weft bench`: a small benchmark end to end, and the checks on its
//! checkpoint and options.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn scene(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenes")
        .join(name)
}

fn weft(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_weft"))
        .current_dir(dir)
        .args(args)
        .output()
        .expect("weft runs")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn last_json(o: &Output) -> serde_json::Value {
    let text = String::from_utf8_lossy(&o.stdout);
    let line = text.lines().last().expect("some output");
    serde_json::from_str(line).unwrap_or_else(|e| panic!("last line is not JSON ({e}): {line}"))
}

fn positive(j: &serde_json::Value, key: &str) -> f64 {
    let v = j[key]
        .as_f64()
        .unwrap_or_else(|| panic!("{key} is not a number: {j}"));
    assert!(v.is_finite() && v > 0.0, "{key} = {v}");
    v
}

/// One run of one window on one thread.
const ONE_QUICK_RUN: &[&str] = &["--windows", "1", "--repeats", "1", "--threads", "1"];

/// `weft bench SCENE --size SIZE --checkpoint CK EXTRA…` in `dir`.
fn bench_from(dir: &Path, scene: &Path, size: &str, ck: &Path, extra: &[&str]) -> Output {
    let mut args = vec![
        "bench",
        scene.to_str().unwrap(),
        "--size",
        size,
        "--checkpoint",
        ck.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    weft(dir, &args)
}

/// Makes a crumple checkpoint of `size` vertices at t = `warmup` in `dir`
/// through a one-window bench, and returns its path.
fn small_checkpoint(dir: &Path, size: &str, warmup: &str) -> PathBuf {
    let ck = dir.join(format!("crumple-{size}.wckp"));
    let mut extra = vec!["--warmup", warmup, "--make-checkpoint"];
    extra.extend_from_slice(ONE_QUICK_RUN);
    let o = bench_from(dir, &scene("crumple.toml"), size, &ck, &extra);
    assert!(o.status.success(), "bench failed: {}", stderr(&o));
    ck
}

#[test]
fn bench_reports_throughput_and_efficiency_from_a_checkpoint() {
    let tmp = tempfile::tempdir().unwrap();
    let ck = tmp.path().join("c.wckp");
    let crumple = scene("crumple.toml");
    let o = weft(
        tmp.path(),
        &[
            "bench",
            crumple.to_str().unwrap(),
            "--set",
            "size=150",
            "--warmup",
            "0.1",
            "--make-checkpoint",
            "--checkpoint",
            ck.to_str().unwrap(),
            "--windows",
            "2",
            "--repeats",
            "2",
            "--threads",
            "1,2",
            "--json",
        ],
    );
    let err = stderr(&o);
    assert!(o.status.success(), "bench failed: {err}");
    print!("{}", String::from_utf8_lossy(&o.stdout));
    assert!(ck.exists(), "no checkpoint written");
    assert!(tmp.path().join("c.warmup/manifest.json").exists());
    assert!(err.contains("active stencils"), "{err}");
    let j = last_json(&o);

    assert_eq!(j["scene"], "crumple");
    assert_eq!(j["steps_per_window"], 140);
    let window = positive(&j, "window_seconds");
    assert!((window - 1.0 / 3000.0).abs() < 1e-12, "window {window}");
    // The checkpoint is at the first window boundary at or after 0.1 s.
    let t0 = positive(&j, "start_time");
    assert!((0.1..0.1 + window + 1e-12).contains(&t0), "start {t0}");
    assert!(j["start_active_stencils"].as_u64().unwrap() > 0, "{j}");
    // The world is built once, its step estimated on the most threads asked.
    positive(&j, "build_seconds");
    assert_eq!(j["build_workers"], serde_json::json!([1, 2]), "{j}");
    positive(&j, "internal_evaluations_per_window");
    assert!(positive(&j, "narrow_queries_per_window") >= 1.0);
    assert!(j["rollbacks_per_window"].as_f64().unwrap() >= 0.0);
    assert_eq!(j["windows"], 2);
    assert_eq!(j["repeats"], 2);
    assert_eq!(j["deterministic"], true);
    let hash = j["state_hash"].as_str().unwrap();
    assert_eq!(hash.len(), 32, "{hash}");
    // Linux: the process peak per vertex.
    if Path::new("/proc/self/status").exists() {
        positive(&j, "peak_rss_bytes");
        positive(&j, "peak_bytes_per_vertex");
    }
    let m = &j["machine"];
    assert!(m["available_cpus"].as_u64().unwrap() >= 1, "{m}");

    let results = j["results"].as_array().unwrap();
    assert_eq!(results.len(), 2);
    for (r, n) in results.iter().zip([1u64, 2]) {
        assert_eq!(r["threads"], n);
        assert_eq!(
            r["runs_wall_seconds_per_window"].as_array().unwrap().len(),
            2
        );
        let wall = positive(r, "wall_seconds_per_window");
        let st = &r["stage_seconds_per_window"];
        let stages = four_stages(st);
        assert!(stages <= wall * 1.0001, "stages {stages} > wall {wall}");
        positive(r, "internal_evaluations_per_core_second");
        positive(r, "internal_evaluations_per_events_core_second");
        positive(r, "narrow_queries_per_second");
        let e = positive(r, "parallel_efficiency");
        assert!(e <= 1.5, "efficiency {e}");
        positive(r, "speedup");
    }
    assert_eq!(results[0]["parallel_efficiency"], 1.0);
    // Every queried vertex has at least its start and end breakpoints.
    let b = positive(&j, "breakpoints_per_queried_vertex");
    assert!(b >= 2.0, "{b} breakpoints per queried vertex");
    // A share, when anything was certified.
    let share = &j["block_certified_share"];
    assert!(
        share.is_null() || (0.0..=1.0).contains(&share.as_f64().unwrap()),
        "{share}"
    );
}

#[test]
fn a_checkpoint_of_another_scene_or_size_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let ck = small_checkpoint(tmp.path(), "100", "0.002");
    let crumple = scene("crumple.toml");
    let drape = scene("drape.toml");
    for (scene, size) in [(&crumple, "120"), (&drape, "100")] {
        let o = bench_from(tmp.path(), scene, size, &ck, ONE_QUICK_RUN);
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(1), "{err}");
        assert!(
            err.contains("the checkpoint was made from another scene, size or overrides"),
            "{err}"
        );
        assert!(err.contains("--make-checkpoint"), "{err}");
        assert!(!err.contains("panicked"), "{err}");
    }
    // The matching scene still runs from it.
    let o = bench_from(tmp.path(), &crumple, "100", &ck, ONE_QUICK_RUN);
    assert!(o.status.success(), "{}", stderr(&o));
}

#[test]
fn missing_checkpoint_and_bad_options_are_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let crumple = scene("crumple.toml");
    let c = crumple.to_str().unwrap();
    // No checkpoint at the default path: say how to make one.
    let o = weft(tmp.path(), &["bench", c, "--size", "100"]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("bench/crumple-100.wckp"), "{err}");
    assert!(err.contains("--make-checkpoint"), "{err}");

    let cases: &[(&[&str], &str)] = &[
        (&["--threads", "0"], "at least 1"),
        (&["--threads", "1,1"], "twice"),
        (&["--windows", "0"], "--windows"),
        (&["--repeats", "0"], "--repeats"),
        (&["--make-checkpoint", "--warmup", "0"], "--warmup"),
        (&["--project", "16"], "--project needs --ranks"),
        (
            &["--project", "16", "--ranks", "1,2"],
            "--project needs --ranks",
        ),
        (
            &["--project", "16", "--ranks", "1,2,4", "--threads", "2"],
            "--threads 1",
        ),
        (
            &[
                "--project",
                "16",
                "--ranks",
                "1,2,4",
                "--threads",
                "1",
                "--bandwidth-gbs",
                "0",
            ],
            "--bandwidth-gbs",
        ),
    ];
    for (extra, want) in cases {
        let mut args = vec!["bench", c, "--size", "100"];
        args.extend_from_slice(extra);
        let o = weft(tmp.path(), &args);
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(1), "{extra:?}: {err}");
        assert!(err.contains(want), "{extra:?}: {err}");
    }
    let o = weft(tmp.path(), &["bench", "no-such-scene.toml"]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("no-such-scene.toml"), "{}", stderr(&o));
    // A checkpoint file that is not one.
    let junk = tmp.path().join("junk.wckp");
    std::fs::write(&junk, b"not a checkpoint").unwrap();
    let o = weft(
        tmp.path(),
        &[
            "bench",
            c,
            "--size",
            "100",
            "--checkpoint",
            junk.to_str().unwrap(),
        ],
    );
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("junk.wckp"), "{err}");
}

/// The sum of the four main stages' figures in `obj`, each positive.
fn four_stages(obj: &serde_json::Value) -> f64 {
    ["events", "broad", "narrow", "commit"]
        .iter()
        .map(|k| positive(obj, k))
        .sum()
}

#[test]
fn bench_over_ranks_reports_traffic_and_narrow_imbalance() {
    let tmp = tempfile::tempdir().unwrap();
    let ck = small_checkpoint(tmp.path(), "150", "0.1");
    let extra = [
        "--windows",
        "2",
        "--repeats",
        "1",
        "--threads",
        "1",
        "--ranks",
        "1,3",
        "--json",
    ];
    let o = bench_from(tmp.path(), &scene("crumple.toml"), "150", &ck, &extra);
    let err = stderr(&o);
    assert!(o.status.success(), "bench failed: {err}");
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(out.contains("with the balancer"), "{out}");
    let j = last_json(&o);
    assert_eq!(j["deterministic"], true, "same bits on 1 and 3 ranks");
    let results = j["results"].as_array().unwrap();
    assert_eq!(results.len(), 2);
    let (one, three) = (&results[0], &results[1]);
    assert_eq!(one["ranks"], 1);
    assert_eq!(one["per_rank"].as_array().unwrap().len(), 1);
    assert!(one["narrow_imbalance"].is_null());
    assert_eq!(one["per_rank"][0]["messages_per_window"], 0.0);
    assert_eq!(three["ranks"], 3);
    assert_eq!(three["executor"], "ranks(3) × threads(1)");
    let ranks = three["per_rank"].as_array().unwrap();
    assert_eq!(ranks.len(), 3);
    for r in ranks {
        positive(r, "messages_per_window");
        positive(r, "bytes_per_window");
        positive(&r["stage_seconds_per_window"], "events");
    }
    // max / mean of three ranks' loads: between 1 and 3.
    for key in ["narrow_imbalance", "narrow_imbalance_home_only"] {
        let x = positive(three, key);
        assert!((1.0..=3.0 + 1e-9).contains(&x), "{key} = {x}");
    }
    // Counted scaling: each rank's work CPU, its stages within it, the sum
    // and the largest; one process is its own reference.
    assert_eq!(one["redundancy"], 1.0);
    assert_eq!(one["speedup_bound"], 1.0);
    let mut sum = 0.0;
    let mut largest = 0.0f64;
    for r in ranks {
        let total = positive(r, "cpu_total_seconds_per_window");
        let cpu = &r["cpu_seconds_per_window"];
        let stages = four_stages(cpu);
        assert!(
            stages <= total * 1.05 + 1e-3,
            "stages {stages} > total {total}"
        );
        let wall = r["stage_seconds_per_window"]["events"].as_f64().unwrap();
        assert!(cpu["events"].as_f64().unwrap() <= wall * 1.05 + 1e-3);
        assert!(r["cpu_polling_seconds_per_window"].as_f64().unwrap() >= 0.0);
        positive(r, "peak_rss_bytes");
        sum += total;
        largest = largest.max(total);
    }
    let counted = positive(three, "cpu_sum_seconds_per_window");
    assert!((counted - sum).abs() <= 1e-9 * sum, "{counted} vs {sum}");
    assert_eq!(three["critical_path_seconds_per_window"], largest);
    // Three ranks repeat some work (redundancy > 0.5 at least) and none can
    // beat three times one process.
    let redundancy = positive(three, "redundancy");
    let bound = positive(three, "speedup_bound");
    assert!(redundancy > 0.5 && bound < 3.5, "{redundancy} {bound}");
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(out.contains("critical path"), "{out}");
}

/// `--project`: the simulated ranks' steps replayed (each measured count)
/// and the model's rank counts, labelled as a model; a slower network gives
/// a slower projection.
#[test]
fn bench_projects_more_ranks_from_the_replayed_steps() {
    let tmp = tempfile::tempdir().unwrap();
    let ck = small_checkpoint(tmp.path(), "150", "0.1");
    let run = |bandwidth: &str| {
        let extra = [
            "--windows",
            "2",
            "--repeats",
            "1",
            "--threads",
            "1",
            "--ranks",
            "1,2,3",
            "--project",
            "1,2,3,64",
            "--bandwidth-gbs",
            bandwidth,
            "--json",
        ];
        let o = bench_from(tmp.path(), &scene("crumple.toml"), "150", &ck, &extra);
        assert!(o.status.success(), "bench failed: {}", stderr(&o));
        let out = String::from_utf8_lossy(&o.stdout).to_string();
        assert!(out.contains("a model, not a measurement"), "{out}");
        last_json(&o)
    };
    let fast_report = run("25");
    let fast = fast_report["projection"].clone();
    let replayed = fast["replayed"].as_array().unwrap();
    assert_eq!(replayed.len(), 2, "{fast}");
    for r in replayed {
        // (ranks, replay, counted critical path): the replay waits at every
        // collective for the slowest rank, so it is never below the
        // critical path's work by much.
        let (replay, critical) = (r[1].as_f64().unwrap(), r[2].as_f64().unwrap());
        assert!(replay > 0.0 && critical > 0.0, "{r}");
        assert!(replay >= 0.9 * critical, "{r}");
    }
    for b in fast["between_collectives"].as_array().unwrap() {
        // (ranks, busiest rank's work summed over the intervals, the mean
        // rank's): the busiest is never below the mean.
        let (most, mean) = (b[1].as_f64().unwrap(), b[2].as_f64().unwrap());
        assert!(mean > 0.0 && most >= mean, "{b}");
    }
    let fit = fast["fit"].as_array().unwrap();
    assert!(fit.iter().all(|f| f.as_f64().unwrap() >= 0.0), "{fast}");
    // The fit and the imbalance by the site of the collective ending each
    // interval: the events stage's exchanges are named, the sites' sums
    // are the whole fit's, largest Σ a first.
    let sites = fast["by_site"].as_array().unwrap();
    let names: Vec<&str> = sites.iter().map(|s| s["site"].as_str().unwrap()).collect();
    assert!(names.contains(&"events: new velocities"), "{names:?}");
    assert!(names.contains(&"events: units' outputs"), "{names:?}");
    let sum = |k: usize| -> f64 { sites.iter().map(|s| s["fit"][k].as_f64().unwrap()).sum() };
    for k in 0..2 {
        let whole = fit[k].as_f64().unwrap();
        assert!((sum(k) - whole).abs() <= 1e-9 * whole.max(1.0), "{fast}");
    }
    let a: Vec<f64> = sites
        .iter()
        .map(|s| s["fit"][0].as_f64().unwrap())
        .collect();
    assert!(a.windows(2).all(|w| w[0] >= w[1]), "{a:?}");
    let projected = fast["projected"].as_array().unwrap();
    let ranks: Vec<u64> = projected
        .iter()
        .map(|p| p[0]["ranks"].as_u64().unwrap())
        .collect();
    assert_eq!(ranks, [1, 2, 3, 64]);
    for p in projected {
        let q = &p[0];
        let sum = q["work"].as_f64().unwrap()
            + q["collectives"].as_f64().unwrap()
            + q["point_to_point"].as_f64().unwrap();
        assert!((q["seconds"].as_f64().unwrap() - sum).abs() < 1e-12, "{q}");
        assert!(p[1].as_f64().unwrap() > 0.0, "an efficiency: {p}");
    }
    assert_eq!(
        projected[0][0]["collectives"], 0.0,
        "one rank talks to no one"
    );
    // One rank is the measured one process, not the fit over 2 and 3 ranks
    // (which counts the work every rank of a run over ranks repeats).
    assert_eq!(projected[0][0]["measured"], true, "{fast}");
    assert_eq!(projected[1][0]["measured"], false, "{fast}");
    let one = (fast_report["results"].as_array().unwrap().iter())
        .find(|t| t["ranks"] == 1)
        .expect("the 1-rank run");
    assert_eq!(
        projected[0][0]["seconds"], one["wall_seconds_per_window"],
        "{fast_report}"
    );
    let slow = run("0.01")["projection"].clone();
    let at64 = |j: &serde_json::Value| j["projected"][3][0]["collectives"].as_f64().unwrap();
    assert!(
        at64(&slow) > at64(&fast),
        "{} vs {}",
        at64(&slow),
        at64(&fast)
    );
}
