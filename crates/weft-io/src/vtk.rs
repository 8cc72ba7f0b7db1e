//! VTK XML output for ParaView and VisIt: one `.vtu` per frame and a `.pvd`
//! collection that lists the frames with their times.
//!
//! The `.vtu` is an `UnstructuredGrid` of triangles (cell type 5) with
//! `Float64` points and, if given, a `velocity` point-data array. The arrays
//! are stored as raw little-endian binary in the `AppendedData` section, each
//! block prefixed by its byte count as a `UInt64` (`header_type="UInt64"`), so
//! the file holds the exact `f64` bits: `read(write(x)) == x` bit for bit.
//! Connectivity and offsets are `Int64`, the cell types `UInt8`.

use crate::atomic::write_atomic;
use crate::error::IoError;
use glam::DVec3;
use std::fmt::Write as _;
use std::path::Path;

/// VTK's cell type of a linear triangle.
pub const VTK_TRIANGLE: u8 = 5;

/// Writes a VTK XML unstructured grid of `triangles` over the points `x`,
/// with the point-data array `velocity` if `v` is given, atomically.
///
/// Refuses (with [`IoError::InvalidInput`]) non-finite values, indices out of
/// range, and a velocity count that differs from the point count.
pub fn write_vtu(
    path: &Path,
    x: &[DVec3],
    triangles: &[[u32; 3]],
    v: Option<&[DVec3]>,
) -> Result<(), IoError> {
    crate::check_writable(path, x, triangles, v)?;
    write_atomic(path, &encode_vtu(x, triangles, v))
}

/// The bytes of a `.vtu` file (see [`write_vtu`]; no checks).
pub fn encode_vtu(x: &[DVec3], triangles: &[[u32; 3]], v: Option<&[DVec3]>) -> Vec<u8> {
    // Appended blocks, each a UInt64 byte count and the data; the XML refers
    // to them by their offset from the first byte after the `_` marker.
    let vec3_bytes = |a: &[DVec3]| -> Vec<u8> {
        a.iter()
            .flat_map(|p| p.to_array())
            .flat_map(f64::to_le_bytes)
            .collect()
    };
    let mut blocks = Vec::with_capacity(5);
    if let Some(v) = v {
        blocks.push(vec3_bytes(v));
    }
    blocks.push(vec3_bytes(x));
    blocks.push(
        triangles
            .iter()
            .flatten()
            .flat_map(|&i| i64::from(i).to_le_bytes())
            .collect(),
    );
    blocks.push(
        (1..=triangles.len() as i64)
            .flat_map(|k| (3 * k).to_le_bytes())
            .collect(),
    );
    blocks.push(vec![VTK_TRIANGLE; triangles.len()]);
    let mut data = Vec::with_capacity(blocks.iter().map(|b| 8 + b.len()).sum());
    let mut offsets = Vec::with_capacity(blocks.len());
    for b in &blocks {
        offsets.push(data.len());
        data.extend_from_slice(&(b.len() as u64).to_le_bytes());
        data.extend_from_slice(b);
    }

    let mut o = offsets.into_iter();
    let mut xml = String::new();
    xml.push_str("<?xml version=\"1.0\"?>\n");
    xml.push_str(
        "<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" \
         header_type=\"UInt64\">\n",
    );
    xml.push_str("  <UnstructuredGrid>\n");
    let _ = writeln!(
        xml,
        "    <Piece NumberOfPoints=\"{}\" NumberOfCells=\"{}\">",
        x.len(),
        triangles.len()
    );
    if v.is_some() {
        xml.push_str("      <PointData Vectors=\"velocity\">\n");
        let _ = writeln!(
            xml,
            "        <DataArray type=\"Float64\" Name=\"velocity\" NumberOfComponents=\"3\" \
             format=\"appended\" offset=\"{}\"/>",
            o.next().unwrap_or(0)
        );
        xml.push_str("      </PointData>\n");
    }
    xml.push_str("      <Points>\n");
    let _ = writeln!(
        xml,
        "        <DataArray type=\"Float64\" Name=\"Points\" NumberOfComponents=\"3\" \
         format=\"appended\" offset=\"{}\"/>",
        o.next().unwrap_or(0)
    );
    xml.push_str("      </Points>\n      <Cells>\n");
    for (ty, name) in [
        ("Int64", "connectivity"),
        ("Int64", "offsets"),
        ("UInt8", "types"),
    ] {
        let _ = writeln!(
            xml,
            "        <DataArray type=\"{ty}\" Name=\"{name}\" format=\"appended\" offset=\"{}\"/>",
            o.next().unwrap_or(0)
        );
    }
    xml.push_str("      </Cells>\n    </Piece>\n  </UnstructuredGrid>\n");
    xml.push_str("  <AppendedData encoding=\"raw\">\n   _");
    let mut out = xml.into_bytes();
    out.extend_from_slice(&data);
    out.extend_from_slice(b"\n  </AppendedData>\n</VTKFile>\n");
    out
}

/// Writes a ParaView collection (`.pvd`) listing `entries` as
/// `(time, file)` pairs, `file` relative to the `.pvd`'s folder, atomically.
/// Open the `.pvd` in ParaView to get the whole series with its times.
///
/// Refuses non-finite times.
pub fn write_pvd(path: &Path, entries: &[(f64, String)]) -> Result<(), IoError> {
    if let Some((t, f)) = entries.iter().find(|(t, _)| !t.is_finite()) {
        return Err(IoError::InvalidInput {
            path: path.to_path_buf(),
            message: format!("the time of {f:?} is not finite: {t}"),
        });
    }
    write_atomic(path, encode_pvd(entries).as_bytes())
}

/// The text of a `.pvd` file (see [`write_pvd`]). Times are written in
/// shortest round-trip form.
pub fn encode_pvd(entries: &[(f64, String)]) -> String {
    let mut xml = String::from(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\" \
         byte_order=\"LittleEndian\">\n  <Collection>\n",
    );
    for (t, file) in entries {
        let _ = writeln!(
            xml,
            "    <DataSet timestep=\"{t:?}\" group=\"\" part=\"0\" file=\"{}\"/>",
            escape_xml(file)
        );
    }
    xml.push_str("  </Collection>\n</VTKFile>\n");
    xml
}

/// Escapes the five XML special characters for an attribute value.
fn escape_xml(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            c => out.push(c),
        }
    }
    out
}
