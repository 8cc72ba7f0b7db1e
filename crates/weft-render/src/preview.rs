//! Animated previews: MP4 through an external `ffmpeg`, or an animated GIF
//! with one global palette.
//!
//! The GIF palette is trained once (NeuQuant) on a few frames and applied to
//! every frame through a 2^18-entry lookup table with a light ordered dither,
//! so the colours do not flicker between frames and quantizing a frame is a
//! table lookup per pixel. Frames are LZW-compressed by the rendering
//! threads; the writer only appends bytes.

use crate::error::RenderError;
use crate::files::TempOutput;
use crate::image::Image;
use std::borrow::Cow;
use std::fs::File;
use std::io::{BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};

/// Which animated preview [`render_run`](crate::render_run) writes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum VideoMode {
    /// MP4 when `ffmpeg -version` runs, GIF otherwise.
    #[default]
    Auto,
    /// MP4 through ffmpeg; an error when ffmpeg is missing.
    Mp4,
    /// An animated GIF (no external program).
    Gif,
    /// No animated preview, frames only.
    None,
}

impl std::str::FromStr for VideoMode {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "auto" => Ok(Self::Auto),
            "mp4" => Ok(Self::Mp4),
            "gif" => Ok(Self::Gif),
            "none" => Ok(Self::None),
            _ => Err(format!(
                "unknown video mode {s:?} (expected auto, mp4, gif or none)"
            )),
        }
    }
}

/// Whether `program -version` runs and exits successfully.
pub fn ffmpeg_available(program: &Path) -> bool {
    Command::new(program)
        .arg("-version")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// A GIF palette: 256 colours and a lookup from 6-bit-per-channel colours to
/// palette indices.
#[derive(Clone, Debug)]
pub(crate) struct Palette {
    rgb: Vec<u8>,
    lut: Vec<u8>,
}

/// 4×4 Bayer matrix, centred: offsets in units of 1/16 of the dither step.
const BAYER: [[i8; 4]; 4] = [
    [-8, 0, -6, 2],
    [4, -4, 6, -2],
    [-5, 3, -7, 1],
    [7, -1, 5, -3],
];

impl Palette {
    /// Trains a palette on the pixels of `images` (a few representative
    /// frames).
    pub fn train(images: &[&Image]) -> Palette {
        let mut rgba = Vec::new();
        for img in images {
            for p in img.rgb.chunks_exact(3) {
                rgba.extend_from_slice(&[p[0], p[1], p[2], 255]);
            }
        }
        if rgba.is_empty() {
            rgba.extend_from_slice(&[0, 0, 0, 255]);
        }
        let nq = color_quant::NeuQuant::new(10, 256, &rgba);
        let mut rgb = nq.color_map_rgb();
        rgb.resize(3 * 256, 0);
        let mut lut = vec![0u8; 1 << 18];
        for (key, slot) in lut.iter_mut().enumerate() {
            let c = |shift: u32| ((((key >> shift) & 63) as u8) << 2) | 2;
            *slot = nq.index_of(&[c(12), c(6), c(0), 255]) as u8;
        }
        Palette { rgb, lut }
    }

    /// The palette as `r g b` triples.
    pub fn colors(&self) -> &[u8] {
        &self.rgb
    }

    /// Palette indices of `img`, with an ordered dither of about ±4 levels
    /// that breaks up bands in the background gradient and smooth shading.
    pub fn indices(&self, img: &Image) -> Vec<u8> {
        let w = img.width as usize;
        img.rgb
            .chunks_exact(3)
            .enumerate()
            .map(|(i, p)| {
                let d = BAYER[(i / w) & 3][(i % w) & 3] as i32 / 2;
                let q = |v: u8| ((v as i32 + d).clamp(0, 255) as usize) >> 2;
                self.lut[(q(p[0]) << 12) | (q(p[1]) << 6) | q(p[2])]
            })
            .collect()
    }

    /// A GIF frame of `img`, LZW-compressed (so threads can share the work),
    /// shown for `delay` hundredths of a second.
    pub fn encode_frame(&self, img: &Image, delay: u16) -> gif::Frame<'static> {
        let mut frame = gif::Frame {
            width: img.width as u16,
            height: img.height as u16,
            delay,
            buffer: Cow::Owned(self.indices(img)),
            ..gif::Frame::default()
        };
        frame.make_lzw_pre_encoded();
        frame
    }
}

/// GIF frame delay (hundredths of a second) for `fps`; at least 2, since
/// browsers slow shorter delays down to 10.
pub(crate) fn gif_delay(fps: f64) -> u16 {
    (100.0 / fps).round().clamp(2.0, 65535.0) as u16
}

/// An animated GIF being written frame by frame.
pub(crate) struct GifWriter {
    // Dropped first: an abandoned encoder closes its file before the
    // temporary file is removed.
    encoder: gif::Encoder<BufWriter<File>>,
    out: TempOutput,
}

impl GifWriter {
    /// Starts `path` (written to a temporary file until [`GifWriter::finish`]).
    pub fn create(
        path: &Path,
        width: u32,
        height: u32,
        palette: &Palette,
    ) -> Result<Self, RenderError> {
        let out = TempOutput::new(path);
        let enc_err = |e: gif::EncodingError| RenderError::Encode {
            path: path.to_path_buf(),
            message: e.to_string(),
        };
        let file = File::create(&out.tmp).map_err(|e| RenderError::io(&out.tmp, e))?;
        let mut encoder = gif::Encoder::new(
            BufWriter::new(file),
            width as u16,
            height as u16,
            palette.colors(),
        )
        .map_err(enc_err)?;
        encoder.set_repeat(gif::Repeat::Infinite).map_err(enc_err)?;
        Ok(GifWriter { encoder, out })
    }

    /// Appends a frame from [`Palette::encode_frame`].
    pub fn push(&mut self, frame: &gif::Frame<'_>) -> Result<(), RenderError> {
        self.encoder
            .write_lzw_pre_encoded_frame(frame)
            .map_err(|e| RenderError::Encode {
                path: self.out.path.clone(),
                message: e.to_string(),
            })
    }

    /// Writes the trailer and moves the file into place.
    pub fn finish(self) -> Result<PathBuf, RenderError> {
        let path = self.out.path.clone();
        let enc_err = |message: String| RenderError::Encode {
            path: path.clone(),
            message,
        };
        let mut w = self
            .encoder
            .into_inner()
            .map_err(|e| enc_err(e.to_string()))?;
        w.flush().map_err(|e| RenderError::io(&path, e))?;
        drop(w);
        self.out.commit()
    }
}

/// An MP4 being encoded by an `ffmpeg` child process fed raw RGB frames.
pub(crate) struct Mp4Writer {
    /// `None` once finished.
    out: Option<TempOutput>,
    program: String,
    child: Child,
    stdin: Option<ChildStdin>,
    stderr: Option<std::thread::JoinHandle<String>>,
    frame_bytes: usize,
}

impl Mp4Writer {
    /// Starts `program` writing `path` at `fps` frames per second. Odd sizes
    /// are cropped by one pixel: yuv420p needs even width and height.
    pub fn create(
        program: &Path,
        path: &Path,
        width: u32,
        height: u32,
        fps: f64,
    ) -> Result<Self, RenderError> {
        let out = TempOutput::new(path);
        let name = program.display().to_string();
        let mut child = Command::new(program)
            .args(["-hide_banner", "-loglevel", "error", "-y"])
            .args(["-f", "rawvideo", "-pix_fmt", "rgb24"])
            .args(["-video_size", &format!("{width}x{height}")])
            .args(["-framerate", &format!("{fps}")])
            .args(["-i", "-"])
            .args(["-vf", "crop=trunc(iw/2)*2:trunc(ih/2)*2"])
            .args([
                "-pix_fmt",
                "yuv420p",
                "-movflags",
                "+faststart",
                "-f",
                "mp4",
            ])
            .arg(&out.tmp)
            .stdin(Stdio::piped())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| RenderError::Video {
                program: name.clone(),
                message: format!("cannot start: {e}"),
            })?;
        let stdin = child.stdin.take();
        // Drained on a thread so a chatty ffmpeg never blocks on a full pipe.
        let stderr = child.stderr.take().map(|mut s| {
            std::thread::spawn(move || {
                let mut text = String::new();
                let _ = s.read_to_string(&mut text);
                text
            })
        });
        Ok(Mp4Writer {
            out: Some(out),
            program: name,
            child,
            stdin,
            stderr,
            frame_bytes: 3 * width as usize * height as usize,
        })
    }

    /// Sends one frame (`3 * width * height` RGB bytes).
    pub fn push(&mut self, rgb: &[u8]) -> Result<(), RenderError> {
        debug_assert_eq!(rgb.len(), self.frame_bytes);
        let result = match self.stdin.as_mut() {
            Some(stdin) => stdin.write_all(rgb),
            None => Err(std::io::Error::other("stdin closed")),
        };
        result.map_err(|e| {
            let detail = self.stop();
            RenderError::Video {
                program: self.program.clone(),
                message: format!("writing frames failed ({e}){detail}"),
            }
        })
    }

    /// Closes the pipe, waits for ffmpeg and moves the file into place.
    pub fn finish(mut self) -> Result<PathBuf, RenderError> {
        drop(self.stdin.take());
        let status = self.child.wait().map_err(|e| RenderError::Video {
            program: self.program.clone(),
            message: format!("cannot wait for ffmpeg: {e}"),
        })?;
        let log = self
            .stderr
            .take()
            .and_then(|h| h.join().ok())
            .unwrap_or_default();
        if !status.success() {
            return Err(RenderError::Video {
                program: self.program.clone(),
                message: format!("exited with {status}: {}", log.trim()),
            });
        }
        match self.out.take() {
            Some(out) => out.commit(),
            None => unreachable!("finish consumes the writer"),
        }
    }

    /// Kills ffmpeg after a failed write; returns what it said, for the error.
    fn stop(&mut self) -> String {
        drop(self.stdin.take());
        let _ = self.child.kill();
        let _ = self.child.wait();
        let log = self
            .stderr
            .take()
            .and_then(|h| h.join().ok())
            .unwrap_or_default();
        if log.trim().is_empty() {
            String::new()
        } else {
            format!(": {}", log.trim())
        }
    }
}

impl Drop for Mp4Writer {
    fn drop(&mut self) {
        // An abandoned encode (an error elsewhere) must not leave a process.
        if self.stdin.is_some() {
            self.stop();
        }
    }
}
