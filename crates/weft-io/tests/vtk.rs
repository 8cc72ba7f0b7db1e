//! VTK output: `.vtu` frames read back bit for bit by a small reader written
//! here, `.pvd` collections, and well-formed XML.

use glam::DVec3;
use std::collections::BTreeMap;
use weft_io::vtk::{encode_vtu, write_pvd, write_vtu, VTK_TRIANGLE};
use weft_io::IoError;

/// One `<DataArray .../>` of the header: its attributes.
type Attrs = BTreeMap<String, String>;

/// The parts of a `.vtu` this reader understands.
struct Vtu {
    header: String,
    trailer: String,
    points: usize,
    cells: usize,
    arrays: BTreeMap<String, (Attrs, Vec<u8>)>,
}

fn attrs(tag: &str) -> Attrs {
    let mut out = Attrs::new();
    let mut rest = tag;
    while let Some(eq) = rest.find("=\"") {
        let key = rest[..eq].rsplit(' ').next().unwrap().to_string();
        let after = &rest[eq + 2..];
        let end = after.find('"').expect("closing quote");
        out.insert(key, after[..end].to_string());
        rest = &after[end + 1..];
    }
    out
}

/// Parses a raw-appended `.vtu` with UInt64 block headers.
fn read_vtu(bytes: &[u8]) -> Vtu {
    let marker = b"<AppendedData encoding=\"raw\">";
    let at = bytes
        .windows(marker.len())
        .position(|w| w == marker)
        .expect("an AppendedData section");
    let underscore = at + bytes[at..].iter().position(|&b| b == b'_').unwrap();
    let header = String::from_utf8(bytes[..underscore].to_vec()).expect("UTF-8 header");
    assert!(header.contains("header_type=\"UInt64\""));
    assert!(header.contains("byte_order=\"LittleEndian\""));
    let data = &bytes[underscore + 1..];
    let piece = attrs(&header[header.find("<Piece").unwrap()..]);
    let mut arrays = BTreeMap::new();
    let mut end = 0;
    for part in header.split("<DataArray").skip(1) {
        let a = attrs(&part[..part.find("/>").unwrap()]);
        assert_eq!(a["format"], "appended");
        let off: usize = a["offset"].parse().unwrap();
        let len = u64::from_le_bytes(data[off..off + 8].try_into().unwrap()) as usize;
        let block = data[off + 8..off + 8 + len].to_vec();
        end = end.max(off + 8 + len);
        arrays.insert(a["Name"].clone(), (a, block));
    }
    Vtu {
        header,
        trailer: String::from_utf8(data[end..].to_vec()).unwrap(),
        points: piece["NumberOfPoints"].parse().unwrap(),
        cells: piece["NumberOfCells"].parse().unwrap(),
        arrays,
    }
}

fn f64s(b: &[u8]) -> Vec<u64> {
    b.chunks_exact(8)
        .map(|c| u64::from_le_bytes(c.try_into().unwrap()))
        .collect()
}

fn i64s(b: &[u8]) -> Vec<i64> {
    b.chunks_exact(8)
        .map(|c| i64::from_le_bytes(c.try_into().unwrap()))
        .collect()
}

/// Checks that every opened tag is closed in order (`<?...?>` and `<.../>`
/// stand alone).
fn assert_balanced(xml: &str) {
    let mut stack: Vec<String> = Vec::new();
    let mut rest = xml;
    while let Some(open) = rest.find('<') {
        let close = rest[open..].find('>').expect("unterminated tag") + open;
        let tag = &rest[open + 1..close];
        rest = &rest[close + 1..];
        if tag.starts_with('?') {
            assert!(tag.ends_with('?'), "processing instruction {tag}");
        } else if let Some(name) = tag.strip_prefix('/') {
            assert_eq!(stack.pop().as_deref(), Some(name.trim()), "in {xml}");
        } else if !tag.ends_with('/') {
            stack.push(tag.split_whitespace().next().unwrap().to_string());
        }
    }
    assert!(stack.is_empty(), "unclosed: {stack:?}");
}

fn tricky_values() -> (Vec<DVec3>, Vec<DVec3>, Vec<[u32; 3]>) {
    let x = vec![
        DVec3::new(0.1, -0.0, 1e-310),
        DVec3::new(1.0 / 3.0, f64::MAX, -f64::MIN_POSITIVE),
        DVec3::new(std::f64::consts::PI, 2.5e-17, -7.0),
        DVec3::new(0.30000000000000004, 1e300, -1e-300),
    ];
    let v = vec![
        DVec3::new(-0.1, 0.2, 0.3),
        DVec3::new(1e-20, -1e20, 0.0),
        DVec3::new(5e-324, -5e-324, 1.0),
        DVec3::new(0.7, 0.8, 0.9),
    ];
    (x, v, vec![[0, 1, 2], [0, 2, 3]])
}

#[test]
fn vtu_round_trips_the_bits_of_points_velocities_and_triangles() {
    let (x, v, tris) = tricky_values();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("frame_00000.vtu");
    write_vtu(&path, &x, &tris, Some(&v)).unwrap();
    let vtu = read_vtu(&std::fs::read(&path).unwrap());
    assert_eq!((vtu.points, vtu.cells), (4, 2));

    let (a, points) = &vtu.arrays["Points"];
    assert_eq!(
        (a["type"].as_str(), a["NumberOfComponents"].as_str()),
        ("Float64", "3")
    );
    let want: Vec<u64> = x
        .iter()
        .flat_map(|p| p.to_array())
        .map(f64::to_bits)
        .collect();
    assert_eq!(f64s(points), want);

    let (a, vel) = &vtu.arrays["velocity"];
    assert_eq!(a["type"], "Float64");
    let want: Vec<u64> = v
        .iter()
        .flat_map(|p| p.to_array())
        .map(f64::to_bits)
        .collect();
    assert_eq!(f64s(vel), want);
    assert!(vtu.header.contains("<PointData Vectors=\"velocity\">"));

    assert_eq!(i64s(&vtu.arrays["connectivity"].1), [0, 1, 2, 0, 2, 3]);
    assert_eq!(i64s(&vtu.arrays["offsets"].1), [3, 6]);
    assert_eq!(vtu.arrays["types"].1, [VTK_TRIANGLE; 2]);
    assert_eq!(vtu.arrays["types"].0["type"], "UInt8");

    // The binary section ends where the last block ends; the rest closes tags.
    assert_eq!(vtu.trailer, "\n  </AppendedData>\n</VTKFile>\n");
    assert_balanced(&format!("{}{}", vtu.header, vtu.trailer));
}

#[test]
fn vtu_without_velocities_has_no_point_data() {
    let (x, _, tris) = tricky_values();
    let vtu = read_vtu(&encode_vtu(&x, &tris, None));
    assert!(!vtu.header.contains("PointData"));
    assert!(!vtu.arrays.contains_key("velocity"));
    let want: Vec<u64> = x
        .iter()
        .flat_map(|p| p.to_array())
        .map(f64::to_bits)
        .collect();
    assert_eq!(f64s(&vtu.arrays["Points"].1), want);
    assert_balanced(&format!("{}{}", vtu.header, vtu.trailer));
    // An empty mesh is still a valid file.
    let empty = read_vtu(&encode_vtu(&[], &[], None));
    assert_eq!((empty.points, empty.cells), (0, 0));
}

#[test]
fn vtu_refuses_data_it_cannot_represent() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.vtu");
    let (mut x, v, tris) = tricky_values();
    let e = write_vtu(&path, &x, &[[0, 1, 9]], None).unwrap_err();
    assert!(matches!(e, IoError::InvalidInput { .. }), "{e}");
    let e = write_vtu(&path, &x, &tris, Some(&v[..3])).unwrap_err();
    assert!(e.to_string().contains("3 velocities for 4 vertices"), "{e}");
    x[2].y = f64::NAN;
    let e = write_vtu(&path, &x, &tris, None).unwrap_err();
    assert!(e.to_string().contains("vertex 2"), "{e}");
    assert!(!path.exists(), "nothing is written on refusal");
}

#[test]
fn pvd_lists_the_frames_with_their_times() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("frames.pvd");
    let entries = vec![
        (0.0, "frames-vtk/frame_00000.vtu".to_string()),
        (1.0 / 30.0, "frames-vtk/frame_00001.vtu".to_string()),
        (0.1, "odd & <name>.vtu".to_string()),
    ];
    write_pvd(&path, &entries).unwrap();
    let xml = std::fs::read_to_string(&path).unwrap();
    assert_balanced(&xml);
    assert!(xml.contains("<VTKFile type=\"Collection\""));
    let sets: Vec<Attrs> = xml
        .split("<DataSet")
        .skip(1)
        .map(|p| attrs(&p[..p.find("/>").unwrap()]))
        .collect();
    assert_eq!(sets.len(), 3);
    for ((t, f), a) in entries.iter().zip(&sets) {
        assert_eq!(a["timestep"].parse::<f64>().unwrap().to_bits(), t.to_bits());
        let file = a["file"]
            .replace("&lt;", "<")
            .replace("&gt;", ">")
            .replace("&amp;", "&");
        assert_eq!(&file, f);
    }
    let e = write_pvd(&path, &[(f64::INFINITY, "x.vtu".into())]).unwrap_err();
    assert!(e.to_string().contains("not finite"), "{e}");
}
