//! PLY reader (Turk's Stanford polygon format): ascii, binary little-endian
//! and binary big-endian. Vertices come from the `vertex` element's `x`, `y`,
//! `z` properties (any scalar type), faces from the `face` element's
//! `vertex_indices` (or `vertex_index`) list; other elements and properties
//! are read past and ignored.

use super::text::show;
use crate::{ErrorKind, IndexedMesh, Location, MeshError};
use raymesh_geometry::Vec3;
use rayon::prelude::*;

/// How a PLY file stores its data.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PlyEncoding {
    /// Whitespace-separated text.
    Ascii,
    /// Binary, little-endian.
    BinaryLittleEndian,
    /// Binary, big-endian.
    BinaryBigEndian,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(name: &[u8]) -> Option<Self> {
        Some(match name {
            b"char" | b"int8" => Self::I8,
            b"uchar" | b"uint8" => Self::U8,
            b"short" | b"int16" => Self::I16,
            b"ushort" | b"uint16" => Self::U16,
            b"int" | b"int32" => Self::I32,
            b"uint" | b"uint32" => Self::U32,
            b"float" | b"float32" => Self::F32,
            b"double" | b"float64" => Self::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    fn is_int(self) -> bool {
        !matches!(self, Self::F32 | Self::F64)
    }
}

#[derive(Clone, Copy, Debug)]
enum Prop {
    Scalar(Scalar),
    List(Scalar, Scalar),
}

#[derive(Debug)]
struct Element {
    name: Vec<u8>,
    count: usize,
    count_line: u64,
    props: Vec<(Vec<u8>, Prop)>,
}

impl Element {
    /// The fewest bytes one instance can take (binary) or tokens (ascii).
    fn min_size(&self, binary: bool) -> usize {
        self.props
            .iter()
            .map(|(_, p)| match (p, binary) {
                (Prop::Scalar(s), true) | (Prop::List(s, _), true) => s.size(),
                (_, false) => 1, // at least one character per value
            })
            .sum::<usize>()
            .max(1)
    }
}

/// Where the data values come from.
trait Source {
    fn scalar(&mut self, ty: Scalar) -> Result<f64, MeshError>;
    fn location(&self) -> Location;
    fn err(&self, kind: ErrorKind) -> MeshError {
        MeshError::new(self.location(), kind)
    }
}

struct Ascii<'a> {
    bytes: &'a [u8],
    pos: usize,
    line: u64,
}

impl Source for Ascii<'_> {
    fn scalar(&mut self, ty: Scalar) -> Result<f64, MeshError> {
        while self.pos < self.bytes.len() && self.bytes[self.pos].is_ascii_whitespace() {
            if self.bytes[self.pos] == b'\n' {
                self.line += 1;
            }
            self.pos += 1;
        }
        let start = self.pos;
        while self.pos < self.bytes.len() && !self.bytes[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
        let tok = &self.bytes[start..self.pos];
        if tok.is_empty() {
            return Err(self.err(ErrorKind::Truncated("the data ends early".into())));
        }
        let v = std::str::from_utf8(tok)
            .ok()
            .and_then(|s| s.parse::<f64>().ok())
            .ok_or_else(|| {
                self.err(ErrorKind::Syntax(format!(
                    "expected a number, found '{}'",
                    show(tok)
                )))
            })?;
        if ty.is_int() && v.fract() != 0.0 {
            return Err(self.err(ErrorKind::Syntax(format!(
                "expected an integer, found '{}'",
                show(tok)
            ))));
        }
        Ok(v)
    }

    /// The line of the next value (whitespace ahead is skipped in thought).
    fn location(&self) -> Location {
        let ahead = &self.bytes[self.pos..];
        let ws = ahead.iter().take_while(|b| b.is_ascii_whitespace());
        Location::Line(self.line + ws.filter(|&&b| b == b'\n').count() as u64)
    }
}

/// The value of a binary scalar of type `ty` at the start of `b` (which
/// holds at least `ty.size()` bytes).
#[inline]
fn decode(b: &[u8], ty: Scalar, big_endian: bool) -> f64 {
    let n = ty.size();
    let mut a = [0u8; 8];
    a[..n].copy_from_slice(&b[..n]);
    if big_endian {
        a[..n].reverse();
    }
    match ty {
        Scalar::I8 => a[0] as i8 as f64,
        Scalar::U8 => a[0] as f64,
        Scalar::I16 => i16::from_le_bytes([a[0], a[1]]) as f64,
        Scalar::U16 => u16::from_le_bytes([a[0], a[1]]) as f64,
        Scalar::I32 => i32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
        Scalar::U32 => u32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
        Scalar::F32 => f32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
        Scalar::F64 => f64::from_le_bytes(a),
    }
}

struct Binary<'a> {
    bytes: &'a [u8],
    pos: usize,
    big_endian: bool,
}

impl Source for Binary<'_> {
    fn scalar(&mut self, ty: Scalar) -> Result<f64, MeshError> {
        let n = ty.size();
        let Some(b) = self.bytes.get(self.pos..self.pos + n) else {
            return Err(self.err(ErrorKind::Truncated(format!(
                "need {n} more bytes, the file has {}",
                self.bytes.len() - self.pos
            ))));
        };
        self.pos += n;
        Ok(decode(b, ty, self.big_endian))
    }

    fn location(&self) -> Location {
        Location::Byte(self.pos as u64)
    }
}

struct Header {
    encoding: PlyEncoding,
    elements: Vec<Element>,
    /// Byte offset where the data starts, and its line number.
    data_start: usize,
    data_line: u64,
}

fn header_err(line: u64, msg: impl Into<String>) -> MeshError {
    MeshError::at_line(line, ErrorKind::Syntax(msg.into()))
}

fn parse_header(bytes: &[u8]) -> Result<Header, MeshError> {
    let mut pos = 0usize;
    let mut line = 0u64;
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    loop {
        if pos >= bytes.len() {
            return Err(MeshError::at_line(
                line,
                ErrorKind::Truncated("no 'end_header'".into()),
            ));
        }
        let end = bytes[pos..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(bytes.len(), |i| pos + i);
        let raw = &bytes[pos..end];
        let l = raw.strip_suffix(b"\r").unwrap_or(raw);
        // A byte-order mark before `ply` (see `strip_bom`); the data's
        // byte offsets stay the file's.
        let l = if pos == 0 {
            super::text::strip_bom(l)
        } else {
            l
        };
        pos = (end + 1).min(bytes.len());
        line += 1;
        let toks: Vec<&[u8]> = super::text::tokens(l).collect();
        if line == 1 {
            if toks.first() != Some(&&b"ply"[..]) {
                return Err(header_err(1, "expected 'ply'"));
            }
            continue;
        }
        match toks.first().copied() {
            Some(b"format") => {
                encoding = Some(match toks.get(1).copied() {
                    Some(b"ascii") => PlyEncoding::Ascii,
                    Some(b"binary_little_endian") => PlyEncoding::BinaryLittleEndian,
                    Some(b"binary_big_endian") => PlyEncoding::BinaryBigEndian,
                    other => {
                        return Err(header_err(
                            line,
                            format!("unknown format '{}'", show(other.unwrap_or_default())),
                        ))
                    }
                });
            }
            Some(b"comment") | Some(b"obj_info") | None => {}
            Some(b"element") => {
                let (Some(name), Some(count)) = (toks.get(1), toks.get(2)) else {
                    return Err(header_err(line, "expected 'element NAME COUNT'"));
                };
                let count = super::text::parse_int(count, line, "an element count")?;
                if count < 0 || count > u32::MAX as i64 - 1 {
                    return Err(MeshError::at_line(
                        line,
                        ErrorKind::TooLarge(format!("element count {count}")),
                    ));
                }
                elements.push(Element {
                    name: name.to_vec(),
                    count: count as usize,
                    count_line: line,
                    props: Vec::new(),
                });
            }
            Some(b"property") => {
                let Some(el) = elements.last_mut() else {
                    return Err(header_err(line, "'property' before any 'element'"));
                };
                let ty = |t: Option<&&[u8]>| {
                    t.and_then(|t| Scalar::parse(t)).ok_or_else(|| {
                        header_err(
                            line,
                            format!(
                                "unknown property type '{}'",
                                show(t.copied().unwrap_or_default())
                            ),
                        )
                    })
                };
                let prop = if toks.get(1) == Some(&&b"list"[..]) {
                    let count_ty = ty(toks.get(2))?;
                    if !count_ty.is_int() {
                        return Err(header_err(line, "a list count must be an integer type"));
                    }
                    (toks.get(4), Prop::List(count_ty, ty(toks.get(3))?))
                } else {
                    (toks.get(2), Prop::Scalar(ty(toks.get(1))?))
                };
                let name = prop
                    .0
                    .ok_or_else(|| header_err(line, "property without a name"))?;
                el.props.push((name.to_vec(), prop.1));
            }
            Some(b"end_header") => break,
            Some(other) => {
                return Err(header_err(
                    line,
                    format!("unknown header line '{}'", show(other)),
                ));
            }
        }
    }
    let encoding = encoding.ok_or_else(|| header_err(2, "no 'format' line"))?;
    Ok(Header {
        encoding,
        elements,
        data_start: pos,
        data_line: line + 1,
    })
}

pub(super) fn read(bytes: &[u8]) -> Result<IndexedMesh, MeshError> {
    let h = parse_header(bytes)?;
    let data = &bytes[h.data_start..];
    let binary = h.encoding != PlyEncoding::Ascii;
    // Counts must be backed by bytes before anything is allocated for them.
    let mut need: u128 = 0;
    for el in &h.elements {
        need += el.count as u128 * el.min_size(binary) as u128;
        if need > data.len() as u128 {
            return Err(MeshError::at_line(
                el.count_line,
                ErrorKind::TooLarge(format!(
                    "{} '{}' elements cannot fit in the {} bytes of data",
                    el.count,
                    String::from_utf8_lossy(&el.name),
                    data.len()
                )),
            ));
        }
    }
    let nv = h
        .elements
        .iter()
        .find(|e| e.name == b"vertex")
        .map_or(0, |e| e.count);
    // Counts were checked against the data size, so this reservation is bounded.
    let mut mesh = IndexedMesh::with_capacity(nv, 0, 0);
    let mut face = Vec::new();
    match h.encoding {
        PlyEncoding::Ascii => {
            let mut src = Ascii {
                bytes,
                pos: h.data_start,
                line: h.data_line,
            };
            for el in &h.elements {
                read_element(el, &mut src, &mut mesh, nv, &mut face)?;
            }
        }
        e => {
            let big_endian = e == PlyEncoding::BinaryBigEndian;
            let mut src = Binary {
                bytes,
                pos: h.data_start,
                big_endian,
            };
            for el in &h.elements {
                let rest = &bytes[src.pos..];
                if let Some(used) = read_fixed(el, rest, big_endian, &mut mesh, nv) {
                    src.pos += used;
                } else {
                    read_element(el, &mut src, &mut mesh, nv, &mut face)?;
                }
            }
        }
    }
    Ok(mesh)
}

/// Where a vertex element of scalars only keeps `x`, `y` and `z`: each
/// one's byte offset and type in a record, and the record's size. `None`
/// when a property is a list or a coordinate is missing.
fn vertex_layout(el: &Element) -> Option<([(usize, Scalar); 3], usize)> {
    let mut stride = 0;
    let mut at = [None; 3];
    for (name, prop) in &el.props {
        let Prop::Scalar(ty) = *prop else {
            return None;
        };
        if let Some(axis) = [b"x".as_slice(), b"y", b"z"].iter().position(|a| a == name) {
            at[axis] = Some((stride, ty));
        }
        stride += ty.size();
    }
    Some(([at[0]?, at[1]?, at[2]?], stride))
}

/// The count and index types of a face element whose one property is a
/// list, and its record size if every list holds 3 indices. `None` for
/// any other face element.
fn face_layout(el: &Element) -> Option<(Scalar, Scalar, usize)> {
    match el.props.as_slice() {
        [(_, Prop::List(cty, ity))] => Some((*cty, *ity, cty.size() + 3 * ity.size())),
        _ => None,
    }
}

/// Parses vertex records (`out.len()` of them, `stride` bytes each) in
/// parallel; `None` when a coordinate is not finite.
fn parse_vertices(
    records: &[u8],
    (at, stride): ([(usize, Scalar); 3], usize),
    big_endian: bool,
    out: &mut [Vec3],
) -> Option<()> {
    out.par_iter_mut()
        .zip(records.par_chunks_exact(stride))
        .try_for_each(|(out, r)| {
            let p = at.map(|(off, ty)| decode(&r[off..], ty, big_endian) as f32);
            *out = Vec3::from_array(p);
            p.iter().all(|v| v.is_finite()).then_some(())
        })
}

/// Parses triangle records (`out.len() / 3` of them) in parallel into
/// their indices; `None` when a list's length is not 3 or an index is not
/// below `nv`.
fn parse_faces(
    records: &[u8],
    (cty, ity, stride): (Scalar, Scalar, usize),
    big_endian: bool,
    nv: usize,
    out: &mut [u32],
) -> Option<()> {
    out.par_chunks_exact_mut(3)
        .zip(records.par_chunks_exact(stride))
        .try_for_each(|(t, r)| {
            if decode(r, cty, big_endian) != 3.0 {
                return None;
            }
            for (k, v) in t.iter_mut().enumerate() {
                let i = decode(&r[cty.size() + k * ity.size()..], ity, big_endian);
                if !(i >= 0.0 && (i as usize) < nv) {
                    return None;
                }
                *v = i as u32;
            }
            Some(())
        })
}

/// Records of a binary element that all have one size, parsed in parallel:
/// a vertex element of scalars only, or a face element whose one property
/// is a list of 3 indices in every record. Returns the bytes used, or
/// `None` (having changed nothing) when the element is not of that form
/// or something in it is wrong: then the one-record-at-a-time reader
/// takes it, and reports any error with its byte offset.
fn read_fixed(
    el: &Element,
    data: &[u8],
    big_endian: bool,
    mesh: &mut IndexedMesh,
    nv: usize,
) -> Option<usize> {
    /// Below this many records the plain reader is as fast.
    const MIN_RECORDS: usize = 4096;
    if el.count < MIN_RECORDS {
        return None;
    }
    if el.name == b"vertex" && mesh.positions.is_empty() {
        let layout = vertex_layout(el)?;
        let records = data.get(..el.count.checked_mul(layout.1)?)?;
        let mut positions = vec![Vec3::ZERO; el.count];
        parse_vertices(records, layout, big_endian, &mut positions)?;
        mesh.positions = positions;
        return Some(records.len());
    }
    if el.name == b"face" && mesh.num_faces() == 0 {
        let layout = face_layout(el)?;
        let records = data.get(..el.count.checked_mul(layout.2)?)?;
        // Written in place: no list of triangles in between.
        let mut indices = vec![0u32; 3 * el.count];
        parse_faces(records, layout, big_endian, nv, &mut indices)?;
        mesh.append_triangles_unchecked(indices);
        return Some(records.len());
    }
    None
}

/// What a streamed element becomes.
enum Plan {
    Vertices([(usize, Scalar); 3], usize),
    Faces(Scalar, Scalar, usize),
    /// Read past: fixed-size records of scalars.
    Skip(usize),
}

impl Plan {
    /// Bytes in one record.
    fn stride(&self) -> usize {
        match *self {
            Self::Vertices(_, s) | Self::Faces(_, _, s) | Self::Skip(s) => s,
        }
    }
}

/// Reads a binary PLY file as it comes in, `chunk` bytes at a time, each
/// chunk's records parsed in parallel, so that the file is never held
/// whole in memory (what a memory map would save, without one): the
/// peak is the mesh plus one chunk. Works when the file is binary, has
/// one `vertex` element of scalars, at most one `face` element of
/// triangles only, and other elements of scalars only; returns `None`
/// otherwise, and for anything wrong in the data, so that the whole-file
/// reader, which names the byte, takes it. `progress(bytes, size)` is
/// called after each chunk.
pub(super) fn read_stream(
    file: &mut impl std::io::Read,
    size: u64,
    chunk: usize,
    progress: &mut dyn FnMut(u64, u64),
) -> std::io::Result<Option<IndexedMesh>> {
    use std::io::Read;
    /// Longest header looked for before giving the file to the whole-file reader.
    const MAX_HEADER: usize = 1 << 20;
    let mut buf = Vec::new();
    let header_end = loop {
        let had = buf.len();
        let n = file.by_ref().take(64 << 10).read_to_end(&mut buf)?;
        // "end_header" may straddle the previous read: look from a little before it.
        let from = had.saturating_sub(16);
        if let Some(i) = find(&buf[from..], b"end_header") {
            let at = from + i;
            if let Some(nl) = buf[at..].iter().position(|&b| b == b'\n') {
                break at + nl + 1;
            }
        }
        if n == 0 || buf.len() > MAX_HEADER {
            return Ok(None);
        }
    };
    let Ok(h) = parse_header(&buf[..header_end]) else {
        return Ok(None);
    };
    let big_endian = match h.encoding {
        PlyEncoding::Ascii => return Ok(None),
        e => e == PlyEncoding::BinaryBigEndian,
    };
    let data_size = size.saturating_sub(header_end as u64);
    let mut plans = Vec::with_capacity(h.elements.len());
    let (mut nv, mut nf, mut need) = (None, None, 0u128);
    for el in &h.elements {
        let plan = if el.name == b"vertex" && nv.is_none() {
            nv = Some(el.count);
            let (at, stride) = match vertex_layout(el) {
                Some(l) => l,
                None => return Ok(None),
            };
            Plan::Vertices(at, stride)
        } else if el.name == b"face" && nf.is_none() {
            nf = Some(el.count);
            let Some((cty, ity, stride)) = face_layout(el) else {
                return Ok(None);
            };
            Plan::Faces(cty, ity, stride)
        } else if el.name == b"vertex" || el.name == b"face" {
            return Ok(None);
        } else {
            let mut stride = 0;
            for (_, p) in &el.props {
                let Prop::Scalar(ty) = p else {
                    return Ok(None);
                };
                stride += ty.size();
            }
            Plan::Skip(stride)
        };
        need += el.count as u128 * plan.stride() as u128;
        plans.push(plan);
    }
    // A file too short for its counts goes to the reader that says where it ends.
    if need > data_size as u128 {
        return Ok(None);
    }
    let nv = nv.unwrap_or(0);
    let mut mesh = IndexedMesh::with_capacity(0, 0, 0);
    buf.drain(..header_end);
    let mut done = header_end as u64;
    for (el, plan) in h.elements.iter().zip(&plans) {
        let stride = plan.stride();
        let per_chunk = (chunk / stride.max(1)).max(1);
        let mut positions = Vec::new();
        let mut indices = Vec::new();
        match plan {
            Plan::Vertices(..) => positions = vec![Vec3::ZERO; el.count],
            Plan::Faces(..) => indices = vec![0u32; 3 * el.count],
            Plan::Skip(_) => {}
        }
        let mut first = 0;
        while first < el.count {
            let n = per_chunk.min(el.count - first);
            let bytes = n * stride;
            if buf.len() < bytes {
                let want = (bytes - buf.len()) as u64;
                if file.by_ref().take(want).read_to_end(&mut buf)? < want as usize {
                    return Ok(None);
                }
            }
            let records = &buf[..bytes];
            let ok = match *plan {
                Plan::Vertices(at, stride) => parse_vertices(
                    records,
                    (at, stride),
                    big_endian,
                    &mut positions[first..first + n],
                ),
                Plan::Faces(cty, ity, stride) => parse_faces(
                    records,
                    (cty, ity, stride),
                    big_endian,
                    nv,
                    &mut indices[3 * first..3 * (first + n)],
                ),
                Plan::Skip(_) => Some(()),
            };
            if ok.is_none() {
                return Ok(None);
            }
            buf.drain(..bytes);
            first += n;
            done += bytes as u64;
            progress(done, size.max(done));
        }
        match plan {
            Plan::Vertices(..) => mesh.positions = positions,
            Plan::Faces(..) => mesh.append_triangles_unchecked(indices),
            Plan::Skip(_) => {}
        }
    }
    // Bytes after the last element are ignored, as the whole-file reader does.
    progress(size.max(done), size.max(done));
    Ok(Some(mesh))
}

/// Where `needle` first occurs in `hay`.
fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

/// Reads one element's records one at a time into `mesh`.
fn read_element(
    el: &Element,
    src: &mut impl Source,
    mesh: &mut IndexedMesh,
    nv: usize,
    face: &mut Vec<u32>,
) -> Result<(), MeshError> {
    {
        let is_vertex = el.name == b"vertex";
        let is_face = el.name == b"face";
        let xyz: Vec<Option<usize>> = el
            .props
            .iter()
            .map(|(n, _)| match n.as_slice() {
                b"x" => Some(0),
                b"y" => Some(1),
                b"z" => Some(2),
                _ => None,
            })
            .collect();
        if is_vertex {
            for axis in 0..3 {
                if !xyz.contains(&Some(axis)) {
                    return Err(MeshError::at_line(
                        el.count_line,
                        ErrorKind::Syntax(format!(
                            "vertex element has no '{}' property",
                            ["x", "y", "z"][axis]
                        )),
                    ));
                }
            }
        }
        let face_list = if is_face {
            let pos = el
                .props
                .iter()
                .position(|(n, p)| {
                    matches!(p, Prop::List(..)) && (n == b"vertex_indices" || n == b"vertex_index")
                })
                .or_else(|| {
                    el.props
                        .iter()
                        .position(|(_, p)| matches!(p, Prop::List(..)))
                });
            Some(pos.ok_or_else(|| {
                MeshError::at_line(
                    el.count_line,
                    ErrorKind::Syntax("face element has no list property".into()),
                )
            })?)
        } else {
            None
        };
        if is_face {
            mesh.reserve_faces(el.count);
        }
        for _ in 0..el.count {
            let mut p = [0.0f32; 3];
            let start = src.location();
            for (k, (_, prop)) in el.props.iter().enumerate() {
                match *prop {
                    Prop::Scalar(ty) => {
                        let v = src.scalar(ty)?;
                        if is_vertex {
                            if let Some(axis) = xyz[k] {
                                let f = v as f32;
                                if !f.is_finite() {
                                    return Err(MeshError::new(
                                        start,
                                        ErrorKind::NonFinite(format!("{v}")),
                                    ));
                                }
                                p[axis] = f;
                            }
                        }
                    }
                    Prop::List(cty, ity) => {
                        let n = src.scalar(cty)?;
                        if n < 0.0 {
                            return Err(
                                src.err(ErrorKind::Syntax(format!("negative list length {n}")))
                            );
                        }
                        let n = n as usize;
                        let wanted = face_list == Some(k);
                        if wanted {
                            if n < 3 {
                                return Err(MeshError::new(start, ErrorKind::FaceTooSmall(n)));
                            }
                            face.clear();
                        }
                        for _ in 0..n {
                            let i = src.scalar(ity)?;
                            if wanted {
                                if !(i >= 0.0 && (i as usize) < nv) {
                                    return Err(MeshError::new(
                                        start,
                                        ErrorKind::IndexOutOfRange {
                                            index: i as i64,
                                            vertices: nv,
                                        },
                                    ));
                                }
                                face.push(i as u32);
                            }
                        }
                    }
                }
            }
            if is_vertex {
                mesh.positions.push(Vec3::from_array(p));
            }
            if face_list.is_some() {
                mesh.push_face_unchecked(face);
            }
        }
    }
    Ok(())
}
