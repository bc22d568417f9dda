//! The numpy `.npy` files of `../shared/BENCH.md`: rays as `float32`
//! `(N, 8)` arrays (`ox oy oz tmin dx dy dz tmax`) and hits as `(N,)`
//! records `t <f4, prim <i4, u <f4, v <f4` (a miss is `t = inf, prim = -1`).

use anyhow::{bail, Context, Result};
#[cfg(test)]
use raymesh_accel::Ray;
use std::io::Write;
use std::path::Path;

const MAGIC: &[u8] = b"\x93NUMPY";

/// The dtype of hit records, as numpy spells it.
pub const HIT_DESCR: &str = "[('t', '<f4'), ('prim', '<i4'), ('u', '<f4'), ('v', '<f4')]";

/// One record of a hits file.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HitRecord {
    /// Ray parameter, `inf` for a miss.
    pub t: f32,
    /// Triangle index, -1 for a miss.
    pub prim: i32,
    /// Weight of the 2nd corner.
    pub u: f32,
    /// Weight of the 3rd corner.
    pub v: f32,
}

impl HitRecord {
    /// The record of a miss.
    pub const MISS: Self = Self {
        t: f32::INFINITY,
        prim: -1,
        u: 0.0,
        v: 0.0,
    };
}

/// A parsed `.npy` header.
struct Header {
    descr: String,
    fortran: bool,
    shape: Vec<usize>,
    data_start: usize,
}

/// Value of `'key':` in the header dict, up to the next top-level comma.
fn dict_value<'a>(dict: &'a str, key: &str) -> Option<&'a str> {
    let at = dict.find(&format!("'{key}'"))? + key.len() + 2;
    let rest = dict[at..].trim_start().strip_prefix(':')?.trim_start();
    let mut depth = 0i32;
    for (i, ch) in rest.char_indices() {
        match ch {
            '(' | '[' => depth += 1,
            ')' | ']' => depth -= 1,
            ',' | '}' if depth == 0 => return Some(rest[..i].trim()),
            _ => {}
        }
    }
    None
}

fn parse_header(bytes: &[u8]) -> Result<Header> {
    if bytes.len() < 10 || !bytes.starts_with(MAGIC) {
        bail!("not a .npy file (no \\x93NUMPY magic)");
    }
    let major = bytes[6];
    let (len, start) = match major {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 => {
            if bytes.len() < 12 {
                bail!("truncated .npy header");
            }
            (
                u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
                12,
            )
        }
        v => bail!("unsupported .npy version {v}"),
    };
    let dict = bytes
        .get(start..start + len)
        .context("truncated .npy header")?;
    let dict = std::str::from_utf8(dict).context(".npy header is not text")?;
    let descr = dict_value(dict, "descr").context(".npy header has no 'descr'")?;
    let fortran =
        dict_value(dict, "fortran_order").context(".npy header has no 'fortran_order'")? == "True";
    let shape_text = dict_value(dict, "shape").context(".npy header has no 'shape'")?;
    let shape = shape_text
        .trim_matches(|c| c == '(' || c == ')')
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.trim_end_matches('L').parse::<usize>())
        .collect::<Result<Vec<_>, _>>()
        .with_context(|| format!("bad shape {shape_text}"))?;
    Ok(Header {
        descr: descr.trim_matches(|c| c == '\'' || c == '"').to_string(),
        fortran,
        shape,
        data_start: start + len,
    })
}

/// Parses the bytes of a rays file into rays ([`Ray::from_row`]): what
/// the tests check the rows' columns by.
#[cfg(test)]
fn parse_rays(bytes: &[u8]) -> Result<Vec<Ray>> {
    Ok(parse_ray_rows(bytes)?.iter().map(Ray::from_row).collect())
}

/// Reads the rows of an `(N, 8)` little-endian `float32` rays file
/// (`ox oy oz tmin dx dy dz tmax`, as BENCH.md lays them out), as they
/// are: the queries that take rows (`Scene::intersect_bare_row`, ...)
/// make each ray where they trace it.
///
/// The data goes from the file straight into the rows (32 bytes a ray),
/// with no copy of the file in memory beside them: a `Vec<Ray>` takes
/// 60 bytes a ray, and reading the whole file first took 32 more.
pub fn read_ray_rows(path: &Path) -> Result<Vec<[f32; 8]>> {
    let file =
        std::fs::File::open(path).with_context(|| format!("{}: cannot read", path.display()))?;
    read_rows_from(file).with_context(|| format!("{}: bad rays array", path.display()))
}

/// [`read_ray_rows`] of an open file.
fn read_rows_from(mut file: std::fs::File) -> Result<Vec<[f32; 8]>> {
    use std::io::{Read, Seek, SeekFrom};
    let len = file.metadata()?.len();
    // The header: its fixed part, then as many bytes as it says it has.
    let mut head = Vec::new();
    Read::take(&mut file, 12).read_to_end(&mut head)?;
    let dict_len = match (head.get(6), head.get(8..12)) {
        (Some(1), Some(b)) => u64::from(u16::from_le_bytes([b[0], b[1]])) + 10,
        (Some(2 | 3), Some(b)) => u64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])) + 12,
        _ => 0,
    };
    let more = dict_len.saturating_sub(head.len() as u64);
    Read::take(&mut file, more).read_to_end(&mut head)?;
    let h = parse_header(&head)?;
    let n = ray_count(&h)?;
    let need = n.checked_mul(32).context("shape too large")?;
    let have = len.saturating_sub(h.data_start as u64);
    if have < need as u64 {
        bail!("truncated: {n} rays need {need} bytes of data, the file has {have}");
    }
    file.seek(SeekFrom::Start(h.data_start as u64))?;
    let mut rows = vec![[0.0f32; 8]; n];
    if h.fortran {
        // Column by column: each of the eight columns read in turn into
        // its place in every row.
        let mut col = vec![0u8; 4 * n];
        for c in 0..8 {
            file.read_exact(&mut col)?;
            for (row, v) in rows.iter_mut().zip(col.chunks_exact(4)) {
                row[c] = f32::from_le_bytes(v.try_into().expect("4 bytes"));
            }
        }
    } else {
        file.read_exact(bytemuck::cast_slice_mut(&mut rows))?;
        // The file's floats are little-endian; so are this machine's but
        // where they are not.
        if cfg!(target_endian = "big") {
            for v in rows.iter_mut().flatten() {
                *v = f32::from_bits(u32::from_le(v.to_bits()));
            }
        }
    }
    Ok(rows)
}

/// The number of rays a rays file's header announces, or why it is not
/// one: `<f4` and `(N, 8)`.
fn ray_count(h: &Header) -> Result<usize> {
    if h.descr != "<f4" {
        bail!(
            "dtype is '{}', expected '<f4' (little-endian float32)",
            h.descr
        );
    }
    match h.shape[..] {
        [n, 8] => Ok(n),
        _ => bail!(
            "shape is {:?}, expected (N, 8): ox oy oz tmin dx dy dz tmax",
            h.shape
        ),
    }
}

/// Parses the bytes of a rays file into its rows (see [`read_ray_rows`]).
pub fn parse_ray_rows(bytes: &[u8]) -> Result<Vec<[f32; 8]>> {
    let h = parse_header(bytes)?;
    let n = ray_count(&h)?;
    let data = &bytes[h.data_start..];
    let need = n.checked_mul(32).context("shape too large")?;
    if data.len() < need {
        bail!(
            "truncated: {n} rays need {need} bytes of data, the file has {}",
            data.len()
        );
    }
    let get = |row: usize, col: usize| {
        let i = if h.fortran {
            col * n + row
        } else {
            row * 8 + col
        };
        f32::from_le_bytes(data[4 * i..4 * i + 4].try_into().unwrap())
    };
    Ok((0..n).map(|r| std::array::from_fn(|c| get(r, c))).collect())
}

/// Writes a `.npy` header for the given dtype and shape (format 1.0, 64-byte aligned).
fn write_header(w: &mut impl Write, descr: &str, shape: &str) -> std::io::Result<()> {
    let mut dict = format!("{{'descr': {descr}, 'fortran_order': False, 'shape': {shape}, }}");
    let unpadded = MAGIC.len() + 4 + dict.len() + 1;
    dict.push_str(&" ".repeat((64 - unpadded % 64) % 64));
    dict.push('\n');
    w.write_all(MAGIC)?;
    w.write_all(&[1, 0])?;
    w.write_all(&(dict.len() as u16).to_le_bytes())?;
    w.write_all(dict.as_bytes())
}

/// Writes rays as an `(N, 8)` `float32` array.
pub fn write_rays(w: &mut impl Write, rays: &[[f32; 8]]) -> std::io::Result<()> {
    write_header(w, "'<f4'", &format!("({}, 8)", rays.len()))?;
    for r in rays {
        for v in r {
            w.write_all(&v.to_le_bytes())?;
        }
    }
    Ok(())
}

/// Writes hit records.
pub fn write_hits(w: &mut impl Write, hits: &[HitRecord]) -> std::io::Result<()> {
    write_header(w, HIT_DESCR, &format!("({},)", hits.len()))?;
    for h in hits {
        w.write_all(&h.t.to_le_bytes())?;
        w.write_all(&h.prim.to_le_bytes())?;
        w.write_all(&h.u.to_le_bytes())?;
        w.write_all(&h.v.to_le_bytes())?;
    }
    Ok(())
}

/// Reads hit records (for tests and comparisons).
#[cfg(test)]
pub fn parse_hits(bytes: &[u8]) -> Result<Vec<HitRecord>> {
    let h = parse_header(bytes)?;
    let compact: String = h.descr.chars().filter(|c| !c.is_whitespace()).collect();
    if compact != HIT_DESCR.replace(' ', "") {
        bail!("dtype is {}, expected {HIT_DESCR}", h.descr);
    }
    let n = match h.shape[..] {
        [n] => n,
        _ => bail!("shape is {:?}, expected (N,)", h.shape),
    };
    let data = &bytes[h.data_start..];
    if data.len() < n * 16 {
        bail!(
            "truncated: {n} hits need {} bytes, the file has {}",
            n * 16,
            data.len()
        );
    }
    Ok(data
        .chunks_exact(16)
        .take(n)
        .map(|c| HitRecord {
            t: f32::from_le_bytes(c[0..4].try_into().unwrap()),
            prim: i32::from_le_bytes(c[4..8].try_into().unwrap()),
            u: f32::from_le_bytes(c[8..12].try_into().unwrap()),
            v: f32::from_le_bytes(c[12..16].try_into().unwrap()),
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use raymesh_geometry::Vec3;

    /// The rows of a rays file's bytes, parsed from memory and read from
    /// a file holding them, which must agree: the same rows, bit for bit,
    /// or the same error.
    fn parse_both(bytes: &[u8]) -> Result<Vec<[f32; 8]>> {
        use std::sync::atomic::{AtomicUsize, Ordering};
        static NEXT: AtomicUsize = AtomicUsize::new(0);
        let path = std::env::temp_dir().join(format!(
            "raymesh-npy-{}-{}.npy",
            std::process::id(),
            NEXT.fetch_add(1, Ordering::Relaxed)
        ));
        std::fs::write(&path, bytes).unwrap();
        let read = read_ray_rows(&path);
        std::fs::remove_file(&path).unwrap();
        let parsed = parse_ray_rows(bytes);
        match (&parsed, &read) {
            (Ok(a), Ok(b)) => {
                let bits = |r: &Vec<[f32; 8]>| -> Vec<u32> {
                    r.iter().flatten().map(|v| v.to_bits()).collect()
                };
                assert_eq!(bits(a), bits(b));
            }
            (Err(a), Err(b)) => assert_eq!(a.to_string(), b.root_cause().to_string()),
            _ => panic!("parsed {parsed:?}, read {read:?}"),
        }
        parsed
    }

    #[test]
    fn rays_round_trip() {
        let rays = [[0.0, 1.0, 2.0, 0.0, 0.0, 0.0, 1.0, f32::INFINITY], [1.0; 8]];
        let mut b = Vec::new();
        write_rays(&mut b, &rays).unwrap();
        assert_eq!(b.iter().position(|&c| c == b'\n').unwrap() % 64, 63);
        let back = parse_rays(&b).unwrap();
        assert_eq!(parse_both(&b).unwrap(), rays);
        // Trailing bytes past the rows are left alone.
        b.extend_from_slice(&[7; 5]);
        assert_eq!(parse_both(&b).unwrap(), rays);
        assert_eq!(back.len(), 2);
        assert_eq!(back[0].origin(), Vec3::new(0.0, 1.0, 2.0));
        assert_eq!(back[0].tmax(), f32::INFINITY);
        assert_eq!(back[1].dir(), Vec3::ONE);
    }

    #[test]
    fn hits_round_trip() {
        let hits = [
            HitRecord {
                t: 1.5,
                prim: 7,
                u: 0.25,
                v: 0.5,
            },
            HitRecord::MISS,
        ];
        let mut b = Vec::new();
        write_hits(&mut b, &hits).unwrap();
        assert_eq!(parse_hits(&b).unwrap(), hits);
    }

    #[test]
    fn bad_arrays_are_clear_errors() {
        let mut b = Vec::new();
        write_rays(&mut b, &[[0.0; 8]; 3]).unwrap();
        let e = parse_both(&b[..b.len() - 1]).unwrap_err().to_string();
        assert!(e.contains("truncated: 3 rays need 96 bytes"), "{e}");
        let e = parse_both(b"hello world").unwrap_err().to_string();
        assert!(e.contains("not a .npy"), "{e}");
        let mut w = Vec::new();
        write_header(&mut w, "'<f8'", "(3, 8)").unwrap();
        assert!(parse_both(&w)
            .unwrap_err()
            .to_string()
            .contains("dtype is '<f8'"));
        let mut w = Vec::new();
        write_header(&mut w, "'<f4'", "(3, 7)").unwrap();
        assert!(parse_both(&w)
            .unwrap_err()
            .to_string()
            .contains("expected (N, 8)"));
        let mut w = Vec::new();
        write_header(&mut w, "'<f4'", "(24,)").unwrap();
        assert!(parse_both(&w)
            .unwrap_err()
            .to_string()
            .contains("expected (N, 8)"));
        assert!(parse_both(&b[..9]).is_err());
        assert!(parse_both(&b[..40])
            .unwrap_err()
            .to_string()
            .contains("truncated .npy header"));
        assert!(parse_both(&[]).is_err());
        let e = read_ray_rows(Path::new("/nonexistent/rays.npy")).unwrap_err();
        assert!(
            format!("{e:#}").contains("/nonexistent/rays.npy: cannot read"),
            "{e:#}"
        );
    }

    #[test]
    fn fortran_order_is_read_by_column() {
        let mut w = Vec::new();
        let dict = "{'descr': '<f4', 'fortran_order': True, 'shape': (2, 8), }";
        w.extend_from_slice(MAGIC);
        w.extend_from_slice(&[1, 0]);
        w.extend_from_slice(&(dict.len() as u16).to_le_bytes());
        w.extend_from_slice(dict.as_bytes());
        for col in 0..8 {
            for row in 0..2 {
                w.extend_from_slice(&((row * 10 + col) as f32 + 1.0).to_le_bytes());
            }
        }
        let r = parse_rays(&w).unwrap();
        assert_eq!(r[1].origin(), Vec3::new(11.0, 12.0, 13.0));
        let rows = parse_both(&w).unwrap();
        assert_eq!(rows[0], [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0]);
        assert_eq!(rows[1][7], 18.0);
        // One byte short of the last column.
        assert!(parse_both(&w[..w.len() - 1])
            .unwrap_err()
            .to_string()
            .contains("truncated: 2 rays need 64 bytes"));
    }
}
