//! # weft-render — pictures only
//!
//! Previews and plots of weft runs, with no GPU and no system libraries:
//!
//! * [`render_run`] reads a run folder written by `weft run`
//!   (`frames.jsonl`, the PLY/OBJ frames, `objects.json`), also while the run
//!   is still writing it, and writes one PNG per frame to `DIR/render/`, then
//!   `DIR/preview.mp4` through `ffmpeg` when it is installed, or an animated
//!   `DIR/preview.gif` otherwise (or both into [`RenderOptions::out`]);
//! * [`plot_stats`] draws `stats.jsonl` and `timing.jsonl` as PNG line charts
//!   (energy, momentum, contacts, wall time), also while the run is still
//!   writing them;
//! * the pieces are public for other uses: [`Rasterizer`] (a z-buffered,
//!   supersampled software rasterizer with two-sided Lambert shading),
//!   [`Camera`] (perspective look-at, and [`Camera::fit`] to a bounding box),
//!   [`Image`] (RGB8 with PNG encoding), [`RunFolder`] (the run-folder
//!   reader), and [`chart`] with the built-in [`font`].
//!
//! Every error is a [`RenderError`] whose `Display` names the file and, for a
//! malformed line, the line (`run/frames.jsonl:3: malformed frame record: …`).
//!
//! ```no_run
//! use weft_render::{render_run, RenderOptions, VideoMode};
//!
//! let opts = RenderOptions { width: 480, height: 360, video: VideoMode::Gif, ..Default::default() };
//! let report = render_run("out/drape".as_ref(), &opts)?;
//! for f in report.files() {
//!     println!("{}", f.display());
//! }
//! # Ok::<(), weft_render::RenderError>(())
//! ```

pub mod camera;
pub mod chart;
pub mod error;
mod files;
pub mod font;
pub mod image;
mod json_lines;
pub mod plot;
pub mod preview;
pub mod raster;
pub mod render;
pub mod run_folder;

pub use camera::Camera;
pub use error::RenderError;
pub use image::Image;
pub use plot::{plot_stats, PlotReport};
pub use preview::{ffmpeg_available, VideoMode};
pub use raster::{Rasterizer, Surface};
pub use render::{
    is_frame, render_run, RenderOptions, RenderReport, PREVIEW_GIF, PREVIEW_MP4, RENDER_FOLDER,
};
pub use run_folder::{FrameEntry, FrameMesh, ObjectRange, RunFolder};
