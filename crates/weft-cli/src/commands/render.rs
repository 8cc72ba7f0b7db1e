//! `weft render DIR [--out OUT]`: PNG frames of a run folder (finished or
//! still running) and an MP4 (ffmpeg) or GIF preview; see
//! [`weft_render::render_run`].

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::Args;
use glam::DVec3;
use weft_render::{render_run, Camera, RenderOptions, VideoMode};

#[derive(Debug, Args)]
pub struct RenderArgs {
    /// Run folder written by `weft run` (holds frames.jsonl); it may still be running.
    pub dir: PathBuf,
    /// Folder for the PNG frames and the preview; files of an earlier render are never deleted,
    /// and those not rewritten are reported [default: DIR/render for the frames, DIR for the
    /// preview]
    #[arg(long, value_name = "OUT")]
    pub out: Option<PathBuf>,
    /// Image width in pixels.
    #[arg(long, default_value_t = 640)]
    pub width: u32,
    /// Image height in pixels.
    #[arg(long, default_value_t = 480)]
    pub height: u32,
    /// Render every N-th frame.
    #[arg(long, default_value_t = 1, value_name = "N")]
    pub every: usize,
    /// Animated preview: auto (MP4 if ffmpeg runs, else GIF), mp4, gif or none.
    #[arg(long, default_value = "auto", value_parser = parse_video)]
    pub video: VideoMode,
    /// Preview frame rate [default: real time, from frames.jsonl].
    #[arg(long)]
    pub fps: Option<f64>,
    /// Camera position (needs --target); without it the scene's camera table is
    /// used, or else the camera is fitted.
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vec3, allow_hyphen_values = true)]
    pub eye: Option<DVec3>,
    /// Point the camera looks at (needs --eye).
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vec3, allow_hyphen_values = true)]
    pub target: Option<DVec3>,
    /// Camera up direction (also orients a fitted camera).
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vec3, allow_hyphen_values = true, default_value = "0,1,0")]
    pub up: DVec3,
    /// Vertical field of view in degrees.
    #[arg(long, value_name = "DEG", default_value_t = Camera::DEFAULT_FOV_Y_DEGREES)]
    pub fov: f64,
    /// Samples per pixel along each axis (1 to 4).
    #[arg(long, default_value_t = 3, value_name = "N")]
    pub supersample: u32,
    /// The ffmpeg program to use for MP4.
    #[arg(long, default_value = "ffmpeg", value_name = "PROGRAM")]
    pub ffmpeg: PathBuf,
}

fn parse_video(s: &str) -> Result<VideoMode, String> {
    s.parse()
}

/// Parses `X,Y,Z` into a vector of finite numbers.
pub fn parse_vec3(s: &str) -> Result<DVec3, String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != 3 {
        return Err(format!("expected X,Y,Z (three numbers), got {s:?}"));
    }
    let mut v = [0.0; 3];
    for (slot, p) in v.iter_mut().zip(&parts) {
        *slot = p
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| format!("{p:?} is not a finite number"))?;
    }
    Ok(DVec3::from_array(v))
}

/// The options `args` describe.
pub fn options(args: &RenderArgs) -> anyhow::Result<RenderOptions> {
    let camera = match (args.eye, args.target) {
        (Some(eye), Some(target)) => Some(Camera {
            eye,
            target,
            up: args.up,
            fov_y_degrees: args.fov,
        }),
        // The scene's `[camera]`, when the run's manifest leads to one.
        (None, None) => crate::commands::run::camera_of_run(&args.dir),
        _ => anyhow::bail!("--eye and --target go together (or leave both out to fit the camera)"),
    };
    Ok(RenderOptions {
        width: args.width,
        height: args.height,
        camera,
        up: args.up,
        fov_y_degrees: args.fov,
        every: args.every,
        video: args.video,
        fps: args.fps,
        supersample: args.supersample,
        ffmpeg: args.ffmpeg.clone(),
        threads: 0,
        out: args.out.clone(),
    })
}

pub fn run(args: RenderArgs) -> anyhow::Result<ExitCode> {
    let opts = options(&args)?;
    let report = render_run(&args.dir, &opts)
        .with_context(|| format!("cannot render {}", args.dir.display()))?;
    println!(
        "wrote {} frames ({}x{}) to {} in {:.2} s",
        report.frames.len(),
        report.width,
        report.height,
        report.frames_dir.display(),
        report.seconds
    );
    if let Some(p) = &report.preview {
        println!("wrote {} ({:.3} frames/s)", p.display(), report.fps);
    }
    let c = report.camera;
    println!(
        "camera: --eye {},{},{} --target {},{},{} --up {},{},{} --fov {}",
        c.eye.x,
        c.eye.y,
        c.eye.z,
        c.target.x,
        c.target.y,
        c.target.z,
        c.up.x,
        c.up.y,
        c.up.z,
        c.fov_y_degrees
    );
    for w in &report.warnings {
        eprintln!("warning: {w}");
    }
    Ok(ExitCode::SUCCESS)
}
