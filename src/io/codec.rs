//! Dispatch from a [`Format`] to its module: decode bytes, finish decoded
//! yarns into knitvox's frame (units, up axis, radius), read one file,
//! encode yarns as bytes.

use std::path::Path;

use super::error::{FormatError, IoError};
use super::types::{
    Decoded, DirResources, Format, Provenance, ReadOptions, Resources, WriteOptions, YarnData,
};
use super::{bcc, gltf, h5, obj, ply, poly, pyp};
use crate::geom::{GeomError, Units, UpAxis, Yarns};

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

/// Converts a decoded file into knitvox's frame (metres, +Y up), fills
/// radii, welds repeated points ([`crate::geom::Yarns::weld`]), validates.
pub fn finish(format: Format, d: Decoded, opts: &ReadOptions) -> Result<YarnData, GeomError> {
    finish_with(format, d, opts, true)
}

/// [`finish`], welding only when `weld` is set (a sequence's later frames
/// are welded by its first frame's map instead).
fn finish_with(
    format: Format,
    mut d: Decoded,
    opts: &ReadOptions,
    weld: bool,
) -> Result<YarnData, GeomError> {
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
    let had_rest = d.yarns.rest.is_some();
    // Welded in metres, with the radii the read settled on: the
    // tolerance is a fraction of the yarn radius.
    let (yarns, weld) = if weld {
        d.yarns.weld()
    } else {
        let w = crate::geom::Weld::identity(&d.yarns);
        (d.yarns, w)
    };
    if !weld.is_identity() {
        d.notes.extend(weld_notes(&weld, had_rest));
        if let Some(f) = &mut d.frames {
            if f.num_vertices == weld.input_points() {
                *f = weld.frames(f);
            }
        }
    }
    yarns.validate()?;
    if let Some(f) = &d.frames {
        f.validate()?;
    }
    Ok(YarnData {
        format,
        yarns,
        frames: d.frames,
        units,
        up_axis: up,
        radius,
        notes: d.notes,
        weld,
    })
}

/// What a read's welding did, for `inspect` and the stages' warnings.
pub(crate) fn weld_notes(weld: &crate::geom::Weld, had_rest: bool) -> Vec<String> {
    let mut notes = Vec::new();
    if weld.welded_points > 0 {
        notes.push(format!(
            "welded {} repeated point(s) (consecutive points closer than {} yarn radii or of the curve's mean segment: zero-length segments)",
            weld.welded_points,
            crate::geom::WELD_TOLERANCE_RADII
        ));
    }
    if !weld.dropped_curves.is_empty() {
        let shown: Vec<String> = weld
            .dropped_curves
            .iter()
            .take(8)
            .map(|c| c.to_string())
            .collect();
        notes.push(format!(
            "dropped {} curve(s) that welding left with too few points (curve {}{})",
            weld.dropped_curves.len(),
            shown.join(", "),
            if weld.dropped_curves.len() > 8 {
                ", ..."
            } else {
                ""
            }
        ));
    }
    if had_rest {
        notes.push(
            "the stored rest shape is dropped: its segments no longer match the welded curves"
                .into(),
        );
    }
    notes
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

/// Reads one file (never a sequence).
pub fn read_single(path: &Path, opts: &ReadOptions) -> Result<YarnData, IoError> {
    read_single_with(path, opts, true)
}

/// [`read_single`], welding repeated points only when `weld` is set.
pub(crate) fn read_single_with(
    path: &Path,
    opts: &ReadOptions,
    weld: bool,
) -> Result<YarnData, IoError> {
    let format = format_of(path)?;
    let decoded = if format == Format::Hdf5 {
        h5::read_file(path, opts)?
    } else {
        // A binary format's signature first: a file of up to the budget
        // that is not one is refused without being read whole (measured: a
        // 2 GiB sparse `.bcc` took 6-8 s and 2 GiB to be told so).
        if let Some(magic) = signature(format) {
            let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
            refuse_without_signature(path, "yarn file", opts.max_memory, format, magic, |head| {
                decode(format, head, opts, &DirResources(dir.clone())).map(|_| ())
            })?;
        }
        let data = super::input::read_input(path, "yarn file", opts.max_memory)?;
        let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
        decode(format, &data, opts, &DirResources(dir)).map_err(|source| IoError::Format {
            path: path.to_path_buf(),
            format,
            source,
        })?
    };
    finish_with(format, decoded, opts, weld).map_err(|source| IoError::Invalid {
        path: path.to_path_buf(),
        format,
        source,
    })
}

/// Refuses `path` (a `format` file, the `what` of messages) from its first
/// 64 bytes when they do not start with `magic`, with the error `decode`
/// gives for them (the one the whole file would give), before a file of up
/// to `max_bytes` is read whole. 64 bytes: a BCC header, enough of a PLY's
/// first line for its message.
pub(crate) fn refuse_without_signature(
    path: &Path,
    what: &'static str,
    max_bytes: u64,
    format: Format,
    magic: &[u8],
    decode: impl FnOnce(&[u8]) -> Result<(), FormatError>,
) -> Result<(), IoError> {
    let head = super::input::read_prefix(path, what, max_bytes, 64)?;
    if head.len() < magic.len() || head.starts_with(magic) {
        return Ok(());
    }
    decode(&head).map_err(|source| IoError::Format {
        path: path.to_path_buf(),
        format,
        source,
    })
}

/// The bytes a file of `format` starts with, where it has such a
/// signature (BCC, PLY, GLB).
fn signature(format: Format) -> Option<&'static [u8]> {
    match format {
        Format::Bcc => Some(b"BCC"),
        Format::Ply => Some(b"ply"),
        Format::Glb => Some(b"glTF"),
        _ => None,
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
