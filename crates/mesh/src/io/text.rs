//! Shared helpers for the line-oriented text formats.

use crate::{ErrorKind, MeshError};
use raymesh_geometry::Vec3;

/// The UTF-8 byte-order mark some Windows tools write at the start of a
/// text file.
pub(crate) const BOM: &[u8] = b"\xef\xbb\xbf";

/// `bytes` without a leading UTF-8 byte-order mark ([`BOM`]): the text
/// formats read a file that starts with one as the file without it (line
/// numbers are the same; an editor does not show the mark).
pub(crate) fn strip_bom(bytes: &[u8]) -> &[u8] {
    bytes.strip_prefix(BOM).unwrap_or(bytes)
}

/// Splits `bytes` into pieces of about `chunk` bytes, each ending after a
/// line end whose line does not continue (`continues(line)`, the line
/// without its `\n`, is false) or at the end of `bytes`: the units a
/// text reader parses in parallel.
pub(crate) fn pieces(bytes: &[u8], chunk: usize, continues: impl Fn(&[u8]) -> bool) -> Vec<&[u8]> {
    let mut pieces = Vec::new();
    let mut at = 0usize;
    while at < bytes.len() {
        let mut end = (at + chunk.max(1)).min(bytes.len());
        while end < bytes.len() {
            match bytes[end..].iter().position(|&b| b == b'\n') {
                None => end = bytes.len(),
                Some(k) => {
                    let nl = end + k;
                    end = nl + 1;
                    if !continues(&bytes[..nl]) {
                        break;
                    }
                }
            }
        }
        pieces.push(&bytes[at..end]);
        at = end;
    }
    pieces
}

/// Reads up to `chunk` more bytes of `file` onto `buf` and says how much
/// of `buf` a streamed text reader can parse now: `(end, eof)`, with `end`
/// after the last line end whose line does not continue (the rest waits
/// for the next read), or all of `buf` at the end of the file; `None`
/// when no such line end has come in yet.
pub(crate) fn read_lines(
    file: &mut impl std::io::Read,
    buf: &mut Vec<u8>,
    chunk: usize,
    continues: impl Fn(&[u8]) -> bool,
) -> std::io::Result<Option<(usize, bool)>> {
    use std::io::Read;
    let old = buf.len();
    let eof = file.by_ref().take(chunk as u64).read_to_end(buf)? < chunk;
    if eof {
        return Ok(Some((buf.len(), true)));
    }
    // Only the bytes just read can hold one: the earlier ones had none.
    let mut upto = buf.len();
    while let Some(k) = buf[old..upto].iter().rposition(|&b| b == b'\n') {
        let nl = old + k;
        if !continues(&buf[..nl]) {
            return Ok(Some((nl + 1, false)));
        }
        upto = nl;
    }
    Ok(None)
}

/// Lines of a text file with their 1-based numbers, `\r\n` tolerated.
pub(crate) fn lines(bytes: &[u8]) -> impl Iterator<Item = (u64, &[u8])> {
    bytes.split(|&b| b == b'\n').enumerate().map(|(i, l)| {
        let l = l.strip_suffix(b"\r").unwrap_or(l);
        (i as u64 + 1, l)
    })
}

/// Whitespace-separated tokens of a line.
pub(crate) fn tokens(line: &[u8]) -> impl Iterator<Item = &[u8]> {
    line.split(|b| b.is_ascii_whitespace())
        .filter(|t| !t.is_empty())
}

/// The token as text, for messages (lossy, shortened).
pub(crate) fn show(tok: &[u8]) -> String {
    let s = String::from_utf8_lossy(&tok[..tok.len().min(40)]).into_owned();
    if tok.len() > 40 {
        format!("{s}...")
    } else {
        s
    }
}

/// Parses a finite `f32` coordinate.
pub(crate) fn parse_coord(tok: &[u8], line: u64) -> Result<f32, MeshError> {
    let s = std::str::from_utf8(tok).ok();
    match s.and_then(|s| s.parse::<f32>().ok()) {
        Some(v) if v.is_finite() => Ok(v),
        Some(_) => Err(MeshError::at_line(line, ErrorKind::NonFinite(show(tok)))),
        None => Err(MeshError::at_line(
            line,
            ErrorKind::Syntax(format!("expected a number, found '{}'", show(tok))),
        )),
    }
}

/// Parses three coordinates from the token iterator.
pub(crate) fn parse_vec3<'a>(
    toks: &mut impl Iterator<Item = &'a [u8]>,
    line: u64,
) -> Result<Vec3, MeshError> {
    let mut c = [0.0f32; 3];
    for (i, v) in c.iter_mut().enumerate() {
        let tok = toks.next().ok_or_else(|| {
            MeshError::at_line(
                line,
                ErrorKind::Syntax(format!("expected 3 coordinates, found {i}")),
            )
        })?;
        *v = parse_coord(tok, line)?;
    }
    Ok(Vec3::from_array(c))
}

/// Parses a signed integer token.
pub(crate) fn parse_int(tok: &[u8], line: u64, what: &str) -> Result<i64, MeshError> {
    std::str::from_utf8(tok)
        .ok()
        .and_then(|s| s.parse::<i64>().ok())
        .ok_or_else(|| {
            MeshError::at_line(
                line,
                ErrorKind::Syntax(format!("expected {what}, found '{}'", show(tok))),
            )
        })
}

/// Checks a header count: non-negative, below `u32::MAX`, and small enough
/// that `count` items of at least `min_bytes` each fit in `remaining` bytes.
pub(crate) fn check_count(
    n: i64,
    line: u64,
    what: &str,
    remaining: usize,
    min_bytes: usize,
) -> Result<usize, MeshError> {
    if n < 0 {
        return Err(MeshError::at_line(
            line,
            ErrorKind::Syntax(format!("negative {what} {n}")),
        ));
    }
    if n > u32::MAX as i64 - 1 || (n as u128) * (min_bytes as u128) > remaining as u128 {
        return Err(MeshError::at_line(
            line,
            ErrorKind::TooLarge(format!(
                "{n} {what} cannot fit in the {remaining} bytes that follow"
            )),
        ));
    }
    Ok(n as usize)
}
