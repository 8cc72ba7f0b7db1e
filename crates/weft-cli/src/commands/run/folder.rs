//! The output folder of a run: whether a fresh run may write into it, and
//! which of its files a run wrote — exactly those `--overwrite` removes.
//!
//! A run's files follow from its manifest: fixed names (the line files, the
//! checkpoint, the manifest itself, the preview, the reproduction bundle),
//! frames by pattern (`frame_NNNNN.EXT`) in the frame folders the manifest
//! lists, rendered frames (`render/frame_NNNNN.png`), and the temporary
//! files of writes a kill interrupted (`.NAME.PID[.N].tmp` of any of those).
//! Anything else in the folder — a user's notes, a plot — is not weft's to
//! remove. A folder with no manifest that `--overwrite` writes into anyway
//! loses the files named as a run's outputs (fixed names, frames in every
//! frame folder), so none of them passes for the new run's.

use std::path::Path;

use anyhow::{bail, Context};
use weft_io::scene::FrameFormat;
use weft_render::{is_frame, PREVIEW_GIF, PREVIEW_MP4, RENDER_FOLDER};

use super::manifest::{self, Manifest};
use super::outputs::{frames_folder, FRAMES_FILE, PVD_FILE, STATS_FILE, TIMING_FILE};
use super::CHECKPOINT_FILE;

/// Files a run writes at fixed places in its folder (the manifest last: it
/// says what the others are).
const FIXED_FILES: [&str; 11] = [
    "objects.json",
    STATS_FILE,
    TIMING_FILE,
    FRAMES_FILE,
    PVD_FILE,
    CHECKPOINT_FILE,
    PREVIEW_MP4,
    PREVIEW_GIF,
    "repro/window_start.ply",
    "repro/window_start.json",
    manifest::FILE,
];

const REPRO_FOLDER: &str = "repro";
const ALL_FORMATS: [FrameFormat; 3] = [FrameFormat::Ply, FrameFormat::Obj, FrameFormat::Vtk];

/// Checks that a fresh run may write into `out`: a folder (or nothing yet)
/// that is empty, or holds a run and `overwrite` is given, or holds other
/// files and `overwrite` is given.
pub fn check_fresh_out(out: &Path, overwrite: bool) -> anyhow::Result<()> {
    let shown = out.display();
    let meta = match std::fs::metadata(out) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => bail!("cannot use {shown} as the output folder: {e}"),
    };
    if !meta.is_dir() {
        bail!(
            "{shown} is a file, not a folder: --out names the folder the run writes its \
             frames, stats and checkpoints into (it is created if missing)"
        );
    }
    if out.join(manifest::FILE).exists() {
        if overwrite {
            // Its manifest must say which files are the run's.
            Manifest::read(out).with_context(|| {
                format!("cannot tell which files of {shown} the run there wrote")
            })?;
            return Ok(());
        }
        if out.join(CHECKPOINT_FILE).exists() {
            bail!(
                "{shown} already holds a run; continue it with `weft run --resume {shown}`, \
                 replace it with --overwrite, or choose another --out"
            );
        }
        bail!(
            "{shown} already holds a run that ended before its first checkpoint (there is \
             nothing to resume); replace it with --overwrite, or choose another --out"
        );
    }
    let empty = std::fs::read_dir(out)
        .with_context(|| format!("cannot list {shown}"))?
        .next()
        .is_none();
    if !empty && !overwrite {
        bail!(
            "{shown} is not empty and holds no weft run (it has no {}); choose a new or \
             empty folder, or give --overwrite to write into it anyway (files there named as \
             a run's outputs — stats.jsonl, checkpoint.wckp, frames/frame_*.ply … — are then \
             removed first; nothing else is touched)",
            manifest::FILE
        );
    }
    Ok(())
}

/// Removes the files of the run in `out`, as its manifest describes them, and
/// then the run's own folders where they are left empty. Where `out` holds no
/// manifest (a folder `--overwrite` writes into anyway), the files named as a
/// run's outputs are removed: the fixed names and the frames in every frame
/// folder (not `render/`, whose PNGs only a manifest says are weft's), so no
/// stale checkpoint or frame passes for the new run's.
pub fn remove_previous_run(out: &Path) -> anyhow::Result<()> {
    let (formats, with_render) = if out.join(manifest::FILE).exists() {
        (frame_formats(&Manifest::read(out)?), true)
    } else {
        (ALL_FORMATS.to_vec(), false)
    };
    for file in run_files(out, &formats, with_render) {
        match std::fs::remove_file(&file) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                return Err(e).with_context(|| {
                    format!("cannot remove {} of the run replaced", file.display())
                });
            }
            _ => {}
        }
    }
    let folders = formats.iter().map(|&f| frames_folder(f));
    let render = with_render.then_some(RENDER_FOLDER);
    for folder in folders.chain(render).chain([REPRO_FOLDER]) {
        // Fails, keeping it, where anything else is in it.
        let _ = std::fs::remove_dir(out.join(folder));
    }
    Ok(())
}

/// Removes the temporary files a killed process left behind in `out` (its
/// frame folders included): a checkpoint or frame whose write never reached
/// its rename (the checkpoint is then the previous one, and the frame is
/// written again after the resume).
pub fn remove_abandoned_temporaries(out: &Path) {
    for path in weft_temporaries(out, &ALL_FORMATS) {
        let _ = std::fs::remove_file(path);
    }
}

/// The frame formats of the run `m` describes (every format for a manifest
/// from before they were recorded).
fn frame_formats(m: &Manifest) -> Vec<FrameFormat> {
    if m.frame_folders.is_empty() {
        return ALL_FORMATS.to_vec();
    }
    ALL_FORMATS
        .into_iter()
        .filter(|&f| m.frame_folders.iter().any(|d| d == frames_folder(f)))
        .collect()
}

/// Every file in `out` that a run writing frames in `formats` wrote, its
/// rendered frames if `with_render`.
fn run_files(out: &Path, formats: &[FrameFormat], with_render: bool) -> Vec<std::path::PathBuf> {
    let mut files: Vec<_> = FIXED_FILES
        .iter()
        .map(|name| out.join(name))
        .filter(|p| p.is_file())
        .collect();
    for &f in formats {
        files.extend(matching(&out.join(frames_folder(f)), |n| {
            is_frame(n, f.extension())
        }));
    }
    if with_render {
        files.extend(matching(&out.join(RENDER_FOLDER), |n| is_frame(n, "png")));
    }
    files.extend(weft_temporaries(out, formats));
    // The manifest last: a removal cut short can be repeated.
    files.sort_by_key(|p| p.ends_with(manifest::FILE));
    files
}

/// The files directly in `dir` whose names `keep` accepts.
fn matching(dir: &Path, keep: impl Fn(&str) -> bool) -> Vec<std::path::PathBuf> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    entries
        .flatten()
        .filter(|e| e.file_type().is_ok_and(|t| t.is_file()))
        .filter(|e| e.file_name().to_str().is_some_and(&keep))
        .map(|e| e.path())
        .collect()
}

/// The temporary files of weft's writes in `out`, its frame folders and its
/// render folder.
fn weft_temporaries(out: &Path, formats: &[FrameFormat]) -> Vec<std::path::PathBuf> {
    let folders = formats.iter().map(|&f| frames_folder(f));
    let mut found = Vec::new();
    for folder in [""].into_iter().chain(folders).chain([RENDER_FOLDER]) {
        found.extend(matching(&out.join(folder), |name| {
            temporary_of(name).is_some_and(|target| {
                FIXED_FILES.contains(&target)
                    || ALL_FORMATS.iter().any(|f| is_frame(target, f.extension()))
                    || is_frame(target, "png")
            })
        }));
    }
    found
}

/// The file a temporary `.NAME.PID.N.tmp` (weft-io's atomic writes) or
/// `.NAME.PID.tmp` (weft-render's) was to become: `NAME`.
fn temporary_of(name: &str) -> Option<&str> {
    let mut rest = name.strip_prefix('.')?.strip_suffix(".tmp")?;
    let numeric = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
    let mut numbers = 0;
    while numbers < 2 {
        match rest.rsplit_once('.') {
            Some((head, n)) if numeric(n) => rest = head,
            _ => break,
        }
        numbers += 1;
    }
    (numbers > 0).then_some(rest)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_and_temporaries_are_told_by_name() {
        assert!(is_frame("frame_00012.ply", "ply"));
        assert!(!is_frame("frame_00012.ply", "vtu"));
        assert_eq!(
            temporary_of(".checkpoint.wckp.4242.7.tmp"),
            Some("checkpoint.wckp")
        );
        assert_eq!(temporary_of(".preview.gif.99.tmp"), Some("preview.gif"));
        assert_eq!(temporary_of(".notes.tmp"), None);
        assert_eq!(temporary_of("notes.txt"), None);
    }
}
