//! File formats: bytes <-> geom types. One module per format; no solver code.
//!
//! Every decoder parses from bytes first (`decode`), and the path-level API
//! ([`read_path`], [`write_path`]) is a thin wrapper that adds the file name to
//! errors, resolves external resources (glTF buffers), converts units and up
//! axes, handles frame sequences (`name.####.ext`) and writes atomically.

pub mod atomic;
pub mod bcc;
pub mod bytes;
pub mod character_h5;
pub mod checkpoint;
pub mod confined;
mod error;
pub mod gltf;
pub mod gltf_skin;
pub mod h5;
pub mod lock;
pub mod obj;
pub mod overwrite;
pub mod plot;
pub mod ply;
pub mod poly;
pub mod pyp;
pub mod sequence;
pub mod vtkhdf;

use std::fmt;
use std::path::{Path, PathBuf};

pub use error::{ErrorClass, FormatError, IoError, Location};

use crate::geom::{GeomError, Units, UpAxis, YarnFrames, Yarns};

/// Default yarn radius (m) when a file carries none: 1 mm, the HYLC papers' yarn radius.
pub const DEFAULT_RADIUS_M: f64 = 1.0e-3;

/// Largest number of points a reader accepts by default (2^31): beyond every real garment,
/// well below what would exhaust memory.
pub const DEFAULT_MAX_POINTS: u64 = 1 << 31;

/// Default memory budget of a read (bytes): 4 GiB. The binary replaces it
/// with `--max-memory` (default a quarter of the physical memory) through
/// [`set_max_memory`].
pub const DEFAULT_MAX_MEMORY: u64 = 4 << 30;

static MAX_MEMORY: std::sync::atomic::AtomicU64 =
    std::sync::atomic::AtomicU64::new(DEFAULT_MAX_MEMORY);

/// Sets the process's memory budget (bytes): the default of
/// [`ReadOptions::max_memory`] and the budget of the asset (`.vtkhdf`)
/// readers, which take no options. Called once by the binary (`--max-memory`).
pub fn set_max_memory(bytes: u64) {
    MAX_MEMORY.store(bytes, std::sync::atomic::Ordering::Relaxed);
}

/// The process's memory budget (bytes), see [`set_max_memory`].
pub fn max_memory() -> u64 {
    MAX_MEMORY.load(std::sync::atomic::Ordering::Relaxed)
}

/// The yarn-curve file formats knitvox reads and writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Format {
    /// Cem Yuksel's binary curve collection (PL, C0, BS curves).
    Bcc,
    /// Wavefront OBJ `v` / `l` polylines.
    Obj,
    /// YarnBall-style text `.poly` (POINTS / POLYS / END).
    Poly,
    /// MADYPG / HYLC periodic yarn tile.
    Pyp,
    /// glTF 2.0 JSON (`.gltf`).
    Gltf,
    /// glTF 2.0 binary (`.glb`).
    Glb,
    /// Stanford PLY, ascii or binary.
    Ply,
    /// knitvox HDF5 yarns and frames (schemas/yarns-hdf5.md).
    Hdf5,
}

impl Format {
    pub const ALL: [Format; 8] = [
        Format::Bcc,
        Format::Obj,
        Format::Poly,
        Format::Pyp,
        Format::Gltf,
        Format::Glb,
        Format::Ply,
        Format::Hdf5,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Format::Bcc => "bcc",
            Format::Obj => "obj",
            Format::Poly => "poly",
            Format::Pyp => "pyp",
            Format::Gltf => "gltf",
            Format::Glb => "glb",
            Format::Ply => "ply",
            Format::Hdf5 => "hdf5",
        }
    }

    pub fn extensions(self) -> &'static [&'static str] {
        match self {
            Format::Bcc => &["bcc"],
            Format::Obj => &["obj"],
            Format::Poly => &["poly"],
            Format::Pyp => &["pyp"],
            Format::Gltf => &["gltf"],
            Format::Glb => &["glb"],
            Format::Ply => &["ply"],
            Format::Hdf5 => &["h5", "hdf5"],
        }
    }

    /// Formats knitvox can write.
    pub fn is_writable(self) -> bool {
        !matches!(self, Format::Poly | Format::Pyp)
    }

    /// Whether a file of this format holds a whole frame sequence by itself.
    pub fn holds_frames(self) -> bool {
        matches!(self, Format::Hdf5)
    }

    /// Whether a file of this format stores the yarns' rest shape (rest
    /// lengths, curvatures, twists and directors); the others keep only
    /// the positions.
    pub fn holds_rest_shape(self) -> bool {
        matches!(self, Format::Hdf5)
    }

    /// Formats whose files carry no length unit (the reader takes `--units`).
    pub fn is_unitless(self) -> bool {
        matches!(self, Format::Bcc | Format::Obj | Format::Poly | Format::Ply)
    }

    /// The format of a path, from its extension (case-insensitive).
    pub fn from_path(path: &Path) -> Option<Format> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        Format::ALL
            .into_iter()
            .find(|f| f.extensions().contains(&ext.as_str()))
    }
}

impl fmt::Display for Format {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Options for reading yarn files.
#[derive(Debug, Clone, PartialEq)]
pub struct ReadOptions {
    /// Unit of a unitless file. Default: what the file declares, else metres (reported as assumed).
    pub units: Option<Units>,
    /// Up axis of the file. Default: what the file declares (BCC header, glTF: +Y), else +Y (assumed).
    pub up_axis: Option<UpAxis>,
    /// Polyline samples per spline span for BCC C0/BS curves. Default [`bcc::DEFAULT_SPLINE_SAMPLES`]
    /// (1: C0 curves keep exactly their control points).
    pub spline_samples: Option<usize>,
    /// Periodic tiles: repeat a `.pyp` tile this many times along its x and y periods. Default 1x1.
    pub tile: [usize; 2],
    /// Yarn radius (m) for files without one; also overrides a file's radius when
    /// `override_radius` is set. Default [`DEFAULT_RADIUS_M`].
    pub radius: f64,
    /// Use `radius` even where the file has its own.
    pub override_radius: bool,
    /// Refuse files with more points than this (guards memory). Default [`DEFAULT_MAX_POINTS`].
    pub max_points: u64,
    /// Memory budget (bytes): the most a reader allocates for data a file
    /// declares (compressed HDF5 datasets, external buffers, tiled copies),
    /// checked before allocating. Default [`max_memory`] ([`DEFAULT_MAX_MEMORY`]
    /// unless the binary set `--max-memory`, default a quarter of the physical memory).
    pub max_memory: u64,
}

impl Default for ReadOptions {
    fn default() -> Self {
        ReadOptions {
            units: None,
            up_axis: None,
            spline_samples: None,
            tile: [1, 1],
            radius: DEFAULT_RADIUS_M,
            override_radius: false,
            max_points: DEFAULT_MAX_POINTS,
            max_memory: max_memory(),
        }
    }
}

/// What a decoder found, in the file's own units and axes.
#[derive(Debug, Clone, PartialEq)]
pub struct Decoded {
    /// Curves in file coordinates. If `radius_in_file` is false the radii are placeholders.
    pub yarns: Yarns,
    /// Frames in file coordinates, for formats that hold sequences.
    pub frames: Option<YarnFrames>,
    /// The unit the file declares, if any.
    pub units: Option<Units>,
    /// The up axis the file declares, if any.
    pub up_axis: Option<UpAxis>,
    /// Whether the radii come from the file.
    pub radius_in_file: bool,
    /// Free-form facts worth showing in `inspect` (curve type, header text, ...).
    pub notes: Vec<String>,
}

impl Decoded {
    /// A decoded set of curves with nothing declared.
    pub fn plain(yarns: Yarns) -> Decoded {
        Decoded {
            yarns,
            frames: None,
            units: None,
            up_axis: None,
            radius_in_file: false,
            notes: Vec::new(),
        }
    }
}

/// Where a reported unit or axis came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Provenance {
    /// Given by the caller (`--units`, `--up-axis`, `--radius`).
    Option,
    /// Declared by the file (header, spec).
    File,
    /// Nobody said: knitvox's default was assumed.
    Assumed,
}

/// Yarns read from a file, converted to metres and +Y up, with the facts of the read.
#[derive(Debug, Clone, PartialEq)]
pub struct YarnData {
    pub format: Format,
    pub yarns: Yarns,
    pub frames: Option<YarnFrames>,
    pub units: (Units, Provenance),
    pub up_axis: (UpAxis, Provenance),
    pub radius: Provenance,
    pub notes: Vec<String>,
}

impl YarnData {
    /// What the read assumed instead of reading it from the file or an
    /// option: `unit m`, `up axis +y`.
    pub fn assumed(&self) -> Vec<String> {
        assumed_names(self.units, self.up_axis)
    }

    /// A warning when the yarns' size is implausible for clothing and the
    /// unit or up axis was assumed ([`crate::geom::garment_size_warning`]).
    pub fn size_warning(&self) -> Option<String> {
        let b = self.yarns.bounds()?;
        crate::geom::garment_size_warning(&b, self.units.0, &self.assumed())
    }
}

/// The names of the assumed ones of a read's unit and up axis.
pub fn assumed_names(units: (Units, Provenance), up_axis: (UpAxis, Provenance)) -> Vec<String> {
    let mut out = Vec::new();
    if units.1 == Provenance::Assumed {
        out.push(format!("unit {}", units.0));
    }
    if up_axis.1 == Provenance::Assumed {
        out.push(format!("up axis {}", up_axis.0));
    }
    out
}

/// Loads resources a file refers to by URI (glTF external buffers).
pub trait Resources {
    /// The bytes of `uri`: exactly `declared` bytes (a resource holding fewer
    /// is an error; more are never read).
    fn load(&self, uri: &str, declared: u64) -> Result<Vec<u8>, String>;
}

/// No external resources: every external reference is an error.
pub struct NoResources;

impl Resources for NoResources {
    fn load(&self, uri: &str, _declared: u64) -> Result<Vec<u8>, String> {
        Err(format!(
            "external resource '{}' cannot be loaded when parsing from bytes alone",
            crate::geom::excerpt(uri)
        ))
    }
}

/// Resources inside a directory (the directory of the referring file), read
/// through [`confined::read_confined`]: no absolute paths, schemes, escapes
/// from the folder (`..`, symlinks), FIFOs or devices.
pub struct DirResources(pub PathBuf);

impl Resources for DirResources {
    fn load(&self, uri: &str, declared: u64) -> Result<Vec<u8>, String> {
        confined::read_confined(&self.0, uri, declared, declared)
    }
}

/// Decodes the bytes of one file of `format` (no frame sequences, no unit conversion).
pub fn decode(
    format: Format,
    data: &[u8],
    opts: &ReadOptions,
    res: &dyn Resources,
) -> Result<Decoded, FormatError> {
    match format {
        Format::Bcc => bcc::decode(data, opts),
        Format::Obj => obj::decode(data, opts),
        Format::Poly => poly::decode(data, opts),
        Format::Pyp => pyp::decode(data, opts),
        Format::Gltf | Format::Glb => gltf::decode(data, opts, res),
        Format::Ply => ply::decode(data, opts),
        Format::Hdf5 => h5::decode(data, opts),
    }
}

/// Converts a decoded file into knitvox's frame (metres, +Y up), fills radii, validates.
pub fn finish(format: Format, mut d: Decoded, opts: &ReadOptions) -> Result<YarnData, GeomError> {
    let units = match (opts.units, d.units) {
        (Some(u), _) => (u, Provenance::Option),
        (None, Some(u)) => (u, Provenance::File),
        (None, None) => (Units::METRES, Provenance::Assumed),
    };
    let up = match (opts.up_axis, d.up_axis) {
        (Some(a), _) => (a, Provenance::Option),
        (None, Some(a)) => (a, Provenance::File),
        (None, None) => (UpAxis::Y, Provenance::Assumed),
    };
    d.yarns.file_to_internal(units.0, up.0);
    if let Some(f) = &mut d.frames {
        f.file_to_internal(units.0, up.0);
    }
    let radius = if d.radius_in_file && !opts.override_radius {
        Provenance::File
    } else {
        d.yarns.radius.iter_mut().for_each(|r| *r = opts.radius);
        d.yarns.vertex_radius = None;
        if opts.override_radius {
            Provenance::Option
        } else {
            Provenance::Assumed
        }
    };
    d.yarns.validate()?;
    if let Some(f) = &d.frames {
        f.validate()?;
    }
    Ok(YarnData {
        format,
        yarns: d.yarns,
        frames: d.frames,
        units,
        up_axis: up,
        radius,
        notes: d.notes,
    })
}

/// The format of `path`, or an error naming it.
pub fn format_of(path: &Path) -> Result<Format, IoError> {
    Format::from_path(path).ok_or_else(|| IoError::UnknownFormat {
        path: path.to_path_buf(),
        ext: path
            .extension()
            .map(|e| e.to_string_lossy().into_owned())
            .unwrap_or_default(),
    })
}

/// Reads one yarn file, or a frame sequence when the path holds a `#` run
/// (`name.####.ply`: every existing frame file, in frame order, becomes a frame).
pub fn read_path(path: &Path, opts: &ReadOptions) -> Result<YarnData, IoError> {
    if sequence::is_pattern(path) {
        return sequence::read_sequence(path, opts);
    }
    read_single(path, opts)
}

/// Reads one file (never a sequence).
pub fn read_single(path: &Path, opts: &ReadOptions) -> Result<YarnData, IoError> {
    let format = format_of(path)?;
    let decoded = if format == Format::Hdf5 {
        h5::read_file(path, opts)?
    } else {
        let data = std::fs::read(path).map_err(|source| IoError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
        decode(format, &data, opts, &DirResources(dir)).map_err(|source| IoError::Format {
            path: path.to_path_buf(),
            format,
            source,
        })?
    };
    finish(format, decoded, opts).map_err(|source| IoError::Invalid {
        path: path.to_path_buf(),
        format,
        source,
    })
}

/// Options for writing yarn files.
#[derive(Debug, Clone, PartialEq)]
pub struct WriteOptions {
    /// Unit of the written coordinates for unitless formats (bcc, obj, ply). Default metres.
    /// glTF and HDF5 are always metres.
    pub units: Units,
    /// Up axis of the written coordinates for bcc, obj, ply. Default +Y.
    /// glTF and HDF5 are always +Y up.
    pub up_axis: UpAxis,
    /// First frame number of a written sequence (`name.####.ext`). Default 1.
    pub first_frame: i64,
}

impl Default for WriteOptions {
    fn default() -> Self {
        WriteOptions {
            units: Units::METRES,
            up_axis: UpAxis::Y,
            first_frame: 1,
        }
    }
}

impl WriteOptions {
    /// The unit and axis actually used for `format` (fixed by spec for glTF and HDF5).
    pub fn frame_for(&self, format: Format) -> (Units, UpAxis) {
        match format {
            Format::Gltf | Format::Glb | Format::Hdf5 => (Units::METRES, UpAxis::Y),
            _ => (self.units, self.up_axis),
        }
    }
}

/// Encodes one set of curves (in knitvox's frame) as the bytes of one file.
/// HDF5 is written through [`h5::write_file`] instead (libhdf5 writes files).
pub fn encode(format: Format, yarns: &Yarns, opts: &WriteOptions) -> Result<Vec<u8>, FormatError> {
    let (units, up) = opts.frame_for(format);
    let mut y = yarns.clone();
    y.internal_to_file(units, up);
    match format {
        Format::Bcc => bcc::encode(&y, up),
        Format::Obj => obj::encode(&y, units, up),
        Format::Ply => ply::encode_in(&y, units, up),
        Format::Gltf => gltf::encode(&y, false),
        Format::Glb => gltf::encode(&y, true),
        Format::Poly | Format::Pyp | Format::Hdf5 => Err(FormatError::whole_file(format!(
            "knitvox does not write {format} as bytes"
        ))),
    }
}

/// Writes yarns (and frames, if any) to `path` atomically.
///
/// * HDF5: one file with the rest yarns and all frames.
/// * A path with a `#` run (`out.####.ply`): one file per frame (or the rest
///   yarns as frame `first_frame` when there are no frames).
/// * Otherwise: the rest yarns (frames are not written; use a sequence or HDF5).
///
/// Returns the paths written.
pub fn write_path(
    path: &Path,
    yarns: &Yarns,
    frames: Option<&YarnFrames>,
    opts: &WriteOptions,
) -> Result<Vec<PathBuf>, IoError> {
    let format = format_of(path)?;
    if !format.is_writable() {
        return Err(IoError::Unsupported {
            path: path.to_path_buf(),
            message: format!("knitvox reads {format} but does not write it; write bcc, obj, ply, gltf, glb or h5"),
        });
    }
    if format == Format::Hdf5 {
        if sequence::is_pattern(path) {
            return Err(IoError::Unsupported {
                path: path.to_path_buf(),
                message: "an HDF5 file holds every frame itself; drop the '#' frame pattern".into(),
            });
        }
        h5::write_file(path, yarns, frames)?;
        return Ok(vec![path.to_path_buf()]);
    }
    if sequence::is_pattern(path) {
        return sequence::write_sequence(path, format, yarns, frames, opts);
    }
    let bytes = encode(format, yarns, opts).map_err(|source| IoError::Format {
        path: path.to_path_buf(),
        format,
        source,
    })?;
    atomic::write_bytes(path, &bytes)?;
    Ok(vec![path.to_path_buf()])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn formats_from_extensions() {
        assert_eq!(Format::from_path(Path::new("a/b.BCC")), Some(Format::Bcc));
        assert_eq!(Format::from_path(Path::new("x.hdf5")), Some(Format::Hdf5));
        assert_eq!(
            Format::from_path(Path::new("x.0001.glb")),
            Some(Format::Glb)
        );
        assert_eq!(Format::from_path(Path::new("x.txt")), None);
        assert_eq!(Format::from_path(Path::new("noext")), None);
    }
}
