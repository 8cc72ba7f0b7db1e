//! Checkpoint files: exact round trip, and every kind of damage refused with a
//! message that names the file and the problem.

use std::path::Path;

use weft_core::StencilKey;
use weft_io::checkpoint::{
    decode_checkpoint, encode_checkpoint, read_checkpoint, write_checkpoint, Checkpoint,
    CheckpointError, OutputCursors,
};
use weft_sim::layers::LayerState;
use weft_sim::{EngineState, RunTotals};

fn sample() -> Checkpoint {
    let n = 50;
    Checkpoint {
        weft_version: "0.1.0".into(),
        scene_name: "crumple".into(),
        scene_hash: "0123456789abcdef".into(),
        engine: EngineState {
            tick: 7 << 20,
            window_index: 7,
            x: (0..n)
                .map(|i| [i as f64 * 0.1, f64::MIN_POSITIVE, -0.0])
                .collect(),
            v: (0..n).map(|i| [1e-300, -(i as f64), 3.5]).collect(),
            tau: vec![7 << 20; n],
            layers: vec![
                (
                    StencilKey::vertex_face(3, [10, 11, 12]),
                    LayerState {
                        depth: 4,
                        calm_windows: 1,
                    },
                ),
                (
                    StencilKey::edge_edge([1, 2], [30, 31]),
                    LayerState {
                        depth: 1,
                        calm_windows: 0,
                    },
                ),
            ],
            totals: RunTotals {
                windows: 7,
                rollbacks: 12,
                narrow_queries: 999,
                max_depth: 4,
                max_active_stencils: 40,
            },
        },
        cursors: OutputCursors {
            next_frame: 3,
            stats_bytes: 1234,
            timing_bytes: 567,
            frames_bytes: 89,
        },
        wall_seconds: 12.5,
    }
}

#[test]
fn round_trip_is_exact() {
    let ck = sample();
    let bytes = encode_checkpoint(&ck).unwrap();
    let back = decode_checkpoint(&bytes, Path::new("c.wckp")).unwrap();
    assert_eq!(back, ck);
    // Bit patterns survive (-0.0 == 0.0 would hide a sign loss).
    assert_eq!(back.engine.x[0][2].to_bits(), (-0.0f64).to_bits());
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("c.wckp");
    let mut ran = false;
    write_checkpoint(&p, &ck, || ran = true).unwrap();
    assert!(ran);
    assert_eq!(read_checkpoint(&p).unwrap(), ck);
}

fn refused(bytes: &[u8]) -> String {
    let e = decode_checkpoint(bytes, Path::new("run/checkpoint.wckp")).unwrap_err();
    let msg = e.to_string();
    assert!(msg.starts_with("run/checkpoint.wckp: "), "{msg}");
    msg
}

#[test]
fn damage_is_refused_with_a_clear_message() {
    let good = encode_checkpoint(&sample()).unwrap();
    assert!(refused(b"").contains("not a weft checkpoint"));
    assert!(refused(b"PK\x03\x04 a zip file").contains("not a weft checkpoint"));
    assert!(refused(&good[..20]).contains("inside the 40-byte header"));
    assert!(refused(&good[..good.len() - 1]).contains("truncated"));
    let mut longer = good.clone();
    longer.push(0);
    assert!(refused(&longer).contains("truncated or appended"));
    let mut version = good.clone();
    version[8] = 99;
    let e = decode_checkpoint(&version, Path::new("c")).unwrap_err();
    assert!(
        matches!(e, CheckpointError::Version { found: 99, .. }),
        "{e}"
    );
    // Any single flipped bit of the payload is caught by the checksum.
    for at in [40, 41, good.len() / 2, good.len() - 1] {
        let mut bad = good.clone();
        bad[at] ^= 1;
        assert!(refused(&bad).contains("checksum mismatch"), "byte {at}");
    }
    // So is a flipped checksum.
    let mut bad = good.clone();
    bad[30] ^= 0x80;
    assert!(refused(&bad).contains("checksum mismatch"));
}

#[test]
fn a_failed_write_leaves_the_previous_checkpoint() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("c.wckp");
    let first = sample();
    write_checkpoint(&p, &first, || {}).unwrap();
    // Writing into a folder that vanished fails without touching `p`'s folder.
    let missing = dir.path().join("gone").join("c.wckp");
    assert!(write_checkpoint(&missing, &first, || {}).is_err());
    assert_eq!(read_checkpoint(&p).unwrap(), first);
}
