//! STL reader, ascii and binary. STL stores every triangle's corners
//! separately; corners with bit-identical coordinates are welded into one
//! vertex (with -0.0 taken as 0.0), so that the result has connectivity.

use super::text::{lines, parse_vec3, show, tokens};
use crate::{ErrorKind, IndexedMesh, MeshError};
use raymesh_geometry::Vec3;
use rayon::prelude::*;
use std::collections::HashMap;
use std::sync::atomic::{AtomicU32, Ordering};

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
    // Text, possibly after a byte-order mark (see `strip_bom`).
    let text = super::text::strip_bom(bytes);
    let head = &text[..text.len().min(1024)];
    let looks_text = !head.iter().any(|&b| b == 0 || b > 127);
    if text.trim_ascii_start().starts_with(b"solid") && looks_text {
        return read_ascii(text);
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
        let key = weld_key(p);
        let positions = &mut self.mesh.positions;
        *self.map.entry(key).or_insert_with(|| {
            positions.push(p);
            (positions.len() - 1) as u32
        })
    }
}

/// Byte offset of corner `c` (triangle `c / 3`) of a binary STL.
fn corner_at(c: usize) -> usize {
    84 + 50 * (c / 3) + 12 + 12 * (c % 3)
}

fn read_binary(bytes: &[u8]) -> Result<IndexedMesh, MeshError> {
    let n = triangle_count(bytes) as usize;
    if 3 * n as u64 > u32::MAX as u64 {
        return Err(MeshError::at_byte(
            80,
            ErrorKind::TooLarge(format!(
                "{n} triangles: more corners than 32-bit indices hold"
            )),
        ));
    }
    let f =
        |at: usize| f32::from_le_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]]);
    // Corners are read from the file's bytes where they are, not copied.
    let point = |c: usize| {
        let at = corner_at(c);
        Vec3::new(f(at), f(at + 4), f(at + 8))
    };
    if let Some(c) = (0..3 * n)
        .into_par_iter()
        .position_first(|c| !point(c).is_finite())
    {
        return Err(MeshError::at_byte(
            corner_at(c) as u64,
            ErrorKind::NonFinite(format!("{:?}", point(c))),
        ));
    }
    let (positions, indices) = weld(3 * n, &point);
    let mut mesh = IndexedMesh::with_capacity(0, n, 0);
    mesh.positions = positions;
    mesh.append_triangles_unchecked(indices);
    Ok(mesh)
}

/// Reads a binary STL file as it comes in, `chunk` bytes at a time: the
/// corners are copied out of each chunk in parallel (36 bytes a triangle,
/// where the file takes 50), then welded as [`read`] welds them, so the
/// file is never held whole in memory. Returns `None` for anything else
/// (an ascii file, a size that does not match the triangle count, a
/// corner that is not finite, a file that ends early), so that the
/// whole-file reader, which names the byte, takes it. `progress(bytes,
/// size)` is called after each chunk.
pub(super) fn read_stream(
    file: &mut impl std::io::Read,
    size: u64,
    chunk: usize,
    progress: &mut dyn FnMut(u64, u64),
) -> std::io::Result<Option<IndexedMesh>> {
    use std::io::Read;
    let mut head = Vec::with_capacity(84);
    file.by_ref().take(84).read_to_end(&mut head)?;
    if head.len() < 84 {
        return Ok(None);
    }
    let n = triangle_count(&head) as usize;
    if 84 + 50 * n as u64 != size || 3 * n as u64 > u32::MAX as u64 {
        return Ok(None);
    }
    let per_chunk = (chunk / 50).max(1);
    let mut corners = vec![Vec3::ZERO; 3 * n];
    let mut buf = Vec::with_capacity(per_chunk.min(n) * 50);
    let mut done = 84u64;
    for (k, out) in corners.chunks_mut(3 * per_chunk).enumerate() {
        let tris = out.len() / 3;
        buf.clear();
        if file.by_ref().take(50 * tris as u64).read_to_end(&mut buf)? < 50 * tris {
            return Ok(None);
        }
        let f = |at: usize| f32::from_le_bytes([buf[at], buf[at + 1], buf[at + 2], buf[at + 3]]);
        let finite = out.par_iter_mut().enumerate().all(|(c, p)| {
            let at = 50 * (c / 3) + 12 + 12 * (c % 3);
            *p = Vec3::new(f(at), f(at + 4), f(at + 8));
            p.is_finite()
        });
        if !finite {
            return Ok(None);
        }
        done = 84 + 50 * ((k * per_chunk + tris) as u64);
        progress(done, size);
    }
    let (positions, indices) = weld(3 * n, &|c| corners[c]);
    drop(corners);
    let mut mesh = IndexedMesh::with_capacity(0, n, 0);
    mesh.positions = positions;
    mesh.append_triangles_unchecked(indices);
    progress(size.max(done), size.max(done));
    Ok(Some(mesh))
}

/// The welding key of a point: its bits, with -0.0 taken as 0.0.
#[inline]
fn weld_key(p: Vec3) -> [u32; 3] {
    (p + Vec3::ZERO).to_array().map(f32::to_bits) // -0.0 + 0.0 = +0.0
}

/// Welds bit-identical points in parallel: the vertices in order of first
/// occurrence, and each point's vertex. The same result as welding one
/// point after another ([`Welder`]).
///
/// Points are bucketed by a hash of their key into shards (in increasing
/// index order within each), each shard maps every point to the first
/// point with its key, and a prefix count over those first points numbers
/// the vertices.
fn weld(len: usize, point: &(dyn Fn(usize) -> Vec3 + Sync)) -> (Vec<Vec3>, Vec<u32>) {
    const SHARD_BITS: u32 = 6;
    const SHARDS: usize = 1 << SHARD_BITS;
    const CHUNK: usize = 1 << 16;
    let shard = |k: [u32; 3]| {
        let h = (k[0] as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15)
            ^ (k[1] as u64).wrapping_mul(0xc2b2_ae3d_27d4_eb4f)
            ^ (k[2] as u64).wrapping_mul(0x1656_67b1_9e37_79f9);
        (h.wrapping_mul(0x9e37_79b9_7f4a_7c15) >> (64 - SHARD_BITS)) as usize
    };
    // Per chunk of points, their indices by shard; then each shard's
    // indices in chunk order, so increasing.
    let per_chunk: Vec<Vec<Vec<u32>>> = (0..len.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let mut b = vec![Vec::new(); SHARDS];
            for i in c * CHUNK..((c + 1) * CHUNK).min(len) {
                b[shard(weld_key(point(i)))].push(i as u32);
            }
            b
        })
        .collect();
    // `first[i]`: the first point with point `i`'s key.
    let first: Vec<AtomicU32> = (0..len)
        .into_par_iter()
        .map(|_| AtomicU32::new(0))
        .collect();
    (0..SHARDS).into_par_iter().for_each(|s| {
        let mut map: HashMap<[u32; 3], u32> = HashMap::new();
        for i in per_chunk.iter().flat_map(|b| b[s].iter().copied()) {
            let f = *map.entry(weld_key(point(i as usize))).or_insert(i);
            first[i as usize].store(f, Ordering::Relaxed);
        }
    });
    drop(per_chunk);
    let first: Vec<u32> = first.into_par_iter().map(AtomicU32::into_inner).collect();
    // Number the first points in order: counts per chunk, then offsets.
    let counts: Vec<u32> = first
        .par_chunks(CHUNK)
        .enumerate()
        .map(|(c, ch)| {
            ch.iter()
                .enumerate()
                .filter(|&(k, &f)| f as usize == c * CHUNK + k)
                .count() as u32
        })
        .collect();
    let mut offsets = Vec::with_capacity(counts.len());
    let mut total = 0u32;
    for c in counts {
        offsets.push(total);
        total += c;
    }
    // The vertex of each first point, numbered in order...
    let mut indices = vec![0u32; len];
    indices
        .par_chunks_mut(CHUNK)
        .zip(first.par_chunks(CHUNK))
        .enumerate()
        .for_each(|(c, (v, ch))| {
            let mut next = offsets[c];
            for (k, &f) in ch.iter().enumerate() {
                if f as usize == c * CHUNK + k {
                    v[k] = next;
                    next += 1;
                }
            }
        });
    // ...then every other point takes its first point's (which comes
    // before it, so is already final).
    for (i, &f) in first.iter().enumerate() {
        if f as usize != i {
            indices[i] = indices[f as usize];
        }
    }
    // Each vertex's position is its first point's (as written, -0.0 kept).
    let positions: Vec<Vec3> = (0..len)
        .into_par_iter()
        .filter(|&i| first[i] as usize == i)
        .map(point)
        .collect();
    debug_assert_eq!(positions.len(), total as usize);
    (positions, indices)
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

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// One point after another, as the ascii reader welds.
    fn weld_one_by_one(points: &[Vec3]) -> (Vec<Vec3>, Vec<u32>) {
        let mut w = Welder::new(points.len());
        let idx = points.iter().map(|&p| w.vertex(p)).collect();
        (w.mesh.positions, idx)
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(500))]
        /// Parallel welding numbers vertices as one-by-one welding does,
        /// with many repeats, and -0.0 next to 0.0.
        #[test]
        fn parallel_weld_matches_one_by_one(
            picks in proptest::collection::vec((0usize..12, 0usize..12, 0usize..3), 0..400),
        ) {
            let pool = [0.0f32, -0.0, 1.0, -1.0, 0.5, 3.25, 1e-30, -1e30, 7.0, 2.0, 0.1, 0.3];
            let points: Vec<Vec3> = picks
                .iter()
                .map(|&(a, b, c)| Vec3::new(pool[a], pool[b], pool[c]))
                .collect();
            let (pp, pi) = weld(points.len(), &|i| points[i]);
            let (sp, si) = weld_one_by_one(&points);
            prop_assert_eq!(pi, si);
            let bits = |v: &[Vec3]| v.iter().map(|p| p.to_array().map(f32::to_bits)).collect::<Vec<_>>();
            prop_assert_eq!(bits(&pp), bits(&sp));
        }
    }

    #[test]
    fn a_large_weld_spans_chunks() {
        // 300K points over 1,000 distinct ones: every shard and chunk busy.
        let points: Vec<Vec3> = (0..300_000u32)
            .map(|i| {
                let k = (i.wrapping_mul(2_654_435_761) >> 7) % 1000;
                Vec3::new(k as f32, (k % 7) as f32, -((k % 3) as f32))
            })
            .collect();
        assert_eq!(weld(points.len(), &|i| points[i]), weld_one_by_one(&points));
    }
}
