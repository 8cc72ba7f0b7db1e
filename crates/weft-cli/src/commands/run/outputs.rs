//! The files a run writes while it goes: frames in every requested format,
//! `frames.jsonl`, `stats.jsonl`, `timing.jsonl` and, for VTK, `frames.pvd`.
//!
//! Everything but `timing.jsonl` is a function of the committed states only,
//! so a run resumed from a checkpoint rewrites the same bytes: on resume the
//! line files are cut back to the lengths the checkpoint recorded and frames
//! after its frame cursor are removed, then writing simply continues.
//!
//! A window's lines and a frame's line reach their files as they are written
//! (see `line_file.rs`), a frame's line after its files, so `weft render DIR`
//! works on a run in progress.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use serde::{Deserialize, Serialize};
use weft_io::checkpoint::OutputCursors;
use weft_io::scene::FrameFormat;
use weft_sim::{CommittedWindow, World};

use super::faults;
use super::line_file::LineFile;

/// The folder (under the output folder) that frames of `format` go to.
pub fn frames_folder(format: FrameFormat) -> &'static str {
    match format {
        FrameFormat::Ply => "frames",
        FrameFormat::Obj => "frames-obj",
        FrameFormat::Vtk => "frames-vtk",
    }
}

/// The VTK series index, in the output folder.
pub const PVD_FILE: &str = "frames.pvd";
/// The line files, in the output folder.
pub const STATS_FILE: &str = "stats.jsonl";
pub const TIMING_FILE: &str = "timing.jsonl";
pub const FRAMES_FILE: &str = "frames.jsonl";

/// One line of `frames.jsonl`.
#[derive(Debug, Serialize, Deserialize)]
pub struct FrameRecord {
    pub frame: u64,
    /// Path of the frame in the first listed format, relative to the folder.
    pub file: String,
    pub time: f64,
    pub window: u64,
}

pub struct RunOutputs {
    out: PathBuf,
    formats: Vec<FrameFormat>,
    /// Simulated seconds between frames.
    frame_dt: f64,
    stats: LineFile,
    timing: LineFile,
    frames: LineFile,
    next_frame: u64,
    /// (time, file relative to the folder) of every VTK frame so far.
    pvd: Vec<(f64, String)>,
}

impl RunOutputs {
    /// Starts the files of a fresh run (replacing any of a previous one),
    /// with a frame every `frame_dt` simulated seconds.
    pub fn create(out: &Path, formats: &[FrameFormat], frame_dt: f64) -> anyhow::Result<Self> {
        for &f in formats {
            let dir = out.join(frames_folder(f));
            std::fs::create_dir_all(&dir)
                .with_context(|| format!("cannot create {}", dir.display()))?;
        }
        Ok(Self {
            out: out.to_path_buf(),
            formats: formats.to_vec(),
            frame_dt,
            stats: LineFile::create(&out.join(STATS_FILE))?,
            timing: LineFile::create(&out.join(TIMING_FILE))?,
            frames: LineFile::create(&out.join(FRAMES_FILE))?,
            next_frame: 0,
            pvd: Vec::new(),
        })
    }

    /// Continues the files of a run at the checkpoint's `cursors`.
    pub fn resume(
        out: &Path,
        formats: &[FrameFormat],
        frame_dt: f64,
        cursors: &OutputCursors,
    ) -> anyhow::Result<Self> {
        // Lines written after the checkpoint are cut, and written again.
        let stats = LineFile::resume(&out.join(STATS_FILE), cursors.stats_bytes)?;
        let timing = LineFile::resume(&out.join(TIMING_FILE), cursors.timing_bytes)?;
        let frames = LineFile::resume(&out.join(FRAMES_FILE), cursors.frames_bytes)?;
        let mut pvd = Vec::new();
        let text = std::fs::read_to_string(out.join(FRAMES_FILE))?;
        for (n, line) in text.lines().enumerate() {
            let r: FrameRecord = serde_json::from_str(line).with_context(|| {
                format!(
                    "{}:{}: malformed frame record",
                    out.join(FRAMES_FILE).display(),
                    n + 1
                )
            })?;
            pvd.push((r.time, vtk_name(r.frame)));
        }
        if pvd.len() as u64 != cursors.next_frame {
            bail!(
                "{} lists {} frames, the checkpoint expects {}",
                out.join(FRAMES_FILE).display(),
                pvd.len(),
                cursors.next_frame
            );
        }
        for &f in formats {
            let dir = out.join(frames_folder(f));
            std::fs::create_dir_all(&dir)?;
            remove_frames_from(&dir, f, cursors.next_frame)?;
        }
        Ok(Self {
            out: out.to_path_buf(),
            formats: formats.to_vec(),
            frame_dt,
            stats,
            timing,
            frames,
            next_frame: cursors.next_frame,
            pvd: if formats.contains(&FrameFormat::Vtk) {
                pvd
            } else {
                Vec::new()
            },
        })
    }

    pub fn frames_written(&self) -> u64 {
        self.next_frame
    }

    /// Appends a committed window's lines.
    pub fn record_window(&mut self, window: &CommittedWindow) -> anyhow::Result<()> {
        self.stats.append(&serde_json::to_string(&window.stats)?)?;
        self.timing
            .append(&serde_json::to_string(&window.timing)?)?;
        Ok(())
    }

    /// Writes every frame due at the world's (committed) time: frame k is the
    /// first committed state at or after `k / frame_rate`.
    pub fn frames_due(&mut self, world: &World) -> anyhow::Result<()> {
        while world.time() + 1e-12 >= self.next_frame as f64 * self.frame_dt {
            self.write_frame(world)?;
        }
        Ok(())
    }

    fn write_frame(&mut self, world: &World) -> anyhow::Result<()> {
        let k = self.next_frame;
        faults::injected("write:frame", k).with_context(|| {
            format!(
                "cannot write frame {k} in {}",
                self.out.join(frames_folder(self.formats[0])).display()
            )
        })?;
        let mut first = None;
        for &format in &self.formats {
            let rel = format!("{}/{}", frames_folder(format), frame_name(k, format));
            let path = self.out.join(&rel);
            match format {
                FrameFormat::Ply => {
                    weft_io::write_ply(&path, &world.x, &world.triangles, Some(&world.v))?
                }
                FrameFormat::Obj => weft_io::write_obj(&path, &world.x, &world.triangles)?,
                FrameFormat::Vtk => {
                    weft_io::vtk::write_vtu(&path, &world.x, &world.triangles, Some(&world.v))?;
                    self.pvd.push((world.time(), rel.clone()));
                    weft_io::vtk::write_pvd(&self.out.join(PVD_FILE), &self.pvd)?;
                }
            }
            first.get_or_insert(rel);
        }
        let rec = FrameRecord {
            frame: k,
            file: first.unwrap_or_default(),
            time: world.time(),
            window: world.window_index,
        };
        self.frames.append(&serde_json::to_string(&rec)?)?;
        self.next_frame += 1;
        Ok(())
    }

    /// Where every file stands, made durable first: a checkpoint records it.
    pub fn cursors(&self) -> anyhow::Result<OutputCursors> {
        for f in [&self.stats, &self.timing, &self.frames] {
            f.sync()?;
        }
        Ok(OutputCursors {
            next_frame: self.next_frame,
            stats_bytes: self.stats.len(),
            timing_bytes: self.timing.len(),
            frames_bytes: self.frames.len(),
        })
    }
}

fn frame_name(k: u64, format: FrameFormat) -> String {
    format!("frame_{k:05}.{}", format.extension())
}

fn vtk_name(k: u64) -> String {
    format!(
        "{}/{}",
        frames_folder(FrameFormat::Vtk),
        frame_name(k, FrameFormat::Vtk)
    )
}

/// Removes `frame_NNNNN.EXT` files with `NNNNN >= from` (written after the
/// checkpoint by the run being resumed; they are written again).
fn remove_frames_from(dir: &Path, format: FrameFormat, from: u64) -> anyhow::Result<()> {
    let ext = format!(".{}", format.extension());
    for entry in std::fs::read_dir(dir)? {
        let entry = entry?;
        let name = entry.file_name();
        let Some(name) = name.to_str() else { continue };
        let index = name
            .strip_prefix("frame_")
            .and_then(|r| r.strip_suffix(ext.as_str()))
            .and_then(|n| n.parse::<u64>().ok());
        if index.is_some_and(|k| k >= from) {
            std::fs::remove_file(entry.path())
                .with_context(|| format!("cannot remove {}", entry.path().display()))?;
        }
    }
    Ok(())
}
