//! OFF reader (Geomview's Object File Format, as CGAL and Princeton's
//! shape benchmark write it): `OFF`, then `nv nf ne`, then one vertex per
//! line and one face per line (`n i0 … in-1`). Colours, normals and texture
//! coordinates after the required values (COFF, NOFF, STOFF) are ignored;
//! `#` starts a comment.

use super::text::{
    check_count, lines, parse_int, parse_vec3, pieces, read_lines, show, strip_bom, tokens, BOM,
};
use crate::{ErrorKind, IndexedMesh, MeshError};
use raymesh_geometry::Vec3;
use rayon::prelude::*;

/// Strips a `#` comment.
fn uncomment(line: &[u8]) -> &[u8] {
    match line.iter().position(|&b| b == b'#') {
        Some(i) => &line[..i],
        None => line,
    }
}

/// Reads the header (the keyword, and the counts on its line or the
/// next) from the file's records (lines with text after comments are
/// stripped): the vertex and face counts, checked against `size`, the
/// file's bytes, and the line they were on.
fn header<'a>(
    it: &mut impl Iterator<Item = (u64, &'a [u8])>,
    size: usize,
) -> Result<(usize, usize, u64), MeshError> {
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
    let nv = check_count(nv_raw, cline, "vertices", size, 2)?;
    let nf = check_count(nf_raw, cline, "faces", size - 2 * nv, 2)?;
    Ok((nv, nf, cline))
}

/// Parses face line `l` (line `n`) of a mesh of `nv` vertices into `face`.
fn parse_face(l: &[u8], n: u64, nv: usize, face: &mut Vec<u32>) -> Result<(), MeshError> {
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
    Ok(())
}

/// The records of `bytes`: its lines with comments stripped, blank ones left out.
fn records(bytes: &[u8]) -> impl Iterator<Item = (u64, &[u8])> {
    lines(bytes)
        .map(|(n, l)| (n, uncomment(l)))
        .filter(|(_, l)| !l.trim_ascii().is_empty())
}

pub(super) fn read(bytes: &[u8]) -> Result<IndexedMesh, MeshError> {
    let bytes = strip_bom(bytes);
    let mut it = records(bytes);
    let (nv, nf, cline) = header(&mut it, bytes.len())?;
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
        parse_face(l, n, nv, &mut face)?;
        mesh.push_face_unchecked(&face);
    }
    Ok(mesh)
}

/// One piece's records, parsed: vertices, then faces (sizes and indices).
#[derive(Default)]
struct Piece {
    positions: Vec<Vec3>,
    sizes: Vec<u32>,
    indices: Vec<u32>,
}

/// Reads an OFF file as it comes in, about `chunk` bytes at a time: each
/// chunk's lines are split into pieces, their records counted, then
/// parsed in parallel (a record is a vertex or a face by its number) and
/// put in the mesh, so the file is never held whole in memory. Returns
/// `None` for anything wrong (the whole-file reader, which names the
/// line, takes it). `progress(bytes, size)` is called after each chunk.
pub(super) fn read_stream(
    file: &mut impl std::io::Read,
    size: u64,
    chunk: usize,
    progress: &mut dyn FnMut(u64, u64),
) -> std::io::Result<Option<IndexedMesh>> {
    let chunk = chunk.max(1);
    let Ok(size_bytes) = usize::try_from(size) else {
        return Ok(None);
    };
    let mut buf = Vec::new();
    let mut counts = None;
    let mut mesh = IndexedMesh::with_capacity(0, 0, 0);
    let (mut done, mut record) = (0u64, 0usize);
    loop {
        // Complete lines only (OFF lines do not continue).
        let Some((mut end, eof)) = read_lines(file, &mut buf, chunk, |_| false)? else {
            continue;
        };
        if done == 0 && counts.is_none() && buf.starts_with(BOM) {
            // A byte-order mark (see `strip_bom`), counted as read.
            buf.drain(..BOM.len());
            (end, done) = (end - BOM.len(), BOM.len() as u64);
        }
        let mut from = 0;
        if counts.is_none() {
            // The header: parsed again from the start as lines come in
            // until it is whole.
            let mut it = records(&buf[..end]);
            match header(&mut it, size_bytes) {
                Ok((nv, nf, cline)) => {
                    counts = Some((nv, nf));
                    from = buf[..end]
                        .iter()
                        .enumerate()
                        .filter(|&(_, &b)| b == b'\n')
                        .nth(cline as usize - 1)
                        .map_or(end, |(i, _)| i + 1);
                }
                // Lines ran out: read on (a header never takes megabytes:
                // past that the whole-file reader says what is wrong).
                // Anything else is an error to report.
                Err(e) if !eof && matches!(e.kind, ErrorKind::Truncated(_)) && end < 1 << 26 => {
                    continue
                }
                Err(_) => return Ok(None),
            }
        }
        let (nv, nf) = counts.expect("the header is read");
        let block = &buf[from..end];
        // Pieces of whole lines, and the number of records before each.
        let pieces = pieces(block, (chunk / 8).max(1), |_| false);
        let sizes: Vec<usize> = pieces.par_iter().map(|p| records(p).count()).collect();
        let mut firsts = Vec::with_capacity(sizes.len());
        for n in sizes {
            firsts.push(record);
            record += n;
        }
        let parsed: Option<Vec<Piece>> = pieces
            .par_iter()
            .zip(&firsts)
            .map(|(p, &first)| {
                let mut out = Piece::default();
                let mut face = Vec::new();
                for (k, (_, l)) in records(p).enumerate() {
                    let r = first + k;
                    if r < nv {
                        out.positions.push(parse_vec3(&mut tokens(l), 0).ok()?);
                    } else if r < nv + nf {
                        parse_face(l, 0, nv, &mut face).ok()?;
                        out.sizes.push(face.len() as u32);
                        out.indices.extend_from_slice(&face);
                    }
                }
                Some(out)
            })
            .collect();
        let Some(parsed) = parsed else {
            return Ok(None);
        };
        for p in parsed {
            mesh.positions.extend_from_slice(&p.positions);
            let mut at = 0;
            for &n in &p.sizes {
                mesh.push_face_unchecked(&p.indices[at..at + n as usize]);
                at += n as usize;
            }
        }
        done += end as u64;
        buf.drain(..end);
        progress(done, size.max(done));
        if eof {
            break;
        }
    }
    // A file that ends early goes to the reader that says where.
    match counts {
        Some((nv, nf)) if record >= nv + nf => Ok(Some(mesh)),
        _ => Ok(None),
    }
}
