//! OBJ reader: geometry only. `v x y z [w|r g b]` and `f a b c …` with
//! `v`, `v/vt`, `v//vn` or `v/vt/vn` corners, 1-based or negative (relative)
//! indices, and `\` line continuations. Every other statement (texture
//! coordinates, normals, groups, materials, lines, points) is skipped.

use super::text::{lines, parse_int, parse_vec3, show, tokens};
use crate::{ErrorKind, IndexedMesh, MeshError};

pub(super) fn read(bytes: &[u8]) -> Result<IndexedMesh, MeshError> {
    let mut mesh = IndexedMesh::new();
    // Faces may name vertices defined later; resolve after reading.
    let mut faces: Vec<i64> = Vec::new();
    let mut face_starts: Vec<(usize, u64)> = Vec::new();
    let mut pending: Option<(u64, Vec<u8>)> = None;
    for (n, raw) in lines(bytes) {
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
            Some(b"v") => mesh.positions.push(parse_vec3(&mut toks, lno)?),
            Some(b"f") => {
                face_starts.push((faces.len(), lno));
                let before = faces.len();
                let nv = mesh.positions.len() as i64;
                for tok in toks {
                    let vtok = tok.split(|&b| b == b'/').next().unwrap_or_default();
                    let i = parse_int(vtok, lno, "a vertex index")?;
                    let resolved = match i {
                        0 => {
                            return Err(MeshError::at_line(
                                lno,
                                ErrorKind::Syntax("vertex index 0 (OBJ indices start at 1)".into()),
                            ))
                        }
                        i if i < 0 => {
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
                        }
                        i => i - 1,
                    };
                    faces.push(resolved);
                }
                let count = faces.len() - before;
                if count < 3 {
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
