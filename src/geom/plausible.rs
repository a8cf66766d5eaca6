//! Is a garment's size plausible for clothing? A file read in the wrong unit
//! is off by 10x-1000x (a glove from a unitless BCC in cm read as metres is
//! 35 m long); when the unit or up axis was assumed rather than declared, the
//! commands that read yarns (`embed`, `convert`, `simulate`) warn.

use super::{Bounds, Units};

/// Bounding-box diagonals (m) taken as clothing: 1 cm (a tiny swatch, a
/// doll's mitten) to 5 m (a long scarf, a blanket). Outside them the unit is
/// probably wrong.
pub const GARMENT_DIAGONAL_M: (f64, f64) = (0.01, 5.0);

/// A warning (one line) when `bounds` (m) is implausible for clothing and
/// something about the read was assumed: `assumed` names what (e.g.
/// `["unit m", "up axis +y"]`), `units` is the unit the file was read in.
/// None when the size is plausible or nothing was assumed.
pub fn garment_size_warning(bounds: &Bounds, units: Units, assumed: &[String]) -> Option<String> {
    let d = bounds.diagonal();
    let (lo, hi) = GARMENT_DIAGONAL_M;
    if assumed.is_empty() || !d.is_finite() || (lo..=hi).contains(&d) {
        return None;
    }
    let s = bounds.size();
    let hint = suggested_unit(d, units).map_or(
        String::from("give --units (`[garment] units` in a job) with the file's unit"),
        |u| format!("is the file in {u}? try --units {u} (`[garment] units` in a job)"),
    );
    Some(format!(
        "a {d:.3} m garment: the yarns are {:.3} x {:.3} x {:.3} m (diagonal {d:.3} m), implausible for \
         clothing ({lo} to {hi} m), and the {} assumed, not declared by the file: {hint}",
        s[0],
        s[1],
        s[2],
        match assumed {
            [one] => format!("{one} was"),
            _ => format!("{} were", assumed.join(" and ")),
        }
    ))
}

/// The named unit (mm, cm, m) that brings diagonal `d` (m, read in `units`)
/// closest to half a metre within the clothing range, if one does.
fn suggested_unit(d: f64, units: Units) -> Option<&'static str> {
    unit_into(d, d, units, GARMENT_DIAGONAL_M, 0.5)
}

/// The named unit (mm, cm, m) other than `units` that brings lengths
/// `lo..=hi` (m, read in `units`) inside `range`, the one closest to
/// `typical` (m), if one does.
fn unit_into(
    lo: f64,
    hi: f64,
    units: Units,
    range: (f64, f64),
    typical: f64,
) -> Option<&'static str> {
    let s = 1.0 / units.metres_per_unit;
    [("mm", 0.001), ("cm", 0.01), ("m", 1.0)]
        .into_iter()
        .filter(|&(_, m)| m != units.metres_per_unit)
        .map(|(name, m)| (name, lo * s * m, hi * s * m))
        .filter(|&(_, a, b)| range.0 <= a && b <= range.1)
        .min_by(|a, b| {
            let off = |x: f64| (x / typical).ln().abs();
            off(a.2).total_cmp(&off(b.2))
        })
        .map(|(name, _, _)| name)
}

/// Yarn radii (m) taken as knitting yarn: 0.01 mm (a fine thread) to 10 mm
/// (the thickest roving is about 2 cm across). Outside them a file's radius
/// was read in the wrong unit, or `--radius` was given in millimetres.
pub const YARN_RADIUS_M: (f64, f64) = (1e-5, 1e-2);

/// A warning (one line) when yarn radii `min..=max` (m) are implausible for
/// knitting yarn. `from_file`: the radii are the file's, read in `units`
/// (a wrong unit scales them too); otherwise they were given in metres
/// (`--radius`, `[garment] radius`). None when they are plausible.
pub fn yarn_radius_warning(min: f64, max: f64, units: Units, from_file: bool) -> Option<String> {
    let (lo, hi) = YARN_RADIUS_M;
    if !(min.is_finite() && max.is_finite()) || (lo <= min && max <= hi) {
        return None;
    }
    let shown = if min < max {
        format!("{min:.3e} to {max:.3e} m")
    } else {
        format!("{max:.3e} m")
    };
    let range = format!("{} to {} mm", lo * 1e3, hi * 1e3);
    if from_file {
        let hint = unit_into(min, max, units, YARN_RADIUS_M, 1e-3).map_or(
            String::from("check the file's unit (--units) or give --radius with --override-radius"),
            |u| format!("is the file in {u}? try --units {u} (`[garment] units` in a job)"),
        );
        Some(format!(
            "the file's yarn radius is {shown} read in {units}, implausible for knitting yarn ({range}): {hint}"
        ))
    } else {
        Some(format!(
            "the yarn radius is {shown}, implausible for knitting yarn ({range}): --radius \
             (`[garment] radius` in a job) is in metres (1 mm is 0.001)"
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cube(side: f64) -> Bounds {
        Bounds {
            min: [0.0; 3],
            max: [side; 3],
        }
    }

    #[test]
    fn warns_only_when_assumed_and_implausible() {
        let assumed = vec!["unit m".to_string()];
        // A glove in cm read as metres: 20 m across.
        let w = garment_size_warning(&cube(20.0), Units::METRES, &assumed).unwrap();
        assert!(
            w.contains("--units cm") && w.contains("unit m was assumed"),
            "{w}"
        );
        assert!(garment_size_warning(&cube(20.0), Units::METRES, &[]).is_none());
        assert!(garment_size_warning(&cube(0.2), Units::METRES, &assumed).is_none());
        assert!(
            w.starts_with("a 34.641 m garment") && w.contains("is the file in cm?"),
            "{w}"
        );
        // 1 mm across: no named unit makes it larger; only the generic hint.
        let w = garment_size_warning(&cube(0.001), Units::METRES, &assumed).unwrap();
        assert!(
            w.contains("give --units") && !w.contains("--units mm"),
            "{w}"
        );
        // The bounds: 5 m is plausible, 5.1 m is not.
        let diag = |d: f64| cube(d / 3f64.sqrt());
        assert!(garment_size_warning(&diag(4.99), Units::METRES, &assumed).is_none());
        assert!(garment_size_warning(&diag(5.1), Units::METRES, &assumed).is_some());
        assert!(garment_size_warning(&diag(0.0099), Units::METRES, &assumed).is_some());
    }

    #[test]
    fn an_implausible_radius_suggests_the_unit_or_says_radii_are_in_metres() {
        // A file in cm read as metres: a 0.25 mm yarn is 25 mm thick.
        let w = yarn_radius_warning(0.025, 0.025, Units::METRES, true).unwrap();
        assert!(
            w.contains("try --units cm") && w.contains("2.500e-2 m"),
            "{w}"
        );
        // Read in mm where the file is in m: 0.25 µm.
        let w = yarn_radius_warning(2.5e-7, 2.5e-7, Units::MILLIMETRES, true).unwrap();
        assert!(w.contains("try --units m ("), "{w}");
        // `--radius 0.5` meant as mm: 50 cm.
        let w = yarn_radius_warning(0.5, 0.5, Units::METRES, false).unwrap();
        assert!(w.contains("in metres") && !w.contains("--units"), "{w}");
        for r in [1e-5, 2.5e-4, 1e-3, 1e-2] {
            assert!(
                yarn_radius_warning(r, r, Units::METRES, true).is_none(),
                "{r}"
            );
        }
        assert!(yarn_radius_warning(1e-3, 0.02, Units::METRES, false).is_some());
    }
}
