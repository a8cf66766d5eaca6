//! Named built-in patterns. Knit grids are written as seen from the front,
//! top course first (the grid text format), so each reads like its chart.

use super::{grid::parse_grid, Pattern, PatternError};

/// Names of the built-in patterns, knits first.
pub const BUILTIN_NAMES: [&str; 10] = [
    "stockinette",
    "garter",
    "rib1x1",
    "rib2x2",
    "seed",
    "basketweave",
    "plain",
    "twill",
    "satin",
    "basket",
];

/// Grid text of a built-in (see `schemas/pattern-grid.md`).
pub fn builtin_text(name: &str) -> Option<&'static str> {
    Some(match name {
        // Every stitch knit: Vs on the front, purl bumps on the back.
        "stockinette" => "K\n",
        // Alternate knit and purl courses (all-knit worked flat).
        "garter" => "P\nK\n",
        // Knit and purl wales alternate.
        "rib1x1" => "KP\n",
        "rib2x2" => "KKPP\n",
        // 1x1 rib shifted by one wale every course.
        "seed" => "PK\nKP\n",
        // Knit basketweave: 4x4 blocks of stockinette and reverse stockinette.
        "basketweave" => concat!(
            "PPPPKKKK\n",
            "PPPPKKKK\n",
            "PPPPKKKK\n",
            "PPPPKKKK\n",
            "KKKKPPPP\n",
            "KKKKPPPP\n",
            "KKKKPPPP\n",
            "KKKKPPPP\n",
        ),
        // Wovens: 1 = weft over warp. Plain: over one, under one.
        "plain" => "01\n10\n",
        // 2/2 twill: over two, under two, shifted one warp per weft.
        "twill" => "1001\n0011\n0110\n1100\n",
        // 5-end satin (move 2): each weft goes under one warp of five.
        "satin" => "11011\n01111\n11110\n11101\n10111\n",
        // 2x2 basket (hopsack): plain weave with doubled yarns.
        "basket" => "0011\n0011\n1100\n1100\n",
        _ => return None,
    })
}

/// The built-in pattern `name`, or an error listing the known names.
pub fn builtin(name: &str) -> Result<Pattern, PatternError> {
    let key = name.trim().to_ascii_lowercase().replace(['-', '_'], "");
    let key = match key.as_str() {
        "stocking" | "stockinet" | "jersey" => "stockinette".to_string(),
        "rib" | "1x1rib" => "rib1x1".to_string(),
        "2x2rib" => "rib2x2".to_string(),
        "moss" => "seed".to_string(),
        _ => key,
    };
    let text = builtin_text(&key).ok_or_else(|| PatternError::UnknownPattern {
        name: name.to_string(),
        known: BUILTIN_NAMES.to_vec(),
    })?;
    parse_grid(text)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_builtin_parses_and_unknown_lists_names() {
        for n in BUILTIN_NAMES {
            builtin(n).unwrap();
        }
        assert_eq!(builtin("Rib-1x1").unwrap(), builtin("rib1x1").unwrap());
        let e = builtin("cable").unwrap_err();
        let msg = e.to_string();
        assert!(
            msg.contains("cable") && msg.contains("stockinette") && msg.contains("satin"),
            "{msg}"
        );
        // Satin: every weft goes under exactly one warp, each warp once.
        if let Ok(Pattern::Woven(w)) = builtin("satin") {
            for row in &w.rows {
                assert_eq!(row.iter().filter(|b| !**b).count(), 1);
            }
            for j in 0..5 {
                assert_eq!(w.rows.iter().filter(|r| !r[j]).count(), 1);
            }
        } else {
            panic!("satin is woven");
        }
    }
}
