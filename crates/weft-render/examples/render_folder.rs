//! Renders a run folder and plots its stats, printing the time per frame:
//!
//! ```sh
//! cargo run --release -p weft-render --example render_folder -- out/drape 480 360 gif
//! ```
//!
//! Arguments: `DIR [WIDTH HEIGHT [VIDEO [FFMPEG]]]`.

use std::path::PathBuf;
use weft_render::{plot_stats, render_run, RenderOptions, VideoMode};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let dir = PathBuf::from(
        args.next()
            .ok_or("usage: render_folder DIR [WIDTH HEIGHT [VIDEO [FFMPEG]]]")?,
    );
    let width = args.next().map_or(Ok(480), |s| s.parse())?;
    let height = args.next().map_or(Ok(360), |s| s.parse())?;
    let video: VideoMode = args.next().map_or(Ok(VideoMode::Auto), |s| s.parse())?;
    let mut opts = RenderOptions {
        width,
        height,
        video,
        ..Default::default()
    };
    if let Some(program) = args.next() {
        opts.ffmpeg = program.into();
    }
    let report = render_run(&dir, &opts)?;
    println!(
        "{} frames at {width}x{height} + {:?} preview in {:.3} s ({:.1} frames/s)",
        report.frames.len(),
        report.video,
        report.seconds,
        report.frames.len() as f64 / report.seconds
    );
    let t = std::time::Instant::now();
    let plots = plot_stats(&dir, &dir.join("plots"))?.files;
    println!(
        "{} plots in {:.3} s",
        plots.len(),
        t.elapsed().as_secs_f64()
    );
    Ok(())
}
