//! OFF reader (Geomview's Object File Format, as CGAL and Princeton's
//! shape benchmark write it): `OFF`, then `nv nf ne`, then one vertex per
//! line and one face per line (`n i0 … in-1`). Colours, normals and texture
//! coordinates after the required values (COFF, NOFF, STOFF) are ignored;
//! `#` starts a comment.

use super::text::{check_count, lines, parse_int, parse_vec3, show, tokens};
use crate::{ErrorKind, IndexedMesh, MeshError};

/// Strips a `#` comment.
fn uncomment(line: &[u8]) -> &[u8] {
    match line.iter().position(|&b| b == b'#') {
        Some(i) => &line[..i],
        None => line,
    }
}

pub(super) fn read(bytes: &[u8]) -> Result<IndexedMesh, MeshError> {
    let mut it = lines(bytes)
        .map(|(n, l)| (n, uncomment(l)))
        .filter(|(_, l)| !l.trim_ascii().is_empty());
    let (hline, header) = it
        .next()
        .ok_or_else(|| MeshError::at_line(1, ErrorKind::Truncated("no OFF header".into())))?;
    let mut htoks = tokens(header);
    let keyword = htoks.next().unwrap_or_default();
    match keyword {
        b"OFF" | b"COFF" | b"NOFF" | b"CNOFF" | b"STOFF" | b"STNOFF" | b"STCOFF" | b"STCNOFF"
        | b"CSTOFF" => {}
        k if k.ends_with(b"OFF") => {
            return Err(MeshError::at_line(
                hline,
                ErrorKind::Unsupported(format!("OFF variant '{}'", show(k))),
            ))
        }
        k => {
            return Err(MeshError::at_line(
                hline,
                ErrorKind::Syntax(format!("expected 'OFF', found '{}'", show(k))),
            ))
        }
    }
    let mut rest: Vec<&[u8]> = htoks.collect();
    if rest.first() == Some(&&b"BINARY"[..]) {
        return Err(MeshError::at_line(
            hline,
            ErrorKind::Unsupported("binary OFF".into()),
        ));
    }
    let mut cline = hline;
    if rest.is_empty() {
        let (n, l) = it.next().ok_or_else(|| {
            MeshError::at_line(
                hline,
                ErrorKind::Truncated("no vertex and face counts".into()),
            )
        })?;
        cline = n;
        rest = tokens(l).collect();
    }
    if rest.len() < 2 {
        return Err(MeshError::at_line(
            cline,
            ErrorKind::Syntax("expected counts 'vertices faces [edges]'".into()),
        ));
    }
    let nv_raw = parse_int(rest[0], cline, "a vertex count")?;
    let nf_raw = parse_int(rest[1], cline, "a face count")?;
    // Absurd counts are errors before anything is allocated: every element
    // takes at least 2 bytes. Smaller shortfalls are reported as truncation
    // where the data ends, and reservations are capped by the file size.
    let nv = check_count(nv_raw, cline, "vertices", bytes.len(), 2)?;
    let nf = check_count(nf_raw, cline, "faces", bytes.len() - 2 * nv, 2)?;
    let cap = bytes.len() / 6;
    let mut mesh = IndexedMesh::with_capacity(nv.min(cap), nf.min(cap), 3 * nf.min(cap));
    let mut last = cline;
    for k in 0..nv {
        let (n, l) = it.next().ok_or_else(|| {
            MeshError::at_line(
                last,
                ErrorKind::Truncated(format!("expected {nv} vertices, found {k}")),
            )
        })?;
        last = n;
        mesh.positions.push(parse_vec3(&mut tokens(l), n)?);
    }
    let mut face = Vec::new();
    for k in 0..nf {
        let (n, l) = it.next().ok_or_else(|| {
            MeshError::at_line(
                last,
                ErrorKind::Truncated(format!("expected {nf} faces, found {k}")),
            )
        })?;
        last = n;
        let mut toks = tokens(l);
        let count = parse_int(toks.next().unwrap_or_default(), n, "a vertex count")?;
        if count < 3 {
            return Err(MeshError::at_line(
                n,
                ErrorKind::FaceTooSmall(count.max(0) as usize),
            ));
        }
        face.clear();
        for j in 0..count {
            let tok = toks.next().ok_or_else(|| {
                MeshError::at_line(
                    n,
                    ErrorKind::Syntax(format!("face announces {count} vertices, found {j}")),
                )
            })?;
            let i = parse_int(tok, n, "a vertex index")?;
            if i < 0 || i as usize >= nv {
                return Err(MeshError::at_line(
                    n,
                    ErrorKind::IndexOutOfRange {
                        index: i,
                        vertices: nv,
                    },
                ));
            }
            face.push(i as u32);
        }
        mesh.push_face_unchecked(&face);
    }
    Ok(mesh)
}
