//! `weft render` and `weft plot` on run folders built by hand: outputs, exit
//! codes, and errors that name the file and line.

use std::path::Path;
use std::process::ExitCode;

use glam::DVec3;

fn weft(args: &[&str]) -> ExitCode {
    weft_cli::run(std::iter::once("weft").chain(args.iter().copied()))
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A run folder of `frames` frames: a square cloth (two triangles per cell,
/// `n × n` vertices) drifting down over a small tetrahedron obstacle, with
/// `frames.jsonl`, `objects.json`, `stats.jsonl` and `timing.jsonl`.
fn write_run(dir: &Path, frames: usize) {
    let n = 6u32;
    std::fs::create_dir_all(dir.join("frames")).unwrap();
    let mut frame_lines = String::new();
    let mut stats = String::new();
    let mut timing = String::new();
    for k in 0..frames {
        let t = k as f64 * 0.05;
        let mut x = Vec::new();
        let mut tris = Vec::new();
        for i in 0..n {
            for j in 0..n {
                let (u, v) = (
                    i as f64 / (n - 1) as f64 - 0.5,
                    j as f64 / (n - 1) as f64 - 0.5,
                );
                x.push(DVec3::new(u, 0.5 - t - 0.2 * (u * u + v * v), v));
            }
        }
        for i in 0..n - 1 {
            for j in 0..n - 1 {
                let a = i * n + j;
                tris.push([a, a + 1, a + n + 1]);
                tris.push([a, a + n + 1, a + n]);
            }
        }
        let o = x.len() as u32;
        x.extend([
            DVec3::new(-0.2, 0.0, -0.2),
            DVec3::new(0.2, 0.0, -0.2),
            DVec3::new(0.0, 0.0, 0.25),
            DVec3::new(0.0, 0.3, 0.0),
        ]);
        tris.extend([[0, 2, 1], [0, 1, 3], [1, 2, 3], [2, 0, 3]].map(|f| f.map(|i| i + o)));
        let v = vec![DVec3::new(0.0, -1.0, 0.0); x.len()];
        let rel = format!("frames/frame_{k:05}.ply");
        weft_io::write_ply(&dir.join(&rel), &x, &tris, Some(&v)).unwrap();
        frame_lines.push_str(&format!(
            "{{\"frame\":{k},\"file\":\"{rel}\",\"time\":{t:?},\"window\":{k}}}\n"
        ));
        stats.push_str(&format!(
            "{{\"window\":{k},\"time\":{t:?},\"tick\":{k},\"internal_events\":10,\
             \"internal_stencil_evaluations\":100,\"layer_events\":{k},\"layer_kicks\":0,\
             \"rollbacks\":{},\"active_stencils\":{},\"depth_histogram\":[],\"max_depth\":1,\
             \"candidates\":4,\"confirmed\":0,\"retired_layers\":0,\"breakpoints\":36,\
             \"min_separation\":null,\"kinetic_energy\":{},\"potential_energy\":{},\
             \"contact_energy\":0.0,\"linear_momentum\":[0.0,{},0.0],\
             \"angular_momentum\":[0.0,0.0,0.0]}}\n",
            k % 2,
            3 * k,
            0.1 * t,
            -0.1 * t,
            -0.02 * t
        ));
        timing.push_str(&format!(
            "{{\"window\":{k},\"wall_seconds\":0.02,\"stage_seconds\":{{\"events\":0.01,\
             \"broad\":0.004,\"narrow\":0.005,\"commit\":0.001}}}}\n"
        ));
    }
    std::fs::write(dir.join("frames.jsonl"), frame_lines).unwrap();
    std::fs::write(dir.join("stats.jsonl"), stats).unwrap();
    std::fs::write(dir.join("timing.jsonl"), timing).unwrap();
    let (cv, ct) = (n * n, 2 * (n - 1) * (n - 1));
    std::fs::write(
        dir.join("objects.json"),
        format!(
            "{{\"objects\":[{{\"name\":\"cloth\",\"vertices\":[0,{cv}],\"triangles\":[0,{ct}],\"cloth\":true}},\
             {{\"name\":\"rock\",\"vertices\":[{cv},{}],\"triangles\":[{ct},{}],\"cloth\":false}}]}}",
            cv + 4,
            ct + 4
        ),
    )
    .unwrap();
}

fn png_size(path: &Path) -> (u32, u32) {
    let img = weft_render::Image::read_png(path).unwrap();
    (img.width, img.height)
}

#[test]
fn render_writes_frames_and_a_gif_without_ffmpeg() {
    let dir = tempfile::tempdir().unwrap();
    write_run(dir.path(), 5);
    let missing = dir.path().join("missing-ffmpeg");
    let code = weft(&[
        "render",
        s(dir.path()),
        "--width",
        "96",
        "--height",
        "72",
        "--ffmpeg",
        s(&missing),
    ]);
    assert_eq!(code, ExitCode::SUCCESS);
    for k in 0..5 {
        let png = dir.path().join(format!("render/frame_{k:05}.png"));
        assert_eq!(png_size(&png), (96, 72), "{}", png.display());
    }
    let gif = std::fs::File::open(dir.path().join("preview.gif")).unwrap();
    let mut d = gif::DecodeOptions::new().read_info(gif).unwrap();
    let mut n = 0;
    while d.read_next_frame().unwrap().is_some() {
        n += 1;
    }
    assert_eq!(n, 5);
    assert!(!dir.path().join("preview.mp4").exists());
}

#[test]
fn render_takes_a_camera_a_stride_and_no_video() {
    let dir = tempfile::tempdir().unwrap();
    write_run(dir.path(), 5);
    let code = weft(&[
        "render",
        s(dir.path()),
        "--width",
        "64",
        "--height",
        "48",
        "--every",
        "2",
        "--video",
        "none",
        "--eye",
        "2,-1.5,3",
        "--target",
        "0,0.2,0",
        "--up",
        "0,1,0",
        "--fov",
        "50",
    ]);
    assert_eq!(code, ExitCode::SUCCESS);
    assert_eq!(
        names_in(&dir.path().join("render")),
        ["frame_00000.png", "frame_00002.png", "frame_00004.png"]
    );
    assert!(!dir.path().join("preview.gif").exists());

    // An eye without a target, a malformed vector, a bad mode: errors.
    let bad_camera = weft(&["render", s(dir.path()), "--eye", "1,2,3", "--video", "none"]);
    assert_eq!(bad_camera, ExitCode::from(1));
    let bad_vector = weft(&["render", s(dir.path()), "--eye", "1,2", "--target", "0,0,0"]);
    assert_eq!(bad_vector, ExitCode::from(2));
    let bad_mode = weft(&["render", s(dir.path()), "--video", "avi"]);
    assert_eq!(bad_mode, ExitCode::from(2));
    let bad_size = weft(&["render", s(dir.path()), "--width", "0", "--video", "none"]);
    assert_eq!(bad_size, ExitCode::from(1));
}

fn names_in(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

#[test]
fn render_takes_an_output_folder_and_never_deletes_earlier_frames() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    write_run(&run, 5);
    let small = ["--width", "64", "--height", "48"];
    let render = |extra: &[&str]| {
        let mut args = vec!["render", s(&run)];
        args.extend(small);
        args.extend(extra);
        weft(&args)
    };
    assert_eq!(render(&["--video", "none"]), ExitCode::SUCCESS);
    let all: Vec<String> = (0..5).map(|k| format!("frame_{k:05}.png")).collect();
    assert_eq!(names_in(&run.join("render")), all);

    // Into another folder: every other frame and the GIF there, the run
    // folder's render untouched.
    let out = dir.path().join("out");
    let code = render(&["--out", s(&out), "--every", "2", "--video", "gif"]);
    assert_eq!(code, ExitCode::SUCCESS);
    assert_eq!(
        names_in(&out),
        [
            "frame_00000.png",
            "frame_00002.png",
            "frame_00004.png",
            "preview.gif"
        ]
    );
    assert_eq!(names_in(&run.join("render")), all);
    assert!(!run.join("preview.gif").exists());

    // Every other frame into the default folder again: the frames it does
    // not write stay.
    assert_eq!(
        render(&["--every", "2", "--video", "none"]),
        ExitCode::SUCCESS
    );
    assert_eq!(names_in(&run.join("render")), all);
}

#[test]
fn render_works_on_a_run_still_writing_its_frames() {
    let dir = tempfile::tempdir().unwrap();
    write_run(dir.path(), 4);
    // Frame 4's line is half written, as by a run in progress.
    let frames = dir.path().join("frames.jsonl");
    let mut text = std::fs::read_to_string(&frames).unwrap();
    text.push_str("{\"frame\":4,\"file\":\"fra");
    std::fs::write(&frames, text).unwrap();
    let out = dir.path().join("now");
    let code = weft(&[
        "render",
        s(dir.path()),
        "--out",
        s(&out),
        "--width",
        "64",
        "--height",
        "48",
        "--video",
        "none",
    ]);
    assert_eq!(code, ExitCode::SUCCESS);
    let want: Vec<String> = (0..4).map(|k| format!("frame_{k:05}.png")).collect();
    assert_eq!(names_in(&out), want);
}

#[test]
fn render_fails_cleanly_on_broken_run_folders() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    // Missing folder, then a folder without frames.jsonl.
    assert_eq!(weft(&["render", s(&run)]), ExitCode::from(1));
    std::fs::create_dir_all(&run).unwrap();
    assert_eq!(
        weft(&["render", s(&run), "--video", "none"]),
        ExitCode::from(1)
    );

    write_run(&run, 3);
    let frames = run.join("frames.jsonl");
    let good = std::fs::read_to_string(&frames).unwrap();
    std::fs::write(&frames, good.replace("\"time\":0.05", "\"time\":\"later\"")).unwrap();
    assert_eq!(
        weft(&["render", s(&run), "--video", "none"]),
        ExitCode::from(1)
    );
    let e = weft_render::render_run(&run, &weft_render::RenderOptions::default()).unwrap_err();
    assert!(e.to_string().contains("frames.jsonl:2:"), "{e}");

    std::fs::write(&frames, &good).unwrap();
    let ply = run.join("frames/frame_00001.ply");
    let bytes = std::fs::read(&ply).unwrap();
    std::fs::write(&ply, &bytes[..bytes.len() / 2]).unwrap();
    assert_eq!(
        weft(&["render", s(&run), "--video", "none"]),
        ExitCode::from(1)
    );
    let args = ["weft", "render", s(&run), "--video", "none"];
    let cli = <weft_cli::Cli as clap::Parser>::try_parse_from(args).unwrap();
    let weft_cli::Command::Render(a) = cli.command else {
        panic!("parsed as another command")
    };
    let e = weft_cli::commands::render::run(a).unwrap_err();
    let msg = format!("{e:#}");
    assert!(
        msg.contains("frame 1") && msg.contains("frame_00001.ply"),
        "{msg}"
    );
}

#[test]
fn plot_writes_charts_and_names_a_malformed_line() {
    let dir = tempfile::tempdir().unwrap();
    write_run(dir.path(), 6);
    assert_eq!(weft(&["plot", s(dir.path())]), ExitCode::SUCCESS);
    for name in ["energy", "momentum", "contacts", "time"] {
        let png = dir.path().join(format!("plots/{name}.png"));
        let img = weft_render::Image::read_png(&png).unwrap();
        assert!(img.count_not([255, 255, 255]) > 5_000, "{name} is blank");
    }

    let out = dir.path().join("elsewhere");
    let stats = dir.path().join("stats.jsonl");
    assert_eq!(
        weft(&["plot", s(&stats), "--out", s(&out)]),
        ExitCode::SUCCESS
    );
    assert!(out.join("energy.png").is_file() && out.join("time.png").is_file());

    let mut text = std::fs::read_to_string(&stats).unwrap();
    text.push_str("not json\n");
    std::fs::write(&stats, text).unwrap();
    assert_eq!(weft(&["plot", s(dir.path())]), ExitCode::from(1));
    let e = weft_render::plot_stats(dir.path(), &out).unwrap_err();
    assert!(e.to_string().contains("stats.jsonl:7:"), "{e}");
    assert_eq!(
        weft(&["plot", s(&dir.path().join("nope"))]),
        ExitCode::from(1)
    );
}
