//! Text grids of stitch codes (Leaf §4: "pattern files mimic the spatial
//! layout of the pattern and show up as rectangular patterns of text"). The
//! format is documented in `schemas/pattern-grid.md`:
//!
//! * one line per course (knit) or weft (woven), written as the fabric is
//!   seen from the front: the **top line is the last course**, the bottom
//!   line the first (like a knitting chart);
//! * knit codes `K` (knit) and `P` (purl), case-insensitive; woven codes `1`
//!   (weft over warp) and `0` (warp over weft); one grid is all knit or all
//!   woven;
//! * spaces and tabs between codes are ignored; `#` starts a comment that
//!   runs to the end of the line; blank lines are skipped;
//! * every row has the same number of codes.

use super::types::{KnitGrid, Pattern, PatternError, Stitch, WeaveMatrix};

#[derive(Clone, Copy, PartialEq)]
enum Cell {
    Stitch(Stitch),
    Woven(bool),
}

/// Most codes per row and rows per grid accepted (a guard against feeding
/// the generator an image-sized file by mistake).
pub const MAX_GRID_SIDE: usize = 4096;

/// Parses a grid text into a pattern. Errors name the 1-based line and column.
pub fn parse_grid(text: &str) -> Result<Pattern, PatternError> {
    let err = |line: usize, column: usize, message: String| PatternError::Grid {
        line,
        column,
        message,
    };
    // (line number, cells with their columns), top line first.
    let mut rows: Vec<(usize, Vec<(usize, Cell)>)> = Vec::new();
    let mut kind: Option<(bool, usize, usize)> = None; // (woven?, line, column) of the first code
    for (li, raw) in text.lines().enumerate() {
        let line = li + 1;
        let mut cells = Vec::new();
        for (ci, ch) in raw.chars().enumerate() {
            let column = ci + 1;
            let cell = match ch {
                '#' => break,
                ' ' | '\t' | '\r' | '\u{feff}' => continue,
                'K' | 'k' => Cell::Stitch(Stitch::Knit),
                'P' | 'p' => Cell::Stitch(Stitch::Purl),
                '1' => Cell::Woven(true),
                '0' => Cell::Woven(false),
                other => {
                    return Err(err(
                        line,
                        column,
                        format!(
                            "unknown stitch code '{}'; knit grids use K and P, woven grids 1 (weft over) and 0 (warp over)",
                            other.escape_default()
                        ),
                    ))
                }
            };
            let woven = matches!(cell, Cell::Woven(_));
            match kind {
                None => kind = Some((woven, line, column)),
                Some((k, l0, c0)) if k != woven => {
                    return Err(err(
                        line,
                        column,
                        format!(
                            "'{ch}' is a {} code but the grid started as {} at line {l0}, column {c0}; \
                             a grid is all knit (K, P) or all woven (0, 1)",
                            if woven { "woven" } else { "knit" },
                            if k { "woven" } else { "knit" },
                        ),
                    ))
                }
                _ => {}
            }
            if cells.len() == MAX_GRID_SIDE {
                return Err(err(
                    line,
                    column,
                    format!("more than {MAX_GRID_SIDE} codes in a row"),
                ));
            }
            cells.push((column, cell));
        }
        if cells.is_empty() {
            continue;
        }
        if let Some((l0, first)) = rows.first() {
            if cells.len() != first.len() {
                let column = cells
                    .get(first.len())
                    .map_or_else(|| raw.chars().count() + 1, |c| c.0);
                return Err(err(
                    line,
                    column,
                    format!(
                        "row has {} codes but the first row (line {l0}) has {}; grids are rectangular",
                        cells.len(),
                        first.len()
                    ),
                ));
            }
        }
        if rows.len() == MAX_GRID_SIDE {
            return Err(err(line, 1, format!("more than {MAX_GRID_SIDE} rows")));
        }
        rows.push((line, cells));
    }
    if rows.is_empty() {
        return Err(err(
            text.lines().count().max(1),
            1,
            "no stitch codes found (every line is blank or a comment)".into(),
        ));
    }
    // Bottom course first.
    rows.reverse();
    let woven = kind.is_some_and(|k| k.0);
    Ok(if woven {
        Pattern::Woven(WeaveMatrix {
            rows: rows
                .iter()
                .map(|(_, r)| {
                    r.iter()
                        .map(|(_, c)| matches!(c, Cell::Woven(true)))
                        .collect()
                })
                .collect(),
        })
    } else {
        Pattern::Knit(KnitGrid {
            rows: rows
                .iter()
                .map(|(_, r)| {
                    r.iter()
                        .map(|(_, c)| match c {
                            Cell::Stitch(s) => *s,
                            Cell::Woven(_) => Stitch::Knit, // unreachable: kinds are checked
                        })
                        .collect()
                })
                .collect(),
        })
    })
}

/// Writes a pattern back as grid text (top course first), the inverse of [`parse_grid`].
pub fn to_grid_text(p: &Pattern) -> String {
    let mut out = String::new();
    let push_rows = |out: &mut String, rows: Vec<String>| {
        for r in rows.iter().rev() {
            out.push_str(r);
            out.push('\n');
        }
    };
    match p {
        Pattern::Knit(g) => push_rows(
            &mut out,
            g.rows
                .iter()
                .map(|r| {
                    r.iter()
                        .map(|s| if *s == Stitch::Knit { 'K' } else { 'P' })
                        .collect()
                })
                .collect(),
        ),
        Pattern::Woven(w) => push_rows(
            &mut out,
            w.rows
                .iter()
                .map(|r| r.iter().map(|&b| if b { '1' } else { '0' }).collect())
                .collect(),
        ),
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use Stitch::{Knit as K, Purl as P};

    #[test]
    fn parses_bottom_course_first_with_comments() {
        let g = parse_grid("# seed-ish\nK P  # top course\n\n p k\n").unwrap();
        assert_eq!(
            g,
            Pattern::Knit(KnitGrid {
                rows: vec![vec![P, K], vec![K, P]]
            })
        );
        assert_eq!(to_grid_text(&g), "KP\nPK\n");
        assert_eq!(parse_grid(&to_grid_text(&g)).unwrap(), g);
    }

    #[test]
    fn woven_grid() {
        let g = parse_grid("10\n01\n").unwrap();
        assert!(matches!(g, Pattern::Woven(_)));
    }

    fn grid_err(text: &str) -> (usize, usize, String) {
        match parse_grid(text) {
            Err(PatternError::Grid {
                line,
                column,
                message,
            }) => (line, column, message),
            other => panic!("expected a grid error, got {other:?}"),
        }
    }

    #[test]
    fn errors_name_line_and_column() {
        let (l, c, m) = grid_err("KP\nKX\n");
        assert_eq!((l, c), (2, 2));
        assert!(m.contains("'X'"), "{m}");
        let (l, c, m) = grid_err("KPK\n# c\nKP\n");
        assert_eq!((l, c), (3, 3));
        assert!(m.contains("rectangular"), "{m}");
        let (l, c, _) = grid_err("KPK\nKPKK\n");
        assert_eq!((l, c), (2, 4));
        let (l, c, m) = grid_err("K P\n1 0\n");
        assert_eq!((l, c), (2, 1));
        assert!(m.contains("all knit"), "{m}");
        let (l, _, m) = grid_err("# nothing\n\n");
        assert_eq!(l, 2);
        assert!(m.contains("no stitch codes"));
        let (_, _, m) = grid_err("K\u{1}");
        assert!(m.contains("\\u{1}"), "{m}");
    }
}
