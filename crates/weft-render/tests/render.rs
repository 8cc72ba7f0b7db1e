//! weft-render end to end: the rasterizer, the camera fit, `render_run` on a
//! run folder built here, the GIF and the ffmpeg fallbacks, and the plots.

use glam::DVec3;
use std::path::{Path, PathBuf};
use weft_render::raster::{BACKGROUND_TOP, CLOTH_COLORS, OBSTACLE};
use weft_render::{
    plot_stats, render_run, Camera, Image, Rasterizer, RenderError, RenderOptions, Surface,
    VideoMode,
};

/// A UV sphere of radius `r` around `c` with counter-clockwise outward faces.
fn sphere(c: DVec3, r: f64, rings: u32, segments: u32) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let mut x = vec![c + DVec3::Y * r];
    for i in 1..rings {
        let th = std::f64::consts::PI * i as f64 / rings as f64;
        for j in 0..segments {
            let ph = std::f64::consts::TAU * j as f64 / segments as f64;
            x.push(c + r * DVec3::new(th.sin() * ph.cos(), th.cos(), -th.sin() * ph.sin()));
        }
    }
    x.push(c - DVec3::Y * r);
    let ring = |i: u32, j: u32| 1 + (i - 1) * segments + j % segments;
    let last = x.len() as u32 - 1;
    let mut t = Vec::new();
    for j in 0..segments {
        t.push([0, ring(1, j), ring(1, j + 1)]);
        t.push([last, ring(rings - 1, j + 1), ring(rings - 1, j)]);
        for i in 1..rings - 1 {
            let (a, b, c2, d) = (
                ring(i, j),
                ring(i, j + 1),
                ring(i + 1, j),
                ring(i + 1, j + 1),
            );
            t.push([a, c2, d]);
            t.push([a, d, b]);
        }
    }
    (x, t)
}

/// An `n × n` vertex grid in the xz plane at height `y`, side `size`.
fn cloth(n: u32, size: f64, y: f64) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let mut x = Vec::new();
    for i in 0..n {
        for j in 0..n {
            let (u, v) = (i as f64 / (n - 1) as f64, j as f64 / (n - 1) as f64);
            x.push(DVec3::new((u - 0.5) * size, y, (v - 0.5) * size));
        }
    }
    let mut t = Vec::new();
    for i in 0..n - 1 {
        for j in 0..n - 1 {
            let a = i * n + j;
            t.push([a, a + 1, a + n + 1]);
            t.push([a, a + n + 1, a + n]);
        }
    }
    (x, t)
}

/// Writes a run folder like `weft run` does: `frames` PLY frames of a cloth
/// (n × n) falling over a sphere, `frames.jsonl` at 30 fps, `objects.json`,
/// `stats.jsonl` and `timing.jsonl`.
fn write_run(dir: &Path, frames: usize, n: u32) {
    std::fs::create_dir_all(dir.join("frames")).unwrap();
    let (sx, st) = sphere(DVec3::ZERO, 0.3, 12, 24);
    let mut lines = String::new();
    let mut ntri = 0;
    let mut nvert = 0;
    for k in 0..frames {
        let t = k as f64 / 30.0;
        let (mut x, mut tris) = cloth(n, 1.0, 0.45 - 0.5 * t);
        // Sag the cloth over time so frames differ.
        for p in &mut x {
            p.y -= 0.3 * t * (1.0 - (p.x * p.x + p.z * p.z).min(1.0));
        }
        let off = x.len() as u32;
        x.extend(&sx);
        tris.extend(st.iter().map(|f| f.map(|i| i + off)));
        let v = vec![DVec3::new(0.0, -0.5, 0.0); x.len()];
        let rel = format!("frames/frame_{k:05}.ply");
        weft_io::write_ply(&dir.join(&rel), &x, &tris, Some(&v)).unwrap();
        lines.push_str(&format!(
            "{{\"frame\":{k},\"file\":\"{rel}\",\"time\":{t:?},\"window\":{k}}}\n"
        ));
        ntri = tris.len();
        nvert = x.len();
    }
    std::fs::write(dir.join("frames.jsonl"), lines).unwrap();
    let cloth_t = 2 * (n - 1) * (n - 1);
    let cloth_v = n * n;
    std::fs::write(
        dir.join("objects.json"),
        format!(
            "{{\"objects\":[{{\"name\":\"cloth\",\"vertices\":[0,{cloth_v}],\"triangles\":[0,{cloth_t}],\"cloth\":true}},\
             {{\"name\":\"ball\",\"vertices\":[{cloth_v},{nvert}],\"triangles\":[{cloth_t},{ntri}],\"cloth\":false}}]}}"
        ),
    )
    .unwrap();
    write_stats(dir, 40);
}

fn write_stats(dir: &Path, windows: usize) {
    let mut stats = String::new();
    let mut timing = String::new();
    for w in 0..windows {
        let t = (w + 1) as f64 * 0.01;
        stats.push_str(&format!(
            "{{\"window\":{w},\"time\":{t},\"tick\":{},\"internal_events\":100,\
             \"internal_stencil_evaluations\":1000,\"layer_events\":{},\"layer_kicks\":3,\
             \"rollbacks\":{},\"active_stencils\":{},\"depth_histogram\":[5,2],\"max_depth\":{},\
             \"candidates\":40,\"confirmed\":2,\"retired_layers\":1,\"breakpoints\":500,\
             \"min_separation\":0.001,\"kinetic_energy\":{},\"potential_energy\":{},\
             \"contact_energy\":{},\"linear_momentum\":[0.0,{},0.0],\
             \"angular_momentum\":[1e-6,0.0,{}]}}\n",
            (w + 1) << 20,
            w * 7,
            w % 3,
            w * w,
            w / 10,
            0.5 * t * t,
            -0.5 * t * t + 1e-3 * t,
            1e-4 * t,
            -0.2 * t,
            2e-5 * t,
        ));
        timing.push_str(&format!(
            "{{\"window\":{w},\"wall_seconds\":{},\"stage_seconds\":{{\"events\":{},\
             \"broad\":{},\"narrow\":{},\"commit\":0.0001}}}}\n",
            0.01 + 0.001 * w as f64,
            0.006,
            0.002,
            0.001 * w as f64,
        ));
    }
    std::fs::write(dir.join("stats.jsonl"), stats).unwrap();
    std::fs::write(dir.join("timing.jsonl"), timing).unwrap();
}

/// `gif_opts` without a video: the frames only.
fn frames_only_opts() -> RenderOptions {
    RenderOptions {
        video: VideoMode::None,
        ..gif_opts()
    }
}

fn gif_opts() -> RenderOptions {
    RenderOptions {
        width: 160,
        height: 120,
        video: VideoMode::Gif,
        supersample: 2,
        ..Default::default()
    }
}

fn gif_frames(path: &Path) -> (u16, u16, usize, Vec<u16>) {
    let mut opts = gif::DecodeOptions::new();
    opts.set_color_output(gif::ColorOutput::RGBA);
    let mut d = opts
        .read_info(std::fs::File::open(path).unwrap())
        .expect("the GIF decodes");
    let (w, h) = (d.width(), d.height());
    let mut delays = Vec::new();
    while let Some(f) = d.read_next_frame().expect("frame decodes") {
        assert_eq!((f.width, f.height), (w, h));
        delays.push(f.delay);
    }
    (w, h, delays.len(), delays)
}

#[test]
fn a_near_triangle_hides_a_far_one_in_either_drawing_order() {
    let camera = Camera {
        eye: DVec3::new(0.0, 0.0, 5.0),
        target: DVec3::ZERO,
        up: DVec3::Y,
        fov_y_degrees: 40.0,
    };
    // Facing the camera (counter-clockwise seen from +z).
    let near = [
        DVec3::new(-1.0, -1.0, 1.0),
        DVec3::new(1.0, -1.0, 1.0),
        DVec3::new(0.0, 1.0, 1.0),
    ];
    let far = near.map(|p| p * DVec3::new(3.0, 3.0, 1.0) - DVec3::new(0.0, 0.0, 2.0));
    let x: Vec<DVec3> = near.iter().chain(&far).copied().collect();
    let mut r = Rasterizer::new(64, 64, 2);
    for (tris, surfaces) in [
        (
            [[0, 1, 2], [3, 4, 5]],
            [Surface::Cloth(0), Surface::Obstacle],
        ),
        (
            [[3, 4, 5], [0, 1, 2]],
            [Surface::Obstacle, Surface::Cloth(0)],
        ),
    ] {
        let img = r.render(&x, &tris, &surfaces, &camera);
        let c = img.pixel(32, 34);
        // Cloth is warm (red well above blue), the obstacle grey.
        assert!(c[0] as i32 - c[2] as i32 > 60, "centre {c:?} is not cloth");
        // Outside the near triangle but inside the far one: grey.
        let g = img.pixel(32, 6);
        assert!(
            (g[0] as i32 - g[2] as i32).abs() < 20 && g != img.pixel(0, 0),
            "{g:?}"
        );
    }
}

/// Whether `pixels` form one 8-connected set.
fn connected(pixels: &[(i64, i64)]) -> bool {
    let set: std::collections::HashSet<(i64, i64)> = pixels.iter().copied().collect();
    let mut seen = std::collections::HashSet::new();
    let mut stack: Vec<(i64, i64)> = pixels.first().copied().into_iter().collect();
    while let Some((x, y)) = stack.pop() {
        if !seen.insert((x, y)) {
            continue;
        }
        for (dx, dy) in (-1..=1).flat_map(|dx| (-1..=1).map(move |dy| (dx, dy))) {
            if set.contains(&(x + dx, y + dy)) {
                stack.push((x + dx, y + dy));
            }
        }
    }
    seen.len() == set.len()
}

#[test]
fn a_ribbon_seen_edge_on_is_a_continuous_line() {
    let camera = Camera {
        eye: DVec3::new(0.0, 0.0, 5.0),
        target: DVec3::ZERO,
        up: DVec3::Y,
        fov_y_degrees: 40.0,
    };
    let (w, h) = (200u32, 150u32);
    let mut r = Rasterizer::new(w, h, 3);
    let empty = r.render(&[], &[], &[], &camera).clone();
    // A strip of 40 segments, 2 long and 0.1 wide: its length runs along
    // `along` (across the image: level, then slanted), its width towards
    // the eye, so the eye lies in its plane; last turned by `tilt` radians
    // about its length, so that it is a tenth of a pixel wide on screen.
    let slanted = DVec3::new(1.0, 0.35, 0.0).normalize();
    for (along, tilt) in [(DVec3::X, 0.0), (slanted, 0.0), (slanted, 0.025f64)] {
        let across = tilt.cos() * DVec3::Z + tilt.sin() * along.cross(DVec3::Z);
        let mut x = Vec::new();
        for i in 0..=40 {
            let s = -1.0 + i as f64 / 20.0;
            x.push(s * along - 0.05 * across);
            x.push(s * along + 0.05 * across);
        }
        let t: Vec<[u32; 3]> = (0..40u32)
            .flat_map(|i| [[2 * i, 2 * i + 2, 2 * i + 3], [2 * i, 2 * i + 3, 2 * i + 1]])
            .collect();
        let img = r.render(&x, &t, &vec![Surface::Cloth(0); t.len()], &camera);
        let drawn: Vec<(i64, i64)> = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .filter(|&(x, y)| img.pixel(x, y) != empty.pixel(x, y))
            .map(|(x, y)| (x as i64, y as i64))
            .collect();
        assert!(!drawn.is_empty(), "{along}: nothing drawn");
        assert!(connected(&drawn), "{along}: the line is broken into pieces");
        // From one projected end to the other (the ends are about 40 pixels
        // left and right of the centre), and a line, not a smear.
        let end = 206.0 * along.x / 5.0;
        let (x0, x1) = (
            drawn.iter().map(|p| p.0).min().unwrap(),
            drawn.iter().map(|p| p.0).max().unwrap(),
        );
        let centre = (w / 2) as f64;
        assert!(
            (x0 as f64 - (centre - end)).abs() <= 2.0 && (x1 as f64 - (centre + end)).abs() <= 2.0,
            "{along}: drawn from column {x0} to {x1}, the strip spans {:.0} to {:.0}",
            centre - end,
            centre + end
        );
        for col in x0..=x1 {
            let n = drawn.iter().filter(|p| p.0 == col).count();
            assert!((1..=3).contains(&n), "{along}: column {col} has {n} pixels");
        }
    }
}

#[test]
fn a_fitted_camera_centres_a_unit_sphere() {
    let (x, t) = sphere(DVec3::new(3.0, -2.0, 7.0), 1.0, 24, 48);
    let (w, h) = (200, 150);
    let camera = Camera::fit_points(&x, w as f64 / h as f64, DVec3::Y, 35.0).unwrap();
    let mut r = Rasterizer::new(w, h, 3);
    let empty = r.render(&[], &[], &[], &camera).clone();
    for surface in [Surface::Obstacle, Surface::Cloth(0)] {
        let img = r.render(&x, &t, &vec![surface; t.len()], &camera).clone();
        let c = img.pixel(w / 2, h / 2);
        let want = if surface == Surface::Cloth(0) {
            CLOTH_COLORS[0].front
        } else {
            OBSTACLE
        };
        // Lit: a fraction of the base colour in every channel, never background.
        assert_ne!(c, empty.pixel(w / 2, h / 2));
        for k in 0..3 {
            assert!(
                c[k] as f64 <= want[k] as f64 * 1.05 + 1.0,
                "{c:?} vs {want:?}"
            );
            assert!(c[k] as f64 >= want[k] as f64 * 0.25, "{c:?} vs {want:?}");
        }
        for (cx, cy) in [(0, 0), (w - 1, 0), (0, h - 1), (w - 1, h - 1)] {
            assert_eq!(
                img.pixel(cx, cy),
                empty.pixel(cx, cy),
                "corner ({cx}, {cy})"
            );
        }
        // Centred: the sphere's extent is symmetric about the image centre.
        let row: Vec<bool> = (0..w)
            .map(|x| img.pixel(x, h / 2) != empty.pixel(x, h / 2))
            .collect();
        let (l, rr) = (
            row.iter().position(|&b| b).unwrap() as i64,
            row.iter().rposition(|&b| b).unwrap() as i64,
        );
        assert!((l + rr - (w as i64 - 1)).abs() <= 2, "spans {l}..{rr}");
        assert!(l > 5 && rr < w as i64 - 6, "the sphere fits: {l}..{rr}");
    }
    let top = empty.pixel(0, 0);
    assert!((0..3).all(|k| (top[k] as i32 - BACKGROUND_TOP[k] as i32).abs() <= 1));
}

#[test]
fn render_run_writes_pngs_and_a_gif_with_every_frame() {
    let dir = tempfile::tempdir().unwrap();
    write_run(dir.path(), 7, 12);
    let report = render_run(dir.path(), &gif_opts()).unwrap();
    assert_eq!(report.frames.len(), 7);
    assert_eq!(report.video, VideoMode::Gif);
    assert!((report.fps - 30.0).abs() < 1e-9, "fps {}", report.fps);
    for (k, f) in report.frames.iter().enumerate() {
        assert_eq!(f, &dir.path().join(format!("render/frame_{k:05}.png")));
        let img = Image::read_png(f).unwrap();
        assert_eq!((img.width, img.height), (160, 120));
    }
    // Cloth and obstacle are both visible in the first frame.
    let img = Image::read_png(&report.frames[0]).unwrap();
    let warm = img
        .rgb
        .chunks_exact(3)
        .filter(|p| p[0] as i32 - p[2] as i32 > 60)
        .count();
    let grey = img
        .rgb
        .chunks_exact(3)
        .filter(|p| (p[0] as i32 - p[2] as i32).abs() < 12 && p[0] < 175)
        .count();
    assert!(warm > 500 && grey > 100, "warm {warm}, grey {grey}");
    let preview = report.preview.clone().unwrap();
    assert_eq!(preview, dir.path().join("preview.gif"));
    let (w, h, n, delays) = gif_frames(&preview);
    assert_eq!((w, h, n), (160, 120, 7));
    assert!(delays.iter().all(|&d| d == 3), "{delays:?}");
    assert_eq!(report.files().len(), 8);
    // No temporary files are left behind.
    let names: Vec<String> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(names.iter().all(|n| !n.ends_with(".tmp")), "{names:?}");
}

fn frame_pngs(dir: &Path, frames: &[u32]) -> Vec<PathBuf> {
    frames
        .iter()
        .map(|k| dir.join(format!("frame_{k:05}.png")))
        .collect()
}

#[test]
fn a_second_render_overwrites_its_frames_and_keeps_the_others() {
    let dir = tempfile::tempdir().unwrap();
    write_run(dir.path(), 7, 8);
    let render = dir.path().join("render");
    render_run(dir.path(), &gif_opts()).unwrap();
    // Frame 0 will be written again: spoil it to see that it is replaced.
    std::fs::write(render.join("frame_00000.png"), b"old").unwrap();
    let opts = RenderOptions {
        every: 3,
        ..frames_only_opts()
    };
    let report = render_run(dir.path(), &opts).unwrap();
    assert_eq!(report.preview, None);
    assert_eq!(report.video, VideoMode::None);
    assert!((report.fps - 10.0).abs() < 1e-9);
    assert_eq!(report.frames_dir, render);
    assert_eq!(report.frames, frame_pngs(&render, &[0, 3, 6]));
    Image::read_png(&render.join("frame_00000.png")).expect("frame 0 rewritten");
    // The first render's other frames and its GIF are kept, and reported.
    assert_eq!(report.earlier_frames, frame_pngs(&render, &[1, 2, 4, 5]));
    for k in 0..7 {
        assert!(
            render.join(format!("frame_{k:05}.png")).is_file(),
            "frame {k}"
        );
    }
    assert!(dir.path().join("preview.gif").is_file());
    let warnings = report.warnings.join("\n");
    assert!(
        warnings.contains("4 frame PNGs")
            && warnings.contains("frame_00001.png to frame_00005.png"),
        "{warnings}"
    );
    assert!(
        warnings.contains("preview.gif is from an earlier render"),
        "{warnings}"
    );

    // A run with fewer frames than the last render (here, cut back to 3):
    // the frames beyond stay, and the report says so.
    let frames = dir.path().join("frames.jsonl");
    let text = std::fs::read_to_string(&frames).unwrap();
    let first3: String = text.lines().take(3).map(|l| format!("{l}\n")).collect();
    std::fs::write(&frames, first3).unwrap();
    let report = render_run(dir.path(), &frames_only_opts()).unwrap();
    assert_eq!(report.frames, frame_pngs(&render, &[0, 1, 2]));
    assert_eq!(report.earlier_frames, frame_pngs(&render, &[3, 4, 5, 6]));
    assert!(
        report
            .warnings
            .iter()
            .any(|w| w.contains("4 frame PNGs") && w.contains("frame_00003.png to frame_00006.png")),
        "{:?}",
        report.warnings
    );
}

#[test]
fn a_render_into_another_folder_leaves_the_run_folder_alone() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    write_run(&run, 3, 6);
    render_run(&run, &gif_opts()).unwrap();
    let before: Vec<Vec<u8>> = frame_pngs(&run.join("render"), &[0, 1, 2])
        .iter()
        .map(|p| std::fs::read(p).unwrap())
        .collect();
    let gif_before = std::fs::read(run.join("preview.gif")).unwrap();

    let out = dir.path().join("renders/wide");
    let opts = RenderOptions {
        width: 200,
        out: Some(out.clone()),
        ..gif_opts()
    };
    let report = render_run(&run, &opts).unwrap();
    assert_eq!(report.frames_dir, out);
    assert_eq!(report.frames, frame_pngs(&out, &[0, 1, 2]));
    assert_eq!(report.preview, Some(out.join("preview.gif")));
    assert_eq!(gif_frames(&out.join("preview.gif")).0, 200);
    assert!(report.earlier_frames.is_empty() && report.warnings.is_empty());
    // The run folder's own render is untouched.
    let after: Vec<Vec<u8>> = frame_pngs(&run.join("render"), &[0, 1, 2])
        .iter()
        .map(|p| std::fs::read(p).unwrap())
        .collect();
    assert!(before == after, "DIR/render changed");
    assert!(std::fs::read(run.join("preview.gif")).unwrap() == gif_before);
}

#[test]
fn a_run_still_writing_frames_jsonl_renders_its_complete_frames() {
    let dir = tempfile::tempdir().unwrap();
    write_run(dir.path(), 4, 6);
    // The run is writing frame 4's line: half of it is there, no newline.
    let frames = dir.path().join("frames.jsonl");
    let mut text = std::fs::read_to_string(&frames).unwrap();
    text.push_str("{\"frame\":4,\"file\":\"frames/frame_000");
    std::fs::write(&frames, &text).unwrap();
    let opts = frames_only_opts();
    let report = render_run(dir.path(), &opts).unwrap();
    assert_eq!(report.frames.len(), 4);
    assert!(
        report
            .warnings
            .iter()
            .any(|w| w.contains("frames.jsonl:5:") && w.contains("incomplete last line")),
        "{:?}",
        report.warnings
    );
    // A whole line that is malformed is still an error, last or not.
    text.push_str("04.ply\",\"time\":\"soon\"}\n");
    std::fs::write(&frames, &text).unwrap();
    let e = render_run(dir.path(), &opts).unwrap_err().to_string();
    assert!(
        e.contains("frames.jsonl:5:") && e.contains("malformed"),
        "{e}"
    );
}

#[test]
fn auto_picks_a_gif_when_ffmpeg_is_missing_and_mp4_then_fails() {
    let dir = tempfile::tempdir().unwrap();
    write_run(dir.path(), 3, 6);
    let missing = dir.path().join("no-such-ffmpeg");
    let opts = RenderOptions {
        video: VideoMode::Auto,
        ffmpeg: missing.clone(),
        ..gif_opts()
    };
    let report = render_run(dir.path(), &opts).unwrap();
    assert_eq!(report.video, VideoMode::Gif);
    assert!(report.warnings.is_empty(), "{:?}", report.warnings);
    assert_eq!(gif_frames(report.preview.as_ref().unwrap()).2, 3);

    let e = render_run(
        dir.path(),
        &RenderOptions {
            video: VideoMode::Mp4,
            ..opts
        },
    )
    .unwrap_err();
    assert!(matches!(e, RenderError::Video { .. }), "{e}");
    assert!(e.to_string().contains("no-such-ffmpeg"), "{e}");
}

/// An ffmpeg that answers `-version` but fails to encode: Auto falls back to
/// a GIF built from the PNG frames; an explicit MP4 fails with its message.
#[cfg(unix)]
#[test]
fn a_failing_ffmpeg_falls_back_to_gif_in_auto_mode() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    write_run(dir.path(), 4, 6);
    let fake = dir.path().join("fake-ffmpeg");
    std::fs::write(
        &fake,
        "#!/bin/sh\n[ \"$1\" = -version ] && exit 0\ncat >/dev/null\necho 'no encoder here' >&2\nexit 3\n",
    )
    .unwrap();
    std::fs::set_permissions(&fake, std::fs::Permissions::from_mode(0o755)).unwrap();
    let opts = RenderOptions {
        video: VideoMode::Auto,
        ffmpeg: fake,
        ..gif_opts()
    };
    let report = render_run(dir.path(), &opts).unwrap();
    assert_eq!(report.video, VideoMode::Gif);
    assert_eq!(report.warnings.len(), 1);
    assert!(
        report.warnings[0].contains("no encoder here"),
        "{:?}",
        report.warnings
    );
    assert_eq!(gif_frames(report.preview.as_ref().unwrap()).2, 4);
    assert!(!dir.path().join("preview.mp4").exists());

    let e = render_run(
        dir.path(),
        &RenderOptions {
            video: VideoMode::Mp4,
            ..opts
        },
    )
    .unwrap_err();
    assert!(e.to_string().contains("no encoder here"), "{e}");
}

#[test]
fn a_run_without_objects_json_is_all_cloth() {
    let dir = tempfile::tempdir().unwrap();
    write_run(dir.path(), 1, 10);
    std::fs::remove_file(dir.path().join("objects.json")).unwrap();
    let report = render_run(dir.path(), &frames_only_opts()).unwrap();
    let img = Image::read_png(&report.frames[0]).unwrap();
    let grey = img
        .rgb
        .chunks_exact(3)
        .filter(|p| (p[0] as i32 - p[2] as i32).abs() < 12 && p[0] < 175)
        .count();
    assert!(grey < 20, "{grey} grey pixels");
    // A single frame implies no rate: the default is used.
    assert_eq!(report.fps, weft_render::render::DEFAULT_FPS);
}

/// The hue of a colour in degrees; `None` for the greys (background,
/// obstacles, anti-aliased edges) whose hue says nothing.
fn hue(p: &[u8]) -> Option<f64> {
    let [r, g, b] = [p[0], p[1], p[2]].map(f64::from);
    let (max, min) = (r.max(g).max(b), r.min(g).min(b));
    if max - min < 40.0 {
        return None;
    }
    let h = if max == r {
        (g - b) / (max - min)
    } else if max == g {
        2.0 + (b - r) / (max - min)
    } else {
        4.0 + (r - g) / (max - min)
    };
    Some((60.0 * h).rem_euclid(360.0))
}

/// The median of the hues of the coloured pixels in columns `xs`.
fn median_hue(img: &Image, xs: std::ops::Range<u32>) -> f64 {
    let mut hues: Vec<f64> = xs
        .flat_map(|x| (0..img.height).map(move |y| (x, y)))
        .filter_map(|(x, y)| hue(&img.pixel(x, y)))
        .collect();
    assert!(hues.len() > 200, "only {} coloured pixels", hues.len());
    hues.sort_by(f64::total_cmp);
    hues[hues.len() / 2]
}

#[test]
fn each_cloth_gets_its_own_colour() {
    // One frame of two equal cloths side by side (left and right of x = 0),
    // listed as two cloth objects, seen from above and in front.
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir_all(dir.path().join("frames")).unwrap();
    let (a, ta) = cloth(8, 0.8, 0.0);
    let nv = a.len() as u32;
    let mut x: Vec<DVec3> = a.iter().map(|p| *p - DVec3::X * 0.5).collect();
    x.extend(a.iter().map(|p| *p + DVec3::X * 0.5));
    let mut t = ta.clone();
    t.extend(ta.iter().map(|f| f.map(|i| i + nv)));
    weft_io::write_ply(&dir.path().join("frames/frame_00000.ply"), &x, &t, None).unwrap();
    std::fs::write(
        dir.path().join("frames.jsonl"),
        "{\"frame\":0,\"file\":\"frames/frame_00000.ply\",\"time\":0.0}\n",
    )
    .unwrap();
    let nt = ta.len();
    std::fs::write(
        dir.path().join("objects.json"),
        format!(
            "{{\"objects\":[{{\"name\":\"left\",\"vertices\":[0,{nv}],\"triangles\":[0,{nt}],\"cloth\":true}},\
             {{\"name\":\"right\",\"vertices\":[{nv},{}],\"triangles\":[{nt},{}],\"cloth\":true}}]}}",
            2 * nv,
            2 * nt
        ),
    )
    .unwrap();
    let opts = RenderOptions {
        camera: Some(Camera {
            eye: DVec3::new(0.0, 2.5, 1.5),
            target: DVec3::ZERO,
            up: DVec3::Y,
            fov_y_degrees: 40.0,
        }),
        ..frames_only_opts()
    };
    let report = render_run(dir.path(), &opts).unwrap();
    let img = Image::read_png(&report.frames[0]).unwrap();
    let w = img.width;
    let (left, right) = (median_hue(&img, 0..w / 2), median_hue(&img, w / 2..w));
    let apart = (left - right).abs().min(360.0 - (left - right).abs());
    assert!(
        apart > 60.0,
        "left cloth hue {left:.0}°, right cloth hue {right:.0}°: too alike"
    );
}

#[test]
fn errors_name_the_file_and_line() {
    let dir = tempfile::tempdir().unwrap();
    let opts = frames_only_opts();
    let missing = dir.path().join("nothing-here");
    let e = render_run(&missing, &opts).unwrap_err().to_string();
    assert!(
        e.contains("nothing-here") && e.contains("no such folder"),
        "{e}"
    );

    let e = render_run(dir.path(), &opts).unwrap_err().to_string();
    assert!(e.contains("frames.jsonl"), "{e}");

    write_run(dir.path(), 3, 5);
    let frames = dir.path().join("frames.jsonl");
    let text = std::fs::read_to_string(&frames).unwrap();
    let mut lines: Vec<&str> = text.lines().collect();
    lines[1] = "{\"frame\":1,\"file\":";
    std::fs::write(&frames, lines.join("\n")).unwrap();
    let e = render_run(dir.path(), &opts).unwrap_err().to_string();
    assert!(e.contains("frames.jsonl:2:"), "{e}");

    std::fs::write(&frames, text).unwrap();
    std::fs::write(
        dir.path().join("frames/frame_00002.ply"),
        b"ply\nformat nonsense\n",
    )
    .unwrap();
    let e = render_run(dir.path(), &opts).unwrap_err().to_string();
    assert!(
        e.contains("frame 2") && e.contains("frame_00002.ply"),
        "{e}"
    );

    std::fs::copy(
        dir.path().join("frames/frame_00000.ply"),
        dir.path().join("frames/frame_00002.ply"),
    )
    .unwrap();
    std::fs::remove_file(dir.path().join("frames/frame_00001.ply")).unwrap();
    let e = render_run(dir.path(), &opts).unwrap_err().to_string();
    assert!(e.contains("frame_00001.ply"), "{e}");

    let bad = RenderOptions {
        every: 0,
        ..opts.clone()
    };
    assert!(matches!(
        render_run(dir.path(), &bad),
        Err(RenderError::Option(_))
    ));
    let bad = RenderOptions {
        camera: Some(Camera {
            eye: DVec3::ZERO,
            target: DVec3::ZERO,
            up: DVec3::Y,
            fov_y_degrees: 30.0,
        }),
        ..opts
    };
    let e = render_run(dir.path(), &bad).unwrap_err().to_string();
    assert!(e.contains("eye and target coincide"), "{e}");
}

#[test]
fn plots_are_drawn_from_stats_and_timing() {
    let dir = tempfile::tempdir().unwrap();
    write_stats(dir.path(), 60);
    let out = dir.path().join("plots");
    let files = plot_stats(dir.path(), &out).unwrap().files;
    let names: Vec<String> = files
        .iter()
        .map(|f| f.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    assert_eq!(
        names,
        ["energy.png", "momentum.png", "contacts.png", "time.png"]
    );
    for f in &files {
        let img = Image::read_png(f).unwrap();
        assert_eq!(img.width, weft_render::plot::CHART_WIDTH);
        let ink = img.count_not(weft_render::chart::BACKGROUND);
        assert!(ink > 10_000, "{}: {ink} non-background pixels", f.display());
        // Coloured lines, not only black text and grey grid.
        let coloured = img
            .rgb
            .chunks_exact(3)
            .filter(|p| p.iter().max().unwrap() - p.iter().min().unwrap() > 80)
            .count();
        assert!(
            coloured > 300,
            "{}: {coloured} coloured pixels",
            f.display()
        );
    }

    // A stats file as input, without timing beside it: three charts.
    std::fs::remove_file(dir.path().join("timing.jsonl")).unwrap();
    let files = plot_stats(&dir.path().join("stats.jsonl"), &out)
        .unwrap()
        .files;
    assert_eq!(files.len(), 3);
}

/// A run in progress may be cut off mid-line in `stats.jsonl` and
/// `timing.jsonl`: the torn last line is skipped with a warning, as `weft
/// render` does for `frames.jsonl`, and the whole lines are plotted.
#[test]
fn plots_are_drawn_from_a_run_still_writing_its_stats() {
    let dir = tempfile::tempdir().unwrap();
    write_stats(dir.path(), 5);
    for (name, torn) in [
        ("stats.jsonl", "{\"window\":5,\"time\":0.06,\"ti"),
        ("timing.jsonl", "{\"window\":5,\"wall_sec"),
    ] {
        let path = dir.path().join(name);
        let text = std::fs::read_to_string(&path).unwrap() + torn;
        std::fs::write(&path, text).unwrap();
    }
    let report = plot_stats(dir.path(), &dir.path().join("plots")).unwrap();
    assert_eq!(report.files.len(), 4);
    assert_eq!(report.warnings.len(), 2, "{:?}", report.warnings);
    for (w, name) in report
        .warnings
        .iter()
        .zip(["stats.jsonl:6:", "timing.jsonl:6:"])
    {
        assert!(
            w.contains(name) && w.contains("incomplete last line"),
            "{w}"
        );
    }
}

#[test]
fn a_malformed_stats_line_is_reported_with_file_and_line() {
    let dir = tempfile::tempdir().unwrap();
    write_stats(dir.path(), 5);
    let stats = dir.path().join("stats.jsonl");
    let mut text = std::fs::read_to_string(&stats).unwrap();
    text.push_str("{\"window\":5,\"time\":\"soon\"}\n");
    std::fs::write(&stats, text).unwrap();
    let e = plot_stats(dir.path(), &dir.path().join("plots")).unwrap_err();
    assert!(
        matches!(e, RenderError::Format { line: Some(6), .. }),
        "{e}"
    );
    assert!(e.to_string().contains("stats.jsonl:6:"), "{e}");

    let timing = dir.path().join("timing.jsonl");
    std::fs::write(&stats, "\n").unwrap();
    let e = plot_stats(&stats, &dir.path().join("plots")).unwrap_err();
    assert!(e.to_string().contains("no windows"), "{e}");
    write_stats(dir.path(), 3);
    std::fs::write(&timing, "{\"window\":0}\n").unwrap();
    let e = plot_stats(dir.path(), &dir.path().join("plots")).unwrap_err();
    assert!(e.to_string().contains("timing.jsonl:1:"), "{e}");
    let e = plot_stats(&dir.path().join("absent.jsonl"), dir.path()).unwrap_err();
    assert!(e.to_string().contains("absent.jsonl"), "{e}");
}

#[test]
fn the_legend_stays_clear_of_curves_that_fill_its_usual_corner() {
    use weft_render::chart::{draw_chart, Chart, Panel, Series, Style};
    // Level and low on the left, a dense wiggle from 0 to 1 on the right:
    // curves fill the top right, where the legend used to go, and both
    // bottom corners; the top left is free.
    let points = (0..=800)
        .map(|i| {
            let x = i as f64 / 800.0;
            let y = if x < 0.5 {
                0.15
            } else {
                0.5 + 0.5 * (300.0 * x).sin()
            };
            (x, y)
        })
        .collect();
    let curve = Series {
        name: "kinetic".into(),
        color: [31, 119, 180],
        points,
        style: Style::Line,
    };
    // A second series with no finite point: it is listed in the legend but
    // changes neither the axes nor the curves.
    let unplotted = Series {
        name: "contact".into(),
        color: [255, 127, 14],
        points: vec![(f64::NAN, f64::NAN)],
        style: Style::Line,
    };
    let chart = |series| Chart {
        title: "Energy".into(),
        x_label: "simulated time (s)".into(),
        panels: vec![Panel {
            title: "energy (J)".into(),
            series,
        }],
    };
    let with_legend = draw_chart(&chart(vec![curve.clone(), unplotted]), 1000);
    let without = draw_chart(&chart(vec![curve]), 1000);
    assert_eq!(
        (with_legend.width, with_legend.height),
        (without.width, without.height)
    );
    // The two charts differ only where the legend is; there, the chart
    // without it must show no curve (a coloured pixel).
    let coloured = |p: [u8; 3]| p.iter().max().unwrap() - p.iter().min().unwrap() > 20;
    let (mut legend, mut hidden) = (0, 0);
    for y in 0..without.height {
        for x in 0..without.width {
            if with_legend.pixel(x, y) != without.pixel(x, y) {
                legend += 1;
                hidden += usize::from(coloured(without.pixel(x, y)));
            }
        }
    }
    assert!(legend > 1000, "no legend drawn ({legend} pixels differ)");
    assert_eq!(hidden, 0, "the legend hides {hidden} pixels of the curve");
}
