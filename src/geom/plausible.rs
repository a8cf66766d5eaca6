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
    let hint = suggested_unit(d, units).map_or(String::from("give --units"), |u| {
        format!("give --units {u} if that is the file's unit")
    });
    Some(format!(
        "the yarns are {:.3} x {:.3} x {:.3} m (diagonal {d:.3} m), implausible for clothing ({lo} to {hi} m), \
         and the {} assumed, not declared by the file: {hint}",
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
    let (lo, hi) = GARMENT_DIAGONAL_M;
    let file_d = d / units.metres_per_unit;
    [("mm", 0.001), ("cm", 0.01), ("m", 1.0)]
        .into_iter()
        .map(|(name, m)| (name, file_d * m))
        .filter(|&(_, dm)| (lo..=hi).contains(&dm))
        .min_by(|a, b| (a.1 / 0.5).ln().abs().total_cmp(&(b.1 / 0.5).ln().abs()))
        .map(|(name, _)| name)
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
}
