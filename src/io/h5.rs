//! knitvox HDF5 yarns and frames (the layout is documented in `schemas/yarns-hdf5.md`).
//!
//! libhdf5 reads and writes files, not byte slices, so this module differs a
//! little from the other formats:
//!
//! * [`read_file`] opens the path with libhdf5 (so a file that another process
//!   is writing is reported as [`IoError::Busy`], not as corrupt);
//! * [`decode`] opens the bytes as an in-memory *file image* (core driver,
//!   `H5Pset_file_image`): the same validation, no temporary file;
//! * [`write_file`] writes a whole file atomically, and [`FrameWriter`] streams
//!   frames one at a time into a dot-prefixed temporary file that is renamed
//!   onto the target by [`FrameWriter::finish`];
//! * [`read_frame`] reads one frame without loading the others;
//! * [`list_datasets`] and [`read_dataset_f64`] inspect any HDF5 file.
//!
//! Every dataset's rank, shape and type class is checked before it is read,
//! and sizes are checked against `ReadOptions::max_points` and against the
//! bytes the file actually stores, so a hostile file cannot make the reader
//! allocate more than it can justify.

use std::ffi::CString;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use hdf5::types::{FixedAscii, FixedUnicode, TypeDescriptor, VarLenAscii, VarLenUnicode};
use hdf5::{Dataset, Extent, Group, LinkType, LocationType};

use super::{Decoded, Format, FormatError, IoError, ReadOptions};
use crate::geom::{RestShape, Units, UpAxis, Vec3, YarnFrames, YarnMaterial, Yarns};

/// Value of the root attribute `knitvox_format` in a yarns file.
pub const FORMAT_NAME: &str = "yarns";
/// Layout version written in the root attribute `knitvox_format_version`;
/// readers refuse files with a larger version.
pub const FORMAT_VERSION: i64 = 1;
/// gzip level of `/frames/points` (with the shuffle filter before it).
pub const FRAME_DEFLATE_LEVEL: u8 = 4;
/// Largest number of vertices in one chunk of `/frames/points`. A frame of up
/// to this many vertices is exactly one chunk; beyond it (never for a real
/// garment) a frame spans several chunks so a chunk stays under libhdf5's
/// 4 GiB chunk limit.
pub const MAX_CHUNK_VERTICES: usize = 1 << 24;
/// Most elements [`read_dataset_f64`] reads from one dataset (2 GiB of f64).
pub const MAX_INSPECT_ELEMENTS: u64 = 1 << 28;
/// Most datasets and groups [`list_datasets`] visits (guards link cycles).
pub const MAX_LISTED_OBJECTS: usize = 100_000;

/// gzip cannot shrink data by more than about 1032:1; a compressed dataset that
/// claims more than this many times its stored bytes is lying about its size.
const MAX_COMPRESSION_RATIO: u64 = 1100;
/// A dataset declaring more than this many bytes (64 MiB) is held to the
/// compression-bomb rules below before it is read.
pub const BOMB_MIN_BYTES: u64 = 64 << 20;
/// Such a dataset, compressed, declaring more than this many times the bytes
/// it stores is refused as a likely compression bomb: real curves and frames
/// compress by a few times, not a thousand.
pub const BOMB_RATIO: u64 = 1000;
/// Chunk length of the resizable `/frames/times` dataset.
const TIMES_CHUNK: usize = 1024;
/// Deepest group nesting [`list_datasets`] follows.
const MAX_LIST_DEPTH: usize = 32;

const WRITE_FLAG_MESSAGE: &str =
    "the file is marked as being written by another process (its HDF5 \
'open for write' consistency flag is set): wait for the writer to finish; if no writer is running, \
the file was not closed cleanly and `h5clear -s FILE` clears the flag";
const LOCK_MESSAGE: &str =
    "another process holds a lock on the file (it is being written): retry when \
it is done; on file systems without working locks (some NFS) set HDF5_USE_FILE_LOCKING=FALSE";

// ---------------------------------------------------------------------------
// Opening files and images
// ---------------------------------------------------------------------------

/// Why a file could not be opened.
enum OpenError {
    /// Another process is writing it (write flag set, or lock held).
    Busy(String),
    /// The content is not a readable HDF5 file.
    Format(FormatError),
}

/// Every description on a libhdf5 error stack, outermost first.
fn error_frames(e: &hdf5::Error) -> Vec<String> {
    match e {
        hdf5::Error::HDF5(stack) => match stack.clone().expand() {
            Ok(s) => s
                .iter()
                .map(|f| f.description().trim().to_string())
                .collect(),
            Err(_) => vec![e.to_string()],
        },
        hdf5::Error::Internal(s) => vec![s.clone()],
    }
}

/// One readable line for a libhdf5 error: the innermost (root-cause) frame,
/// with the function prefix (`H5F__super_read(): `) removed.
pub(crate) fn h5_message(e: &hdf5::Error) -> String {
    let frames = error_frames(e);
    let deepest = frames.last().cloned().unwrap_or_else(|| e.to_string());
    let msg = match deepest.find("(): ") {
        Some(i) => deepest[i + 4..].to_string(),
        None => deepest,
    };
    // libhdf5 puts a newline inside some messages (ctime output).
    msg.split_whitespace().collect::<Vec<_>>().join(" ")
}

fn classify_open_error(e: &hdf5::Error) -> OpenError {
    let all = error_frames(e).join("; ").to_ascii_lowercase();
    if all.contains("already open for write") || all.contains("consistency flag") {
        OpenError::Busy(WRITE_FLAG_MESSAGE.into())
    } else if all.contains("unable to lock") || all.contains("lock the file") {
        OpenError::Busy(LOCK_MESSAGE.into())
    } else if all.contains("file signature not found") {
        OpenError::Format(FormatError::whole_file(
            "not an HDF5 file: no HDF5 signature found (another format, or truncated before the superblock)",
        ))
    } else if all.contains("truncated file") {
        OpenError::Format(FormatError::whole_file(format!(
            "truncated HDF5 file ({})",
            h5_message(e)
        )))
    } else {
        OpenError::Format(FormatError::whole_file(format!(
            "libhdf5 cannot open it: {}",
            h5_message(e)
        )))
    }
}

fn busy(path: &Path, message: String) -> IoError {
    IoError::Busy {
        path: path.to_path_buf(),
        message,
    }
}

pub(crate) fn format_err(path: &Path, source: FormatError) -> IoError {
    IoError::Format {
        path: path.to_path_buf(),
        format: Format::Hdf5,
        source,
    }
}

pub(crate) fn write_err(path: &Path, source: impl Into<std::io::Error>) -> IoError {
    IoError::Write {
        path: path.to_path_buf(),
        source: source.into(),
    }
}

pub(crate) fn invalid_input(message: String) -> std::io::Error {
    std::io::Error::new(std::io::ErrorKind::InvalidInput, message)
}

/// Opens `path` read-only, classifying failures (missing file, busy, not HDF5).
/// Datasets are read one by one, each checked against the memory budget, so
/// the file itself may be larger than the budget (a long frames file).
pub(crate) fn open_path(path: &Path) -> Result<hdf5::File, IoError> {
    open_path_within(path, "HDF5 file", None)
}

/// [`open_path`] for a file read whole (yarns, a character cache): refused
/// before libhdf5 sees it when it holds more than `max_bytes` bytes.
pub(crate) fn open_path_within(
    path: &Path,
    what: &'static str,
    max_bytes: Option<u64>,
) -> Result<hdf5::File, IoError> {
    // Let the OS report missing files and permissions first: clearer than
    // libhdf5's text. libhdf5 opens by path and would block on a FIFO, so it
    // only sees a path checked to be a regular file.
    let (_checked, len) = super::input::open_regular(path, what, max_bytes)?;
    if len == 0 {
        return Err(format_err(
            path,
            FormatError::whole_file("empty file (0 bytes): not an HDF5 file"),
        ));
    }
    hdf5::File::open(path).map_err(|e| match classify_open_error(&e) {
        OpenError::Busy(m) => busy(path, m),
        OpenError::Format(f) => format_err(path, f),
    })
}

/// The current libhdf5 error stack as an error (after a raw call failed).
fn last_h5_error() -> hdf5::Error {
    match hdf5::Error::query() {
        Ok(e) | Err(e) => e,
    }
}

/// Opens `data` as a read-only in-memory HDF5 file (core driver + file image;
/// libhdf5 copies the bytes).
fn open_image(data: &[u8]) -> Result<hdf5::File, OpenError> {
    use hdf5_sys::h5f::{H5Fopen, H5F_ACC_RDONLY};
    use hdf5_sys::h5p::{H5Pcreate, H5Pset_fapl_core, H5Pset_file_image};

    if data.is_empty() {
        return Err(OpenError::Format(FormatError::whole_file(
            "empty file (0 bytes): not an HDF5 file",
        )));
    }
    // The core driver treats two images with the same name as one open file,
    // so every image gets a name of its own.
    static IMAGE_COUNTER: AtomicU64 = AtomicU64::new(0);
    let n = IMAGE_COUNTER.fetch_add(1, Ordering::Relaxed);
    let name =
        CString::new(format!("knitvox-image-{}-{n}.h5", std::process::id())).map_err(|_| {
            OpenError::Format(FormatError::whole_file(
                "internal error naming the file image",
            ))
        })?;
    let opened: hdf5::Result<hdf5::File> = hdf5::sync::sync(|| unsafe {
        let fapl_id = H5Pcreate(*hdf5::globals::H5P_FILE_ACCESS);
        if fapl_id < 0 {
            return Err(last_h5_error());
        }
        // Owns fapl_id from here on and closes it on every path.
        let _fapl: hdf5::PropertyList = hdf5::from_id(fapl_id)?;
        if H5Pset_fapl_core(fapl_id, 1 << 16, 0) < 0 {
            return Err(last_h5_error());
        }
        if H5Pset_file_image(fapl_id, data.as_ptr() as *mut _, data.len()) < 0 {
            return Err(last_h5_error());
        }
        let id = H5Fopen(name.as_ptr(), H5F_ACC_RDONLY, fapl_id);
        if id < 0 {
            return Err(last_h5_error());
        }
        hdf5::from_id::<hdf5::File>(id)
    });
    opened.map_err(|e| match classify_open_error(&e) {
        OpenError::Busy(_) => OpenError::Format(FormatError::whole_file(
            "the file's HDF5 'open for write' consistency flag is set: it is being written by another \
             process, or its writer did not close it cleanly (`h5clear -s FILE` clears the flag if the \
             writer is dead)",
        )),
        other => other,
    })
}

// ---------------------------------------------------------------------------
// Type and shape checks
// ---------------------------------------------------------------------------

/// The class of an HDF5 datatype, as far as this module cares.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Kind {
    Int { signed: bool },
    Float,
    Enum,
    String,
    Other(&'static str),
}

#[derive(Debug, Clone, Copy)]
pub(crate) struct TypeInfo {
    pub(crate) kind: Kind,
    /// Bytes per element in the file.
    pub(crate) size: usize,
}

impl TypeInfo {
    pub(crate) fn describe(self) -> String {
        match self.kind {
            Kind::Int { signed: true } => format!("int{}", self.size * 8),
            Kind::Int { signed: false } => format!("uint{}", self.size * 8),
            Kind::Float => format!("float{}", self.size * 8),
            Kind::Enum => format!("enum ({} bytes)", self.size),
            Kind::String => "string".into(),
            Kind::Other(name) => name.into(),
        }
    }

    fn is_numeric(self) -> bool {
        matches!(self.kind, Kind::Int { .. } | Kind::Float)
    }
}

/// Classifies a datatype with raw libhdf5 calls (hdf5-metno's descriptor
/// cannot describe every type, e.g. float16 without its `f16` feature).
pub(crate) fn type_info(dt: &hdf5::Datatype) -> TypeInfo {
    use hdf5_sys::h5t::{H5T_class_t, H5T_sign_t, H5Tget_class, H5Tget_sign, H5Tget_size};
    hdf5::sync::sync(|| unsafe {
        let id = dt.id();
        let size = H5Tget_size(id);
        let kind = match H5Tget_class(id) {
            H5T_class_t::H5T_INTEGER => Kind::Int {
                signed: H5Tget_sign(id) == H5T_sign_t::H5T_SGN_2,
            },
            H5T_class_t::H5T_FLOAT => Kind::Float,
            H5T_class_t::H5T_ENUM => Kind::Enum,
            H5T_class_t::H5T_STRING => Kind::String,
            H5T_class_t::H5T_COMPOUND => Kind::Other("compound"),
            H5T_class_t::H5T_ARRAY => Kind::Other("array"),
            H5T_class_t::H5T_VLEN => Kind::Other("variable-length sequence"),
            H5T_class_t::H5T_REFERENCE => Kind::Other("reference"),
            H5T_class_t::H5T_OPAQUE => Kind::Other("opaque"),
            H5T_class_t::H5T_BITFIELD => Kind::Other("bitfield"),
            H5T_class_t::H5T_TIME => Kind::Other("time"),
            _ => Kind::Other("unknown type"),
        };
        TypeInfo { kind, size }
    })
}

/// Refuses an external link: its target lives in another file, which a
/// dropped file must not make knitvox open. Hard and soft
/// links (paths inside this file) are followed.
pub(crate) fn check_link(group: &Group, name: &str, loc: &str) -> Result<(), FormatError> {
    let mut kind = None;
    group
        .iter_visit_default(|n, info| {
            if n == name {
                kind = Some(info.link_type);
            }
            Ok(())
        })
        .map_err(|e| loc_err(loc, &e))?;
    match kind {
        Some(LinkType::External) => Err(FormatError::at_path(
            loc,
            "is an external link to another file; knitvox reads only what the file itself holds",
        )),
        _ => Ok(()),
    }
}

/// Refuses datasets whose data lives in other files: external storage
/// (raw data in named files) and virtual datasets (mapped from other
/// datasets, possibly in other files). Every HDF5 reader opens datasets
/// through [`Ds::open`], which calls this.
pub(crate) fn check_storage(ds: &Dataset, loc: &str) -> Result<(), FormatError> {
    let dcpl = ds.create_plist().map_err(|e| loc_err(loc, &e))?;
    if dcpl.layout() == hdf5::dataset::Layout::Virtual {
        return Err(FormatError::at_path(
            loc,
            "is a virtual dataset (its data is mapped from other datasets or files); knitvox reads only data stored in the file",
        ));
    }
    let external = dcpl.get_external().map_err(|e| loc_err(loc, &e))?;
    if let Some(first) = external.first() {
        return Err(FormatError::at_path(
            loc,
            format!(
                "stores its data in {} external file(s) ('{}'...); knitvox reads only data stored in the file",
                external.len(),
                crate::geom::excerpt(&first.name)
            ),
        ));
    }
    Ok(())
}

pub(crate) fn loc_err(loc: &str, e: &hdf5::Error) -> FormatError {
    FormatError::at_path(loc, format!("libhdf5 cannot read it: {}", h5_message(e)))
}

/// Refuses a dataset at `loc` whose whole read would take `needed` bytes
/// (over [`BOMB_MIN_BYTES`]) from far fewer stored: compressed at more than
/// [`BOMB_RATIO`] to one, or chunked with chunks missing from the file
/// (libhdf5 makes them up from the fill value, so a few stored bytes can
/// declare gigabytes).
pub(crate) fn check_bomb(ds: &Dataset, loc: &str, needed: u64) -> Result<(), FormatError> {
    if needed <= BOMB_MIN_BYTES {
        return Ok(());
    }
    let stored = ds.storage_size();
    if !ds.filters().is_empty() && needed > stored.saturating_mul(BOMB_RATIO) {
        return Err(FormatError::at_path(
            loc,
            format!(
                "declares {needed} bytes stored compressed in {stored} bytes, more than {BOMB_RATIO} to one: \
                 refused as a likely compression bomb (datasets over {BOMB_MIN_BYTES} bytes may not exceed that ratio)"
            ),
        ));
    }
    if let (Some(chunk), Some(allocated)) = (ds.chunk(), ds.num_chunks()) {
        let shape = ds.shape();
        let total = shape
            .iter()
            .zip(&chunk)
            .map(|(&s, &c)| s.div_ceil(c.max(1)) as u64)
            .fold(1u64, u64::saturating_mul);
        if (allocated as u64) < total {
            return Err(FormatError::at_path(
                loc,
                format!(
                    "declares {needed} bytes in {total} chunks of which the file stores only {allocated}: \
                     refused as a likely compression bomb (the missing chunks would be made up from the fill value)"
                ),
            ));
        }
    }
    Ok(())
}

thread_local! {
    /// The budget of the whole-file read running on this thread
    /// ([`whole_file_budget`]), and the bytes each dataset it guarded
    /// declared.
    static FILE_LEDGER: std::cell::RefCell<Option<FileLedger>> =
        const { std::cell::RefCell::new(None) };
}

struct FileLedger {
    budget: u64,
    charged: std::collections::BTreeMap<String, u64>,
}

/// While alive, every dataset guarded on this thread ([`Ds::guard_declared`])
/// counts against one budget together: a file read whole (yarns, an asset,
/// a character cache) may not hold more than the budget in all its datasets,
/// each within it but together far beyond (measured: a 3.6 MB yarn file
/// whose points and radii each declared just under 2 GiB held 3.37 GiB).
/// A dataset guarded twice counts once, at its largest.
pub(crate) struct LedgerScope {
    previous: Option<FileLedger>,
}

impl Drop for LedgerScope {
    fn drop(&mut self) {
        let previous = self.previous.take();
        FILE_LEDGER.with(|l| *l.borrow_mut() = previous);
    }
}

/// Starts a whole-file read under `budget` bytes ([`LedgerScope`]).
pub(crate) fn whole_file_budget(budget: u64) -> LedgerScope {
    let previous = FILE_LEDGER.with(|l| {
        l.borrow_mut().replace(FileLedger {
            budget,
            charged: Default::default(),
        })
    });
    LedgerScope { previous }
}

/// Charges `bytes` for the dataset at `loc` to the running whole-file read,
/// if any; the error says how much the file's datasets declare together.
fn charge(loc: &str, bytes: u64) -> Result<(), String> {
    FILE_LEDGER.with(|l| {
        let mut l = l.borrow_mut();
        let Some(ledger) = l.as_mut() else {
            return Ok(());
        };
        let before = ledger.charged.get(loc).copied().unwrap_or(0);
        let total: u64 = ledger
            .charged
            .values()
            .fold(0u64, |a, b| a.saturating_add(*b))
            .saturating_sub(before)
            .saturating_add(bytes.max(before));
        if total > ledger.budget {
            return Err(format!(
                "with the datasets read before it the file declares {total} bytes, more than the memory budget of {} bytes (--max-memory)",
                ledger.budget
            ));
        }
        ledger.charged.insert(loc.to_string(), bytes.max(before));
        Ok(())
    })
}

/// A dataset's shape, type, and read helpers with its path for errors.
pub(crate) struct Ds {
    pub(crate) ds: Dataset,
    pub(crate) loc: String,
    pub(crate) shape: Vec<usize>,
    pub(crate) ty: TypeInfo,
    /// Memory budget (bytes) for reading it, see [`ReadOptions::max_memory`].
    pub(crate) budget: u64,
}

impl Ds {
    pub(crate) fn open(
        group: &Group,
        group_path: &str,
        name: &str,
        required: bool,
    ) -> Result<Option<Ds>, FormatError> {
        let loc = format!("{}/{name}", group_path.trim_end_matches('/'));
        if !group.link_exists(name) {
            return if required {
                Err(FormatError::at_path(&loc, "required dataset is missing"))
            } else {
                Ok(None)
            };
        }
        match group.loc_type_by_name(name) {
            Ok(LocationType::Dataset) => {}
            Ok(other) => {
                return Err(FormatError::at_path(
                    &loc,
                    format!("expected a dataset, found a {other:?}").to_lowercase(),
                ))
            }
            Err(e) => return Err(loc_err(&loc, &e)),
        }
        check_link(group, name, &loc)?;
        let ds = group.dataset(name).map_err(|e| loc_err(&loc, &e))?;
        check_storage(&ds, &loc)?;
        let space = ds.space().map_err(|e| loc_err(&loc, &e))?;
        let shape = space.shape();
        let ty = type_info(&ds.dtype().map_err(|e| loc_err(&loc, &e))?);
        Ok(Some(Ds {
            ds,
            loc,
            shape,
            ty,
            budget: super::max_memory(),
        }))
    }

    /// The same dataset read under the memory budget `bytes`.
    pub(crate) fn with_budget(mut self, bytes: u64) -> Ds {
        self.budget = bytes;
        self
    }

    pub(crate) fn err(&self, message: impl Into<String>) -> FormatError {
        FormatError::at_path(&self.loc, message)
    }

    /// Checks the rank and the fixed extents (`None` = any length).
    pub(crate) fn expect_shape(
        &self,
        expected: &[Option<usize>],
        what: &str,
    ) -> Result<(), FormatError> {
        let ok = self.shape.len() == expected.len()
            && self
                .shape
                .iter()
                .zip(expected)
                .all(|(s, e)| e.is_none_or(|e| e == *s));
        if ok {
            Ok(())
        } else {
            Err(self.err(format!("shape {:?}, expected {what}", self.shape)))
        }
    }

    pub(crate) fn expect_float(&self) -> Result<(), FormatError> {
        match self.ty.kind {
            Kind::Float => Ok(()),
            _ => Err(self.err(format!(
                "type {}, expected floating point (float64)",
                self.ty.describe()
            ))),
        }
    }

    pub(crate) fn len(&self) -> usize {
        self.shape.first().copied().unwrap_or(0)
    }

    /// Refuses to read `elems` elements when the file does not store enough
    /// bytes to hold them (uncompressed) or to plausibly expand into them (compressed).
    pub(crate) fn guard_storage(&self, elems: usize) -> Result<(), FormatError> {
        self.guard_declared(elems)?;
        // Within the budget, but still far more than the file can justify.
        let needed = (elems as u64).saturating_mul(self.ty.size as u64);
        check_bomb(&self.ds, &self.loc, needed)
    }

    /// [`Ds::guard_storage`] without the compression-bomb rules (a reader
    /// that checks several datasets together applies them last).
    pub(crate) fn guard_declared(&self, elems: usize) -> Result<(), FormatError> {
        let needed = (elems as u64).saturating_mul(self.ty.size as u64);
        if needed == 0 {
            return Ok(());
        }
        let stored = self.ds.storage_size();
        let filtered = !self.ds.filters().is_empty();
        let justified = if filtered {
            stored.saturating_mul(MAX_COMPRESSION_RATIO)
        } else {
            stored
        };
        if needed > justified {
            return Err(self.err(format!(
                "declares {elems} values ({needed} bytes) but the file stores only {stored} bytes for it{}",
                if filtered { " (compressed)" } else { "" }
            )));
        }
        if needed > self.budget {
            return Err(self.err(format!(
                "declares {elems} values ({needed} bytes), more than the memory budget of {} bytes (--max-memory)",
                self.budget
            )));
        }
        charge(&self.loc, needed).map_err(|m| self.err(m))
    }

    pub(crate) fn read_f64_into(&self, buf: &mut [f64]) -> Result<(), FormatError> {
        if buf.is_empty() {
            return Ok(());
        }
        self.guard_storage(buf.len())?;
        self.ds
            .read_into_raw(buf)
            .map(|_| ())
            .map_err(|e| loc_err(&self.loc, &e))
    }

    pub(crate) fn read_f64(&self, elems: usize) -> Result<Vec<f64>, FormatError> {
        self.guard_storage(elems)?;
        let mut v = vec![0.0; elems];
        self.read_f64_into(&mut v)?;
        Ok(v)
    }

    /// Reads a 1-D integer dataset as u64, refusing negative values.
    pub(crate) fn read_index(&self, elems: usize) -> Result<Vec<u64>, FormatError> {
        if elems == 0 {
            return Ok(Vec::new());
        }
        self.guard_storage(elems)?;
        match self.ty.kind {
            Kind::Int { signed: true } => {
                let v: Vec<i64> = self.ds.read_raw().map_err(|e| loc_err(&self.loc, &e))?;
                v.into_iter()
                    .enumerate()
                    .map(|(i, x)| {
                        u64::try_from(x)
                            .map_err(|_| self.err(format!("entry {i} is negative ({x})")))
                    })
                    .collect()
            }
            Kind::Int { signed: false } => self.ds.read_raw().map_err(|e| loc_err(&self.loc, &e)),
            _ => Err(self.err(format!("type {}, expected integers", self.ty.describe()))),
        }
    }
}

// ---------------------------------------------------------------------------
// Attributes
// ---------------------------------------------------------------------------

pub(crate) fn attr_loc(owner: &str, name: &str) -> String {
    format!("{}@{name}", if owner.is_empty() { "/" } else { owner })
}

/// A string attribute (variable- or fixed-length, ASCII or UTF-8), if present.
pub(crate) fn read_str_attr(
    obj: &hdf5::Location,
    owner: &str,
    name: &str,
) -> Result<Option<String>, FormatError> {
    let loc = attr_loc(owner, name);
    let names = obj.attr_names().map_err(|e| loc_err(owner, &e))?;
    if !names.iter().any(|n| n == name) {
        return Ok(None);
    }
    let attr = obj.attr(name).map_err(|e| loc_err(&loc, &e))?;
    if attr.size() != 1 {
        return Err(FormatError::at_path(
            &loc,
            format!("expected one string, found shape {:?}", attr.shape()),
        ));
    }
    let desc = attr
        .dtype()
        .and_then(|d| d.to_descriptor())
        .map_err(|e| loc_err(&loc, &e))?;
    let read = match desc {
        TypeDescriptor::VarLenUnicode => attr
            .read_raw::<VarLenUnicode>()
            .map(|v| v[0].as_str().to_string()),
        TypeDescriptor::VarLenAscii => attr
            .read_raw::<VarLenAscii>()
            .map(|v| v[0].as_str().to_string()),
        TypeDescriptor::FixedAscii(n) if n <= 256 => attr
            .read_raw::<FixedAscii<256>>()
            .map(|v| v[0].as_str().to_string()),
        TypeDescriptor::FixedUnicode(n) if n <= 256 => attr
            .read_raw::<FixedUnicode<256>>()
            .map(|v| v[0].as_str().to_string()),
        other => {
            return Err(FormatError::at_path(
                &loc,
                format!("type {other}, expected a short string"),
            ))
        }
    };
    read.map(Some).map_err(|e| loc_err(&loc, &e))
}

/// An integer attribute, if present.
pub(crate) fn read_int_attr(
    obj: &hdf5::Location,
    owner: &str,
    name: &str,
) -> Result<Option<i64>, FormatError> {
    let loc = attr_loc(owner, name);
    let names = obj.attr_names().map_err(|e| loc_err(owner, &e))?;
    if !names.iter().any(|n| n == name) {
        return Ok(None);
    }
    let attr = obj.attr(name).map_err(|e| loc_err(&loc, &e))?;
    let ty = type_info(&attr.dtype().map_err(|e| loc_err(&loc, &e))?);
    if attr.size() != 1 || !matches!(ty.kind, Kind::Int { .. }) {
        return Err(FormatError::at_path(
            &loc,
            format!(
                "expected one integer, found {} of shape {:?}",
                ty.describe(),
                attr.shape()
            ),
        ));
    }
    let v: Vec<i64> = attr.read_raw().map_err(|e| loc_err(&loc, &e))?;
    Ok(v.first().copied())
}

/// A scalar floating-point attribute, if present.
pub(crate) fn read_float_attr(
    obj: &hdf5::Location,
    owner: &str,
    name: &str,
) -> Result<Option<f64>, FormatError> {
    let loc = attr_loc(owner, name);
    let names = obj.attr_names().map_err(|e| loc_err(owner, &e))?;
    if !names.iter().any(|n| n == name) {
        return Ok(None);
    }
    let attr = obj.attr(name).map_err(|e| loc_err(&loc, &e))?;
    let ty = type_info(&attr.dtype().map_err(|e| loc_err(&loc, &e))?);
    if attr.size() != 1 || !matches!(ty.kind, Kind::Float) {
        return Err(FormatError::at_path(
            &loc,
            format!(
                "expected one floating-point number, found {} of shape {:?}",
                ty.describe(),
                attr.shape()
            ),
        ));
    }
    let v: Vec<f64> = attr.read_raw().map_err(|e| loc_err(&loc, &e))?;
    Ok(v.first().copied())
}

/// Writes an ASCII string attribute as a fixed-length string of exactly its
/// length. Fixed-length strings live in the (checksummed) object header;
/// variable-length ones live in libhdf5's global heap, which carries no
/// checksum and which libhdf5 trusts blindly when reading (a flipped byte
/// there can crash the reader).
pub(crate) fn write_str_attr(obj: &hdf5::Location, name: &str, value: &str) -> hdf5::Result<()> {
    const MAX: usize = 256;
    if value.len() > MAX {
        return Err(hdf5::Error::from(format!(
            "attribute {name}: longer than {MAX} bytes"
        )));
    }
    let v = FixedAscii::<MAX>::from_ascii(value.as_bytes())
        .map_err(|e| hdf5::Error::from(format!("attribute {name}: {e}")))?;
    let attr = obj
        .new_attr_builder()
        .empty_as(TypeDescriptor::FixedAscii(value.len().max(1)))
        .shape(())
        .create(name)?;
    attr.as_writer().write_scalar(&v)
}

// ---------------------------------------------------------------------------
// Reading
// ---------------------------------------------------------------------------

/// Decodes the bytes of a knitvox HDF5 yarns file (opened as an in-memory
/// file image). Coordinates stay in the file's declared units and axes.
pub fn decode(data: &[u8], opts: &ReadOptions) -> Result<Decoded, FormatError> {
    let file = match open_image(data) {
        Ok(f) => f,
        Err(OpenError::Format(e)) => return Err(e),
        Err(OpenError::Busy(m)) => return Err(FormatError::whole_file(m)),
    };
    decode_file(&file, opts)
}

/// Reads a knitvox HDF5 yarns file. A file that another process is writing
/// (write flag set, or locked) is [`IoError::Busy`]; content problems are
/// [`IoError::Format`] naming the dataset.
pub fn read_file(path: &Path, opts: &ReadOptions) -> Result<Decoded, IoError> {
    let file = open_path_within(path, "yarn file", Some(opts.max_memory))?;
    let _budget = whole_file_budget(opts.max_memory);
    decode_file(&file, opts).map_err(|e| format_err(path, e))
}

/// A short list of what the root group holds, for "not a knitvox file" errors.
pub(crate) fn describe_top_level(root: &Group) -> String {
    let names = match root.member_names() {
        Ok(n) => n,
        Err(e) => return format!("its top level cannot be listed: {}", h5_message(&e)),
    };
    if names.is_empty() {
        return "the file holds no groups or datasets".into();
    }
    const SHOWN: usize = 8;
    let mut items: Vec<String> = names
        .iter()
        .take(SHOWN)
        .map(|n| match root.loc_type_by_name(n) {
            Ok(LocationType::Group) => format!("group /{n}"),
            Ok(LocationType::Dataset) => format!("dataset /{n}"),
            _ => format!("/{n}"),
        })
        .collect();
    if names.len() > SHOWN {
        items.push(format!("and {} more", names.len() - SHOWN));
    }
    format!("its top level holds: {}", items.join(", "))
}

/// Checks the root's `knitvox_format` (must be `name` when present) and
/// `knitvox_format_version` (1 to `max_version`); returns notes naming the
/// version and the generator.
pub(crate) fn check_format_attrs(
    root: &Group,
    name: &str,
    max_version: i64,
) -> Result<Vec<String>, FormatError> {
    let mut notes = Vec::new();
    if let Some(kind) = read_str_attr(root, "", "knitvox_format")? {
        if kind != name {
            return Err(FormatError::at_path(
                attr_loc("", "knitvox_format"),
                format!(
                    "this is a knitvox '{}' file, not a '{name}' file",
                    crate::geom::excerpt(&kind)
                ),
            ));
        }
    }
    if let Some(v) = read_int_attr(root, "", "knitvox_format_version")? {
        if !(1..=max_version).contains(&v) {
            return Err(FormatError::at_path(
                attr_loc("", "knitvox_format_version"),
                format!("format version {v} is not supported (this build reads versions 1 to {max_version})"),
            ));
        }
        notes.push(format!("knitvox HDF5 {name} format version {v}"));
    }
    if let Some(g) = read_str_attr(root, "", "generator")? {
        notes.push(format!("generator: {}", crate::geom::excerpt(&g)));
    }
    Ok(notes)
}

/// The root's declared `units` and `up_axis` attributes (`None` when absent).
pub(crate) fn read_units_and_axis(
    root: &Group,
) -> Result<(Option<Units>, Option<UpAxis>), FormatError> {
    let parsed =
        |name: &str| -> Result<Option<String>, FormatError> { read_str_attr(root, "", name) };
    let units = match parsed("units")? {
        Some(u) => Some(
            u.parse::<Units>()
                .map_err(|e| FormatError::at_path(attr_loc("", "units"), e.to_string()))?,
        ),
        None => None,
    };
    let up_axis = match parsed("up_axis")? {
        Some(a) => Some(
            a.parse::<UpAxis>()
                .map_err(|e| FormatError::at_path(attr_loc("", "up_axis"), e.to_string()))?,
        ),
        None => None,
    };
    Ok((units, up_axis))
}

pub(crate) fn open_group(
    parent: &Group,
    name: &str,
    loc: &str,
) -> Result<Option<Group>, FormatError> {
    if !parent.link_exists(name) {
        return Ok(None);
    }
    check_link(parent, name, loc)?;
    match parent.loc_type_by_name(name) {
        Ok(LocationType::Group) => parent.group(name).map(Some).map_err(|e| loc_err(loc, &e)),
        Ok(other) => Err(FormatError::at_path(
            loc,
            format!("expected a group, found a {other:?}").to_lowercase(),
        )),
        Err(e) => Err(loc_err(loc, &e)),
    }
}

/// Reads `/frames/points` and `/frames/times` (positions stay in file units).
fn read_frames(g: &Group, n: usize, opts: &ReadOptions) -> Result<YarnFrames, FormatError> {
    let pts = Ds::open(g, "/frames", "points", true)?
        .ok_or_else(|| FormatError::at_path("/frames/points", "missing"))?
        .with_budget(opts.max_memory);
    pts.expect_shape(
        &[None, None, Some(3)],
        "F x N x 3 (frames x vertices x xyz)",
    )?;
    pts.expect_float()?;
    let (f, nv) = (pts.shape[0], pts.shape[1]);
    if nv != n {
        return Err(pts.err(format!(
            "frames have {nv} vertices but /yarns/points has {n}"
        )));
    }
    let total = f
        .checked_mul(n)
        .filter(|&t| t as u64 <= opts.max_points)
        .ok_or_else(|| {
            pts.err(format!(
                "{f} frames x {n} vertices exceeds the limit of {} positions (max_points)",
                opts.max_points
            ))
        })?;
    let times = Ds::open(g, "/frames", "times", true)?
        .ok_or_else(|| FormatError::at_path("/frames/times", "missing"))?;
    times.expect_shape(&[Some(f)], &format!("[{f}] (one time per frame)"))?;
    times.expect_float()?;
    let t = times.read_f64(f)?;
    if let Some((i, x)) = t.iter().enumerate().find(|(_, x)| !x.is_finite()) {
        return Err(times.err(format!("frame {i}: time {x} is not finite")));
    }
    pts.guard_storage(total.saturating_mul(3))?;
    let mut points = vec![[0.0; 3]; total];
    pts.read_f64_into(points.as_flattened_mut())?;
    if let Some(i) = points.iter().position(|p| !p.iter().all(|x| x.is_finite())) {
        let (fi, v) = (i / n.max(1), i % n.max(1));
        return Err(pts.err(format!(
            "frame {fi}, vertex {v}: coordinate {:?} is not finite",
            points[i]
        )));
    }
    Ok(YarnFrames {
        num_vertices: n,
        times: t,
        points,
    })
}

/// Reads and validates a yarns group (the layout of `/yarns`, see
/// schemas/yarns-hdf5.md) at `gp`; also used for the rest yarns of an asset
/// (io::vtkhdf). Returns the yarns and whether the radii came from the file.
pub(crate) fn read_yarns_group(
    yg: &Group,
    gp: &str,
    opts: &ReadOptions,
) -> Result<(Yarns, bool), FormatError> {
    // Points: N x 3 floats.
    let pts = Ds::open(yg, gp, "points", true)?
        .ok_or_else(|| FormatError::at_path(format!("{gp}/points"), "missing"))?
        .with_budget(opts.max_memory);
    pts.expect_shape(&[None, Some(3)], "N x 3 (vertices x xyz)")?;
    pts.expect_float()?;
    let n = pts.shape[0];
    if n as u64 > opts.max_points {
        return Err(pts.err(format!(
            "{n} points exceeds the limit of {} (max_points)",
            opts.max_points
        )));
    }

    // Offsets: C + 1 monotone integers from 0 to N, each curve >= 2 points.
    let off = Ds::open(yg, gp, "offsets", true)?
        .ok_or_else(|| FormatError::at_path(format!("{gp}/offsets"), "missing"))?;
    off.expect_shape(&[None], "[C + 1] (one offset per curve, plus the end)")?;
    let len = off.len();
    if len == 0 {
        return Err(off.err("empty: needs num_curves + 1 entries, starting with 0"));
    }
    // Checked before reading so the offsets cannot claim more memory than the points justify.
    if len > n + 1 {
        return Err(off.err(format!(
            "{} curves for {n} points: more curves than points",
            len - 1
        )));
    }
    let raw = off.read_index(len)?;
    if raw[0] != 0 {
        return Err(off.err(format!("must start at 0, starts at {}", raw[0])));
    }
    let mut offsets = Vec::with_capacity(len);
    for (c, w) in raw.windows(2).enumerate() {
        let (a, b) = (w[0], w[1]);
        if b < a {
            return Err(off.err(format!("offsets decrease at curve {c} ({a} then {b})")));
        }
        if b > n as u64 {
            return Err(off.err(format!("curve {c} ends at {b}, past the {n} points")));
        }
        if b - a < 2 {
            return Err(off.err(format!(
                "curve {c} has {} point(s); a yarn needs at least 2",
                b - a
            )));
        }
    }
    offsets.extend(raw.iter().map(|&o| o as usize)); // every entry <= n checked above
    if offsets[len - 1] != n {
        return Err(off.err(format!(
            "last offset is {}, expected the point count {n}",
            offsets[len - 1]
        )));
    }
    let c = len - 1;

    let mut points = vec![[0.0; 3]; n];
    pts.read_f64_into(points.as_flattened_mut())?;
    if let Some(v) = points.iter().position(|p| !p.iter().all(|x| x.is_finite())) {
        let curve = offsets.partition_point(|&o| o <= v) - 1;
        return Err(pts.err(format!(
            "vertex {v} (curve {curve}, point {}): coordinate {:?} is not finite",
            v - offsets[curve],
            points[v]
        )));
    }

    // Closed flags: C integers 0/1 (or h5py's boolean enum).
    let cl = Ds::open(yg, gp, "closed", true)?
        .ok_or_else(|| FormatError::at_path(format!("{gp}/closed"), "missing"))?;
    cl.expect_shape(&[Some(c)], &format!("[{c}] (one flag per curve)"))?;
    let flags: Vec<u64> = match cl.ty.kind {
        Kind::Int { .. } => cl.read_index(c)?,
        Kind::Enum if c == 0 => Vec::new(),
        Kind::Enum => {
            cl.guard_storage(c)?;
            let b: Vec<bool> = cl.ds.read_raw().map_err(|e| {
                cl.err(format!(
                    "enum flags are not a boolean (FALSE/TRUE) enum: {}",
                    h5_message(&e)
                ))
            })?;
            b.into_iter().map(u64::from).collect()
        }
        _ => return Err(cl.err(format!("type {}, expected uint8 flags", cl.ty.describe()))),
    };
    if let Some((i, v)) = flags.iter().enumerate().find(|(_, v)| **v > 1) {
        return Err(cl.err(format!(
            "curve {i}: flag {v}, expected 0 (open) or 1 (closed)"
        )));
    }
    let closed: Vec<bool> = flags.into_iter().map(|v| v == 1).collect();

    let positive = |ds: &Ds, v: &[f64], what: &str| -> Result<(), FormatError> {
        match v
            .iter()
            .enumerate()
            .find(|(_, r)| !(r.is_finite() && **r > 0.0))
        {
            Some((i, r)) => Err(ds.err(format!("{what} {i}: {r} is not a positive finite number"))),
            None => Ok(()),
        }
    };
    let vertex_radius = match Ds::open(yg, gp, "vertex_radius", false)? {
        Some(ds) => {
            ds.expect_shape(&[Some(n)], &format!("[{n}] (one radius per vertex)"))?;
            ds.expect_float()?;
            let v = ds.read_f64(n)?;
            positive(&ds, &v, "vertex")?;
            Some(v)
        }
        None => None,
    };
    let (radius, radius_in_file) = match Ds::open(yg, gp, "radius", false)? {
        Some(ds) => {
            ds.expect_shape(&[Some(c)], &format!("[{c}] (one radius per curve)"))?;
            ds.expect_float()?;
            let v = ds.read_f64(c)?;
            positive(&ds, &v, "curve")?;
            (v, true)
        }
        // Per-vertex radii without per-curve ones: the curve radius is their mean.
        None => match &vertex_radius {
            Some(vr) => {
                let r = (0..c)
                    .map(|k| {
                        let s = &vr[offsets[k]..offsets[k + 1]];
                        s.iter().sum::<f64>() / s.len() as f64
                    })
                    .collect();
                (r, true)
            }
            None => (vec![opts.radius; c], false),
        },
    };
    let linear_density = match Ds::open(yg, gp, "linear_density", false)? {
        Some(ds) => {
            ds.expect_shape(&[Some(c)], &format!("[{c}] (one density per curve)"))?;
            ds.expect_float()?;
            let v = ds.read_f64(c)?;
            if let Some((i, d)) = v
                .iter()
                .enumerate()
                .find(|(_, d)| !(d.is_finite() && **d >= 0.0))
            {
                return Err(ds.err(format!(
                    "curve {i}: {d} is not a non-negative finite number"
                )));
            }
            Some(v)
        }
        None => None,
    };

    let yarns = Yarns {
        points,
        offsets,
        closed,
        radius,
        vertex_radius,
        linear_density,
        rest: None,
    };
    let rest = match open_group(yg, "rest", &format!("{gp}/rest"))? {
        Some(rg) => Some(read_rest_group(&rg, &format!("{gp}/rest"), &yarns)?),
        None => None,
    };
    Ok((Yarns { rest, ..yarns }, radius_in_file))
}

/// Validates and reads an open knitvox yarns file.
fn decode_file(file: &hdf5::File, opts: &ReadOptions) -> Result<Decoded, FormatError> {
    let root: &Group = file;
    let yg = match open_group(root, "yarns", "/yarns")? {
        Some(g) => g,
        None => {
            return Err(FormatError::whole_file(format!(
                "not a knitvox yarns file: there is no /yarns group ({})",
                describe_top_level(root)
            )))
        }
    };
    let mut notes = check_format_attrs(root, FORMAT_NAME, FORMAT_VERSION)?;
    let (units, up_axis) = read_units_and_axis(root)?;

    let (yarns, radius_in_file) = read_yarns_group(&yg, "/yarns", opts)?;
    let n = yarns.num_points();
    let frames = match open_group(root, "frames", "/frames")? {
        Some(g) => Some(read_frames(&g, n, opts)?),
        None => None,
    };
    if let Some(f) = &frames {
        notes.push(format!("{} frame(s)", f.num_frames()));
    }
    Ok(Decoded {
        yarns,
        frames,
        units,
        up_axis,
        radius_in_file,
        notes,
    })
}

/// Number of frames in a knitvox HDF5 file (0 when it has no `/frames`).
pub fn frame_count(path: &Path) -> Result<usize, IoError> {
    let file = open_path(path)?;
    let Some(g) = open_group(&file, "frames", "/frames").map_err(|e| format_err(path, e))? else {
        return Ok(0);
    };
    let pts = Ds::open(&g, "/frames", "points", true).map_err(|e| format_err(path, e))?;
    let pts =
        pts.ok_or_else(|| format_err(path, FormatError::at_path("/frames/points", "missing")))?;
    pts.expect_shape(&[None, None, Some(3)], "F x N x 3")
        .map_err(|e| format_err(path, e))?;
    Ok(pts.shape[0])
}

/// Reads frame `f` (0-based) of a knitvox HDF5 file without loading the
/// others. Positions are converted from the file's declared `units` and
/// `up_axis` (default metres, +Y) into knitvox's metres, +Y up.
pub fn read_frame(path: &Path, f: usize) -> Result<Vec<Vec3>, IoError> {
    let file = open_path(path)?;
    read_frame_of(&file, f).map_err(|e| format_err(path, e))
}

fn read_frame_of(file: &hdf5::File, f: usize) -> Result<Vec<Vec3>, FormatError> {
    let root: &Group = file;
    let units = match read_str_attr(root, "", "units")? {
        Some(u) => u
            .parse::<Units>()
            .map_err(|e| FormatError::at_path(attr_loc("", "units"), e.to_string()))?,
        None => Units::METRES,
    };
    let up = match read_str_attr(root, "", "up_axis")? {
        Some(a) => a
            .parse::<UpAxis>()
            .map_err(|e| FormatError::at_path(attr_loc("", "up_axis"), e.to_string()))?,
        None => UpAxis::Y,
    };
    let g = open_group(root, "frames", "/frames")?
        .ok_or_else(|| FormatError::at_path("/frames", "the file has no frames"))?;
    let pts = Ds::open(&g, "/frames", "points", true)?
        .ok_or_else(|| FormatError::at_path("/frames/points", "missing"))?;
    pts.expect_shape(
        &[None, None, Some(3)],
        "F x N x 3 (frames x vertices x xyz)",
    )?;
    pts.expect_float()?;
    let (nf, n) = (pts.shape[0], pts.shape[1]);
    if f >= nf {
        return Err(pts.err(format!(
            "frame {f} requested but the file holds {nf} frame(s)"
        )));
    }
    if n as u64 > super::DEFAULT_MAX_POINTS {
        return Err(pts.err(format!(
            "{n} vertices per frame exceeds the limit of {}",
            super::DEFAULT_MAX_POINTS
        )));
    }
    // One frame of a gzip dataset: at most the whole dataset's stored bytes times the ratio.
    pts.guard_storage(n.saturating_mul(3))?;
    let arr = pts
        .ds
        .read_slice::<f64, _, ndarray::Ix3>(ndarray::s![f..f + 1, .., ..])
        .map_err(|e| loc_err(&pts.loc, &e))?;
    let flat = arr.as_standard_layout();
    let flat = flat
        .as_slice()
        .ok_or_else(|| pts.err("internal error: frame not contiguous"))?;
    let mut out = Vec::with_capacity(n);
    for (v, p) in flat.chunks_exact(3).enumerate() {
        if !p.iter().all(|x| x.is_finite()) {
            return Err(pts.err(format!(
                "frame {f}, vertex {v}: coordinate {p:?} is not finite"
            )));
        }
        let s = units.metres_per_unit;
        out.push(up.to_internal([p[0] * s, p[1] * s, p[2] * s]));
    }
    Ok(out)
}

// ---------------------------------------------------------------------------
// Writing
// ---------------------------------------------------------------------------

pub(crate) fn write_1d<T: hdf5::H5Type>(
    g: &Group,
    name: &str,
    data: &[T],
    units: Option<&str>,
) -> hdf5::Result<()> {
    let ds = g.new_dataset::<T>().shape([data.len()]).create(name)?;
    if !data.is_empty() {
        ds.write_raw(data)?;
    }
    if let Some(u) = units {
        write_str_attr(&ds, "units", u)?;
    }
    Ok(())
}

/// Creates (truncates) an HDF5 file for writing. The v1.10 object formats
/// checksum every piece of metadata, so a corrupted file is detected on read
/// instead of being misread; the upper bound keeps files readable by
/// libhdf5 1.10 even when knitvox links a newer library.
pub(crate) fn create_h5(path: &Path) -> hdf5::Result<hdf5::File> {
    use hdf5::file::LibraryVersion;
    // No file lock on our own temporary file: nobody else opens it (it gets a
    // unique dot-name and is renamed into place when complete), and a child
    // process spawned meanwhile would inherit libhdf5's descriptor (opened
    // without O_CLOEXEC) and with it an exclusive lock that outlives the
    // rename, making every reader of the finished file report it busy.
    hdf5::File::with_options()
        .with_fapl(|p| {
            p.libver_bounds(LibraryVersion::V110, LibraryVersion::V110)
                .file_locking(false)
        })
        // No object times (root group here, the others in `new_group`;
        // hdf5-metno's datasets already go without): the same content gives
        // the same bytes, so a farm can compare a rerun with `cmp`.
        .with_fcpl(|p| p.obj_track_times(false))
        .create(path)
}

/// A child group without object times (see `create_h5`).
pub(crate) fn new_group(parent: &hdf5::Group, name: &str) -> hdf5::Result<hdf5::Group> {
    parent
        .create_group_builder()
        .obj_track_times(false)
        .create(name)
}

/// Root attributes and `/yarns` (coordinates already in metres, +Y up).
fn write_yarns(file: &hdf5::File, y: &Yarns) -> hdf5::Result<()> {
    write_str_attr(file, "knitvox_format", FORMAT_NAME)?;
    file.new_attr::<i64>()
        .shape(())
        .create("knitvox_format_version")?
        .write_scalar(&FORMAT_VERSION)?;
    write_str_attr(file, "units", "m")?;
    write_str_attr(file, "up_axis", "y")?;
    write_str_attr(
        file,
        "generator",
        &format!("knitvox {}", env!("CARGO_PKG_VERSION")),
    )?;
    write_yarns_group(&new_group(file, "yarns")?, y)
}

/// The datasets of a yarns group (`points`, `offsets`, `closed`, `radius`, and
/// `vertex_radius` / `linear_density` when present) into `g`. Also used by the
/// asset file (`/knitvox/rest_yarns`, io::vtkhdf).
pub(crate) fn write_yarns_group(g: &Group, y: &Yarns) -> hdf5::Result<()> {
    let n = y.points.len();
    let pts = g.new_dataset::<f64>().shape([n, 3]).create("points")?;
    if n > 0 {
        pts.write_raw(y.points.as_flattened())?;
    }
    write_str_attr(&pts, "units", "m")?;
    let offsets: Vec<u64> = y.offsets.iter().map(|&o| o as u64).collect();
    write_1d(g, "offsets", &offsets, None)?;
    let closed: Vec<u8> = y.closed.iter().map(|&c| u8::from(c)).collect();
    write_1d(g, "closed", &closed, None)?;
    write_1d(g, "radius", &y.radius, Some("m"))?;
    if let Some(vr) = &y.vertex_radius {
        write_1d(g, "vertex_radius", vr, Some("m"))?;
    }
    if let Some(ld) = &y.linear_density {
        write_1d(g, "linear_density", ld, Some("kg/m"))?;
    }
    if let Some(rest) = &y.rest {
        write_rest_group(g, rest)?;
    }
    Ok(())
}

/// Reads the rest shape of a yarns group (`<yarns>/rest`, see
/// schemas/yarns-hdf5.md): lengths and directors per segment, curvature and
/// twist per vertex, checked against the yarns' segment and vertex counts.
fn read_rest_group(rg: &Group, gp: &str, y: &Yarns) -> Result<RestShape, FormatError> {
    let (ns, nv) = (y.num_segments(), y.points.len());
    let read = |name: &str, shape: &[Option<usize>], what: &str| -> Result<Vec<f64>, FormatError> {
        let ds = Ds::open(rg, gp, name, true)?
            .ok_or_else(|| FormatError::at_path(format!("{gp}/{name}"), "missing"))?;
        ds.expect_shape(shape, what)?;
        ds.expect_float()?;
        let elems = shape.iter().map(|d| d.unwrap_or(0)).product();
        let v = ds.read_f64(elems)?;
        if let Some(i) = v.iter().position(|x| !x.is_finite()) {
            return Err(ds.err(format!("value {i} is not finite")));
        }
        Ok(v)
    };
    let lengths = read("lengths", &[Some(ns)], &format!("[{ns}] (one per segment)"))?;
    let directors = read("directors", &[Some(ns), Some(3)], &format!("[{ns}, 3]"))?;
    let curvature = read("curvature", &[Some(nv), Some(4)], &format!("[{nv}, 4]"))?;
    let twist = read("twist", &[Some(nv)], &format!("[{nv}] (one per vertex)"))?;
    let rest = RestShape {
        lengths,
        directors: directors
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect(),
        curvature: curvature
            .chunks_exact(4)
            .map(|c| [c[0], c[1], c[2], c[3]])
            .collect(),
        twist,
        material: read_material(rg, gp)?,
    };
    rest.validate(ns, nv)
        .map_err(|e| FormatError::at_path(gp, e.to_string()))?;
    Ok(rest)
}

/// The material a rest shape was relaxed under: the group's four
/// attributes named as in [`YarnMaterial::RANGES`] (SI units whatever the
/// file's length unit), all or none.
fn read_material(rg: &Group, gp: &str) -> Result<Option<YarnMaterial>, FormatError> {
    let mut values = [None; 4];
    for (v, (name, lo, hi)) in values.iter_mut().zip(YarnMaterial::RANGES) {
        *v = read_float_attr(rg, gp, name)?;
        if let Some(x) = *v {
            if !(lo..=hi).contains(&x) {
                return Err(FormatError::at_path(
                    attr_loc(gp, name),
                    format!("{x} is outside the accepted [{lo:e}, {hi:e}]"),
                ));
            }
        }
    }
    match values.iter().position(Option::is_none) {
        None => Ok(Some(YarnMaterial::from_values(
            values.map(|v| v.unwrap_or(0.0)),
        ))),
        Some(_) if values.iter().all(Option::is_none) => Ok(None),
        Some(i) => Err(FormatError::at_path(
            attr_loc(gp, YarnMaterial::RANGES[i].0),
            "missing: a rest shape's material needs all of young_modulus, shear_modulus, \
             bend_scale and contact_stiffness",
        )),
    }
}

/// Writes a rest shape as `<yarns>/rest` (lengths in metres).
fn write_rest_group(g: &Group, rest: &RestShape) -> hdf5::Result<()> {
    let rg = new_group(g, "rest")?;
    write_1d(&rg, "lengths", &rest.lengths, Some("m"))?;
    let dirs = rg
        .new_dataset::<f64>()
        .shape([rest.directors.len(), 3])
        .create("directors")?;
    if !rest.directors.is_empty() {
        dirs.write_raw(rest.directors.as_flattened())?;
    }
    let k = rg
        .new_dataset::<f64>()
        .shape([rest.curvature.len(), 4])
        .create("curvature")?;
    if !rest.curvature.is_empty() {
        k.write_raw(rest.curvature.as_flattened())?;
    }
    write_1d(&rg, "twist", &rest.twist, Some("rad"))?;
    if let Some(m) = &rest.material {
        for ((name, _, _), v) in YarnMaterial::RANGES.iter().zip(m.values()) {
            rg.new_attr::<f64>()
                .shape(())
                .create(*name)?
                .write_scalar(&v)?;
        }
    }
    Ok(())
}

/// The open, growing `/frames` datasets of a file being written.
struct FramesOut {
    points: Dataset,
    times: Dataset,
    n: usize,
    count: usize,
    /// `/frames/{elastic_energy, reaction_forces, external_forces}`, made
    /// on the first [`FrameWriter::push_mechanics`].
    mechanics: Option<MechanicsOut>,
}

struct MechanicsOut {
    energy: Dataset,
    reactions: Dataset,
    external: Dataset,
}

impl MechanicsOut {
    fn create(g: &hdf5::Group, n: usize) -> hdf5::Result<MechanicsOut> {
        let vec_ds = |name: &str| -> hdf5::Result<Dataset> {
            let ds = g
                .new_dataset::<f64>()
                .chunk([1, n.clamp(1, MAX_CHUNK_VERTICES), 3])
                .shuffle()
                .deflate(FRAME_DEFLATE_LEVEL)
                .shape([Extent::from(0..), Extent::from(n.max(1)), Extent::from(3)])
                .create(name)?;
            write_str_attr(&ds, "units", "N")?;
            Ok(ds)
        };
        let energy = g
            .new_dataset::<f64>()
            .chunk([TIMES_CHUNK])
            .shape([Extent::from(0..)])
            .create("elastic_energy")?;
        write_str_attr(&energy, "units", "J")?;
        Ok(MechanicsOut {
            energy,
            reactions: vec_ds("reaction_forces")?,
            external: vec_ds("external_forces")?,
        })
    }
}

impl FramesOut {
    fn create(file: &hdf5::File, n: usize) -> hdf5::Result<FramesOut> {
        let g = new_group(file, "frames")?;
        // Frames grow along the first axis; with no vertices the vertex axis must be
        // resizable too, since a chunk may not exceed a fixed extent of 0.
        let vert_extent = if n == 0 {
            Extent::from(0..)
        } else {
            Extent::from(n)
        };
        let points = g
            .new_dataset::<f64>()
            .chunk([1, n.clamp(1, MAX_CHUNK_VERTICES), 3])
            .shuffle()
            .deflate(FRAME_DEFLATE_LEVEL)
            .shape([Extent::from(0..), vert_extent, Extent::from(3)])
            .create("points")?;
        write_str_attr(&points, "units", "m")?;
        let times = g
            .new_dataset::<f64>()
            .chunk([TIMES_CHUNK])
            .shape([Extent::from(0..)])
            .create("times")?;
        write_str_attr(&times, "units", "s")?;
        Ok(FramesOut {
            points,
            times,
            n,
            count: 0,
            mechanics: None,
        })
    }

    /// Mechanics of the last pushed frame (its index is `count - 1`).
    fn push_mechanics(
        &mut self,
        file: &hdf5::File,
        energy: f64,
        reactions: &[Vec3],
        external: &[Vec3],
    ) -> hdf5::Result<()> {
        let f = self.count - 1;
        if self.mechanics.is_none() {
            if f != 0 {
                return Err(hdf5::Error::from(
                    "mechanics must be written with every frame, starting at the first",
                ));
            }
            self.mechanics = Some(MechanicsOut::create(&file.group("frames")?, self.n)?);
        }
        let m = self.mechanics.as_ref().expect("created above");
        if m.energy.shape()[0] != f {
            return Err(hdf5::Error::from(
                "mechanics written twice or skipped for a frame",
            ));
        }
        m.energy.resize([f + 1])?;
        m.energy.write_slice(
            ndarray::ArrayView1::from(&[energy][..]),
            ndarray::s![f..f + 1],
        )?;
        for (ds, v) in [(&m.reactions, reactions), (&m.external, external)] {
            ds.resize([f + 1, self.n.max(1), 3])?;
            if self.n > 0 {
                let view = ndarray::ArrayView3::from_shape((1, self.n, 3), v.as_flattened())?;
                ds.write_slice(view, ndarray::s![f..f + 1, .., ..])?;
            }
        }
        Ok(())
    }

    fn push(&mut self, time: f64, points: &[Vec3]) -> hdf5::Result<()> {
        let f = self.count;
        self.points.resize([f + 1, self.n, 3])?;
        if self.n > 0 {
            let view = ndarray::ArrayView3::from_shape((1, self.n, 3), points.as_flattened())?;
            self.points
                .write_slice(view, ndarray::s![f..f + 1, .., ..])?;
        }
        self.times.resize([f + 1])?;
        self.times.write_slice(
            ndarray::ArrayView1::from(&[time][..]),
            ndarray::s![f..f + 1],
        )?;
        self.count += 1;
        Ok(())
    }
}

fn check_frame(n: usize, frame: usize, time: f64, points: &[Vec3]) -> Result<(), std::io::Error> {
    if points.len() != n {
        return Err(invalid_input(format!(
            "frame {frame}: {} positions for {n} yarn vertices",
            points.len()
        )));
    }
    if !time.is_finite() {
        return Err(invalid_input(format!(
            "frame {frame}: time {time} is not finite"
        )));
    }
    if let Some(v) = points.iter().position(|p| !p.iter().all(|x| x.is_finite())) {
        return Err(invalid_input(format!(
            "frame {frame}, vertex {v}: coordinate {:?} is not finite",
            points[v]
        )));
    }
    Ok(())
}

/// The text stored by [`FrameWriter::add_text`] under `name`, or `None`
/// when the file has none.
pub fn read_text(path: &Path, name: &str) -> Result<Option<String>, IoError> {
    let file = open_path(path)?;
    let Ok(ds) = file.dataset(&format!("metadata/{name}")) else {
        return Ok(None);
    };
    let at = format!("/metadata/{name}");
    if let Ok(g) = file.group("metadata") {
        check_link(&g, name, &at).map_err(|e| format_err(path, e))?;
    }
    check_storage(&ds, &at).map_err(|e| format_err(path, e))?;
    if ds.size() as u64 > super::max_memory() {
        return Err(format_err(
            path,
            FormatError::at_path(
                &at,
                format!(
                    "declares {} bytes, more than the memory budget of {} bytes (--max-memory)",
                    ds.size(),
                    super::max_memory()
                ),
            ),
        ));
    }
    check_bomb(&ds, &at, ds.size() as u64).map_err(|e| format_err(path, e))?;
    let bytes: Vec<u8> = ds
        .read_raw()
        .map_err(|e| format_err(path, FormatError::at_path(&at, format!("unreadable: {e}"))))?;
    String::from_utf8(bytes)
        .map(Some)
        .map_err(|e| format_err(path, FormatError::at_path(&at, format!("not UTF-8: {e}"))))
}

/// Writes yarns (metres, +Y up) and optionally their frames to `path`
/// atomically: libhdf5 writes a dot-prefixed temporary file in the same
/// directory, which is fsynced and renamed onto `path`.
pub fn write_file(path: &Path, yarns: &Yarns, frames: Option<&YarnFrames>) -> Result<(), IoError> {
    yarns.validate().map_err(|e| {
        write_err(
            path,
            invalid_input(format!("refusing to write invalid yarns: {e}")),
        )
    })?;
    if let Some(fr) = frames {
        if fr.num_vertices != yarns.num_points() {
            return Err(write_err(
                path,
                invalid_input(format!(
                    "frames have {} vertices, the yarns {}",
                    fr.num_vertices,
                    yarns.num_points()
                )),
            ));
        }
        fr.validate().map_err(|e| {
            write_err(
                path,
                invalid_input(format!("refusing to write invalid frames: {e}")),
            )
        })?;
    }
    super::atomic::write_with(path, |tmp| {
        let file = create_h5(tmp)?;
        write_yarns(&file, yarns)?;
        if let Some(fr) = frames {
            let mut out = FramesOut::create(&file, fr.num_vertices)?;
            for f in 0..fr.num_frames() {
                out.push(fr.times[f], fr.frame(f))?;
            }
        }
        file.close()?;
        Ok(())
    })
}

/// Streams frames into a knitvox HDF5 file one at a time, so a long
/// simulation never holds every frame in memory. The file is built under a
/// dot-prefixed temporary name in the target's directory and appears at the
/// target path only when [`FrameWriter::finish`] succeeds; dropping the writer
/// unfinished removes the temporary file.
pub struct FrameWriter {
    // Field order is drop order: datasets, then the file, then the temp path.
    frames: Option<FramesOut>,
    file: Option<hdf5::File>,
    tmp: Option<tempfile::TempPath>,
    /// Removes the temporary file on SIGINT/SIGTERM (see io::atomic).
    _registered: super::atomic::TempGuard,
    path: PathBuf,
}

impl FrameWriter {
    /// Starts a file at `path` holding `yarns` (metres, +Y up) and no frames yet.
    pub fn create(path: &Path, yarns: &Yarns) -> Result<FrameWriter, IoError> {
        yarns.validate().map_err(|e| {
            write_err(
                path,
                invalid_input(format!("refusing to write invalid yarns: {e}")),
            )
        })?;
        let dir = match path.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let name = path
            .file_name()
            .ok_or_else(|| write_err(path, invalid_input("output path has no file name".into())))?;
        // Created and registered with signals held: no unregistered window.
        let (tmp, registered) = super::atomic::hold_signals(|| {
            let tmp = tempfile::Builder::new()
                .prefix(&format!(".{}.", name.to_string_lossy()))
                .suffix(".tmp")
                .tempfile_in(&dir)?
                .into_temp_path();
            let registered = super::atomic::TempGuard::register(&tmp);
            Ok::<_, std::io::Error>((tmp, registered))
        })
        .map_err(|e| write_err(path, e))?;
        let file = create_h5(&tmp).map_err(|e| write_err(path, e))?;
        write_yarns(&file, yarns).map_err(|e| write_err(path, e))?;
        let frames =
            FramesOut::create(&file, yarns.num_points()).map_err(|e| write_err(path, e))?;
        Ok(FrameWriter {
            frames: Some(frames),
            file: Some(file),
            tmp: Some(tmp),
            _registered: registered,
            path: path.to_path_buf(),
        })
    }

    /// Appends one frame: `points` (one position per yarn vertex, metres) at `time` (s).
    pub fn push(&mut self, time: f64, points: &[Vec3]) -> Result<(), IoError> {
        let path = self.path.clone();
        let out = self
            .frames
            .as_mut()
            .ok_or_else(|| write_err(&path, std::io::Error::other("writer already finished")))?;
        check_frame(out.n, out.count, time, points).map_err(|e| write_err(&path, e))?;
        out.push(time, points).map_err(|e| write_err(&path, e))
    }

    /// Stores the mechanics of the frame just pushed: the elastic energy (J)
    /// and, per yarn vertex, the force the clamps/handles exert on it and the
    /// external force (N; zero where none). Either with every frame from the
    /// first or never (schemas/yarns-hdf5.md, `/frames/elastic_energy`,
    /// `/frames/reaction_forces`, `/frames/external_forces`).
    pub fn push_mechanics(
        &mut self,
        energy: f64,
        reactions: &[Vec3],
        external: &[Vec3],
    ) -> Result<(), IoError> {
        let path = self.path.clone();
        let (Some(out), Some(file)) = (self.frames.as_mut(), self.file.as_ref()) else {
            return Err(write_err(
                &path,
                std::io::Error::other("writer already finished"),
            ));
        };
        if out.count == 0 || reactions.len() != out.n || external.len() != out.n {
            return Err(write_err(
                &path,
                invalid_input(format!(
                    "mechanics of frame {}: {} reactions and {} external forces for {} vertices",
                    out.count.saturating_sub(1),
                    reactions.len(),
                    external.len(),
                    out.n
                )),
            ));
        }
        if !energy.is_finite()
            || reactions
                .iter()
                .chain(external)
                .flatten()
                .any(|v| !v.is_finite())
        {
            return Err(write_err(
                &path,
                invalid_input(format!("mechanics of frame {}: not finite", out.count - 1)),
            ));
        }
        out.push_mechanics(file, energy, reactions, external)
            .map_err(|e| write_err(&path, e))
    }

    /// Stores the clamp force on each clamped band per frame (N, the
    /// resultant the band holds the yarns with, its own weight and inertia
    /// aside) as `/frames/clamp_forces` (`F x B x 3`, attribute `units =
    /// "N"`; schemas/yarns-hdf5.md), once every frame is pushed: `forces[f]`
    /// for frame `f`, the same number of bands in each.
    pub fn add_clamp_forces(&mut self, forces: &[Vec<Vec3>]) -> Result<(), IoError> {
        let path = self.path.clone();
        let (Some(out), Some(file)) = (self.frames.as_ref(), self.file.as_ref()) else {
            return Err(write_err(
                &path,
                std::io::Error::other("writer already finished"),
            ));
        };
        let bands = forces.first().map_or(0, Vec::len);
        if forces.len() != out.count
            || bands == 0
            || bands > MAX_CLAMP_BANDS
            || forces.iter().any(|f| f.len() != bands)
            || forces.iter().flatten().flatten().any(|v| !v.is_finite())
        {
            return Err(write_err(
                &path,
                invalid_input(format!(
                    "clamp forces: {} frames of up to {} bands (finite) for {} frames written (1 to {MAX_CLAMP_BANDS} bands)",
                    forces.len(),
                    forces.iter().map(Vec::len).max().unwrap_or(0),
                    out.count
                )),
            ));
        }
        let write = || -> hdf5::Result<()> {
            let flat: Vec<f64> = forces.iter().flatten().flatten().copied().collect();
            let view = ndarray::ArrayView3::from_shape((forces.len(), bands, 3), &flat)?;
            let ds = file
                .group("frames")?
                .new_dataset::<f64>()
                .shape([forces.len(), bands, 3])
                .create("clamp_forces")?;
            ds.write(view)?;
            write_str_attr(&ds, "units", "N")
        };
        write().map_err(|e| write_err(&path, e))
    }

    /// Stores `text` (UTF-8: a scene file, a JSON parameter record) as the
    /// byte dataset `/metadata/<name>` (uint8 `[len]`, attribute
    /// `encoding = "utf-8"`), so a frame file carries what produced it.
    /// Names are plain identifiers; a name used twice is an error.
    pub fn add_text(&mut self, name: &str, text: &str) -> Result<(), IoError> {
        let path = self.path.clone();
        if name.is_empty() || !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
            return Err(write_err(
                &path,
                invalid_input(format!("metadata name {name:?} is not an identifier")),
            ));
        }
        let file = self
            .file
            .as_ref()
            .ok_or_else(|| write_err(&path, std::io::Error::other("writer already finished")))?;
        let write = || -> hdf5::Result<()> {
            let g = match file.group("metadata") {
                Ok(g) => g,
                Err(_) => new_group(file, "metadata")?,
            };
            let ds = g.new_dataset::<u8>().shape([text.len()]).create(name)?;
            if !text.is_empty() {
                ds.write_raw(text.as_bytes())?;
            }
            write_str_attr(&ds, "encoding", "utf-8")
        };
        write().map_err(|e| write_err(&path, e))
    }

    /// Frames written so far.
    pub fn num_frames(&self) -> usize {
        self.frames.as_ref().map_or(0, |f| f.count)
    }

    /// Closes the file, fsyncs it, renames it onto the target path and fsyncs
    /// the directory. Returns the path written.
    pub fn finish(mut self) -> Result<PathBuf, IoError> {
        let path = self.path.clone();
        drop(self.frames.take());
        if let Some(file) = self.file.take() {
            file.close().map_err(|e| write_err(&path, e))?;
        }
        let tmp = self
            .tmp
            .take()
            .ok_or_else(|| write_err(&path, std::io::Error::other("writer already finished")))?;
        super::atomic::finish_temp(tmp, self._registered, &path)?;
        Ok(path)
    }
}

// ---------------------------------------------------------------------------
// Inspection of any HDF5 file
// ---------------------------------------------------------------------------

/// One dataset of an HDF5 file, as [`list_datasets`] reports it.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct DatasetInfo {
    /// Absolute path inside the file (`/group/name`).
    pub path: String,
    /// Extent of each dimension (empty for a scalar).
    pub shape: Vec<usize>,
    /// Element type: `float64`, `int16`, `uint8`, `string`, `enum (1 bytes)`, `compound`, ...
    pub dtype: String,
    /// Whether [`read_dataset_f64`] can convert it (integers and floats).
    pub numeric: bool,
    /// Chunk shape, `None` for contiguous or compact storage.
    pub chunks: Option<Vec<usize>>,
    /// Filters in pipeline order: `shuffle`, `gzip(4)`, `fletcher32`, `lzf`, `filter 32001`, ...
    pub filters: Vec<String>,
}

fn describe_filter(f: &hdf5::filters::Filter) -> String {
    use hdf5::filters::Filter;
    match f {
        Filter::Deflate(l) => format!("gzip({l})"),
        Filter::Shuffle => "shuffle".into(),
        Filter::Fletcher32 => "fletcher32".into(),
        Filter::SZip(..) => "szip".into(),
        Filter::NBit => "nbit".into(),
        Filter::ScaleOffset(_) => "scaleoffset".into(),
        Filter::User(32000, _) => "lzf".into(),
        Filter::User(32001, _) => "blosc".into(),
        Filter::User(id, _) => format!("filter {id}"),
    }
}

fn visit(
    group: &Group,
    prefix: &str,
    depth: usize,
    seen: &mut usize,
    out: &mut Vec<DatasetInfo>,
) -> hdf5::Result<()> {
    let mut links = Vec::new();
    group.iter_visit_default(|name, info| {
        links.push((name.to_string(), info.link_type));
        Ok(())
    })?;
    for (name, kind) in links {
        *seen += 1;
        // Soft and external links point elsewhere (another file, or a path listed anyway).
        if *seen > MAX_LISTED_OBJECTS || kind != LinkType::Hard {
            continue;
        }
        let path = format!("{prefix}/{name}");
        match group.loc_type_by_name(&name)? {
            LocationType::Group if depth < MAX_LIST_DEPTH => {
                visit(&group.group(&name)?, &path, depth + 1, seen, out)?
            }
            LocationType::Dataset => {
                let ds = group.dataset(&name)?;
                let ty = type_info(&ds.dtype()?);
                out.push(DatasetInfo {
                    path,
                    shape: ds.shape(),
                    dtype: ty.describe(),
                    numeric: ty.is_numeric(),
                    chunks: ds.chunk(),
                    filters: ds.filters().iter().map(describe_filter).collect(),
                });
            }
            _ => {}
        }
    }
    Ok(())
}

/// Every dataset of any HDF5 file (hard links only, depth-first by name).
pub fn list_datasets(path: &Path) -> Result<Vec<DatasetInfo>, IoError> {
    let file = open_path(path)?;
    let mut out = Vec::new();
    let mut seen = 0;
    visit(&file, "", 0, &mut seen, &mut out).map_err(|e| {
        format_err(
            path,
            FormatError::whole_file(format!("cannot list its content: {}", h5_message(&e))),
        )
    })?;
    Ok(out)
}

/// Reads any integer or float dataset of any HDF5 file (contiguous, chunked,
/// gzip, shuffle) converted to f64, with its shape. Refuses datasets of more
/// than [`MAX_INSPECT_ELEMENTS`] elements.
pub fn read_dataset_f64(path: &Path, name: &str) -> Result<(Vec<usize>, Vec<f64>), IoError> {
    let file = open_path(path)?;
    read_dataset_f64_of(&file, name).map_err(|e| format_err(path, e))
}

fn read_dataset_f64_of(
    file: &hdf5::File,
    name: &str,
) -> Result<(Vec<usize>, Vec<f64>), FormatError> {
    read_dataset_f64_checked(file, name, &|_| Ok(()))
}

/// [`read_dataset_f64_of`], its declared shape first passed to `check`
/// (an error message), before anything is read.
fn read_dataset_f64_checked(
    file: &hdf5::File,
    name: &str,
    check: &dyn Fn(&[usize]) -> Result<(), String>,
) -> Result<(Vec<usize>, Vec<f64>), FormatError> {
    let loc = if name.starts_with('/') {
        name.to_string()
    } else {
        format!("/{name}")
    };
    let inner = loc.trim_start_matches('/');
    if inner.is_empty() || !file.link_exists(inner) {
        return Err(FormatError::at_path(&loc, "no such dataset"));
    }
    // Split into parent group and last name so Ds::open can check the object type.
    let (parent, last) = match inner.rsplit_once('/') {
        Some((p, l)) => (file.group(p).map_err(|e| loc_err(&loc, &e))?, l),
        None => (file.group("/").map_err(|e| loc_err(&loc, &e))?, inner),
    };
    let parent_path = &loc[..loc.len() - last.len() - 1];
    let ds = Ds::open(&parent, parent_path, last, true)?
        .ok_or_else(|| FormatError::at_path(&loc, "no such dataset"))?;
    if !ds.ty.is_numeric() {
        return Err(ds.err(format!("type {} is not numeric", ds.ty.describe())));
    }
    check(&ds.shape).map_err(|m| ds.err(m))?;
    let elems = ds
        .shape
        .iter()
        .try_fold(1usize, |a, &d| a.checked_mul(d))
        .filter(|&e| e as u64 <= MAX_INSPECT_ELEMENTS);
    let elems = elems.ok_or_else(|| {
        ds.err(format!(
            "shape {:?} exceeds the limit of {MAX_INSPECT_ELEMENTS} elements",
            ds.shape
        ))
    })?;
    if elems == 0 {
        return Ok((ds.shape.clone(), Vec::new()));
    }
    ds.guard_storage(elems)?;
    let v: Vec<f64> = ds.ds.read_raw().map_err(|e| loc_err(&loc, &e))?;
    Ok((ds.shape.clone(), v))
}

/// Most clamped bands `/frames/clamp_forces` may hold.
pub const MAX_CLAMP_BANDS: usize = 1024;

/// `/frames/clamp_forces` of a knitvox HDF5 frame file
/// ([`FrameWriter::add_clamp_forces`]): per frame, the clamp force (N) on
/// each band. None when the file has none; its shape must be `frames x B x
/// 3` (1 <= B <= [`MAX_CLAMP_BANDS`]), checked before it is read, and every
/// value finite.
pub fn read_clamp_forces(path: &Path, frames: usize) -> Result<Option<Vec<Vec<Vec3>>>, IoError> {
    const LOC: &str = "/frames/clamp_forces";
    let file = open_path(path)?;
    if !file.link_exists("frames") || !file.link_exists("frames/clamp_forces") {
        return Ok(None);
    }
    let check = |shape: &[usize]| -> Result<(), String> {
        match shape {
            [f, b, 3] if *f == frames && (1..=MAX_CLAMP_BANDS).contains(b) => Ok(()),
            _ => Err(format!(
                "shape {shape:?}: expected {frames} frames x 1 to {MAX_CLAMP_BANDS} bands x 3"
            )),
        }
    };
    let (shape, v) =
        read_dataset_f64_checked(&file, LOC, &check).map_err(|e| format_err(path, e))?;
    if let Some(i) = v.iter().position(|x| !x.is_finite()) {
        return Err(format_err(
            path,
            FormatError::at_path(LOC, format!("value {i} is not finite")),
        ));
    }
    let b = shape[1];
    Ok(Some(
        v.chunks_exact(3 * b)
            .map(|fr| fr.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
            .collect(),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::Location;

    fn sample() -> Yarns {
        let mut y = Yarns::new();
        y.push_curve(
            &[[0.0, 0.0, 0.0], [1.0, 0.5, -0.25], [2.0, 1.0, 0.125]],
            false,
            0.001,
        );
        y.push_curve(
            &[
                [0.1, 0.2, 0.3],
                [0.4, 0.5, 0.6],
                [0.7, 0.8, 0.9],
                [1.0, 1.1, 1.2],
            ],
            true,
            0.002,
        );
        y
    }

    fn frames_of(y: &Yarns, n: usize) -> YarnFrames {
        let mut fr = YarnFrames::new(y.num_points());
        for f in 0..n {
            let pts: Vec<Vec3> = y
                .points
                .iter()
                .map(|p| [p[0] + f as f64, p[1] * 0.5, p[2] - 1e-3 * f as f64])
                .collect();
            fr.push_frame(f as f64 / 24.0, &pts).unwrap();
        }
        fr
    }

    #[test]
    fn write_read_and_decode_agree() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.h5");
        let mut y = sample();
        y.linear_density = Some(vec![0.01, 0.02]);
        y.vertex_radius = Some(vec![0.001, 0.0011, 0.0012, 0.002, 0.0021, 0.0022, 0.0023]);
        let fr = frames_of(&y, 3);
        write_file(&p, &y, Some(&fr)).unwrap();
        let d = read_file(&p, &ReadOptions::default()).unwrap();
        assert_eq!(d.yarns, y);
        assert_eq!(d.frames.as_ref(), Some(&fr));
        assert_eq!(d.units, Some(Units::METRES));
        assert_eq!(d.up_axis, Some(UpAxis::Y));
        assert!(d.radius_in_file);
        let bytes = std::fs::read(&p).unwrap();
        let d2 = decode(&bytes, &ReadOptions::default()).unwrap();
        assert_eq!(d2, d);
        assert_eq!(frame_count(&p).unwrap(), 3);
        assert_eq!(read_frame(&p, 2).unwrap(), fr.frame(2));
        assert!(matches!(read_frame(&p, 3), Err(IoError::Format { .. })));
        // Only the target is left in the directory.
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    fn sample_rest(y: &Yarns) -> RestShape {
        let (ns, nv) = (y.num_segments(), y.num_points());
        RestShape {
            lengths: (0..ns).map(|s| 0.5 + s as f64 * 0.125).collect(),
            directors: (0..ns)
                .map(|s| {
                    if s % 2 == 0 {
                        [1.0, 0.0, 0.0]
                    } else {
                        [0.0, 0.6, 0.8]
                    }
                })
                .collect(),
            curvature: (0..nv)
                .map(|v| [v as f64, -0.5, 0.25 * v as f64, 1.0])
                .collect(),
            twist: (0..nv).map(|v| 0.1 * v as f64).collect(),
            material: Some(YarnMaterial::from_values([5e6, 2e6, 0.1, 60.0])),
        }
    }

    #[test]
    fn rest_shape_round_trips_and_is_checked() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("rest.h5");
        let mut y = sample();
        y.rest = Some(sample_rest(&y));
        write_file(&p, &y, None).unwrap();
        let d = read_file(&p, &ReadOptions::default()).unwrap();
        assert_eq!(d.yarns.rest, y.rest);
        // A rest shape that does not fit the yarns is refused, naming the dataset.
        let bad = dir.path().join("bad.h5");
        let mut short = y.clone();
        short.rest.as_mut().unwrap().lengths.pop();
        short.rest.as_mut().unwrap().directors.pop();
        let file = create_h5(&bad).unwrap();
        write_yarns(
            &file,
            &Yarns {
                rest: None,
                ..y.clone()
            },
        )
        .unwrap();
        write_rest_group(&file.group("yarns").unwrap(), short.rest.as_ref().unwrap()).unwrap();
        drop(file);
        let e = read_file(&bad, &ReadOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("/yarns/rest/lengths"), "{e}");
        // The material: absurd or incomplete is refused, naming the attribute.
        let edited = |name: &str, edit: &dyn Fn(&Group)| -> String {
            let q = dir.path().join(format!("{name}.h5"));
            write_file(&q, &y, None).unwrap();
            // No file lock: a child process another test spawns meanwhile
            // would inherit libhdf5's descriptor and keep it locked.
            let f = hdf5::File::with_options()
                .with_fapl(|p| p.file_locking(false))
                .open_rw(&q)
                .unwrap();
            edit(&f.group("yarns/rest").unwrap());
            drop(f);
            read_file(&q, &ReadOptions::default())
                .unwrap_err()
                .to_string()
        };
        let e = edited("absurd", &|g| {
            g.attr("bend_scale").unwrap().write_scalar(&1e3).unwrap()
        });
        assert!(
            e.contains("/yarns/rest@bend_scale") && e.contains("outside"),
            "{e}"
        );
        let e = edited("partial", &|g| g.delete_attr("shear_modulus").unwrap());
        assert!(
            e.contains("/yarns/rest@shear_modulus") && e.contains("missing"),
            "{e}"
        );
        // A rest shape without one (written before it was recorded) reads as none.
        let old = dir.path().join("old.h5");
        let mut unrecorded = y.clone();
        unrecorded.rest.as_mut().unwrap().material = None;
        write_file(&old, &unrecorded, None).unwrap();
        let d = read_file(&old, &ReadOptions::default()).unwrap();
        assert_eq!(d.yarns.rest, unrecorded.rest);
    }

    #[test]
    fn frame_writer_streams_and_is_atomic() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("s.h5");
        let y = sample();
        let fr = frames_of(&y, 4);
        let mut w = FrameWriter::create(&p, &y).unwrap();
        for f in 0..4 {
            w.push(fr.times[f], fr.frame(f)).unwrap();
            assert!(!p.exists(), "target must not appear before finish");
        }
        assert!(w.push(0.0, &y.points[..2]).is_err());
        assert!(w.push(f64::NAN, &y.points).is_err());
        assert_eq!(w.num_frames(), 4);
        assert_eq!(w.finish().unwrap(), p);
        let d = read_file(&p, &ReadOptions::default()).unwrap();
        assert_eq!(d.frames.unwrap(), fr);
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);

        // Dropped unfinished: nothing left behind.
        let q = dir.path().join("dropped.h5");
        let mut w = FrameWriter::create(&q, &y).unwrap();
        w.push(0.0, &y.points).unwrap();
        drop(w);
        assert!(!q.exists());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn empty_yarns_and_zero_frames() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("e.h5");
        let y = Yarns::new();
        write_file(&p, &y, Some(&YarnFrames::new(0))).unwrap();
        let d = read_file(&p, &ReadOptions::default()).unwrap();
        assert_eq!(d.yarns.num_curves(), 0);
        assert_eq!(d.frames.unwrap().num_frames(), 0);
    }

    #[test]
    fn invalid_input_is_refused_on_write() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("bad.h5");
        let mut y = sample();
        y.points[1][0] = f64::INFINITY;
        assert!(matches!(
            write_file(&p, &y, None),
            Err(IoError::Write { .. })
        ));
        let y = sample();
        let fr = YarnFrames::new(3);
        assert!(matches!(
            write_file(&p, &y, Some(&fr)),
            Err(IoError::Write { .. })
        ));
        assert!(!p.exists());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }

    #[test]
    fn garbage_bytes_are_errors() {
        let o = ReadOptions::default();
        assert!(decode(b"", &o).unwrap_err().message.contains("empty"));
        assert!(decode(b"hello world, not hdf5", &o)
            .unwrap_err()
            .message
            .contains("not an HDF5 file"));
        let e = decode(
            &[0x89, b'H', b'D', b'F', b'\r', b'\n', 0x1a, b'\n', 0, 0, 0],
            &o,
        )
        .unwrap_err();
        assert_eq!(e.location, Location::File);
    }

    #[test]
    fn error_messages_are_single_lines() {
        let e = hdf5::Error::Internal("H5F__super_read(): truncated file: eof = 10".into());
        assert_eq!(h5_message(&e), "truncated file: eof = 10");
    }
}
