//! Writers: OBJ, OFF and PLY. Coordinates are written with Rust's shortest
//! round-trip formatting, so reading a written file gives back the same bits.

use super::PlyEncoding;
use crate::IndexedMesh;
use std::io::{self, Write};

/// Writes `v` and `f` statements (1-based indices).
pub fn write_obj(w: &mut impl Write, mesh: &IndexedMesh) -> io::Result<()> {
    writeln!(w, "# written by raymesh")?;
    for p in &mesh.positions {
        writeln!(w, "v {} {} {}", p.x, p.y, p.z)?;
    }
    for f in mesh.faces() {
        w.write_all(b"f")?;
        for &i in f {
            write!(w, " {}", i + 1)?;
        }
        w.write_all(b"\n")?;
    }
    Ok(())
}

/// Writes an `OFF` file.
pub fn write_off(w: &mut impl Write, mesh: &IndexedMesh) -> io::Result<()> {
    writeln!(w, "OFF\n{} {} 0", mesh.num_vertices(), mesh.num_faces())?;
    for p in &mesh.positions {
        writeln!(w, "{} {} {}", p.x, p.y, p.z)?;
    }
    for f in mesh.faces() {
        write!(w, "{}", f.len())?;
        for &i in f {
            write!(w, " {i}")?;
        }
        w.write_all(b"\n")?;
    }
    Ok(())
}

/// Writes a PLY file with `float` x, y, z and a `vertex_indices` list
/// (`uchar` counts when every face has at most 255 vertices, else `uint`).
pub fn write_ply(w: &mut impl Write, mesh: &IndexedMesh, encoding: PlyEncoding) -> io::Result<()> {
    let format = match encoding {
        PlyEncoding::Ascii => "ascii",
        PlyEncoding::BinaryLittleEndian => "binary_little_endian",
        PlyEncoding::BinaryBigEndian => "binary_big_endian",
    };
    let wide = mesh.faces().any(|f| f.len() > 255);
    let count_ty = if wide { "uint" } else { "uchar" };
    write!(
        w,
        "ply\nformat {format} 1.0\ncomment written by raymesh\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\nelement face {}\n\
         property list {count_ty} int vertex_indices\nend_header\n",
        mesh.num_vertices(),
        mesh.num_faces()
    )?;
    let big = encoding == PlyEncoding::BinaryBigEndian;
    let f32b = |v: f32| {
        if big {
            v.to_be_bytes()
        } else {
            v.to_le_bytes()
        }
    };
    let u32b = |v: u32| {
        if big {
            v.to_be_bytes()
        } else {
            v.to_le_bytes()
        }
    };
    for p in &mesh.positions {
        match encoding {
            PlyEncoding::Ascii => writeln!(w, "{} {} {}", p.x, p.y, p.z)?,
            _ => {
                let mut buf = [0u8; 12];
                buf[0..4].copy_from_slice(&f32b(p.x));
                buf[4..8].copy_from_slice(&f32b(p.y));
                buf[8..12].copy_from_slice(&f32b(p.z));
                w.write_all(&buf)?;
            }
        }
    }
    for f in mesh.faces() {
        match encoding {
            PlyEncoding::Ascii => {
                write!(w, "{}", f.len())?;
                for &i in f {
                    write!(w, " {i}")?;
                }
                w.write_all(b"\n")?;
            }
            _ => {
                if wide {
                    w.write_all(&u32b(f.len() as u32))?;
                } else {
                    w.write_all(&[f.len() as u8])?;
                }
                for &i in f {
                    w.write_all(&u32b(i))?;
                }
            }
        }
    }
    Ok(())
}
