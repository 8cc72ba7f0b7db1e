//! [`render_run`]: every (k-th) frame of a run folder to PNG, then an MP4 or
//! GIF preview.
//!
//! Frames are rendered on several threads: worker `t` of `T` takes frames
//! `t, t + T, …` and hands each result over a channel of capacity 2, and the
//! writer receives them round-robin, so the preview gets the frames in order
//! and at most `2 T` finished frames wait in memory.

use crate::camera::Camera;
use crate::error::RenderError;
use crate::image::Image;
use crate::preview::{ffmpeg_available, gif_delay, GifWriter, Mp4Writer, Palette, VideoMode};
use crate::raster::Rasterizer;
use crate::run_folder::{FrameEntry, RunFolder};
use glam::DVec3;
use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{sync_channel, Receiver};
use std::time::Instant;

/// The folder of a run folder the PNG frames go to by default.
pub const RENDER_FOLDER: &str = "render";
/// The MP4 preview's name (in the run folder by default).
pub const PREVIEW_MP4: &str = "preview.mp4";
/// The GIF preview's name (in the run folder by default).
pub const PREVIEW_GIF: &str = "preview.gif";

/// Whether `name` is a frame file `frame_NNNNN.EXT` with extension `ext` (any
/// number of digits): the rendered PNGs and `weft run`'s frame files alike.
///
/// ```
/// use weft_render::is_frame;
/// assert!(is_frame("frame_00012.png", "png"));
/// assert!(!is_frame("frame_00012.png", "ply"));
/// assert!(!is_frame("frame_.png", "png") && !is_frame("frame_12a.png", "png"));
/// ```
pub fn is_frame(name: &str, ext: &str) -> bool {
    name.strip_prefix("frame_")
        .and_then(|r| r.strip_suffix(ext))
        .and_then(|r| r.strip_suffix('.'))
        .is_some_and(|d| !d.is_empty() && d.bytes().all(|b| b.is_ascii_digit()))
}

/// Frame rate of the preview when `frames.jsonl` implies none (one frame).
pub const DEFAULT_FPS: f64 = 24.0;
/// Largest accepted image side, in pixels.
pub const MAX_SIZE: u32 = 8192;

/// What [`render_run`] draws and writes.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderOptions {
    /// Image width in pixels (default 640).
    pub width: u32,
    /// Image height in pixels (default 480).
    pub height: u32,
    /// The camera; `None` fits one ([`Camera::fit_points`]) to all vertices
    /// of up to 9 evenly spaced rendered frames, the first and the last
    /// included, using `up` and `fov_y_degrees`.
    pub camera: Option<Camera>,
    /// Up direction of a fitted camera (default `+y`).
    pub up: DVec3,
    /// Vertical field of view of a fitted camera (default
    /// [`Camera::DEFAULT_FOV_Y_DEGREES`]).
    pub fov_y_degrees: f64,
    /// Render every `every`-th frame of `frames.jsonl` (default 1: all).
    pub every: usize,
    /// Which animated preview to write (default [`VideoMode::Auto`]).
    pub video: VideoMode,
    /// Preview frame rate; `None` plays in real time: the rate implied by the
    /// frame times in `frames.jsonl`, divided by `every`, and rounded to a
    /// whole number when within 5 % of one ([`DEFAULT_FPS`] for a single
    /// frame).
    pub fps: Option<f64>,
    /// Samples per pixel along each axis, 1 to 4 (default 3: 3×3).
    pub supersample: u32,
    /// The ffmpeg program, a name looked up on `PATH` or a path (default
    /// `ffmpeg`).
    pub ffmpeg: PathBuf,
    /// Rendering threads; 0 (default) uses the available parallelism.
    pub threads: usize,
    /// The folder for the PNG frames and the preview; `None` (default) puts
    /// the frames in `DIR/render/` and the preview in `DIR`.
    pub out: Option<PathBuf>,
}

impl Default for RenderOptions {
    fn default() -> Self {
        Self {
            width: 640,
            height: 480,
            camera: None,
            up: DVec3::Y,
            fov_y_degrees: Camera::DEFAULT_FOV_Y_DEGREES,
            every: 1,
            video: VideoMode::Auto,
            fps: None,
            supersample: 3,
            ffmpeg: PathBuf::from("ffmpeg"),
            threads: 0,
            out: None,
        }
    }
}

/// What [`render_run`] wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderReport {
    /// The folder of the PNG frames.
    pub frames_dir: PathBuf,
    /// The PNG frames, in frame order (`frame_NNNNN.png` in `frames_dir`,
    /// named by the frame index of `frames.jsonl`).
    pub frames: Vec<PathBuf>,
    /// Frame PNGs in `frames_dir` that this render did not write (an earlier
    /// render's, left in place), in name order.
    pub earlier_frames: Vec<PathBuf>,
    /// `preview.mp4` or `preview.gif`, if one was written.
    pub preview: Option<PathBuf>,
    /// The preview written: [`VideoMode::Mp4`], [`VideoMode::Gif`] or
    /// [`VideoMode::None`].
    pub video: VideoMode,
    /// The camera used (given or fitted).
    pub camera: Camera,
    /// Preview frame rate.
    pub fps: f64,
    pub width: u32,
    pub height: u32,
    /// What the user should know although the render succeeded: ffmpeg
    /// failing in [`VideoMode::Auto`] (a GIF is written instead), an
    /// incomplete last line of `frames.jsonl` skipped, files of an earlier
    /// render left beside this one's.
    pub warnings: Vec<String>,
    /// Wall-clock seconds of the whole call.
    pub seconds: f64,
}

impl RenderReport {
    /// Every file written: the frames, then the preview.
    pub fn files(&self) -> Vec<&Path> {
        self.frames
            .iter()
            .chain(&self.preview)
            .map(PathBuf::as_path)
            .collect()
    }
}

/// A rendered frame on its way to the preview writer.
enum Payload {
    Gif(gif::Frame<'static>),
    Rgb(Vec<u8>),
    Nothing,
}

/// Everything a rendering thread needs, shared read-only.
struct Job<'a> {
    run: &'a RunFolder,
    frames: &'a [&'a FrameEntry],
    camera: Camera,
    out_dir: &'a Path,
    opts: &'a RenderOptions,
    palette: Option<&'a Palette>,
    delay: u16,
    rgb: bool,
}

/// Renders the run folder `dir` (written by `weft run`, finished or still
/// running) to `frame_NNNNN.png`, one image per selected frame, then writes
/// `preview.mp4` (through ffmpeg) or `preview.gif` as `opts.video` says: all
/// into `opts.out`, or by default the frames into `dir/render/` and the
/// preview into `dir`. Cloth triangles (per `objects.json`; all triangles
/// when it is missing) get one colour per cloth object, obstacles are grey.
///
/// Nothing is deleted: a file this call writes replaces the one of that
/// name, and frame PNGs or a preview of an earlier render that it does not
/// write stay where they are, listed in the report's warnings (and the
/// frames in [`RenderReport::earlier_frames`]).
///
/// Errors name the file (and line) at fault: a missing folder or
/// `frames.jsonl`, a malformed line, an unreadable frame, an output that
/// cannot be written, ffmpeg missing when [`VideoMode::Mp4`] is asked for.
/// In [`VideoMode::Auto`] a failing ffmpeg does not fail the call: the GIF is
/// built from the PNG frames instead and the report carries a warning.
pub fn render_run(dir: &Path, opts: &RenderOptions) -> Result<RenderReport, RenderError> {
    let started = Instant::now();
    check_options(opts)?;
    let run = RunFolder::open(dir)?;
    let selected: Vec<&FrameEntry> = run.frames.iter().step_by(opts.every).collect();
    let camera = match opts.camera {
        Some(c) => c,
        None => fit_camera(&run, &selected, opts)?,
    };
    let video = match opts.video {
        VideoMode::Auto if ffmpeg_available(&opts.ffmpeg) => VideoMode::Mp4,
        VideoMode::Auto => VideoMode::Gif,
        VideoMode::Mp4 if !ffmpeg_available(&opts.ffmpeg) => {
            return Err(RenderError::Video {
                program: opts.ffmpeg.display().to_string(),
                message: "not found (`ffmpeg -version` does not run); install ffmpeg or ask \
                          for a GIF preview"
                    .into(),
            })
        }
        v => v,
    };
    let fps = opts.fps.unwrap_or_else(|| {
        run.implied_frame_rate()
            .map(|r| whole_if_close(r / opts.every as f64))
            .unwrap_or(DEFAULT_FPS)
    });
    let (out_dir, preview_dir) = match &opts.out {
        Some(out) => (out.clone(), out.clone()),
        None => (dir.join(RENDER_FOLDER), dir.to_path_buf()),
    };
    std::fs::create_dir_all(&out_dir).map_err(|e| RenderError::io(&out_dir, e))?;
    std::fs::create_dir_all(&preview_dir).map_err(|e| RenderError::io(&preview_dir, e))?;

    let palette = if video == VideoMode::Gif {
        Some(train_palette(&run, &selected, &camera, opts)?)
    } else {
        None
    };
    let mut warnings = Vec::new();
    if let Some(line) = run.incomplete_last_line {
        warnings.push(crate::json_lines::incomplete_warning(
            &dir.join("frames.jsonl"),
            line,
        ));
    }
    let gif_path = preview_dir.join(PREVIEW_GIF);
    let mp4_path = preview_dir.join(PREVIEW_MP4);
    let mut gif = match &palette {
        Some(p) => Some(GifWriter::create(&gif_path, opts.width, opts.height, p)?),
        None => None,
    };
    // An ffmpeg failure is kept until the frames are done: in Auto mode the
    // GIF is then built from the PNG frames instead.
    let (mut mp4, mut mp4_error) = if video == VideoMode::Mp4 {
        match Mp4Writer::create(&opts.ffmpeg, &mp4_path, opts.width, opts.height, fps) {
            Ok(w) => (Some(w), None),
            Err(e) => (None, Some(e)),
        }
    } else {
        (None, None)
    };
    let job = Job {
        run: &run,
        frames: &selected,
        camera,
        out_dir: &out_dir,
        opts,
        palette: palette.as_ref(),
        delay: gif_delay(fps),
        rgb: mp4.is_some(),
    };
    let frames = render_frames(&job, |payload| {
        match payload {
            Payload::Gif(f) => gif.as_mut().map_or(Ok(()), |g| g.push(&f))?,
            Payload::Rgb(rgb) => {
                if let (Some(m), None) = (mp4.as_mut(), &mp4_error) {
                    if let Err(e) = m.push(&rgb) {
                        mp4_error = Some(e);
                    }
                }
            }
            Payload::Nothing => {}
        }
        Ok(())
    })?;

    let mut preview = None;
    let mut written = video;
    if let Some(g) = gif {
        preview = Some(g.finish()?);
    }
    if video == VideoMode::Mp4 {
        let result = match (mp4_error, mp4) {
            (Some(e), _) => Err(e),
            (None, Some(m)) => m.finish(),
            (None, None) => unreachable!("an MP4 preview has a writer or an error"),
        };
        match result {
            Ok(p) => preview = Some(p),
            Err(e) if opts.video == VideoMode::Auto => {
                warnings.push(format!("{e}; wrote a GIF preview instead"));
                preview = Some(gif_from_pngs(&frames, &gif_path, gif_delay(fps))?);
                written = VideoMode::Gif;
            }
            Err(e) => return Err(e),
        }
    }
    let earlier_frames = earlier_frames(&out_dir, &frames);
    warnings.extend(earlier_render_warnings(
        &out_dir,
        &earlier_frames,
        &[&gif_path, &mp4_path],
        preview.as_deref(),
    ));
    Ok(RenderReport {
        frames_dir: out_dir,
        frames,
        earlier_frames,
        preview,
        video: written,
        camera,
        fps,
        width: opts.width,
        height: opts.height,
        warnings,
        seconds: started.elapsed().as_secs_f64(),
    })
}

/// Frames come at window boundaries, so a 30 fps run implies 29.7 fps or so:
/// within 5 % of a whole number, use the whole number.
fn whole_if_close(fps: f64) -> f64 {
    let whole = fps.round();
    if whole >= 1.0 && (fps - whole).abs() <= 0.05 * fps {
        whole
    } else {
        fps
    }
}

fn check_options(opts: &RenderOptions) -> Result<(), RenderError> {
    let bad = |m: String| Err(RenderError::Option(m));
    if !(1..=MAX_SIZE).contains(&opts.width) || !(1..=MAX_SIZE).contains(&opts.height) {
        return bad(format!(
            "image size {}x{}; each side must be 1 to {MAX_SIZE} pixels",
            opts.width, opts.height
        ));
    }
    if !(1..=4).contains(&opts.supersample) {
        return bad(format!(
            "supersampling {}; expected 1 to 4",
            opts.supersample
        ));
    }
    if opts.every == 0 {
        return bad("frame stride 0; expected 1 or more".into());
    }
    if let Some(fps) = opts.fps {
        if !(fps > 0.0 && fps <= 1000.0) {
            return bad(format!("frame rate {fps}; expected a value in (0, 1000]"));
        }
    }
    if let Some(c) = &opts.camera {
        c.validate().map_err(RenderError::Option)?;
    } else {
        let probe = Camera::fit(DVec3::ZERO, DVec3::ONE, 1.0, opts.up, opts.fov_y_degrees);
        probe.validate().map_err(RenderError::Option)?;
    }
    Ok(())
}

/// How many frames the fitted camera looks at.
const FIT_FRAMES: usize = 9;

/// Fits the camera to all vertices of up to [`FIT_FRAMES`] evenly spaced
/// selected frames, the first and the last included (a cloth can spread wider
/// mid-run than at either end).
fn fit_camera(
    run: &RunFolder,
    selected: &[&FrameEntry],
    opts: &RenderOptions,
) -> Result<Camera, RenderError> {
    let n = selected.len();
    let mut picks: Vec<usize> = if n <= FIT_FRAMES {
        (0..n).collect()
    } else {
        (0..FIT_FRAMES)
            .map(|k| k * (n - 1) / (FIT_FRAMES - 1))
            .collect()
    };
    picks.dedup();
    let mut points = Vec::new();
    for i in picks {
        points.extend(run.read_frame(selected[i])?.positions);
    }
    let aspect = opts.width as f64 / opts.height as f64;
    let fitted = Camera::fit_points(&points, aspect, opts.up, opts.fov_y_degrees);
    // Frames without a finite vertex: any view shows the empty background.
    Ok(fitted.unwrap_or_else(|| {
        Camera::fit(
            DVec3::ZERO,
            DVec3::ZERO,
            aspect,
            opts.up,
            opts.fov_y_degrees,
        )
    }))
}

/// Renders one frame into `raster`'s image.
fn render_image<'r>(
    run: &RunFolder,
    entry: &FrameEntry,
    camera: &Camera,
    raster: &'r mut Rasterizer,
) -> Result<&'r Image, RenderError> {
    let mesh = run.read_frame(entry)?;
    let surfaces = run.surfaces(mesh.triangles.len())?;
    Ok(raster.render(&mesh.positions, &mesh.triangles, &surfaces, camera))
}

/// The GIF palette, trained on the first, middle and last selected frames.
fn train_palette(
    run: &RunFolder,
    selected: &[&FrameEntry],
    camera: &Camera,
    opts: &RenderOptions,
) -> Result<Palette, RenderError> {
    let mut picks = vec![0, selected.len() / 2, selected.len() - 1];
    picks.dedup();
    let mut raster = Rasterizer::new(opts.width, opts.height, opts.supersample);
    let mut images = Vec::new();
    for i in picks {
        images.push(render_image(run, selected[i], camera, &mut raster)?.clone());
    }
    Ok(Palette::train(&images.iter().collect::<Vec<_>>()))
}

/// Renders `job.frames` on worker threads, writes each PNG, and passes the
/// preview payloads to `sink` in frame order. Returns the PNG paths.
fn render_frames(
    job: &Job<'_>,
    mut sink: impl FnMut(Payload) -> Result<(), RenderError>,
) -> Result<Vec<PathBuf>, RenderError> {
    let n = job.frames.len();
    let threads = match job.opts.threads {
        0 => std::thread::available_parallelism().map_or(1, |p| p.get()),
        t => t,
    }
    .clamp(1, n);
    std::thread::scope(|scope| {
        let receivers: Vec<Receiver<Result<(PathBuf, Payload), RenderError>>> = (0..threads)
            .map(|t| {
                let (tx, rx) = sync_channel(2);
                scope.spawn(move || {
                    let o = job.opts;
                    let mut raster = Rasterizer::new(o.width, o.height, o.supersample);
                    for i in (t..n).step_by(threads) {
                        let result = render_one(job, job.frames[i], &mut raster);
                        let failed = result.is_err();
                        // A closed channel means the writer gave up: stop.
                        if tx.send(result).is_err() || failed {
                            break;
                        }
                    }
                });
                rx
            })
            .collect();
        let mut pngs = Vec::with_capacity(n);
        for i in 0..n {
            let (png, payload) = receivers[i % threads]
                .recv()
                // A worker only hangs up early by panicking, which the scope
                // re-raises anyway.
                .expect("a rendering thread panicked")?;
            sink(payload)?;
            pngs.push(png);
        }
        Ok(pngs)
        // The receivers drop here, before the scope joins the workers, so a
        // worker blocked on a full channel after an error wakes up and stops.
    })
}

fn render_one(
    job: &Job<'_>,
    entry: &FrameEntry,
    raster: &mut Rasterizer,
) -> Result<(PathBuf, Payload), RenderError> {
    let img = render_image(job.run, entry, &job.camera, raster)?;
    let png = job.out_dir.join(format!("frame_{:05}.png", entry.frame));
    img.write_png(&png)?;
    let payload = match job.palette {
        Some(p) => Payload::Gif(p.encode_frame(img, job.delay)),
        None if job.rgb => Payload::Rgb(img.rgb.clone()),
        None => Payload::Nothing,
    };
    Ok((png, payload))
}

/// Builds the GIF from PNG frames already on disk (the fallback when ffmpeg
/// fails in [`VideoMode::Auto`]).
fn gif_from_pngs(pngs: &[PathBuf], path: &Path, delay: u16) -> Result<PathBuf, RenderError> {
    let mut picks = vec![0, pngs.len() / 2, pngs.len() - 1];
    picks.dedup();
    let samples = picks
        .into_iter()
        .map(|i| Image::read_png(&pngs[i]))
        .collect::<Result<Vec<_>, _>>()?;
    let palette = Palette::train(&samples.iter().collect::<Vec<_>>());
    let (w, h) = (samples[0].width, samples[0].height);
    let mut gif = GifWriter::create(path, w, h, &palette)?;
    for p in pngs {
        let img = Image::read_png(p)?;
        gif.push(&palette.encode_frame(&img, delay))?;
    }
    gif.finish()
}

/// What to tell about the files of an earlier render left in place: the
/// `earlier` frames in `out_dir`, and each of `previews` that exists but is
/// not the one `written`.
fn earlier_render_warnings(
    out_dir: &Path,
    earlier: &[PathBuf],
    previews: &[&Path],
    written: Option<&Path>,
) -> Vec<String> {
    let mut warnings = Vec::new();
    if let (Some(first), Some(last)) = (earlier.first(), earlier.last()) {
        let name = |p: &Path| {
            p.file_name()
                .unwrap_or_default()
                .to_string_lossy()
                .into_owned()
        };
        warnings.push(format!(
            "{} holds {} frame PNGs of an earlier render that this one did not write \
             ({} to {}); they were left in place",
            out_dir.display(),
            earlier.len(),
            name(first),
            name(last)
        ));
    }
    for &old in previews {
        if old.exists() && written != Some(old) {
            warnings.push(format!(
                "{} is from an earlier render; it was left in place",
                old.display()
            ));
        }
    }
    warnings
}

/// The `frame_*.png` files in `out_dir` that are not in `written` (an
/// earlier render's), sorted by name.
fn earlier_frames(out_dir: &Path, written: &[PathBuf]) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(out_dir) else {
        return Vec::new();
    };
    let written: HashSet<&std::ffi::OsStr> = written.iter().filter_map(|p| p.file_name()).collect();
    let mut earlier: Vec<PathBuf> = entries
        .flatten()
        .filter(|e| {
            let name = e.file_name();
            name.to_str().is_some_and(|n| is_frame(n, "png")) && !written.contains(name.as_os_str())
        })
        .map(|e| e.path())
        .collect();
    earlier.sort();
    earlier
}
