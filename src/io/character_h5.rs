//! HDF5 character caches (schemas/character-hdf5.md): an animated body as
//! triangles plus per-frame vertex positions, exported from any DCC (the
//! Blender script in pipelines/, h5py, or `knitvox bake`). Read into an
//! [`anim::cache::BodyCache`](crate::anim::cache::BodyCache) in knitvox's
//! metres, +Y up.
//!
//! The file is untrusted: it is opened through the same guarded paths as the
//! yarn files (no external links, external storage or virtual datasets;
//! every declared size checked against the storage and `--max-memory`
//! before allocating).

use std::path::Path;

use hdf5::Group;

use super::h5::{
    create_h5, format_err, open_group, open_path, open_path_within, read_str_attr, write_str_attr,
    Ds,
};
use super::{FormatError, IoError};
use crate::anim::cache::BodyCache;
use crate::geom::{Units, UpAxis, Vec3};

/// Value of the root attribute `knitvox_format`.
pub const FORMAT_NAME: &str = "character";
/// Newest layout version this build reads and the one it writes.
pub const FORMAT_VERSION: i64 = 1;

/// A cache as read, with the unit and up axis it declared (or `None`).
#[derive(Debug, Clone, PartialEq)]
pub struct CharacterCache {
    /// In metres, +Y up.
    pub cache: BodyCache,
    /// Declared unit (`None`: metres assumed).
    pub units: Option<Units>,
    /// Declared up axis (`None`: +Y assumed).
    pub up_axis: Option<UpAxis>,
    /// Facts of the read (generator, frames, what was assumed).
    pub notes: Vec<String>,
}

/// Whether `path` is an HDF5 file whose root declares a character cache
/// (so callers can tell it from a glTF character or a yarn file).
pub fn is_character_cache(path: &Path) -> bool {
    let Ok(file) = open_path(path) else {
        return false;
    };
    matches!(read_str_attr(&file, "", "knitvox_format"), Ok(Some(k)) if k == FORMAT_NAME)
        || file.link_exists("character")
}

/// Reads a character cache; `max_memory` bounds what the file may make
/// knitvox allocate (bytes).
pub fn read_character_cache(path: &Path, max_memory: u64) -> Result<CharacterCache, IoError> {
    let file = open_path_within(path, "character cache", Some(max_memory))?;
    let _budget = super::h5::whole_file_budget(max_memory);
    decode(&file, max_memory).map_err(|e| format_err(path, e))
}

fn decode(root: &Group, budget: u64) -> Result<CharacterCache, FormatError> {
    let mut notes = super::h5::check_format_attrs(root, FORMAT_NAME, FORMAT_VERSION)?;
    let (units, up_axis) = super::h5::read_units_and_axis(root)?;
    let g = open_group(root, "character", "/character")?.ok_or_else(|| {
        FormatError::whole_file(format!(
            "not a knitvox character cache: there is no /character group ({})",
            super::h5::describe_top_level(root)
        ))
    })?;
    let mut cache = read_group(&g, budget)?;
    let scale = units.map_or(1.0, |u| u.metres_per_unit);
    let axis = up_axis.unwrap_or(UpAxis::Y);
    let to_internal = |p: &mut Vec3| *p = axis.to_internal(p.map(|x| x * scale));
    cache.points.iter_mut().for_each(to_internal);
    if let Some(r) = cache.rest.as_mut() {
        r.iter_mut().for_each(to_internal);
    }
    cache
        .validate()
        .map_err(|e| FormatError::at_path(e.path.clone(), e.message.clone()))?;
    if units.is_none() {
        notes.push("unit: metres (assumed: the file declares none)".into());
    }
    if up_axis.is_none() {
        notes.push("up axis: +Y (assumed: the file declares none)".into());
    }
    notes.push(format!(
        "{} frame(s) over {:.4} s, {} vertices, {} triangles",
        cache.num_frames(),
        cache.duration(),
        cache.num_vertices,
        cache.triangles.len()
    ));
    Ok(CharacterCache {
        cache,
        units,
        up_axis,
        notes,
    })
}

/// Reads `/character` in file units; sizes are checked before allocating.
fn read_group(g: &Group, budget: u64) -> Result<BodyCache, FormatError> {
    const GP: &str = "/character";
    let tri = Ds::open(g, GP, "triangles", true)?
        .expect("required")
        .with_budget(budget);
    tri.expect_shape(&[None, Some(3)], "T x 3 (vertex indices per triangle)")?;
    let times = Ds::open(g, GP, "times", true)?
        .expect("required")
        .with_budget(budget);
    times.expect_shape(&[None], "[F] (one time per frame, s)")?;
    times.expect_float()?;
    let pts = Ds::open(g, GP, "points", true)?
        .expect("required")
        .with_budget(budget);
    pts.expect_shape(
        &[None, None, Some(3)],
        "F x V x 3 (frames x vertices x xyz)",
    )?;
    pts.expect_float()?;
    let (f, v) = (pts.shape[0], pts.shape[1]);
    if times.len() != f {
        return Err(times.err(format!(
            "{} times for {f} frames of /character/points",
            times.len()
        )));
    }
    let total = f
        .checked_mul(v)
        .and_then(|n| n.checked_mul(3))
        .ok_or_else(|| pts.err(format!("{f} frames x {v} vertices overflows")))?;
    // Everything the cache will hold, against the budget, before any read.
    let bytes = (total as u64)
        .saturating_add((tri.len() as u64).saturating_mul(3))
        .saturating_add(2 * v as u64 * 3)
        .saturating_mul(8);
    if bytes > budget {
        return Err(pts.err(format!(
            "the cache declares {bytes} bytes of data ({f} frames x {v} vertices, {} triangles), more than the memory budget of {budget} bytes (--max-memory)",
            tri.len()
        )));
    }
    let t = times.read_f64(f)?;
    pts.guard_storage(total)?;
    let mut points = vec![[0.0; 3]; f * v];
    pts.read_f64_into(points.as_flattened_mut())?;
    let idx = tri.read_index(tri.len() * 3)?;
    let triangles = idx
        .chunks_exact(3)
        .enumerate()
        .map(|(i, c)| {
            let mut out = [0u32; 3];
            for k in 0..3 {
                out[k] = u32::try_from(c[k])
                    .ok()
                    .filter(|&x| (x as usize) < v)
                    .ok_or_else(|| {
                        FormatError::at_path(
                            format!("{GP}/triangles/{i}"),
                            format!("vertex index {} out of range ({v} vertices)", c[k]),
                        )
                    })?;
            }
            Ok(out)
        })
        .collect::<Result<Vec<_>, FormatError>>()?;
    let rest = match Ds::open(g, GP, "rest_points", false)? {
        Some(r) => {
            let r = r.with_budget(budget);
            r.expect_shape(&[Some(v), Some(3)], &format!("{v} x 3 (rest pose)"))?;
            r.expect_float()?;
            let mut rest = vec![[0.0; 3]; v];
            r.read_f64_into(rest.as_flattened_mut())?;
            Some(rest)
        }
        None => None,
    };
    Ok(BodyCache {
        triangles,
        num_vertices: v,
        times: t,
        points,
        rest,
    })
}

/// Writes `cache` (metres, +Y up) atomically, in metres and +Y up.
pub fn write_character_cache(path: &Path, cache: &BodyCache) -> Result<(), IoError> {
    cache.validate().map_err(|e| {
        super::h5::write_err(
            path,
            super::h5::invalid_input(format!("refusing to write an invalid character cache: {e}")),
        )
    })?;
    super::atomic::write_with(path, |tmp| {
        let file = create_h5(tmp)?;
        write_str_attr(&file, "knitvox_format", FORMAT_NAME)?;
        file.new_attr::<i64>()
            .create("knitvox_format_version")?
            .write_scalar(&FORMAT_VERSION)?;
        write_str_attr(&file, "units", "m")?;
        write_str_attr(&file, "up_axis", "y")?;
        write_str_attr(
            &file,
            "generator",
            &format!("knitvox {}", env!("CARGO_PKG_VERSION")),
        )?;
        let g = super::h5::new_group(&file, "character")?;
        let tri: Vec<u32> = cache.triangles.iter().flatten().copied().collect();
        g.new_dataset::<u32>()
            .shape([cache.triangles.len(), 3])
            .create("triangles")?
            .write_raw(&tri)?;
        super::h5::write_1d(&g, "times", &cache.times, Some("s"))?;
        let (f, v) = (cache.num_frames(), cache.num_vertices);
        let ds = g
            .new_dataset::<f64>()
            .shape([f, v, 3])
            .chunk([1, v, 3])
            .shuffle()
            .deflate(super::h5::FRAME_DEFLATE_LEVEL)
            .create("points")?;
        ds.write_raw(cache.points.as_flattened())?;
        if let Some(rest) = &cache.rest {
            g.new_dataset::<f64>()
                .shape([v, 3])
                .create("rest_points")?
                .write_raw(rest.as_flattened())?;
        }
        file.close()?;
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cache() -> BodyCache {
        BodyCache {
            triangles: vec![[0, 1, 2], [0, 2, 3]],
            num_vertices: 4,
            times: vec![0.0, 0.5, 1.0],
            points: (0..12)
                .map(|i| [i as f64, (i % 4) as f64 * 0.1, 0.25 * (i / 4) as f64])
                .collect(),
            rest: Some(vec![
                [0.0; 3],
                [1.0, 0.0, 0.0],
                [1.0, 1.0, 0.0],
                [0.0, 1.0, 0.0],
            ]),
        }
    }

    #[test]
    fn round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("body.h5");
        let c = cache();
        write_character_cache(&p, &c).unwrap();
        assert!(is_character_cache(&p));
        let back = read_character_cache(&p, 1 << 30).unwrap();
        assert_eq!(back.cache, c);
        assert_eq!(back.units, Some(Units::METRES));
        assert_eq!(back.up_axis, Some(UpAxis::Y));
    }

    #[test]
    fn budget_is_checked_before_reading() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("body.h5");
        write_character_cache(&p, &cache()).unwrap();
        // The file's size is over the budget: refused before libhdf5 opens it.
        let e = read_character_cache(&p, 100).unwrap_err().to_string();
        assert!(
            e.contains("memory budget") && e.contains("it is not read"),
            "{e}"
        );
    }
}
