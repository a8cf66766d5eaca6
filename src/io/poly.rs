//! YarnBall-style `.poly` curves (the PRISMS / Houdini ASCII polygon format).
//!
//! No written specification was found; this reader accepts what Houdini's
//! `.poly` export and the readers that consume it (YarnBall's `readFromPoly`,
//! diamorse skeleton tools) agree on:
//!
//! ```text
//! POINTS
//! 1: x y z [w] [attributes such as c(r, g, b, a)]
//! 2: ...
//! POLYS
//! 1: i j [k ...] [<] [attributes]
//! ...
//! END
//! ```
//!
//! * Sections come in that order: `POINTS`, `POLYS`, `END` (each keyword
//!   alone on its line). `END` is required, so a truncated file is reported
//!   as such; anything after `END` is ignored. Blank lines and lines starting
//!   with `#` are skipped.
//! * Point and polygon labels (`N:`) are 1-based and must count up 1, 2, 3...
//!   (YarnBall checks the same). Coordinates must be finite. An optional
//!   fourth number (a homogeneous weight) and trailing attributes (a name
//!   and a parenthesised list, e.g. `c(0, 0, 0, 1)`) are ignored.
//! * Polygon entries list 1-based point labels. A trailing `<` marks an open
//!   polygon, i.e. a polyline (Houdini's convention); without it an entry of
//!   three or more points is a closed loop (a repeated first point at the end
//!   is dropped). Entries of exactly two points are segments whichever way
//!   they are marked: YarnBall-style files store yarns as one segment per
//!   entry, and those are chained through shared points into polylines (a
//!   chain that returns to its start is closed; a point shared by more than
//!   two segments is an error). Open multi-point entries are taken as written.
//!
//! Errors name the 1-based line. The format carries no unit and no up axis
//! (YarnBall treats the coordinates as centimetres: read its files with
//! `--units cm`). knitvox does not write `.poly`.

use super::bytes::{parse_finite, text_lines};
use super::obj::{assemble, Piece, PieceKind};
use super::{Decoded, FormatError, ReadOptions};
use crate::geom::Vec3;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Section {
    Start,
    Points,
    Polys,
}

/// Splits `N: rest` and checks that the label is `expected` (1-based).
fn label<'a>(
    text: &'a str,
    ln: usize,
    what: &str,
    expected: usize,
) -> Result<&'a str, FormatError> {
    let (id, rest) = text.split_once(':').ok_or_else(|| {
        FormatError::at_line(
            ln,
            format!("{what} line must start with its number and a colon ('N: ...')"),
        )
    })?;
    let id = id.trim();
    let n: u64 = id.parse().map_err(|_| {
        FormatError::at_line(
            ln,
            format!("{what} number '{id}' is not a positive integer"),
        )
    })?;
    if n != expected as u64 {
        return Err(FormatError::at_line(
            ln,
            format!("{what} number {n} out of sequence: expected {expected}"),
        ));
    }
    Ok(rest)
}

/// True for the start of trailing attribute text such as `c(0, 0, 0, 1)`:
/// a name of letters followed by `(`.
fn is_attribute(token: &str) -> bool {
    token
        .split_once('(')
        .is_some_and(|(name, _)| !name.is_empty() && name.chars().all(|c| c.is_ascii_alphabetic()))
}

/// Decodes a `.poly` file (file units and axes; radii are placeholders).
pub fn decode(data: &[u8], opts: &ReadOptions) -> Result<Decoded, FormatError> {
    let mut section = Section::Start;
    let mut ended = false;
    let mut points: Vec<Vec3> = Vec::new();
    let mut indices: Vec<usize> = Vec::new();
    let mut pieces: Vec<Piece> = Vec::new();
    let mut polys_line = 0usize;
    let mut attributes = false;
    for item in text_lines(data) {
        let (ln, raw) = item?;
        let text = raw.trim();
        if text.is_empty() || text.starts_with('#') {
            continue;
        }
        match (text, section) {
            ("POINTS", Section::Start) => {
                section = Section::Points;
                continue;
            }
            ("POLYS", Section::Points) => {
                section = Section::Polys;
                polys_line = ln;
                continue;
            }
            ("END", Section::Points | Section::Polys) => {
                ended = true;
                break;
            }
            ("POINTS" | "POLYS" | "END", _) => {
                let expected = match section {
                    Section::Start => "POINTS",
                    Section::Points => "POLYS or END",
                    Section::Polys => "END",
                };
                return Err(FormatError::at_line(
                    ln,
                    format!("unexpected {text}: expected {expected}"),
                ));
            }
            _ => {}
        }
        match section {
            Section::Start => {
                return Err(FormatError::at_line(
                    ln,
                    "expected POINTS (a .poly file starts with its POINTS section)".to_string(),
                ))
            }
            Section::Points => {
                let rest = label(text, ln, "point", points.len() + 1)?;
                let mut tok = rest.split_ascii_whitespace().peekable();
                let mut p = [0.0; 3];
                for (k, name) in ["x", "y", "z"].iter().enumerate() {
                    let t = tok.next().ok_or_else(|| {
                        FormatError::at_line(ln, format!("point has no {name} coordinate"))
                    })?;
                    p[k] = parse_finite(t, ln, &format!("point {name}"))?;
                }
                if let Some(t) = tok.next_if(|t| !is_attribute(t)) {
                    parse_finite(t, ln, "point weight")?;
                }
                if let Some(t) = tok.next() {
                    if !is_attribute(t) {
                        return Err(FormatError::at_line(
                            ln,
                            format!("unexpected '{t}' after the point coordinates"),
                        ));
                    }
                    attributes = true;
                }
                if points.len() as u64 >= opts.max_points {
                    return Err(FormatError::at_line(
                        ln,
                        format!(
                            "more than {} points (the reader's limit, max_points)",
                            opts.max_points
                        ),
                    ));
                }
                points.push(p);
            }
            Section::Polys => {
                let rest = label(text, ln, "polygon", pieces.len() + 1)?;
                let start = indices.len();
                let mut open = false;
                let mut tok = rest.split_ascii_whitespace();
                for t in tok.by_ref() {
                    if t == "<" {
                        open = true;
                        break;
                    }
                    if is_attribute(t) {
                        attributes = true;
                        break;
                    }
                    let i: u64 = t.parse().map_err(|_| {
                        FormatError::at_line(ln, format!("polygon: '{t}' is not a point number"))
                    })?;
                    if i == 0 || i > points.len() as u64 {
                        return Err(FormatError::at_line(
                            ln,
                            format!(
                                "point number {i} is out of range: the file has points 1 to {}",
                                points.len()
                            ),
                        ));
                    }
                    if indices.len() as u64 >= opts.max_points {
                        return Err(FormatError::at_line(
                            ln,
                            format!(
                                "more than {} point references (the reader's limit, max_points)",
                                opts.max_points
                            ),
                        ));
                    }
                    indices.push(i as usize - 1);
                }
                if let Some(t) = tok.next() {
                    if !is_attribute(t) {
                        return Err(FormatError::at_line(
                            ln,
                            format!("unexpected '{t}' after the polygon's points"),
                        ));
                    }
                    attributes = true;
                }
                let n = indices.len() - start;
                if n < 2 {
                    return Err(FormatError::at_line(
                        ln,
                        format!("a polygon needs at least 2 points, this one has {n}"),
                    ));
                }
                let kind = if n == 2 && indices[start] != indices[start + 1] {
                    PieceKind::Segment
                } else if open {
                    PieceKind::Open
                } else {
                    if indices[start] == indices[indices.len() - 1] {
                        indices.pop(); // repeated first point of a closed loop
                    }
                    PieceKind::Closed
                };
                pieces.push(Piece {
                    start,
                    end: indices.len(),
                    line: ln,
                    kind,
                });
            }
        }
    }
    if !ended {
        let what = match section {
            Section::Start => "no POINTS section",
            Section::Points => "the POINTS section is not followed by POLYS and END",
            Section::Polys => "no END after the POLYS section",
        };
        return Err(FormatError::whole_file(format!(
            "{what} (empty or truncated file?)"
        )));
    }
    if pieces.is_empty() {
        return Err(FormatError::at_line(
            polys_line.max(1),
            format!(
                "no polygons: {} points but nothing connects them into yarns",
                points.len()
            ),
        ));
    }
    let yarns = assemble(&points, &indices, &pieces, opts.radius)?;
    let mut d = Decoded::plain(yarns);
    d.notes.push(format!(
        "{} points, {} polygons",
        points.len(),
        pieces.len()
    ));
    d.notes.push(
        "YarnBall reads .poly coordinates as centimetres (use --units cm for its files)".into(),
    );
    if attributes {
        d.notes.push("point/polygon attributes were ignored".into());
    }
    Ok(d)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::Location;

    fn dec(s: &str) -> Result<Decoded, FormatError> {
        decode(s.as_bytes(), &ReadOptions::default())
    }

    const PTS: &str = "POINTS\n1: 0 0 0\n2: 1 0 0\n3: 1 1 0 c(0, 0, 0, 1)\n4: 0 1 0 1\n";

    #[test]
    fn segments_open_and_closed_polygons() {
        let d = dec(&format!(
            "{PTS}POLYS\n1: 1 2\n2: 2 3\n3: 1 2 3 4\n4: 4 3 2 <\nEND\n"
        ))
        .unwrap();
        let y = &d.yarns;
        assert_eq!(y.num_curves(), 3);
        assert_eq!(
            y.curve(0),
            &[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0]]
        );
        assert!(!y.closed[0]);
        assert_eq!(y.curve(1).len(), 4);
        assert!(y.closed[1]);
        assert_eq!(
            y.curve(2),
            &[[0.0, 1.0, 0.0], [1.0, 1.0, 0.0], [1.0, 0.0, 0.0]]
        );
        assert!(!y.closed[2]);
    }

    #[test]
    fn segment_loop_is_closed() {
        let d = dec(&format!(
            "{PTS}POLYS\n1: 1 2 <\n2: 2 3 <\n3: 3 4 <\n4: 4 1 <\nEND\n"
        ))
        .unwrap();
        assert_eq!(d.yarns.num_curves(), 1);
        assert!(d.yarns.closed[0]);
        assert_eq!(d.yarns.num_points(), 4);
    }

    #[test]
    fn errors_name_lines() {
        let cases: &[(&str, usize, &str)] = &[
            ("POINTS\n1: 0 0 0\n3: 1 0 0\n", 3, "sequence"),
            ("POINTS\n1: 0 0\n", 2, "no z"),
            ("POINTS\n1: 0 nan 0\n", 2, "not finite"),
            ("POINTS\n1 0 0 0\n", 2, "colon"),
            ("POINTS\n1: 0 0 0 1 2\n", 2, "unexpected"),
            (
                "POINTS\n1: 0 0 0\n2: 1 0 0\nPOLYS\n1: 1 3\nEND\n",
                5,
                "out of range",
            ),
            (
                "POINTS\n1: 0 0 0\n2: 1 0 0\nPOLYS\n1: 0 1\nEND\n",
                5,
                "out of range",
            ),
            (
                "POINTS\n1: 0 0 0\n2: 1 0 0\nPOLYS\n1: 1\nEND\n",
                5,
                "at least 2",
            ),
            (
                "POINTS\n1: 0 0 0\n2: 1 0 0\nPOLYS\n1: 1 1\nEND\n",
                5,
                "at least 2",
            ),
            (
                "POINTS\n1: 0 0 0\n2: 1 0 0\nPOLYS\n1: 1 x\nEND\n",
                5,
                "not a point number",
            ),
            ("POINTS\n1: 0 0 0\n2: 1 0 0\nPOLYS\nEND\n", 4, "no polygons"),
            ("1: 0 0 0\n", 1, "expected POINTS"),
            ("POLYS\n", 1, "expected POINTS"),
            ("POINTS\nPOINTS\n", 2, "unexpected POINTS"),
        ];
        for (src, line, what) in cases {
            let e = dec(src).unwrap_err();
            assert_eq!(e.location, Location::Line(*line), "{src:?}: {e}");
            assert!(e.message.contains(what), "{src:?}: {e}");
        }
        for src in [
            "",
            "POINTS\n1: 0 0 0\n",
            "POINTS\n1: 0 0 0\n2: 1 0 0\nPOLYS\n1: 1 2\n",
        ] {
            let e = dec(src).unwrap_err();
            assert_eq!(e.location, Location::File, "{src:?}: {e}");
            assert!(e.message.contains("truncated"), "{src:?}: {e}");
        }
    }
}
