//! Reading and writing mesh files: OBJ, OFF, PLY (ascii, binary little and
//! big endian) and STL (ascii and binary).
//!
//! Readers take the whole file as bytes and never trust a header: every count
//! is checked against the bytes that follow before anything is allocated for
//! it, so a header that claims 10^12 faces is an error, not an allocation.
//! Every error names the line (text) or byte offset (binary) where it was found.
//! OBJ and OFF files, binary STL files and binary PLY files of triangles,
//! the forms big meshes come in, are the exception: [`read_mesh`] parses
//! them as they stream in, chunk by chunk, and hands anything else (or
//! anything wrong) to the whole-file reader.
//!
//! These are hand-written rather than built on tobj, ply-rs or stl_io: those
//! report errors without a line or byte offset, and STL needs its duplicated
//! corners welded into shared vertices, which none of them do.

mod obj;
mod off;
mod ply;
mod stl;
mod text;
mod write;

use crate::{ErrorKind, IndexedMesh, Location, MeshError};
use std::path::Path;

pub use ply::PlyEncoding;
pub use write::{write_obj, write_off, write_ply};

/// A mesh file format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// Wavefront OBJ (geometry only: `v` and `f`).
    Obj,
    /// Object File Format (Geomview / CGAL).
    Off,
    /// Stanford PLY, ascii or binary.
    Ply,
    /// Stereolithography, ascii or binary; corners are welded into vertices.
    Stl,
}

impl Format {
    /// The format named by a file extension (case-insensitive).
    #[must_use]
    pub fn from_extension(path: &Path) -> Option<Self> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        match ext.as_str() {
            "obj" => Some(Self::Obj),
            "off" => Some(Self::Off),
            "ply" => Some(Self::Ply),
            "stl" => Some(Self::Stl),
            _ => None,
        }
    }

    /// The format recognized from the first bytes of a file.
    #[must_use]
    pub fn sniff(bytes: &[u8]) -> Option<Self> {
        let start = text::strip_bom(bytes).trim_ascii_start();
        if start.starts_with(b"ply") {
            Some(Self::Ply)
        } else if start.starts_with(b"OFF")
            || start.starts_with(b"COFF")
            || start.starts_with(b"NOFF")
            || start.starts_with(b"CNOFF")
        {
            Some(Self::Off)
        } else if start.starts_with(b"solid") || stl::is_binary(bytes) {
            Some(Self::Stl)
        } else if start.starts_with(b"v ") || start.starts_with(b"#") || start.starts_with(b"o ") {
            Some(Self::Obj)
        } else {
            None
        }
    }
}

/// Reads a mesh file, choosing the format by extension, else by content.
pub fn read_mesh(path: impl AsRef<Path>) -> Result<IndexedMesh, MeshError> {
    read_mesh_with(path, &mut |_, _| {})
}

/// Bytes read between two calls of a [`read_mesh_with`] progress callback.
const READ_CHUNK: usize = 8 << 20;

/// [`read_mesh`], calling `progress(bytes_read, file_size)` as the file
/// comes in (every 8 MiB, and once at the end), so that a tool can show a
/// progress bar while a multi-gigabyte file loads. Streamed files (OBJ,
/// OFF, binary STL, binary PLY of triangles) are parsed as they come in; a
/// file the streamed reader gives up on is read again from the start,
/// whole, and parsed after (so the bytes reported start over).
pub fn read_mesh_with(
    path: impl AsRef<Path>,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<IndexedMesh, MeshError> {
    let path = path.as_ref();
    let io = |e| MeshError::new(Location::File, ErrorKind::Io(e)).with_path(path);
    if let Some(f) = Format::from_extension(path) {
        if let Some(mesh) = read_stream(path, f, progress).map_err(io)? {
            return Ok(mesh);
        }
    }
    let bytes = read_file(path, progress).map_err(io)?;
    let format = match Format::from_extension(path) {
        Some(f) => f,
        None => Format::sniff(&bytes).ok_or_else(|| {
            let what = match path.extension() {
                Some(e) => format!("extension .{}", e.to_string_lossy()),
                None => "no extension".to_string(),
            };
            MeshError::new(Location::File, ErrorKind::UnknownFormat(what)).with_path(path)
        })?,
    };
    read_bytes(&bytes, format).map_err(|e| e.with_path(path))
}

/// A file parsed as it is read (see [`obj::read_stream`],
/// [`off::read_stream`], [`ply::read_stream`] and [`stl::read_stream`]);
/// `None` when it needs the whole-file reader.
fn read_stream(
    path: &Path,
    format: Format,
    progress: &mut dyn FnMut(u64, u64),
) -> std::io::Result<Option<IndexedMesh>> {
    // A pipe cannot be read twice: only a regular file may give up midway
    // and go to the whole-file reader. (Its metadata, not an opening: a
    // pipe's writer would see its reader go away.)
    if !std::fs::metadata(path).is_ok_and(|m| m.is_file()) {
        return Ok(None);
    }
    let mut file = std::fs::File::open(path)?;
    let size = file.metadata()?.len();
    match format {
        Format::Ply => ply::read_stream(&mut file, size, READ_CHUNK, progress),
        Format::Stl => stl::read_stream(&mut file, size, READ_CHUNK, progress),
        Format::Obj => obj::read_stream(&mut file, size, READ_CHUNK, progress),
        Format::Off => off::read_stream(&mut file, size, READ_CHUNK, progress),
    }
}

/// The whole file, read in chunks with `progress` after each.
fn read_file(path: &Path, progress: &mut dyn FnMut(u64, u64)) -> std::io::Result<Vec<u8>> {
    use std::io::Read;
    let mut file = std::fs::File::open(path)?;
    let size = file.metadata().map_or(0, |m| m.len());
    // The size is a hint (a file may change while it is read): the loop
    // reads to the end whatever it says.
    let mut bytes = Vec::with_capacity(usize::try_from(size).unwrap_or(0));
    loop {
        let n = (&mut file)
            .take(READ_CHUNK as u64)
            .read_to_end(&mut bytes)?;
        progress(bytes.len() as u64, size.max(bytes.len() as u64));
        if n == 0 {
            return Ok(bytes);
        }
    }
}

/// Reads a mesh from bytes in the given format.
pub fn read_bytes(bytes: &[u8], format: Format) -> Result<IndexedMesh, MeshError> {
    if bytes.trim_ascii().is_empty() {
        return Err(MeshError::new(Location::File, ErrorKind::Empty));
    }
    match format {
        Format::Obj => obj::read(bytes),
        Format::Off => off::read(bytes),
        Format::Ply => ply::read(bytes),
        Format::Stl => stl::read(bytes),
    }
}

/// Writes a mesh in the format its extension names (`.obj`, `.off`, `.ply`;
/// PLY is written binary little-endian). Overwrites an existing file: callers
/// decide whether the user asked for that.
pub fn write_mesh(path: impl AsRef<Path>, mesh: &IndexedMesh) -> Result<(), MeshError> {
    let path = path.as_ref();
    let io_err =
        |e: std::io::Error| MeshError::new(Location::File, ErrorKind::Write(e)).with_path(path);
    let format = Format::from_extension(path).ok_or_else(|| {
        MeshError::new(
            Location::File,
            ErrorKind::Unsupported("writing this extension; write .obj, .off or .ply".into()),
        )
        .with_path(path)
    })?;
    let file = std::fs::File::create(path).map_err(io_err)?;
    let mut w = std::io::BufWriter::new(file);
    match format {
        Format::Obj => write_obj(&mut w, mesh),
        Format::Off => write_off(&mut w, mesh),
        Format::Ply => write_ply(&mut w, mesh, PlyEncoding::BinaryLittleEndian),
        Format::Stl => {
            return Err(MeshError::new(
                Location::File,
                ErrorKind::Unsupported("writing STL (it loses shared vertices); use .ply".into()),
            )
            .with_path(path))
        }
    }
    .and_then(|()| std::io::Write::flush(&mut w))
    .map_err(io_err)
}

#[cfg(test)]
mod tests;
