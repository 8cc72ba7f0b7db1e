//! weft-io integration tests: OBJ and PLY readers and writers, the shared data
//! meshes, malformed-input messages, and bit-exact round trips. Every test
//! writes only into a temporary directory.

use std::path::{Path, PathBuf};
use weft_core::{DVec3, MeshError, MeshWarning};
use weft_io::{
    encode_ply, parse_obj, parse_ply, read_mesh, read_obj, read_ply, write_atomic, write_mesh,
    write_obj, write_ply, IoError, ObjObject,
};

/// `/work/shared/data`-style shared folder: `../../../shared/data` from this
/// crate. Panics (fails the test) with a clear message when it is missing.
fn shared_data(rel: &str) -> PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
    assert!(
        root.is_dir(),
        "shared test data not found at {} (expected the read-only `shared/data` folder next to the \
         project checkout); this test needs it and must not pass without it",
        root.display()
    );
    root.join(rel)
}

fn obj(text: &str) -> weft_io::ObjData {
    parse_obj(text, Path::new("t.obj")).unwrap_or_else(|e| panic!("{e}"))
}

/// Parses `text`, expects an error, and checks its message contains every
/// fragment.
fn obj_err(text: &str, fragments: &[&str]) -> IoError {
    let err = parse_obj(text, Path::new("bad.obj")).expect_err("malformed OBJ must be rejected");
    let msg = err.to_string();
    for f in fragments {
        assert!(msg.contains(f), "message {msg:?} lacks {f:?}");
    }
    err
}

fn ply_err(bytes: &[u8], fragments: &[&str]) -> IoError {
    let err = parse_ply(bytes, Path::new("bad.ply")).expect_err("malformed PLY must be rejected");
    let msg = err.to_string();
    for f in fragments {
        assert!(msg.contains(f), "message {msg:?} lacks {f:?}");
    }
    err
}

fn bits(v: &[DVec3]) -> Vec<[u64; 3]> {
    v.iter().map(|p| p.to_array().map(f64::to_bits)).collect()
}

/// Awkward values: non-dyadic decimals, extremes, subnormals, signed zero.
fn awkward_positions() -> Vec<DVec3> {
    vec![
        DVec3::new(0.1, 0.2, 0.3),
        DVec3::new(1e-300, -0.0, 1.0 / 3.0),
        DVec3::new(f64::MAX, f64::MIN_POSITIVE, 5e-324),
        DVec3::new(-123456.789e10, std::f64::consts::PI, -1e16),
    ]
}

mod obj_reader {
    use super::*;

    #[test]
    fn all_face_forms_and_records() {
        let d = obj("# header comment\n\
             mtllib cloth.mtl\n\
             \n\
             v 0 0 0\n\
             v 1 0 0 1.0\n\
             v 1 1 0 0.5 0.5 0.5\n\
             v 0 1 0 # trailing comment\n\
             vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n\
             vn 0 0 1\n\
             usemtl red\ns 1\nl 1 2\n\
             f 1 2 3\n\
             f 1/1 3/3 4/4\n\
             f 1//1 2//1 3//1\n\
             f 1/1/1 3/3/1 4/4/1\n\
             curv 0 1 1 2\n");
        assert_eq!(d.mesh.num_vertices(), 4);
        assert_eq!(d.mesh.positions[2], DVec3::new(1.0, 1.0, 0.0));
        assert_eq!(
            d.mesh.triangles,
            vec![[0, 1, 2], [0, 2, 3], [0, 1, 2], [0, 2, 3]]
        );
        assert_eq!(d.face_lines, vec![16, 17, 18, 19]);
        assert_eq!(d.uvs.len(), 4);
        assert_eq!(d.face_uvs, None, "faces 0 and 2 have no vt indices");
        assert_eq!(
            d.objects,
            vec![ObjObject {
                name: String::new(),
                first_triangle: 0,
                triangle_count: 4
            }]
        );
    }

    #[test]
    fn face_uvs_when_every_face_has_them() {
        let d = obj("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n\
             vt 0 0\nvt 1 0\nvt 1 1\nvt 0.25 0.75\n\
             f 1/1 2/2 3/3 4/4\n");
        assert_eq!(d.face_uvs, Some(vec![[0, 1, 2], [0, 2, 3]]));
        assert_eq!(d.uvs[3], [0.25, 0.75]);
    }

    #[test]
    fn negative_indices_are_relative_to_definitions_so_far() {
        let d = obj("v 0 0 0\nv 1 0 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 1 1\n\
             f -3/-3 -2/-2 -1/-1\n\
             v 0 1 0\nvt 0 1\n\
             f -4/-4 -2/-2 -1/-1\n");
        assert_eq!(d.mesh.triangles, vec![[0, 1, 2], [0, 2, 3]]);
        assert_eq!(d.face_uvs, Some(vec![[0, 1, 2], [0, 2, 3]]));
    }

    #[test]
    fn polygons_are_fan_triangulated_in_order() {
        let d = obj("v 0 0 0\nv 1 0 0\nv 2 1 0\nv 1 2 0\nv 0 1 0\nf 1 2 3 4 5\n");
        assert_eq!(d.mesh.triangles, vec![[0, 1, 2], [0, 2, 3], [0, 3, 4]]);
        assert_eq!(d.face_lines, vec![6, 6, 6]);
    }

    #[test]
    fn several_objects_partition_the_triangles() {
        let d = obj("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n\
             f 1 2 3\n\
             o cloth\ng cloth_material\nf 1 3 4\nf 1 2 4\n\
             g\n\
             o obstacle part\nf 2 3 4\n\
             o empty\n");
        let names: Vec<(&str, usize, usize)> = d
            .objects
            .iter()
            .map(|o| (o.name.as_str(), o.first_triangle, o.triangle_count))
            .collect();
        assert_eq!(
            names,
            vec![
                ("", 0, 1),
                ("cloth_material", 1, 2),
                ("obstacle part", 3, 1)
            ]
        );
    }

    #[test]
    fn crlf_line_endings_and_tabs() {
        let d = obj("v\t0 0 0\r\nv 1 0 0\r\nv 0 1 0\r\nf 1 2 3\r\n");
        assert_eq!(d.mesh.triangles, vec![[0, 1, 2]]);
    }
}

mod obj_errors {
    use super::*;

    #[test]
    fn malformed_number() {
        let e = obj_err("v 0 0 0\nv 1 0.0.1 0\n", &["bad.obj:2:", "\"0.0.1\"", "y"]);
        assert!(matches!(e, IoError::Parse { line: Some(2), .. }));
        obj_err("v 0 0 0\nvt 1 zz\n", &["bad.obj:2:", "\"zz\"", "vt"]);
        obj_err(
            "v 0 0 0\nvn 1 0\n",
            &["bad.obj:2:", "`vn` record has 2 values"],
        );
    }

    #[test]
    fn too_few_coordinates() {
        obj_err(
            "v 0 0\n",
            &["bad.obj:1:", "`v` record has 2 values; expected at least 3"],
        );
    }

    #[test]
    fn too_few_face_vertices() {
        obj_err(
            "v 0 0 0\nv 1 0 0\nv 0 1 0\n\nf 1 2\n",
            &["bad.obj:5:", "face has 2 vertices; at least 3 are needed"],
        );
    }

    #[test]
    fn index_zero() {
        obj_err(
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n",
            &["bad.obj:4:", "vertex index 0", "start at 1"],
        );
    }

    #[test]
    fn index_out_of_range() {
        obj_err(
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n",
            &[
                "bad.obj:4:",
                "vertex index 4",
                "out of range",
                "3 vertices are defined before this line",
            ],
        );
        obj_err(
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -4\n",
            &["bad.obj:4:", "vertex index -4"],
        );
        obj_err(
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/2 3/1\n",
            &["bad.obj:5:", "texture coordinate index 2"],
        );
        obj_err(
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1//1 2//1 3//1\n",
            &["bad.obj:4:", "normal index 1"],
        );
    }

    #[test]
    fn malformed_face_corner() {
        obj_err(
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n",
            &["bad.obj:4:", "invalid vertex index \"x\""],
        );
        obj_err(
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3/1/1/1\n",
            &["bad.obj:4:", "\"3/1/1/1\""],
        );
        obj_err(
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 /1\n",
            &["bad.obj:4:", "no vertex index"],
        );
    }

    #[test]
    fn non_finite_vertex() {
        let e = obj_err(
            "v 0 0 0\nv 1 nan 0\n",
            &["bad.obj:2:", "vertex 2", "non-finite y", "NaN"],
        );
        assert!(matches!(e, IoError::Parse { line: Some(2), .. }));
        obj_err(
            "v 0 0 0\nv 1 0 -inf\n",
            &["bad.obj:2:", "non-finite z", "-inf"],
        );
    }
}

mod shared_meshes {
    use super::*;

    #[test]
    fn data_meshes_have_the_documented_counts() {
        // (file, vertices per the data README and the header, triangles per the header)
        for (name, v, t) in [
            ("square2K.obj", 1939, 3716),
            ("square8K.obj", 8282, 16154),
            ("sphere1K.obj", 1239, 2474),
            ("cylinder3K.obj", 3007, 5754),
            ("skirt4K.obj", 4004, 7496),
        ] {
            let path = shared_data(&format!("meshes/{name}"));
            let f = read_mesh(&path).unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(f.mesh.num_vertices(), v, "{name}");
            assert_eq!(f.mesh.num_triangles(), t, "{name}");
            assert_eq!(f.face_lines.as_ref().map(Vec::len), Some(t));
            assert_eq!(f.objects.len(), 1, "{name}: one (unnamed) group");
            assert!(f.warnings.is_empty(), "{name}: {:?}", f.warnings);
            let topo = weft_core::Topology::build(v, &f.mesh.triangles).unwrap();
            let boundary = topo.is_boundary_vertex.iter().any(|&b| b);
            assert_eq!(
                boundary,
                name != "sphere1K.obj",
                "{name}: only the sphere is closed"
            );
        }
    }

    #[test]
    fn cloth_funnel_frame_is_binary_le_f64() {
        let path = shared_data("ccd/belgrod2023/cloth-funnel/frames/227.ply");
        let d = read_ply(&path).unwrap_or_else(|e| panic!("{e}"));
        assert!(read_mesh(&path).unwrap().warnings.is_empty());
        assert_eq!(d.mesh.num_vertices(), 9450);
        assert_eq!(d.mesh.num_triangles(), 18484);
        assert_eq!(d.velocities, None);
        assert!(d.mesh.positions.iter().all(|p| p.is_finite()));
        // Re-encoding reproduces the same data bit for bit.
        let again = parse_ply(
            &encode_ply(&d.mesh.positions, &d.mesh.triangles, None),
            &path,
        )
        .unwrap();
        assert_eq!(bits(&again.mesh.positions), bits(&d.mesh.positions));
        assert_eq!(again.mesh.triangles, d.mesh.triangles);
    }
}

mod ply_formats {
    use super::*;

    const ASCII: &str = "ply\n\
        format ascii 1.0\n\
        comment a quad and a triangle, with an extra element and properties\n\
        element vertex 5\n\
        property float x\n\
        property float y\n\
        property float z\n\
        property uchar red\n\
        property float vx\n\
        property float vy\n\
        property float vz\n\
        element material 1\n\
        property list uchar float weights\n\
        element face 2\n\
        property uchar flags\n\
        property list uchar uint vertex_index\n\
        end_header\n\
        0 0 0 255 0.5 0 0\n\
        1 0 0 255 0 0.25 0\n\
        1 1 0 0 0 0 1\n\
        0 1 0 0 0 0 0\n\
        2 2 2 7 -1 -1 -1\n\
        3 0.5 0.25 0.25\n\
        0 4 0 1 2 3\n\
        1 3 1 4 2\n";

    fn check(d: &weft_io::PlyData) {
        assert_eq!(d.mesh.num_vertices(), 5);
        assert_eq!(d.mesh.positions[4], DVec3::splat(2.0));
        assert_eq!(d.mesh.triangles, vec![[0, 1, 2], [0, 2, 3], [1, 4, 2]]);
        let v = d.velocities.as_ref().expect("vx vy vz present");
        assert_eq!(v[0], DVec3::new(0.5, 0.0, 0.0));
        assert_eq!(v[4], DVec3::splat(-1.0));
    }

    /// Hand-encodes the same mesh in binary with f32 vertices and the given
    /// byte order (so the big-endian path is tested on bytes weft did not write).
    fn binary(big_endian: bool) -> Vec<u8> {
        let fmt = if big_endian {
            "binary_big_endian"
        } else {
            "binary_little_endian"
        };
        let mut out = format!(
            "ply\nformat {fmt} 1.0\nelement vertex 5\nproperty float x\nproperty float y\n\
             property float z\nproperty uchar red\nproperty float vx\nproperty float vy\n\
             property float vz\nelement material 1\nproperty list uchar float weights\n\
             element face 2\nproperty uchar flags\nproperty list uchar uint vertex_index\nend_header\n"
        )
        .into_bytes();
        let f = |out: &mut Vec<u8>, x: f32| {
            out.extend(if big_endian {
                x.to_be_bytes()
            } else {
                x.to_le_bytes()
            })
        };
        let u = |out: &mut Vec<u8>, x: u32| {
            out.extend(if big_endian {
                x.to_be_bytes()
            } else {
                x.to_le_bytes()
            })
        };
        let verts: [[f32; 7]; 5] = [
            [0., 0., 0., 255., 0.5, 0., 0.],
            [1., 0., 0., 255., 0., 0.25, 0.],
            [1., 1., 0., 0., 0., 0., 1.],
            [0., 1., 0., 0., 0., 0., 0.],
            [2., 2., 2., 7., -1., -1., -1.],
        ];
        for v in verts {
            for (k, &c) in v.iter().enumerate() {
                if k == 3 {
                    out.push(c as u8);
                } else {
                    f(&mut out, c);
                }
            }
        }
        out.push(3);
        for w in [0.5, 0.25, 0.25] {
            f(&mut out, w);
        }
        for face in [&[0u32, 1, 2, 3][..], &[1, 4, 2]] {
            out.push(0);
            out.push(face.len() as u8);
            for &i in face {
                u(&mut out, i);
            }
        }
        out
    }

    #[test]
    fn ascii() {
        check(&parse_ply(ASCII.as_bytes(), Path::new("a.ply")).unwrap());
    }

    #[test]
    fn ascii_crlf() {
        let text = ASCII.replace('\n', "\r\n");
        check(&parse_ply(text.as_bytes(), Path::new("a.ply")).unwrap());
    }

    #[test]
    fn binary_little_endian_f32() {
        check(&parse_ply(&binary(false), Path::new("le.ply")).unwrap());
    }

    #[test]
    fn binary_big_endian_f32() {
        check(&parse_ply(&binary(true), Path::new("be.ply")).unwrap());
    }

    #[test]
    fn all_scalar_types_for_coordinates() {
        for (ty, enc) in [
            (
                "char",
                &(|x: i32| vec![x as i8 as u8]) as &dyn Fn(i32) -> Vec<u8>,
            ),
            ("uint8", &|x| vec![x as u8]),
            ("short", &|x| (x as i16).to_le_bytes().to_vec()),
            ("ushort", &|x| (x as u16).to_le_bytes().to_vec()),
            ("int32", &|x| x.to_le_bytes().to_vec()),
            ("uint", &|x| (x as u32).to_le_bytes().to_vec()),
            ("float32", &|x| (x as f32).to_le_bytes().to_vec()),
            ("double", &|x| (x as f64).to_le_bytes().to_vec()),
        ] {
            let mut b = format!(
                "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty {ty} x\n\
                 property {ty} y\nproperty {ty} z\nelement face 1\n\
                 property list ushort int vertex_indices\nend_header\n"
            )
            .into_bytes();
            for c in [0, 0, 0, 1, 0, 0, 0, 1, 0] {
                b.extend(enc(c));
            }
            b.extend(3u16.to_le_bytes());
            for i in [0i32, 1, 2] {
                b.extend(i.to_le_bytes());
            }
            let d = parse_ply(&b, Path::new("t.ply")).unwrap_or_else(|e| panic!("{ty}: {e}"));
            assert_eq!(d.mesh.positions[2], DVec3::new(0.0, 1.0, 0.0), "{ty}");
            assert_eq!(d.mesh.triangles, vec![[0, 1, 2]], "{ty}");
        }
    }

    /// The same f64 mesh hand-written as ASCII (shortest round-trip decimals)
    /// and big-endian doubles reads back bit for bit, like weft's own
    /// little-endian output.
    #[test]
    fn f64_bit_exact_in_all_three_formats() {
        let p = awkward_positions();
        let t = [[0u32, 1, 2], [0, 2, 3]];
        let header = |fmt: &str| {
            format!(
                "ply\nformat {fmt} 1.0\nelement vertex {}\nproperty double x\n\
                 property double y\nproperty double z\nelement face {}\n\
                 property list uchar int vertex_indices\nend_header\n",
                p.len(),
                t.len()
            )
        };
        let mut ascii = header("ascii");
        for v in &p {
            ascii += &format!("{:?} {:?} {:?}\n", v.x, v.y, v.z);
        }
        for f in &t {
            ascii += &format!("3 {} {} {}\n", f[0], f[1], f[2]);
        }
        let mut be = header("binary_big_endian").into_bytes();
        for v in &p {
            for c in v.to_array() {
                be.extend(c.to_be_bytes());
            }
        }
        for f in &t {
            be.push(3);
            for &i in f {
                be.extend((i as i32).to_be_bytes());
            }
        }
        let le = encode_ply(&p, &t, None);
        for (name, bytes) in [("ascii", ascii.as_bytes()), ("be", &be), ("le", &le)] {
            let d = parse_ply(bytes, Path::new(name)).unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(bits(&d.mesh.positions), bits(&p), "{name}");
            assert_eq!(d.mesh.triangles, t, "{name}");
        }
    }

    #[test]
    fn write_read_round_trip_with_and_without_velocities() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.ply");
        let p = awkward_positions();
        let t = vec![[0, 1, 2], [0, 2, 3]];
        let vel: Vec<DVec3> = p.iter().map(|x| -*x * 0.5).collect();
        for v in [None, Some(vel.as_slice())] {
            write_ply(&path, &p, &t, v).unwrap();
            let bytes = std::fs::read(&path).unwrap();
            assert_eq!(bytes, encode_ply(&p, &t, v), "write_ply writes encode_ply");
            let d = read_ply(&path).unwrap();
            assert_eq!(bits(&d.mesh.positions), bits(&p));
            assert_eq!(d.mesh.triangles, t);
            assert_eq!(d.velocities.as_deref().map(bits), v.map(bits));
        }
    }
}

mod ply_errors {
    use super::*;

    fn good_binary() -> Vec<u8> {
        encode_ply(&[DVec3::ZERO, DVec3::X, DVec3::Y], &[[0, 1, 2]], None)
    }

    #[test]
    fn not_a_ply_file() {
        ply_err(b"solid stl\nfacet\n", &["bad.ply:1:", "not a PLY file"]);
        ply_err(b"", &["bad.ply:1:", "not a PLY file"]);
    }

    #[test]
    fn header_without_end() {
        ply_err(
            b"ply\nformat ascii 1.0\nelement vertex 3\n",
            &["bad.ply:4:", "end_header", "truncated"],
        );
    }

    #[test]
    fn unknown_format() {
        ply_err(
            b"ply\nformat binary_middle_endian 1.0\nend_header\n",
            &["bad.ply:2:", "unknown PLY format \"binary_middle_endian\""],
        );
        ply_err(
            b"ply\nelement vertex 0\nend_header\n",
            &["no \"format\" line"],
        );
    }

    #[test]
    fn bad_header_lines() {
        ply_err(
            b"ply\nformat ascii 1.0\nelement vertex 3\nproperty quad x\nend_header\n",
            &["bad.ply:4:", "unknown property type \"quad\""],
        );
        ply_err(
            b"ply\nformat ascii 1.0\nelement vertex many\nend_header\n",
            &["bad.ply:3:", "invalid count \"many\""],
        );
        ply_err(
            b"ply\nformat ascii 1.0\nproperty float x\nend_header\n",
            &["bad.ply:3:", "before any element"],
        );
        ply_err(
            b"ply\nformat ascii 1.0\nbanana\nend_header\n",
            &["bad.ply:3:", "unrecognised header line \"banana\""],
        );
    }

    #[test]
    fn missing_required_properties() {
        ply_err(
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n0 0\n",
            &["bad.ply:3:", "no \"z\" property"],
        );
        ply_err(
            b"ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\n\
              element face 0\nproperty list uchar int corners\nend_header\n",
            &["bad.ply:7:", "no \"vertex_indices\" list"],
        );
        ply_err(
            b"ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\n\
              property float vx\nend_header\n",
            &["bad.ply:3:", "some but not all"],
        );
    }

    #[test]
    fn truncated_binary_body_names_byte_offset_and_element() {
        let full = good_binary();
        // Cut inside vertex 2's y coordinate.
        let header_len = full.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        let cut = header_len + 2 * 24 + 8 + 3;
        let e = ply_err(
            &full[..cut],
            &[
                "bad.ply:",
                "unexpected end of file at byte",
                "property \"y\" of vertex 2",
            ],
        );
        assert!(matches!(e, IoError::Parse { line: None, .. }));
        assert!(
            e.to_string()
                .contains(&format!("byte {}", header_len + 2 * 24 + 8)),
            "{e}"
        );
        // Cut inside the face list.
        ply_err(
            &full[..full.len() - 2],
            &["item 2 of property \"vertex_indices\" of face 0"],
        );
    }

    #[test]
    fn truncated_ascii_body_names_line() {
        ply_err(
            b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n1 1\n",
            &["bad.ply:9:", "unexpected end of file", "property \"z\" of vertex 1"],
        );
    }

    #[test]
    fn malformed_ascii_value() {
        ply_err(
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 zero 0\n",
            &["bad.ply:8:", "invalid number \"zero\"", "property \"y\" of vertex 0"],
        );
        ply_err(
            b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
              element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n300 0 1 2\n",
            &["bad.ply:13:", "value 300", "out of range", "face 0"],
        );
    }

    #[test]
    fn huge_element_without_properties_is_skipped_quickly() {
        let mut b =
            b"ply\nformat binary_little_endian 1.0\nelement junk 18446744073709551615\n".to_vec();
        let rest = encode_ply(&[DVec3::ZERO, DVec3::X, DVec3::Y], &[[0, 1, 2]], None);
        b.extend(
            rest.strip_prefix(b"ply\nformat binary_little_endian 1.0\n".as_slice())
                .unwrap(),
        );
        let d = parse_ply(&b, Path::new("j.ply")).unwrap();
        assert_eq!(d.mesh.triangles, vec![[0, 1, 2]]);
        // A huge count with properties fails on truncation, not on allocation.
        ply_err(
            b"ply\nformat binary_little_endian 1.0\nelement vertex 18446744073709551615\n\
              property double x\nproperty double y\nproperty double z\nend_header\n",
            &["unexpected end of file at byte", "vertex 0"],
        );
    }

    #[test]
    fn bad_faces() {
        ply_err(
            b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
              element face 2\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n2 0 1\n",
            &["bad.ply:14:", "face 1 (0-based) has 2 vertices"],
        );
        ply_err(
            b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
              element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n",
            &["bad.ply:", "face 0 (0-based) refers to vertex 3", "only 3 vertices"],
        );
        ply_err(
            b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
              element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 -1 2\n",
            &["bad.ply:13:", "face 0 (0-based) has an invalid vertex index -1"],
        );
    }
}

mod round_trip {
    use super::*;

    #[test]
    fn obj_write_then_parse_is_bit_exact() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.obj");
        let p = awkward_positions();
        let t = vec![[0, 1, 2], [0, 2, 3]];
        write_obj(&path, &p, &t).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.contains("v 1e-300 -0.0 "), "{text}");
        let d = read_obj(&path).unwrap();
        assert_eq!(bits(&d.mesh.positions), bits(&p));
        assert_eq!(d.mesh.triangles, t);
        assert_eq!(d.face_lines, vec![6, 7]);
    }

    #[test]
    fn writers_refuse_what_readers_reject() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.obj");
        let mut p = awkward_positions();
        p[1].y = f64::NAN;
        let e = write_obj(&path, &p, &[[0, 1, 2]]).unwrap_err();
        assert!(
            e.to_string().contains("vertex 1 (0-based) is not finite"),
            "{e}"
        );
        let e = write_ply(&dir.path().join("m.ply"), &p[..1], &[[0, 1, 2]], None).unwrap_err();
        assert!(e.to_string().contains("triangle 0 (0-based)"), "{e}");
        let e = write_ply(&dir.path().join("m.ply"), &p[2..], &[], Some(&p[..1])).unwrap_err();
        assert!(e.to_string().contains("1 velocities for 2 vertices"), "{e}");
        assert!(!path.exists() && !dir.path().join("m.ply").exists());
    }

    #[test]
    fn write_mesh_dispatches_on_extension() {
        let dir = tempfile::tempdir().unwrap();
        let p = [DVec3::ZERO, DVec3::X, DVec3::Y];
        for name in ["a.obj", "b.PLY", "c.Obj"] {
            let path = dir.path().join(name);
            write_mesh(&path, &p, &[[0, 1, 2]], None).unwrap();
            let f = read_mesh(&path).unwrap();
            assert_eq!(f.mesh.positions, p);
        }
        let e = write_mesh(&dir.path().join("x.stl"), &p, &[[0, 1, 2]], None).unwrap_err();
        assert!(matches!(e, IoError::UnsupportedFormat { .. }), "{e}");
    }
}

mod read_mesh_validation {
    use super::*;

    fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        p
    }

    #[test]
    fn mesh_error_names_obj_source_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = write(
            dir.path(),
            "deg.obj",
            "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 2 0 0\n\nf 1 2 3\n# collinear:\nf 1 2 4\n",
        );
        let e = read_mesh(&path).unwrap_err();
        assert!(matches!(
            e,
            IoError::Mesh {
                line: Some(8),
                ref mesh,
                ..
            } if matches!(**mesh, MeshError::DegenerateTriangle { triangle: 1, .. })
        ));
        let msg = e.to_string();
        // Elements as the file numbers them: OBJ `v` numbers, faces by line.
        assert!(
            msg.contains("deg.obj:8: the face on line 8 (v 1, v 2, v 4) has zero area"),
            "{msg}"
        );
    }

    #[test]
    fn mesh_error_for_ply_names_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("dup.ply");
        let p = [DVec3::ZERO, DVec3::X, DVec3::Y];
        write_ply(&path, &p, &[[0, 1, 2], [1, 2, 0]], None).unwrap();
        let e = read_mesh(&path).unwrap_err();
        let msg = e.to_string();
        assert!(
            msg.contains("dup.ply: face 1 (vertices 1, 2, 0; 0-based) duplicates face 0"),
            "{msg}"
        );
    }

    #[test]
    fn warnings_are_returned() {
        let dir = tempfile::tempdir().unwrap();
        let path = write(
            dir.path(),
            "w.obj",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 5 5 5\nvt 0 0\nf 1/1 2/1 3/1\n",
        );
        let f = read_mesh(&path).unwrap();
        assert_eq!(
            f.warnings,
            vec![MeshWarning::UnreferencedVertices {
                count: 1,
                first: vec![3]
            }]
        );
        assert_eq!(f.uvs, Some(vec![[0.0, 0.0]]));
        assert_eq!(f.face_uvs, Some(vec![[0, 0, 0]]));
        assert_eq!(f.line_of_triangle(0), Some(6));
    }

    #[test]
    fn empty_obj_is_a_mesh_error() {
        let dir = tempfile::tempdir().unwrap();
        let path = write(dir.path(), "e.obj", "# nothing\nv 0 0 0\n");
        let e = read_mesh(&path).unwrap_err();
        assert!(
            matches!(
                e,
                IoError::Mesh {
                    ref mesh,
                    line: None,
                    ..
                } if **mesh == MeshError::Empty
            ),
            "{e}"
        );
    }

    #[test]
    fn unknown_extension_and_missing_file() {
        let dir = tempfile::tempdir().unwrap();
        let e = read_mesh(&dir.path().join("m.stl")).unwrap_err();
        assert!(
            e.to_string().contains("unsupported mesh format \"stl\""),
            "{e}"
        );
        let e = read_mesh(&dir.path().join("nope.obj")).unwrap_err();
        assert!(
            matches!(e, IoError::Io { .. }) && e.to_string().contains("nope.obj"),
            "{e}"
        );
    }
}

/// Importing third-party meshes: what used to go silently wrong.
mod import {
    use super::*;

    /// Twice the vector area of the triangles of `d` (for a planar polygon:
    /// twice its area, along its normal).
    fn vector_area(d: &weft_io::ObjData) -> DVec3 {
        (0..d.mesh.num_triangles())
            .map(|f| {
                let [a, b, c] = d.mesh.corners(f);
                (b - a).cross(c - a)
            })
            .sum()
    }

    /// What used to happen: `\u{feff}v 0 0 0` was not a `v` record, so every
    /// index shifted by one (here: "vertex index 3 ... out of range").
    #[test]
    fn a_utf8_byte_order_mark_is_skipped() {
        let text = "\u{feff}v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
        let d = obj(text);
        assert_eq!(d.mesh.num_vertices(), 3);
        assert_eq!(d.mesh.triangles, vec![[0, 1, 2]]);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bom.obj");
        std::fs::write(&path, text.as_bytes()).unwrap();
        assert_eq!(read_obj(&path).unwrap().mesh.num_vertices(), 3);
    }

    /// What used to happen: the fan from the first corner ran outside this
    /// arrow (past its reflex corner, v 2) and made an inverted triangle.
    #[test]
    fn a_non_convex_polygon_is_ear_clipped_with_its_uvs() {
        let d = obj("v -4 4 0\nv 0 0 0\nv -4 -4 0\nv 8 0 0\n\
             vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n\
             f 1/1 2/2 3/3 4/4\n");
        assert_eq!(d.mesh.triangles.len(), 2);
        // Both triangles face +z and their areas add up to the arrow's (32).
        for f in 0..2 {
            let [a, b, c] = d.mesh.corners(f);
            assert!((b - a).cross(c - a).z > 0.0, "{:?}", d.mesh.triangles);
        }
        assert_eq!(vector_area(&d), DVec3::new(0.0, 0.0, 64.0));
        // Each texture index travels with its vertex.
        let uvs = d.face_uvs.as_ref().unwrap();
        for (t, uv) in d.mesh.triangles.iter().zip(uvs) {
            assert_eq!(t, uv, "corner k has vt k here");
        }
        assert_eq!(d.face_lines, vec![9, 9]);
    }

    /// What used to happen: the fan from corner 1 made the triangle (1, 2, 3)
    /// of three collinear corners, refused as "triangle 0 ... has zero area".
    #[test]
    fn collinear_corners_make_no_zero_area_triangle() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("square.obj");
        std::fs::write(
            &path,
            "v 0 0 0\nv 1 0 0\nv 2 0 0\nv 2 1 0\nv 2 2 0\nv 1 2 0\nv 0 2 0\nv 0 1 0\n\
             f 1 2 3 4 5 6 7 8\n",
        )
        .unwrap();
        let f = read_mesh(&path).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(f.mesh.num_triangles(), 6);
        for t in 0..6 {
            let [a, b, c] = f.mesh.corners(t);
            assert!((b - a).cross(c - a).z > 0.0, "{:?}", f.mesh.triangles);
        }
    }

    #[test]
    fn a_self_intersecting_polygon_is_refused_naming_its_line_and_vertices() {
        let e = obj_err(
            "v 0 0 0\nv 4 4 0\nv 4 0 0\nv 0 6 0\n# a bow tie\nf 1 2 3 4\n",
            &[
                "bad.obj:6:",
                "the face with 4 corners cannot be triangulated",
                "its edges v 1–v 2 and v 3–v 4 cross",
            ],
        );
        assert!(matches!(e, IoError::Parse { line: Some(6), .. }));
        // Relative indices are named by their `v` numbers too.
        obj_err(
            "v 0 0 0\nv 2 0 0\nv 4 0 0\nf -3 -2 -1 -2\n",
            &["bad.obj:4:", "cannot be triangulated"],
        );
        obj_err(
            "v 0 0 0\nv 1 0 0\nv 2 0 0\nv 3 0 0\nf 1 2 3 4\n",
            &["bad.obj:5:", "zero area: its corners are collinear"],
        );
    }

    /// Triangulating a polygon takes time quadratic in its corners (the
    /// simplicity check, the ear search): a face of 50,000 corners took about
    /// a minute. Faces above 1,000 corners are refused at once, naming the
    /// line and the count; 1,000 corners still triangulate.
    #[test]
    fn a_face_with_too_many_corners_is_refused_at_once() {
        let obj = |n: usize| {
            let mut s = String::new();
            for k in 0..n {
                let a = k as f64 / n as f64 * std::f64::consts::TAU;
                s += &format!("v {} {} 0\n", a.cos(), a.sin());
            }
            s += "f";
            for k in 1..=n {
                s += &format!(" {k}");
            }
            s + "\n"
        };
        let started = std::time::Instant::now();
        let e = obj_err(
            &obj(50_000),
            &[
                "bad.obj:50001:",
                "the face with 50000 corners cannot be triangulated",
                "at most 1000 corners",
            ],
        );
        assert!(matches!(
            e,
            IoError::Parse {
                line: Some(50_001),
                ..
            }
        ));
        obj_err(&obj(1001), &["bad.obj:1002:", "1001 corners"]);
        assert!(started.elapsed().as_secs() < 10, "{:?}", started.elapsed());
        let d = parse_obj(&obj(1000), Path::new("ok.obj")).unwrap();
        assert_eq!(d.mesh.num_triangles(), 998);
    }

    #[test]
    fn ply_polygons_are_ear_clipped_and_refused_alike() {
        let ply = |vertices: &str, faces: &str, count: usize| {
            format!(
                "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n\
                 property float z\nelement face {count}\nproperty list uchar int vertex_indices\n\
                 end_header\n{vertices}{faces}"
            )
        };
        let arrow = "-4 4 0\n0 0 0\n-4 -4 0\n8 0 0\n";
        let d = parse_ply(ply(arrow, "4 0 1 2 3\n", 1).as_bytes(), Path::new("a.ply")).unwrap();
        assert_eq!(d.mesh.num_triangles(), 2);
        assert_eq!(d.face_of_triangle, vec![0, 0]);
        for f in 0..2 {
            let [a, b, c] = d.mesh.corners(f);
            assert!((b - a).cross(c - a).z > 0.0, "{:?}", d.mesh.triangles);
        }
        ply_err(
            ply("0 0 0\n4 4 0\n4 0 0\n0 6 0\n", "3 0 1 2\n4 0 1 2 3\n", 2).as_bytes(),
            &[
                "bad.ply:15:",
                "face 1 (0-based) with 4 corners cannot be triangulated",
                "vertex 0–vertex 1 and vertex 2–vertex 3 cross",
            ],
        );
    }

    /// What used to happen: one stray vertex at 1e30 in a 1 m cloth gave
    /// "triangle 0 ... has zero area (area 1.07e-4, tolerance 1e46)".
    #[test]
    fn a_stray_vertex_far_away_is_named_with_its_obj_number() {
        let src = std::fs::read_to_string(shared_data("meshes/square2K.obj")).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("stray.obj");
        std::fs::write(&path, format!("{src}v 1e30 0 0\n")).unwrap();
        let e = read_mesh(&path).unwrap_err();
        let msg = e.to_string();
        assert!(
            matches!(
                e,
                IoError::Mesh { ref mesh, .. }
                    if matches!(**mesh, MeshError::TooSmallForExtent { far_vertex: 1939, .. })
            ),
            "{msg}"
        );
        assert!(!msg.contains("zero area"), "{msg}");
        assert!(
            msg.contains("too small to resolve in a mesh 1.000e30 m across")
                && msg.contains("v 1940 at (1e30, 0e0, 0e0)"),
            "{msg}"
        );
    }
}

mod atomic {
    use super::*;

    #[test]
    fn replaces_existing_file_and_leaves_no_temporaries() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.bin");
        write_atomic(&path, b"old contents").unwrap();
        write_atomic(&path, b"new").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"new");
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, vec![std::ffi::OsString::from("out.bin")]);
    }

    #[test]
    fn failure_leaves_existing_file_intact() {
        let dir = tempfile::tempdir().unwrap();
        // The target is a non-empty directory: the rename must fail.
        let target = dir.path().join("target");
        std::fs::create_dir(&target).unwrap();
        std::fs::write(target.join("keep"), b"x").unwrap();
        let e = write_atomic(&target, b"data").unwrap_err();
        assert!(e.to_string().contains("target"), "{e}");
        assert_eq!(std::fs::read(target.join("keep")).unwrap(), b"x");
        assert_eq!(
            std::fs::read_dir(dir.path()).unwrap().count(),
            1,
            "temporary removed"
        );
        let e = write_atomic(&dir.path().join("missing/dir/f"), b"data").unwrap_err();
        assert!(matches!(e, IoError::Io { .. }));
    }
}
