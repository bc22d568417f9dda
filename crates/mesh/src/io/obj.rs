//! OBJ reader: geometry only. `v x y z [w|r g b]` and `f a b c …` with
//! `v`, `v/vt`, `v//vn` or `v/vt/vn` corners, 1-based or negative (relative)
//! indices, and `\` line continuations. Every other statement (texture
//! coordinates, normals, groups, materials, lines, points) is skipped.

use super::text::{lines, parse_int, parse_vec3, pieces, read_lines, show, strip_bom, tokens, BOM};
use crate::{ErrorKind, IndexedMesh, MeshError};
use raymesh_geometry::Vec3;
use rayon::prelude::*;

/// Files larger than this are split at line ends into chunks of about
/// this size, parsed in parallel.
const CHUNK: usize = 1 << 20;

pub(super) fn read(bytes: &[u8]) -> Result<IndexedMesh, MeshError> {
    read_chunked(strip_bom(bytes), CHUNK)
}

/// One chunk's statements, parsed up to its first error (if any).
#[derive(Default)]
struct Chunk {
    positions: Vec<Vec3>,
    /// Face corners as written: 1-based, or negative (relative to the
    /// vertices before the face), never 0.
    corners: Vec<i64>,
    /// Per face: where its corners start, its line, and how many of this
    /// chunk's vertices come before it.
    faces: Vec<(usize, u64, usize)>,
    error: Option<MeshError>,
}

/// Whether a line (without its `\n`) continues on the next (`\` last).
fn continues(line: &[u8]) -> bool {
    line.strip_suffix(b"\r").unwrap_or(line).ends_with(b"\\")
}

/// Reads an OBJ file as it comes in, about `chunk` bytes at a time: each
/// chunk is split at line ends into pieces parsed in parallel, and their
/// vertices and faces go into the mesh at once. The peak is the mesh plus
/// one chunk's parse, where reading the whole file first holds the file
/// and every face's corners as written. Returns `None` for anything wrong
/// (an error, an index out of range, no vertex), so that the whole-file
/// reader, which names the line, takes it. `progress(bytes, size)` is
/// called after each chunk.
pub(super) fn read_stream(
    file: &mut impl std::io::Read,
    size: u64,
    chunk: usize,
    progress: &mut dyn FnMut(u64, u64),
) -> std::io::Result<Option<IndexedMesh>> {
    let chunk = chunk.max(1);
    let mut mesh = IndexedMesh::with_capacity(0, 0, 0);
    let (mut buf, mut face) = (Vec::new(), Vec::new());
    let (mut done, mut max_index) = (0u64, 0u32);
    loop {
        let Some((mut end, eof)) = read_lines(file, &mut buf, chunk, continues)? else {
            continue;
        };
        if done == 0 && buf.starts_with(BOM) {
            // A byte-order mark (see `strip_bom`), counted as read.
            buf.drain(..BOM.len());
            (end, done) = (end - BOM.len(), BOM.len() as u64);
        }
        // Line numbers only matter to errors, which the whole-file reader reports.
        let parsed: Vec<Chunk> = pieces(&buf[..end], (chunk / 8).max(1), continues)
            .par_iter()
            .map(|piece| parse_chunk(piece, 0))
            .collect();
        for c in parsed {
            if c.error.is_some() {
                return Ok(None);
            }
            let base = mesh.positions.len() as i64;
            for (k, &(start, _, nv_local)) in c.faces.iter().enumerate() {
                let stop = c.faces.get(k + 1).map_or(c.corners.len(), |f| f.0);
                let nv = base + nv_local as i64;
                face.clear();
                for &i in &c.corners[start..stop] {
                    let resolved = if i < 0 { nv + i } else { i - 1 };
                    let Ok(v) = u32::try_from(resolved) else {
                        return Ok(None);
                    };
                    max_index = max_index.max(v);
                    face.push(v);
                }
                mesh.push_face_unchecked(&face);
            }
            mesh.positions.extend_from_slice(&c.positions);
        }
        done += end as u64;
        buf.drain(..end);
        progress(done, size.max(done));
        if eof {
            break;
        }
    }
    let nv = mesh.positions.len();
    // Indices may name vertices further on; all must exist by the end.
    if nv == 0 || max_index as usize >= nv {
        return Ok(None);
    }
    Ok(Some(mesh))
}

/// Reads `bytes` in chunks of about `chunk` bytes, in parallel; the result,
/// errors included, is what one pass over the file gives.
fn read_chunked(bytes: &[u8], chunk: usize) -> Result<IndexedMesh, MeshError> {
    // Each piece with the number of lines before it.
    let mut line = 0u64;
    let pieces: Vec<(&[u8], u64)> = pieces(bytes, chunk, continues)
        .into_iter()
        .map(|piece| {
            let first = line;
            line += piece.iter().filter(|&&b| b == b'\n').count() as u64;
            (piece, first)
        })
        .collect();
    let chunks: Vec<Chunk> = pieces
        .par_iter()
        .map(|&(piece, first_line)| parse_chunk(piece, first_line))
        .collect();

    // In file order: resolve relative indices against the vertices before
    // each face, and stop at the first error, as one pass would.
    let total_v: usize = chunks.iter().map(|c| c.positions.len()).sum();
    let mut mesh = IndexedMesh::with_capacity(total_v, 0, 0);
    let mut faces: Vec<i64> = Vec::new();
    let mut face_starts: Vec<(usize, u64)> = Vec::new();
    for c in chunks {
        let base = mesh.positions.len() as i64;
        for (k, &(start, lno, nv_local)) in c.faces.iter().enumerate() {
            let end = c.faces.get(k + 1).map_or(c.corners.len(), |f| f.0);
            face_starts.push((faces.len(), lno));
            let nv = base + nv_local as i64;
            for &i in &c.corners[start..end] {
                let resolved = if i < 0 {
                    if -i > nv {
                        return Err(MeshError::at_line(
                            lno,
                            ErrorKind::IndexOutOfRange {
                                index: i,
                                vertices: nv as usize,
                            },
                        ));
                    }
                    nv + i
                } else {
                    i - 1
                };
                faces.push(resolved);
            }
        }
        if let Some(e) = c.error {
            return Err(e);
        }
        mesh.positions.extend_from_slice(&c.positions);
    }
    let nv = mesh.positions.len();
    face_starts.push((faces.len(), 0));
    let mut face = Vec::new();
    for w in face_starts.windows(2) {
        let ((start, lno), (end, _)) = (w[0], w[1]);
        face.clear();
        for &i in &faces[start..end] {
            if i as usize >= nv {
                return Err(MeshError::at_line(
                    lno,
                    ErrorKind::IndexOutOfRange {
                        index: i + 1,
                        vertices: nv,
                    },
                ));
            }
            face.push(i as u32);
        }
        mesh.push_face_unchecked(&face);
    }
    if nv == 0 {
        return Err(MeshError::at_line(
            1,
            ErrorKind::Syntax("no 'v' statement: not an OBJ mesh".into()),
        ));
    }
    Ok(mesh)
}

/// Parses the statements of one piece of the file, whose first line is
/// line `first_line + 1`, up to its first error.
fn parse_chunk(bytes: &[u8], first_line: u64) -> Chunk {
    let mut c = Chunk::default();
    if let Err(e) = parse_into(&mut c, bytes, first_line) {
        c.error = Some(e);
    }
    c
}

fn parse_into(c: &mut Chunk, bytes: &[u8], first_line: u64) -> Result<(), MeshError> {
    let mut pending: Option<(u64, Vec<u8>)> = None;
    for (n, raw) in lines(bytes) {
        let n = n + first_line;
        let owned;
        let (line, lno): (&[u8], u64) = match pending.take() {
            Some((first, mut buf)) => {
                buf.extend_from_slice(raw);
                owned = buf;
                (&owned, first)
            }
            None => (raw, n),
        };
        if let Some(head) = line.strip_suffix(b"\\") {
            let mut buf = head.to_vec();
            buf.push(b' ');
            pending = Some((lno, buf));
            continue;
        }
        let line = match line.iter().position(|&b| b == b'#') {
            Some(i) => &line[..i],
            None => line,
        };
        let mut toks = tokens(line);
        match toks.next() {
            Some(b"v") => c.positions.push(parse_vec3(&mut toks, lno)?),
            Some(b"f") => {
                let before = c.corners.len();
                c.faces.push((before, lno, c.positions.len()));
                for tok in toks {
                    let vtok = tok.split(|&b| b == b'/').next().unwrap_or_default();
                    let i = parse_int(vtok, lno, "a vertex index")?;
                    if i == 0 {
                        return Err(MeshError::at_line(
                            lno,
                            ErrorKind::Syntax("vertex index 0 (OBJ indices start at 1)".into()),
                        ));
                    }
                    c.corners.push(i);
                }
                let count = c.corners.len() - before;
                if count < 3 {
                    // The face stays: one pass would report a relative
                    // index out of range in it first, and so does the merge.
                    return Err(MeshError::at_line(lno, ErrorKind::FaceTooSmall(count)));
                }
            }
            // vt, vn, vp, g, o, s, l, p, usemtl, mtllib, ...: not geometry we keep.
            Some(t) if t.iter().all(|b| b.is_ascii_alphanumeric() || *b == b'_') => {}
            Some(t) => {
                return Err(MeshError::at_line(
                    lno,
                    ErrorKind::Syntax(format!("unknown statement '{}'", show(t))),
                ))
            }
            None => {}
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// What a reading gives, comparable: the mesh, or the error's text
    /// (which names the line and what is wrong).
    fn outcome(r: Result<IndexedMesh, MeshError>) -> Result<IndexedMesh, String> {
        r.map_err(|e| e.to_string())
    }

    fn statement() -> impl Strategy<Value = String> {
        let idx = prop_oneof![-6i64..8, Just(0i64), Just(100), Just(-100)];
        prop_oneof![
            4 => (-3.0f32..3.0, -3.0f32..3.0, -3.0f32..3.0)
                .prop_map(|(x, y, z)| format!("v {x} {y} {z}")),
            4 => proptest::collection::vec(idx, 1..5).prop_map(|v| {
                let c: Vec<String> = v.iter().map(|i| format!("{i}/1")).collect();
                format!("f {}", c.join(" "))
            }),
            1 => Just("vt 0.5 0.5".to_string()),
            1 => Just("# a comment f 1 2 3".to_string()),
            1 => Just(String::new()),
            1 => Just("v 1 2 \\".to_string()),
            1 => Just("f 1 2 \\".to_string()),
            1 => Just("v 1 nan 2".to_string()),
            1 => Just("f 1 x 2".to_string()),
            1 => Just("what?".to_string()),
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2000))]
        /// Any chunking reads what one pass reads: the same mesh, or the
        /// same first error at the same line.
        #[test]
        fn chunked_reading_matches_one_pass(
            lines in proptest::collection::vec(statement(), 0..40),
            crlf in any::<bool>(),
            chunk in 1usize..64,
        ) {
            let text = lines.join(if crlf { "\r\n" } else { "\n" });
            let one = outcome(read_chunked(text.as_bytes(), usize::MAX));
            let many = outcome(read_chunked(text.as_bytes(), chunk));
            prop_assert_eq!(&one, &many);
            // Streamed in chunks: the same mesh for every file one pass
            // reads (progress rising to the file's size), and nothing, for
            // the whole-file reader to report, for every file it rejects.
            let size = text.len() as u64;
            let mut calls = Vec::new();
            let streamed = read_stream(&mut text.as_bytes(), size, chunk, &mut |d, t| calls.push((d, t)))
                .unwrap();
            prop_assert!(calls.windows(2).all(|w| w[0].0 <= w[1].0));
            if streamed.is_some() {
                prop_assert_eq!(calls.last(), Some(&(size, size)));
            }
            prop_assert_eq!(streamed, one.ok());
        }
    }

    #[test]
    fn a_large_file_reads_in_chunks_with_the_right_lines() {
        let mut text = String::new();
        for i in 0..30_000 {
            text.push_str(&format!("v {i} 0 {}\n", i % 7));
        }
        for i in 0..20_000 {
            text.push_str(&format!("f {} {} -1\n", i + 1, i + 2));
        }
        let m = read_chunked(text.as_bytes(), 4096).unwrap();
        assert_eq!(m, read_chunked(text.as_bytes(), usize::MAX).unwrap());
        for chunk in [1000, 4096, 1 << 20] {
            let streamed = read_stream(
                &mut text.as_bytes(),
                text.len() as u64,
                chunk,
                &mut |_, _| {},
            );
            assert_eq!(streamed.unwrap().as_ref(), Some(&m), "chunk {chunk}");
        }
        assert_eq!((m.num_vertices(), m.num_faces()), (30_000, 20_000));
        assert_eq!(m.face(5), &[5, 6, 29_999]);
        // An error deep in the file names its line.
        text.push_str("f 1 2 40000\n");
        let e = read_chunked(text.as_bytes(), 4096).unwrap_err();
        assert!(
            e.to_string().contains(":50001:") || e.to_string().contains("50001"),
            "{e}"
        );
    }
}
