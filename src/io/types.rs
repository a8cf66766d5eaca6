//! The types every format module shares: formats, read and write options,
//! decoded yarns and where their units came from, external resources, and
//! the process-wide memory budget of readers.

use std::fmt;
use std::path::{Path, PathBuf};

use super::confined;

use crate::geom::{Units, UpAxis, Weld, YarnFrames, Yarns, DEFAULT_RADIUS_M};

/// Largest number of points a reader accepts by default (2^31): beyond every real garment,
/// well below what would exhaust memory.
pub const DEFAULT_MAX_POINTS: u64 = 1 << 31;

/// Default memory budget of a read (bytes): 2 GiB. The binary replaces it
/// with `--max-memory` (default an eighth of the physical memory, at most
/// this) through [`set_max_memory`].
pub const DEFAULT_MAX_MEMORY: u64 = 2 << 30;

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

/// Most repeats of a periodic tile along one period ([`ReadOptions::tile`]).
pub const MAX_TILE_REPEATS: usize = 10_000;

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
    /// unless the binary set `--max-memory`, default an eighth of the physical memory, at most 2 GiB).
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
    /// How the file's points map onto `yarns`' (repeated points welded,
    /// [`crate::geom::Yarns::weld`]): per-vertex data of the file, such as
    /// forces stored beside its frames, goes through it.
    pub weld: Weld,
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

    /// A warning when the yarn radii are implausible for knitting yarn
    /// ([`crate::geom::yarn_radius_warning`]): a file's radii read in the
    /// wrong unit, or a radius option given in millimetres.
    pub fn radius_warning(&self) -> Option<String> {
        let y = &self.yarns;
        let radii = y.vertex_radius.as_ref().unwrap_or(&y.radius);
        if radii.is_empty() {
            return None;
        }
        let min = radii.iter().copied().fold(f64::INFINITY, f64::min);
        let max = radii.iter().copied().fold(0.0, f64::max);
        crate::geom::yarn_radius_warning(min, max, self.units.0, self.radius == Provenance::File)
    }

    /// The size and radius warnings of the read, in that order.
    pub fn warnings(&self) -> Vec<String> {
        self.size_warning()
            .into_iter()
            .chain(self.radius_warning())
            .collect()
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

/// Why a resource a file refers to could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum ResourceError {
    /// The file is parsed from bytes alone: there is nowhere to load `uri`
    /// (cut to an excerpt) from.
    #[error("external resource '{uri}' cannot be loaded when parsing from bytes alone")]
    Unavailable { uri: String },
    /// The read of the resource from the file's folder was refused or failed.
    #[error(transparent)]
    Confined(#[from] confined::ConfinedError),
}

/// Loads resources a file refers to by URI (glTF external buffers).
pub trait Resources {
    /// The bytes of `uri`: exactly `declared` bytes (a resource holding fewer
    /// is an error; more are never read).
    fn load(&self, uri: &str, declared: u64) -> Result<Vec<u8>, ResourceError>;
}

/// No external resources: every external reference is an error.
pub struct NoResources;

impl Resources for NoResources {
    fn load(&self, uri: &str, _declared: u64) -> Result<Vec<u8>, ResourceError> {
        Err(ResourceError::Unavailable {
            uri: crate::geom::excerpt(uri),
        })
    }
}

/// Resources inside a directory (the directory of the referring file), read
/// through [`confined::read_confined`]: no absolute paths, schemes, escapes
/// from the folder (`..`, symlinks), FIFOs or devices.
pub struct DirResources(pub PathBuf);

impl Resources for DirResources {
    fn load(&self, uri: &str, declared: u64) -> Result<Vec<u8>, ResourceError> {
        Ok(confined::read_confined(&self.0, uri, declared, declared)?)
    }
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
