//! Reader and writer tests: round trips, errors with locations, fuzzing.

use super::*;
use crate::{ErrorKind, IndexedMesh, Location};
use proptest::prelude::*;
use raymesh_geometry::Vec3;
use std::path::PathBuf;

fn data(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/data")
        .join(name)
}

fn sample() -> IndexedMesh {
    let p = vec![
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(1.5, -0.0, 0.1),
        Vec3::new(0.3, 2.25, 1e-7),
        Vec3::new(-1e6, 3.0, 7.125),
        Vec3::new(0.1, 0.2, 0.3),
    ];
    IndexedMesh::from_polygons(p, [&[0u32, 1, 2][..], &[0, 2, 3, 4], &[4, 3, 1]]).unwrap()
}

fn err(bytes: &[u8], f: Format) -> crate::MeshError {
    read_bytes(bytes, f).expect_err("expected an error")
}

/// A binary STL of the given triangles.
fn stl_binary(tris: &[[Vec3; 3]]) -> Vec<u8> {
    let mut b = vec![b' '; 80];
    b.extend_from_slice(&(tris.len() as u32).to_le_bytes());
    for t in tris {
        b.extend_from_slice(&[0u8; 12]);
        for p in t {
            for c in p.to_array() {
                b.extend_from_slice(&c.to_le_bytes());
            }
        }
        b.extend_from_slice(&[0u8; 2]);
    }
    b
}

#[test]
fn round_trips_keep_every_bit() {
    let m = sample();
    let mut obj = Vec::new();
    write_obj(&mut obj, &m).unwrap();
    assert_eq!(read_bytes(&obj, Format::Obj).unwrap(), m);
    let mut off = Vec::new();
    write_off(&mut off, &m).unwrap();
    assert_eq!(read_bytes(&off, Format::Off).unwrap(), m);
    for enc in [
        PlyEncoding::Ascii,
        PlyEncoding::BinaryLittleEndian,
        PlyEncoding::BinaryBigEndian,
    ] {
        let mut ply = Vec::new();
        write_ply(&mut ply, &m, enc).unwrap();
        assert_eq!(read_bytes(&ply, Format::Ply).unwrap(), m, "{enc:?}");
    }
}

/// Large binary PLYs take the parallel fixed-record path: the same mesh
/// as the ascii reading; a quad among the triangles, a NaN or a bad index
/// deep in the file still come out as the one-record reader has them,
/// errors with their byte offsets.
#[test]
fn large_binary_ply_reads_in_parallel_and_still_reports_errors() {
    let m = crate::synthetic::terrain(20_000).into_indexed();
    let (nv, nf) = (m.num_vertices(), m.num_faces());
    let mut ascii = Vec::new();
    write_ply(&mut ascii, &m, PlyEncoding::Ascii).unwrap();
    assert_eq!(read_bytes(&ascii, Format::Ply).unwrap(), m);
    for enc in [
        PlyEncoding::BinaryLittleEndian,
        PlyEncoding::BinaryBigEndian,
    ] {
        let big = enc == PlyEncoding::BinaryBigEndian;
        let mut b = Vec::new();
        write_ply(&mut b, &m, enc).unwrap();
        assert_eq!(read_bytes(&b, Format::Ply).unwrap(), m, "{enc:?}");
        let put = |b: &mut Vec<u8>, at: usize, v: [u8; 4]| {
            let v = if big { [v[3], v[2], v[1], v[0]] } else { v };
            b[at..at + 4].copy_from_slice(&v);
        };
        let data = b.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        let faces = data + 12 * nv;
        assert_eq!(b.len(), faces + 13 * nf);

        let mut bad = b.clone();
        put(&mut bad, data + 5000 * 12 + 4, f32::NAN.to_le_bytes());
        let e = err(&bad, Format::Ply);
        assert!(matches!(e.kind, ErrorKind::NonFinite(_)), "{e}");
        assert_eq!(e.location, Location::Byte((data + 5000 * 12) as u64));

        let mut bad = b.clone();
        put(
            &mut bad,
            faces + 7000 * 13 + 1 + 4,
            (nv as u32).to_le_bytes(),
        );
        let e = err(&bad, Format::Ply);
        assert!(matches!(e.kind, ErrorKind::IndexOutOfRange { .. }), "{e}");
        assert_eq!(e.location, Location::Byte((faces + 7000 * 13) as u64));
    }
    // A quad after thousands of triangles.
    let mut faces: Vec<Vec<u32>> = m.faces().map(<[u32]>::to_vec).collect();
    faces.insert(6000, vec![0, 1, 2, 3]);
    let q =
        IndexedMesh::from_polygons(m.positions.clone(), faces.iter().map(Vec::as_slice)).unwrap();
    let mut b = Vec::new();
    write_ply(&mut b, &q, PlyEncoding::BinaryLittleEndian).unwrap();
    assert_eq!(read_bytes(&b, Format::Ply).unwrap(), q);
}

#[test]
fn write_mesh_by_extension_and_read_back() {
    // Removed when it goes out of scope, whether the test passes or not.
    let tmp = tempfile::Builder::new()
        .prefix("raymesh-io-")
        .tempdir()
        .unwrap();
    let dir = tmp.path();
    for ext in ["obj", "off", "ply"] {
        let path = dir.join(format!("m.{ext}"));
        write_mesh(&path, &sample()).unwrap();
        assert_eq!(read_mesh(&path).unwrap(), sample());
    }
    assert!(write_mesh(dir.join("m.stl"), &sample()).is_err());
    // Errors of writing say so, with the path (they said "cannot read").
    let e = write_mesh(dir.join("m.xyz"), &sample())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("m.xyz") && e.contains(".obj, .off or .ply"),
        "{e}"
    );
    let missing = dir.join("no-such-folder").join("m.off");
    let e = write_mesh(&missing, &sample()).unwrap_err();
    assert!(matches!(e.kind, ErrorKind::Write(_)), "{e:?}");
    assert!(e.to_string().contains("m.off: cannot write"), "{e}");
}

#[test]
fn stl_binary_and_ascii_weld_corners() {
    let (a, b, c, d) = (Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z);
    let tris = [[a, c, b], [a, b, d], [a, d, c], [b, c, d]];
    let m = read_bytes(&stl_binary(&tris), Format::Stl).unwrap();
    assert_eq!((m.num_vertices(), m.num_faces()), (4, 4));
    let mut ascii = String::from("solid t\n");
    for t in &tris {
        ascii += "  facet normal 0 0 0\n    outer loop\n";
        for p in t {
            ascii += &format!("      vertex {} {} {}\n", p.x, p.y, p.z);
        }
        ascii += "    endloop\n  endfacet\n";
    }
    ascii += "endsolid t\n";
    let m2 = read_bytes(ascii.as_bytes(), Format::Stl).unwrap();
    assert_eq!(m, m2);
    // -0.0 and 0.0 weld.
    let m3 = read_bytes(
        &stl_binary(&[[a, b, c], [Vec3::new(-0.0, 0.0, 0.0), c, d]]),
        Format::Stl,
    )
    .unwrap();
    assert_eq!(m3.num_vertices(), 4);
}

#[test]
fn obj_features() {
    let src = b"# comment\nmtllib x.mtl\no thing\nv 0 0 0\nv 1 0 0 1\nv 0 1 0 0.5 0.5 0.5\nvt 0 0\nvn 0 0 1\n\
                g grp\nusemtl m\ns off\nf 1/1/1 2/1/1 3/1/1\nf -3//1 -2//1 -1//1\nf 1 2 \\\n 3\nl 1 2\n";
    let m = read_bytes(src, Format::Obj).unwrap();
    assert_eq!(m.num_vertices(), 3);
    assert_eq!(m.num_faces(), 3);
    assert!(m.faces().all(|f| f == [0, 1, 2]));
    // Forward references resolve once the file is read.
    let m = read_bytes(b"f 1 2 3\nv 0 0 0\nv 1 0 0\nv 0 1 0\n", Format::Obj).unwrap();
    assert_eq!(m.num_faces(), 1);
}

#[test]
fn off_features() {
    let m = read_bytes(
        b"OFF 3 1 0\n# c\n0 0 0\n1 0 0 # c\n0 1 0\n\n3 0 1 2 255 0 0\n",
        Format::Off,
    )
    .unwrap();
    assert_eq!((m.num_vertices(), m.num_faces()), (3, 1));
    let m = read_bytes(
        b"COFF\n3 1 3\n0 0 0 1 1 1 1\n1 0 0 1 1 1 1\n0 1 0 1 1 1 1\n3 0 1 2\n",
        Format::Off,
    )
    .unwrap();
    assert_eq!(m.num_faces(), 1);
}

/// Each malformed input gives the right error at the right place.
#[test]
fn errors_name_what_and_where() {
    let cases: Vec<(&[u8], Format, Location, &str)> = vec![
        (b"OFF\n3 1 0\n0 0 0\n1 0 0\n", Format::Off, Location::Line(4), "expected 3 vertices, found 2"),
        (b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n", Format::Off, Location::Line(6), "vertex index 3 out of range"),
        (b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n2 0 1\n", Format::Off, Location::Line(6), "face with 2 vertices"),
        (b"OFF\n3 1 0\n0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n", Format::Off, Location::Line(4), "non-finite"),
        (b"OFF\n3 1 0\n0 0 0\n1 inf 0\n0 1 0\n3 0 1 2\n", Format::Off, Location::Line(4), "non-finite"),
        (b"OFF\n3 1 0\n0 0 0\n1 1e39 0\n0 1 0\n3 0 1 2\n", Format::Off, Location::Line(4), "non-finite"),
        (b"OFF\n3 1000000000000 0\n0 0 0\n", Format::Off, Location::Line(2), "cannot fit"),
        (b"OFF\n3 1 0\n0 0 0\n1 0 x\n", Format::Off, Location::Line(4), "expected a number, found 'x'"),
        (b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n4 0 1 2\n", Format::Off, Location::Line(6), "announces 4 vertices, found 3"),
        (b"4OFF\n", Format::Off, Location::Line(1), "unsupported"),
        (b"OOF\n", Format::Off, Location::Line(1), "expected 'OFF'"),
        (b"v 0 0 0\nv 1 0 0\nf 1 2 3\n", Format::Obj, Location::Line(3), "vertex index 3 out of range"),
        (b"v 0 0 0\nv 1 0 0\nf 1 2 -3\n", Format::Obj, Location::Line(3), "vertex index -3 out of range"),
        (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", Format::Obj, Location::Line(4), "index 0"),
        (b"v 0 0 0\nv 1 0 0\nf 1 2\n", Format::Obj, Location::Line(3), "face with 2 vertices"),
        (b"v 0 0\n", Format::Obj, Location::Line(1), "expected 3 coordinates, found 2"),
        (b"v 0 0 NaN\n", Format::Obj, Location::Line(1), "non-finite"),
        (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 5\n",
            Format::Ply, Location::Line(13), "vertex index 5 out of range"),
        (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n1 0 0\n",
            Format::Ply, Location::Line(10), "truncated"),
        (b"ply\nformat ascii 1.0\nelement vertex 1000000000000\nproperty float x\nend_header\n0\n", Format::Ply, Location::Line(3), "element count"),
        (b"ply\nformat ascii 1.0\nelement vertex 100000\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n", Format::Ply, Location::Line(3), "cannot fit"),
        (b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0",
            Format::Ply, Location::Line(3), "cannot fit"),
        (b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n\0\0\0\0\0\0\0\0\0\0\0\0\x03\0\0\0\0",
            Format::Ply, Location::Byte(186), "need 4 more bytes"),
        (b"ply\nformat ascii 2.0x\n", Format::Ply, Location::Line(2), "no 'end_header'"),
        (b"ply\nformat foo 1.0\nend_header\n", Format::Ply, Location::Line(2), "unknown format 'foo'"),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n0\n", Format::Ply, Location::Line(3), "no 'y' property"),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty flot x\nend_header\n", Format::Ply, Location::Line(4), "unknown property type 'flot'"),
        (b"solid x\nfacet normal 0 0 0\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nendloop\n", Format::Stl, Location::Line(6), "face with 2 vertices"),
        (b"solid x\nfacet normal 0 0 0\nouter loop\nvertex 0 0 0\n", Format::Stl, Location::Line(5), "not closed"),
        (b"solid x\nbanana\n", Format::Stl, Location::Line(2), "unexpected 'banana'"),
        (b"\0\0\0\0", Format::Stl, Location::Byte(4), "84-byte header"),
        (b"   \n\t", Format::Obj, Location::File, "empty"),
    ];
    for (bytes, f, loc, msg) in cases {
        let e = err(bytes, f);
        let text = e.to_string();
        assert_eq!(
            e.location,
            loc,
            "{text} for {:?}",
            String::from_utf8_lossy(bytes)
        );
        assert!(text.contains(msg), "'{text}' lacks '{msg}'");
    }
    // A binary STL whose count disagrees with its size.
    let mut b = stl_binary(&[[Vec3::ZERO, Vec3::X, Vec3::Y]]);
    b.truncate(b.len() - 1);
    let e = err(&b, Format::Stl);
    assert!(e.to_string().contains("announces 1 triangles"), "{e}");
    let mut b = stl_binary(&[[Vec3::ZERO, Vec3::X, Vec3::new(f32::NAN, 0.0, 0.0)]]);
    b[80] = 1;
    assert!(matches!(err(&b, Format::Stl).kind, ErrorKind::NonFinite(_)));
}

#[test]
fn read_mesh_names_the_file() {
    let e = read_mesh(data("does-not-exist.off")).unwrap_err();
    assert!(
        e.to_string().contains("does-not-exist.off: cannot read"),
        "{e}"
    );
    // Removed when it goes out of scope, whether the test passes or not.
    let tmp = tempfile::Builder::new()
        .prefix("raymesh-err-")
        .tempdir()
        .unwrap();
    let dir = tmp.path();
    let p = dir.join("bad.off");
    std::fs::write(&p, b"OFF\n3 1 0\n0 0 0\n").unwrap();
    let e = read_mesh(&p).unwrap_err();
    assert!(
        e.to_string()
            .starts_with(&format!("{}:3: truncated", p.display())),
        "{e}"
    );
    let p = dir.join("thing.xyz");
    std::fs::write(&p, b"hello").unwrap();
    let e = read_mesh(&p).unwrap_err();
    assert!(
        e.to_string()
            .contains("unknown mesh format (extension .xyz)"),
        "{e}"
    );
    let p = dir.join("sniffed");
    std::fs::write(&p, b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n").unwrap();
    assert_eq!(read_mesh(&p).unwrap().num_faces(), 1);
}

/// Every fixture in the repository loads with the counts its header gives.
#[test]
fn fixtures_load_with_header_counts() {
    for (name, v, f) in [
        ("tetrahedron.off", 4, 4),
        ("cube_quad.off", 8, 6),
        ("degtri_sliding.off", 8, 8),
        ("mesh_with_border.off", 548, 1014),
        ("double-torus-example.off", 231, 220),
        ("elephant-with-holes.off", 2798, 4463),
        ("sphere.ply", 162, 320),
    ] {
        let m = read_mesh(data(name)).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!((m.num_vertices(), m.num_faces()), (v, f), "{name}");
    }
    let m = read_mesh(data("cube_quad.off")).unwrap();
    assert_eq!(m.num_triangles(), 12);
}

/// The real meshes of `../shared/meshes`, when that folder is there (it is in CI).
#[test]
fn shared_meshes_load_with_header_counts() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/meshes");
    if !dir.is_dir() {
        eprintln!("skipping: {} not found", dir.display());
        return;
    }
    let mut seen = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        let Some(fmt) = Format::from_extension(&path) else {
            continue;
        };
        let m = read_mesh(&path).unwrap_or_else(|e| panic!("{e}"));
        let bytes = std::fs::read(&path).unwrap();
        let expected: Option<(usize, usize)> = match fmt {
            Format::Off => {
                let text = String::from_utf8_lossy(&bytes);
                let mut toks = text.split_whitespace().skip(1);
                Some((
                    toks.next().unwrap().parse().unwrap(),
                    toks.next().unwrap().parse().unwrap(),
                ))
            }
            Format::Ply => {
                let text = String::from_utf8_lossy(&bytes[..bytes.len().min(2000)]);
                let count = |el: &str| {
                    text.lines()
                        .find_map(|l| l.strip_prefix(&format!("element {el} ")))
                        .map(|c| c.trim().parse().unwrap())
                        .unwrap_or(0)
                };
                Some((count("vertex"), count("face")))
            }
            Format::Stl => Some((
                m.num_vertices(),
                u32::from_le_bytes(bytes[80..84].try_into().unwrap()) as usize,
            )),
            Format::Obj => None,
        };
        if let Some((v, f)) = expected {
            assert_eq!(
                (m.num_vertices(), m.num_faces()),
                (v, f),
                "{}",
                path.display()
            );
        }
        seen += 1;
    }
    assert!(seen >= 10, "only {seen} meshes found");
}

/// Valid files of every format, to mutate.
fn seeds() -> Vec<(Vec<u8>, Format)> {
    let m = sample();
    let mut out = Vec::new();
    let mut b = Vec::new();
    write_obj(&mut b, &m).unwrap();
    out.push((b, Format::Obj));
    let mut b = Vec::new();
    write_off(&mut b, &m).unwrap();
    out.push((b, Format::Off));
    for enc in [
        PlyEncoding::Ascii,
        PlyEncoding::BinaryLittleEndian,
        PlyEncoding::BinaryBigEndian,
    ] {
        let mut b = Vec::new();
        write_ply(&mut b, &m, enc).unwrap();
        out.push((b, Format::Ply));
    }
    out.push((
        stl_binary(&[[Vec3::ZERO, Vec3::X, Vec3::Y], [Vec3::X, Vec3::Y, Vec3::Z]]),
        Format::Stl,
    ));
    out.push((std::fs::read(data("sphere.ply")).unwrap(), Format::Ply));
    out.push((std::fs::read(data("cube_quad.off")).unwrap(), Format::Off));
    // Triangles only, with extra properties and elements: the streamed reader's form.
    let t = crate::synthetic::terrain(40).into_indexed();
    out.push((odd_ply(&t, false, 2, 1), Format::Ply));
    out.push((odd_ply(&t, true, 0, 0), Format::Ply));
    out
}

/// A binary PLY of a triangle mesh laid out unlike `write_ply`'s: `x` as
/// a double among other vertex properties, `uint` indices after a
/// `uchar` count, `comments` comment lines, and an `edge` element of
/// scalars before the vertices and a `material` element after the faces
/// when `extra > 0` (`extra` records each).
fn odd_ply(m: &IndexedMesh, big: bool, comments: usize, extra: usize) -> Vec<u8> {
    let enc = if big { "big" } else { "little" };
    let mut h = format!("ply\nformat binary_{enc}_endian 1.0\n");
    for i in 0..comments {
        h.push_str(&format!("comment padding line {i} {}\n", "-".repeat(60)));
    }
    if extra > 0 {
        h.push_str(&format!(
            "element edge {extra}\nproperty int a\nproperty short b\n"
        ));
    }
    h.push_str(&format!(
        "element vertex {}\nproperty uchar red\nproperty double x\nproperty float y\nproperty short s\nproperty float z\n",
        m.num_vertices()
    ));
    h.push_str(&format!(
        "element face {}\nproperty list uchar uint vertex_indices\n",
        m.num_faces()
    ));
    if extra > 0 {
        h.push_str(&format!("element material {extra}\nproperty float shine\n"));
    }
    h.push_str("end_header\n");
    let mut b = h.into_bytes();
    let put = |b: &mut Vec<u8>, bytes: &[u8]| {
        if big {
            b.extend(bytes.iter().rev());
        } else {
            b.extend_from_slice(bytes);
        }
    };
    for i in 0..extra {
        put(&mut b, &(i as i32).to_le_bytes());
        put(&mut b, &(-(i as i16)).to_le_bytes());
    }
    for (i, p) in m.positions.iter().enumerate() {
        b.push(i as u8);
        put(&mut b, &f64::from(p.x).to_le_bytes());
        put(&mut b, &p.y.to_le_bytes());
        put(&mut b, &(i as i16).to_le_bytes());
        put(&mut b, &p.z.to_le_bytes());
    }
    for f in m.faces() {
        b.push(f.len() as u8);
        for &i in f {
            put(&mut b, &i.to_le_bytes());
        }
    }
    for i in 0..extra {
        put(&mut b, &(i as f32).to_le_bytes());
    }
    b
}

/// A random OFF file: header forms, comments and blank lines, vertex lines
/// with extra values or a NaN, faces of 2–4 corners in and out of range,
/// lines after the last face, CRLF or LF.
fn off_text() -> impl Strategy<Value = String> {
    let vertex = prop_oneof![
        6 => (-3i32..3, -3i32..3, -3i32..3).prop_map(|(x, y, z)| format!("{x} {y}.5 {z}")),
        1 => Just("1 2 3 0.5 0.5 0.5 1".to_string()),
        1 => Just("1 nan 2".to_string()),
        1 => Just("1 2".to_string()),
    ];
    let face = prop_oneof![
        6 => proptest::collection::vec(0i64..6, 3..5).prop_map(|v| {
            let c: Vec<String> = v.iter().map(i64::to_string).collect();
            format!("{} {}", v.len(), c.join(" "))
        }),
        1 => Just("3 0 1 9".to_string()),
        1 => Just("2 0 1".to_string()),
        1 => Just("4 0 1 2".to_string()),
        1 => Just("3 0 1 2 255 0 0".to_string()),
    ];
    let noise = prop_oneof![
        Just(String::new()),
        Just("# a comment 3 0 1 2".to_string()),
        Just("   ".to_string()),
    ];
    (
        prop_oneof![
            Just("OFF"),
            Just("COFF"),
            Just("OFF 6 4 0"),
            Just("NOFF 6 4"),
            Just("OF")
        ],
        proptest::collection::vec(vertex, 4..8),
        proptest::collection::vec(face, 2..6),
        proptest::collection::vec(noise, 0..4),
        any::<bool>(),
        0usize..3,
    )
        .prop_map(|(head, vs, fs, noise, crlf, extra)| {
            let mut lines = vec![head.to_string()];
            if !head.contains(' ') && head != "OF" {
                lines.push(format!("{} {} 0", 6, 4));
            }
            lines.extend(noise.iter().cloned());
            lines.extend(vs);
            lines.extend(noise);
            lines.extend(fs);
            lines.extend((0..extra).map(|_| "3 0 1 2".to_string()));
            lines.join(if crlf { "\r\n" } else { "\n" })
        })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, failure_persistence: None, ..ProptestConfig::default() })]

    /// Streamed OFF reading, in chunks of any size, gives one pass's mesh
    /// for every file one pass reads (progress rising to the file's size),
    /// and nothing, for the whole-file reader to report, for every file it
    /// rejects.
    #[test]
    fn streamed_off_reads_what_one_pass_reads(text in off_text(), chunk in 1usize..64) {
        let one = read_bytes(text.as_bytes(), Format::Off).ok();
        let size = text.len() as u64;
        let mut calls = Vec::new();
        let got = off::read_stream(&mut text.as_bytes(), size, chunk, &mut |d, t| calls.push((d, t)))
            .unwrap();
        prop_assert!(calls.windows(2).all(|w| w[0].0 <= w[1].0));
        if got.is_some() {
            prop_assert_eq!(calls.last(), Some(&(size, size)));
        }
        prop_assert_eq!(got, one);
    }
}

/// A large OFF file streams in chunks into the mesh one pass makes, and
/// `read_mesh` on good and bad OFF files gives what `read_bytes` gives.
#[test]
fn off_files_stream_and_read_as_their_bytes_do() {
    let m = crate::synthetic::terrain(5000).into_indexed();
    let mut good = Vec::new();
    write_off(&mut good, &m).unwrap();
    assert_eq!(read_bytes(&good, Format::Off).unwrap(), m);
    for chunk in [1, 7, 1000, 1 << 20] {
        let got = off::read_stream(&mut &good[..], good.len() as u64, chunk, &mut |_, _| {});
        assert_eq!(got.unwrap().as_ref(), Some(&m), "chunk {chunk}");
    }
    let text = String::from_utf8(good).unwrap();
    let cases = [
        text.clone(),
        text.replacen("3 0 ", "3 0 99999999 ", 1),
        text.replacen("\n3 ", "\n2 ", 1),
        text[..text.len() - 20].to_string(),
        text.replacen("OFF", "OFX", 1),
        text.replacen("OFF", "OFF BINARY", 1),
    ];
    for (k, t) in cases.iter().enumerate() {
        let read = file_reads_as_bytes("case.off", Format::Off, t.as_bytes(), &format!("case {k}"));
        assert_eq!(read, k == 0, "case {k}");
    }
}

/// Writes `bytes` to a file named `name` (its extension picks the format)
/// and checks that `read_mesh` on it gives what `read_bytes` gives in
/// `format`: the same mesh, or the same error at the same place. Returns
/// whether it read. `what` names the case in a failure.
fn file_reads_as_bytes(name: &str, format: Format, bytes: &[u8], what: &str) -> bool {
    // Removed when it goes out of scope, whether the test passes or not.
    let tmp = tempfile::Builder::new()
        .prefix(&format!("raymesh-file-{name}-"))
        .tempdir()
        .unwrap();
    let dir = tmp.path();
    let path = dir.join(name);
    std::fs::write(&path, bytes).unwrap();
    let from_file = read_mesh(&path).map_err(|e| (e.kind.to_string(), e.location));
    let from_bytes = read_bytes(bytes, format).map_err(|e| (e.kind.to_string(), e.location));
    assert!(
        from_file == from_bytes,
        "{what}: {:?} vs {:?}",
        from_file.as_ref().err(),
        from_bytes.err()
    );
    from_file.is_ok()
}

/// The streamed PLY reader on `bytes`, `chunk` bytes at a time.
fn streamed(bytes: &[u8], chunk: usize) -> Option<IndexedMesh> {
    streamed_as(bytes, chunk, Format::Ply)
}

/// The streamed reader of `format` on `bytes`, `chunk` bytes at a time;
/// checks that its progress rises to the file's size.
fn streamed_as(bytes: &[u8], chunk: usize, format: Format) -> Option<IndexedMesh> {
    let mut calls = Vec::new();
    let size = bytes.len() as u64;
    let mut progress = |d, t| calls.push((d, t));
    let got = match format {
        Format::Ply => ply::read_stream(&mut &bytes[..], size, chunk, &mut progress),
        Format::Stl => stl::read_stream(&mut &bytes[..], size, chunk, &mut progress),
        Format::Obj => obj::read_stream(&mut &bytes[..], size, chunk, &mut progress),
        Format::Off => off::read_stream(&mut &bytes[..], size, chunk, &mut progress),
    }
    .expect("reading from memory cannot fail");
    if got.is_some() {
        assert!(calls.windows(2).all(|w| w[0].0 <= w[1].0), "{calls:?}");
        assert_eq!(calls.last(), Some(&(size, size)));
    }
    got
}

/// Binary PLYs of triangles are read as they stream in, chunk by chunk,
/// into exactly the mesh the whole-file reader makes: both byte orders,
/// any scalar types, properties and elements read past, a header longer
/// than the first read, records cut anywhere by the chunks.
#[test]
fn streamed_ply_reads_what_the_whole_file_reader_reads() {
    for n in [1, 30, 5000] {
        let m = crate::synthetic::terrain(n).into_indexed();
        for big in [false, true] {
            let enc = if big {
                PlyEncoding::BinaryBigEndian
            } else {
                PlyEncoding::BinaryLittleEndian
            };
            let mut plain = Vec::new();
            write_ply(&mut plain, &m, enc).unwrap();
            // 1000 comment lines push `end_header` past the first 64 KiB read.
            for (bytes, what) in [
                (plain, "write_ply"),
                (odd_ply(&m, big, 3, 7), "odd"),
                (odd_ply(&m, big, 1000, 2), "long header"),
            ] {
                let whole = read_bytes(&bytes, Format::Ply).unwrap();
                assert_eq!(whole, m);
                for chunk in [1, 13, 1000, 1 << 20] {
                    assert_eq!(
                        streamed(&bytes, chunk).as_ref(),
                        Some(&whole),
                        "{n} triangles, {enc:?}, {what}, chunk {chunk}"
                    );
                }
            }
        }
    }
}

/// OBJ files stream too: `read_mesh` on a file gives what `read_bytes`
/// gives, the mesh or the error with its line, for good files and bad
/// (the streamed reader leaves every bad one to the whole-file reader).
#[test]
fn obj_files_read_as_their_bytes_do() {
    let mut good = String::new();
    for i in 0..3000 {
        good.push_str(&format!("v {i} {} 0\n", i % 5));
    }
    for i in 1..2999 {
        good.push_str(&format!("f {i} {} -1 \\\n  {}\n", i + 1, i % 7 + 1));
    }
    let cases = [
        good.clone(),
        format!("{good}f 1 2 3001\n"),
        format!("{good}f 1 2 -3001\n"),
        format!("{good}f 1 2 0\n"),
        format!("{good}wh@t 1 2\n"),
        format!("{good}v 1 nan 2\n"),
        "f 1 2 3\n".to_string(),
        "# nothing\n".to_string(),
    ];
    for (k, text) in cases.iter().enumerate() {
        let read = file_reads_as_bytes(
            "case.obj",
            Format::Obj,
            text.as_bytes(),
            &format!("case {k}"),
        );
        assert_eq!(read, k == 0, "case {k}");
    }
}

/// A pipe is read once, by the whole-file reader: a streamed reading
/// that gave up midway could not start over. A broken binary PLY through a
/// named pipe gives the error its bytes give.
#[cfg(unix)]
#[test]
fn pipes_are_read_once() {
    // Removed when it goes out of scope, whether the test passes or not.
    let tmp = tempfile::Builder::new()
        .prefix("raymesh-pipe-")
        .tempdir()
        .unwrap();
    let dir = tmp.path();
    let path = dir.join("mesh.ply");
    let made = std::process::Command::new("mkfifo").arg(&path).status();
    if !made.is_ok_and(|s| s.success()) {
        return; // no mkfifo here: nothing to test
    }
    let m = crate::synthetic::terrain(200).into_indexed();
    let mut b = Vec::new();
    write_ply(&mut b, &m, PlyEncoding::BinaryLittleEndian).unwrap();
    let data = b.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    b[data + 7 * 12..data + 7 * 12 + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    let want = read_bytes(&b, Format::Ply).map_err(|e| (e.kind.to_string(), e.location));
    let writer = {
        let (path, b) = (path.clone(), b.clone());
        std::thread::spawn(move || std::fs::write(path, b).unwrap())
    };
    let got = read_mesh(&path).map_err(|e| (e.kind.to_string(), e.location));
    writer.join().unwrap();
    assert!(want.is_err());
    assert_eq!(got, want);
}

/// Binary STL files are read as they stream in, chunk by chunk, and
/// welded into exactly the mesh the whole-file reader makes: shared
/// corners, -0.0 and 0.0, duplicate triangles, records cut anywhere by
/// the chunks. Anything else goes to the whole-file reader, whose errors
/// `read_mesh` then gives.
#[test]
fn streamed_stl_welds_what_the_whole_file_reader_welds() {
    let mut meshes: Vec<Vec<[Vec3; 3]>> = [1, 30, 5000]
        .iter()
        .map(|&n| {
            let m = crate::synthetic::terrain(n).into_indexed();
            m.triangles()
                .iter()
                .map(|t| t.map(|i| m.positions[i as usize]))
                .collect()
        })
        .collect();
    let z = Vec3::new(-0.0, 0.0, -0.0);
    meshes.push(vec![
        [z, Vec3::X, Vec3::Y],
        [Vec3::ZERO, Vec3::Y, Vec3::X],
        [z, Vec3::X, Vec3::Y],
    ]);
    for tris in &meshes {
        let bytes = stl_binary(tris);
        let whole = read_bytes(&bytes, Format::Stl).unwrap();
        assert_eq!(whole.num_faces(), tris.len());
        for chunk in [1, 49, 50, 120, 1 << 20] {
            assert_eq!(
                streamed_as(&bytes, chunk, Format::Stl).as_ref(),
                Some(&whole),
                "{} triangles, chunk {chunk}",
                tris.len()
            );
        }
    }
    let b = stl_binary(&meshes[1]);
    let edit = |at: usize, v: &[u8]| {
        let mut c = b.clone();
        c[at..at + v.len()].copy_from_slice(v);
        c
    };
    let mut ascii = b"solid x\nfacet normal 0 0 1\nouter loop\n".to_vec();
    ascii.extend_from_slice(
        b"vertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\nendfacet\nendsolid x\n",
    );
    let cases: Vec<(&str, Vec<u8>)> = vec![
        ("ascii", ascii),
        (
            "NaN",
            edit(84 + 50 * 7 + 12 + 12 + 4, &f32::NAN.to_le_bytes()),
        ),
        (
            "infinite",
            edit(84 + 50 * 29 + 12 + 8, &f32::INFINITY.to_le_bytes()),
        ),
        ("truncated", b[..b.len() - 1].to_vec()),
        ("a count too high", edit(80, &31u32.to_le_bytes())),
        ("short", b[..50].to_vec()),
        ("empty", Vec::new()),
    ];
    for (what, bytes) in &cases {
        for chunk in [7, 1 << 20] {
            assert_eq!(
                streamed_as(bytes, chunk, Format::Stl),
                None,
                "{what}, chunk {chunk}"
            );
        }
        file_reads_as_bytes("case.stl", Format::Stl, bytes, what);
    }
    // A file that shrinks while it is read (its size said more) ends the stream too.
    let short = &b[..b.len() - 50];
    let got = stl::read_stream(&mut &short[..], b.len() as u64, 100, &mut |_, _| {}).unwrap();
    assert_eq!(got, None);
}

/// Whatever the streamed reader cannot take whole it leaves to the
/// whole-file reader (it returns `None`), so that errors keep their byte
/// offsets and polygons still load; `read_mesh` then gives what
/// `read_bytes` gives.
#[test]
fn streamed_ply_leaves_the_rest_to_the_whole_file_reader() {
    let m = crate::synthetic::terrain(200).into_indexed();
    let (nv, nf) = (m.num_vertices(), m.num_faces());
    let mut b = Vec::new();
    write_ply(&mut b, &m, PlyEncoding::BinaryLittleEndian).unwrap();
    let data = b.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    let faces = data + 12 * nv;
    assert_eq!(b.len(), faces + 13 * nf);
    let mut ascii = Vec::new();
    write_ply(&mut ascii, &m, PlyEncoding::Ascii).unwrap();
    let mut quads = Vec::new();
    write_ply(&mut quads, &sample(), PlyEncoding::BinaryLittleEndian).unwrap();
    let edit = |at: usize, v: &[u8]| {
        let mut c = b.clone();
        c[at..at + v.len()].copy_from_slice(v);
        c
    };
    let cases: Vec<(&str, Vec<u8>)> = vec![
        ("ascii", ascii),
        ("a quad", quads),
        ("NaN", edit(data + 40 * 12 + 4, &f32::NAN.to_le_bytes())),
        (
            "bad index",
            edit(faces + 70 * 13 + 5, &(nv as u32).to_le_bytes()),
        ),
        ("truncated", b[..b.len() - 5].to_vec()),
        ("no end_header", b[..data - 11].to_vec()),
        ("empty", Vec::new()),
        (
            "a list in another element",
            String::from_utf8_lossy(&b[..data])
                .replace(
                    "end_header",
                    "element x 0
property list uchar int y
end_header",
                )
                .into_bytes(),
        ),
    ];
    for (what, bytes) in &cases {
        for chunk in [7, 1 << 20] {
            assert_eq!(streamed(bytes, chunk), None, "{what}, chunk {chunk}");
        }
        file_reads_as_bytes("case.ply", Format::Ply, bytes, what);
    }
    // A file that shrinks while it is read (its size said more) ends the stream too.
    let short = &b[..b.len() - 5];
    let size = b.len() as u64;
    for chunk in [7, 1 << 20] {
        let got = ply::read_stream(&mut &short[..], size, chunk, &mut |_, _| {}).unwrap();
        assert_eq!(got, None, "chunk {chunk}");
    }
}

/// Replays the inputs that once made a reader fail (kept in tests/data/fuzz).
#[test]
fn fuzz_regressions() {
    let dir = data("fuzz");
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        let bytes = std::fs::read(&path).unwrap();
        for f in [Format::Obj, Format::Off, Format::Ply, Format::Stl] {
            let _ = read_bytes(&bytes, f);
        }
    }
}

/// Number of fuzz cases; raise with `RAYMESH_FUZZ_CASES` for a long run.
fn fuzz_cases() -> u32 {
    std::env::var("RAYMESH_FUZZ_CASES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(3000)
}

/// A mutation of a byte string: flip, insert, delete, truncate, or splice a token.
#[derive(Clone, Debug)]
enum Mutation {
    Set(usize, u8),
    Insert(usize, Vec<u8>),
    Delete(usize, usize),
    Truncate(usize),
}

fn mutation() -> impl Strategy<Value = Mutation> {
    let tokens = prop_oneof![
        Just(b"-1".to_vec()),
        Just(b"4294967295".to_vec()),
        Just(b"99999999999999".to_vec()),
        Just(b"nan".to_vec()),
        Just(b"inf".to_vec()),
        Just(b"\n".to_vec()),
        Just(b" ".to_vec()),
        Just(b"end_header\n".to_vec()),
        Just(b"element face 5\n".to_vec()),
        Just(b"property list uchar int x\n".to_vec()),
        Just(vec![0xff, 0xff, 0xff, 0x7f]),
        Just(b"f 1 2\n".to_vec()),
        proptest::collection::vec(any::<u8>(), 1..8),
    ];
    prop_oneof![
        (any::<usize>(), any::<u8>()).prop_map(|(i, b)| Mutation::Set(i, b)),
        (any::<usize>(), tokens).prop_map(|(i, t)| Mutation::Insert(i, t)),
        (any::<usize>(), 1usize..16).prop_map(|(i, n)| Mutation::Delete(i, n)),
        any::<usize>().prop_map(Mutation::Truncate),
    ]
}

fn apply(bytes: &mut Vec<u8>, m: &Mutation) {
    let len = bytes.len().max(1);
    match m {
        Mutation::Set(i, b) => {
            if !bytes.is_empty() {
                let i = i % bytes.len();
                bytes[i] = *b;
            }
        }
        Mutation::Insert(i, t) => {
            let i = i % (bytes.len() + 1);
            bytes.splice(i..i, t.iter().copied());
        }
        Mutation::Delete(i, n) => {
            let i = i % len;
            let end = (i + n).min(bytes.len());
            if i < end {
                bytes.drain(i..end);
            }
        }
        Mutation::Truncate(i) => bytes.truncate(i % len),
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: fuzz_cases(), failure_persistence: None, ..ProptestConfig::default() })]

    /// Random bytes never make any reader panic.
    #[test]
    fn fuzz_random_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..600), f in 0usize..4) {
        let format = [Format::Obj, Format::Off, Format::Ply, Format::Stl][f];
        let _ = read_bytes(&bytes, format);
        let _ = Format::sniff(&bytes);
    }

    /// Mutated valid files never make a reader panic, and whatever they
    /// return is a valid mesh (every index in range, every face of 3+).
    #[test]
    fn fuzz_mutated_files(seed in 0usize..11, muts in proptest::collection::vec(mutation(), 1..6), chunk in 1usize..200) {
        let seeds = seeds();
        let (mut bytes, format) = seeds[seed % seeds.len()].clone();
        for m in &muts {
            apply(&mut bytes, m);
        }
        let whole = read_bytes(&bytes, format);
        // The streamed readers never disagree with the whole-file ones.
        if let Some(m) = streamed_as(&bytes, chunk, format) {
            prop_assert_eq!(Some(&m), whole.as_ref().ok());
        }
        if let Ok(mesh) = whole {
            let nv = mesh.num_vertices();
            for f in mesh.faces() {
                prop_assert!(f.len() >= 3);
                prop_assert!(f.iter().all(|&i| (i as usize) < nv));
            }
            prop_assert!(mesh.positions.iter().all(|p| p.is_finite()));
        }
    }
}

/// Reading reports progress chunk by chunk, ending at the file's size, and
/// gives the same mesh as reading without a callback.
#[test]
fn read_mesh_with_reports_progress_to_the_end() {
    // Removed when it goes out of scope, whether the test passes or not.
    let tmp = tempfile::Builder::new()
        .prefix("raymesh-progress-")
        .tempdir()
        .unwrap();
    let dir = tmp.path();
    // An OFF file of about 17 MiB: three chunks.
    let mut text = String::from("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n");
    while text.len() < 17 << 20 {
        text.push_str("# padding padding padding padding padding padding padding\n");
    }
    let path = dir.join("big.off");
    std::fs::write(&path, &text).unwrap();
    let mut calls = Vec::new();
    let mesh = read_mesh_with(&path, &mut |done, total| calls.push((done, total))).unwrap();
    let size = text.len() as u64;
    assert!(calls.len() >= 3, "{calls:?}");
    assert!(calls.windows(2).all(|w| w[0].0 <= w[1].0), "{calls:?}");
    assert!(calls.iter().all(|&(d, t)| t == size && d <= t), "{calls:?}");
    assert_eq!(calls.last(), Some(&(size, size)));
    assert_eq!(mesh.triangles(), vec![[0, 1, 2]]);
}

/// A file that starts with a UTF-8 byte-order mark (as some Windows tools
/// write text) reads as the same file without it, in every format, by
/// the whole-file readers, the streamed ones at any chunk size, and with
/// the format sniffed from the content; errors keep their lines, and a
/// binary PLY's byte offsets stay the file's (three more).
#[test]
fn a_byte_order_mark_is_read_past() {
    let m = sample();
    let mut files: Vec<(Format, Vec<u8>)> = Vec::new();
    for f in [Format::Obj, Format::Off] {
        let mut b = Vec::new();
        if f == Format::Obj {
            write_obj(&mut b, &m).unwrap();
        } else {
            write_off(&mut b, &m).unwrap();
        }
        files.push((f, b));
    }
    for enc in [PlyEncoding::Ascii, PlyEncoding::BinaryLittleEndian] {
        let mut b = Vec::new();
        write_ply(&mut b, &m, enc).unwrap();
        files.push((Format::Ply, b));
    }
    files.push((
        Format::Stl,
        b"solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\n\
          endloop\nendfacet\nendsolid t\n"
            .to_vec(),
    ));
    for (f, plain) in &files {
        let marked = [text::BOM, plain].concat();
        let want = read_bytes(plain, *f).unwrap();
        assert_eq!(read_bytes(&marked, *f).unwrap(), want, "{f:?}");
        assert_eq!(Format::sniff(&marked), Some(*f), "{f:?}");
        for chunk in [1, 2, 3, 4, 7, 64, 1 << 20] {
            let (a, b) = (
                streamed_as(&marked, chunk, *f),
                streamed_as(plain, chunk, *f),
            );
            assert_eq!(a, b, "{f:?}, chunks of {chunk}");
        }
    }
    // Errors: the same line; a binary PLY's offset three bytes on.
    let bad: [(&[u8], Format); 2] = [
        (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", Format::Obj),
        (b"OFF\n3 1 0\n0 0 0\n1 0 0\nx 1 0\n3 0 1 2\n", Format::Off),
    ];
    for (bytes, f) in bad {
        let (a, b) = (err(bytes, f), err(&[text::BOM, bytes].concat(), f));
        assert_eq!(
            (a.location, a.kind.to_string()),
            (b.location, b.kind.to_string()),
            "{f:?}"
        );
    }
    let (_, ply) = &files[3];
    let cut = &ply[..ply.len() - 2];
    let (a, b) = (
        err(cut, Format::Ply),
        err(&[text::BOM, cut].concat(), Format::Ply),
    );
    let (Location::Byte(x), Location::Byte(y)) = (a.location, b.location) else {
        panic!("{a} / {b}")
    };
    assert_eq!((y, b.kind.to_string()), (x + 3, a.kind.to_string()));
    // A mark elsewhere is no mark: still an error.
    assert!(read_bytes(
        &[b"v 0 0 0\n", text::BOM, b"v 1 0 0\n"].concat(),
        Format::Obj
    )
    .is_err());
}
