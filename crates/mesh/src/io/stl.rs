//! STL reader, ascii and binary. STL stores every triangle's corners
//! separately; corners with bit-identical coordinates are welded into one
//! vertex (with -0.0 taken as 0.0), so that the result has connectivity.

use super::text::{lines, parse_vec3, show, tokens};
use crate::{ErrorKind, IndexedMesh, MeshError};
use raymesh_geometry::Vec3;
use std::collections::HashMap;

/// Whether the bytes are a binary STL: 80-byte header, triangle count, and
/// exactly 50 bytes per triangle after it.
pub(super) fn is_binary(bytes: &[u8]) -> bool {
    bytes.len() >= 84 && 84 + 50 * triangle_count(bytes) as u64 == bytes.len() as u64
}

fn triangle_count(bytes: &[u8]) -> u32 {
    u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]])
}

pub(super) fn read(bytes: &[u8]) -> Result<IndexedMesh, MeshError> {
    if is_binary(bytes) {
        return read_binary(bytes);
    }
    let head = &bytes[..bytes.len().min(1024)];
    let looks_text = !head.iter().any(|&b| b == 0 || b > 127);
    if bytes.trim_ascii_start().starts_with(b"solid") && looks_text {
        return read_ascii(bytes);
    }
    if bytes.len() < 84 {
        return Err(MeshError::at_byte(
            bytes.len() as u64,
            ErrorKind::Truncated(format!(
                "binary STL needs an 84-byte header, the file has {} bytes",
                bytes.len()
            )),
        ));
    }
    let n = triangle_count(bytes) as u64;
    Err(MeshError::at_byte(
        80,
        ErrorKind::Truncated(format!(
            "binary STL announces {n} triangles ({} bytes), the file has {} bytes",
            84 + 50 * n,
            bytes.len()
        )),
    ))
}

/// Welds corners into shared vertices by exact coordinates.
struct Welder {
    mesh: IndexedMesh,
    map: HashMap<[u32; 3], u32>,
}

impl Welder {
    fn new(triangles: usize) -> Self {
        Self {
            mesh: IndexedMesh::with_capacity(triangles / 2 + 3, triangles, 3 * triangles),
            map: HashMap::with_capacity(triangles / 2 + 3),
        }
    }

    fn vertex(&mut self, p: Vec3) -> u32 {
        let key = (p + Vec3::ZERO).to_array().map(f32::to_bits); // -0.0 + 0.0 = +0.0
        let positions = &mut self.mesh.positions;
        *self.map.entry(key).or_insert_with(|| {
            positions.push(p);
            (positions.len() - 1) as u32
        })
    }
}

fn read_binary(bytes: &[u8]) -> Result<IndexedMesh, MeshError> {
    let n = triangle_count(bytes) as usize;
    let mut w = Welder::new(n);
    for t in 0..n {
        let off = 84 + 50 * t;
        let mut face = [0u32; 3];
        for (c, slot) in face.iter_mut().enumerate() {
            let at = off + 12 + 12 * c;
            let f = |k: usize| {
                f32::from_le_bytes(bytes[at + 4 * k..at + 4 * k + 4].try_into().unwrap())
            };
            let p = Vec3::new(f(0), f(1), f(2));
            if !p.is_finite() {
                return Err(MeshError::at_byte(
                    at as u64,
                    ErrorKind::NonFinite(format!("{p:?}")),
                ));
            }
            *slot = w.vertex(p);
        }
        w.mesh.push_face_unchecked(&face);
    }
    Ok(w.mesh)
}

fn read_ascii(bytes: &[u8]) -> Result<IndexedMesh, MeshError> {
    let mut w = Welder::new(bytes.len() / 256);
    let mut corners: Vec<u32> = Vec::with_capacity(3);
    let mut in_loop = false;
    let mut last = 1;
    for (n, l) in lines(bytes) {
        last = n;
        let mut toks = tokens(l);
        match toks.next() {
            None => {}
            Some(b"solid") | Some(b"endsolid") | Some(b"facet") | Some(b"endfacet") => {}
            Some(b"outer") => {
                in_loop = true;
                corners.clear();
            }
            Some(b"vertex") => {
                if !in_loop {
                    return Err(MeshError::at_line(
                        n,
                        ErrorKind::Syntax("'vertex' outside 'outer loop'".into()),
                    ));
                }
                let p = parse_vec3(&mut toks, n)?;
                corners.push(w.vertex(p));
            }
            Some(b"endloop") => {
                if corners.len() < 3 {
                    return Err(MeshError::at_line(
                        n,
                        ErrorKind::FaceTooSmall(corners.len()),
                    ));
                }
                w.mesh.push_face_unchecked(&corners);
                in_loop = false;
            }
            Some(t) => {
                return Err(MeshError::at_line(
                    n,
                    ErrorKind::Syntax(format!("unexpected '{}' in ascii STL", show(t))),
                ))
            }
        }
    }
    if in_loop {
        return Err(MeshError::at_line(
            last,
            ErrorKind::Truncated("a facet is not closed".into()),
        ));
    }
    Ok(w.mesh)
}
