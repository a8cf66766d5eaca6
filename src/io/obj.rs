//! Wavefront OBJ polylines: `v` vertices and `l` line elements.
//!
//! # What the reader accepts
//!
//! * `v x y z [more numbers]`: a vertex. Extra numbers (the rational weight
//!   `w`, or the `r g b` colour some tools append) must be numbers and are
//!   ignored. Every coordinate must be finite.
//! * `l i j k ...`: one polyline through the listed vertices. Indices are
//!   1-based; a negative index counts back from the last vertex defined so
//!   far (`-1` is the latest). An entry may be `v/vt`; only the vertex part is
//!   used. A positive index may refer to a vertex defined later in the file.
//!   * An element whose last index equals its first is a closed curve (the
//!     repeated index is dropped).
//!   * Elements with exactly two different indices are segments: some tools
//!     write one `l` per segment. All such segments are chained through their
//!     shared vertices into polylines (a chain that comes back to its start is
//!     closed), like PLY edges. A vertex shared by more than two segments is a
//!     branch and an error. Elements with three or more indices are taken as
//!     written and not chained with segments.
//!   * Continued elements: an `l` whose first index is the last index of the
//!     `l` statement just before it, in the same object and group (no `o` or
//!     `g` between them), continues that element when the earlier one is an
//!     open polyline of three or more indices (not a segment, not closed).
//!     The two are one curve; if the joined element ends on its first index it
//!     is closed. knitvox writes long curves this way (see below). Elements
//!     that merely share a vertex in any other way stay separate curves.
//! * A line ending with `\` continues on the next line (Houdini wraps long
//!   `l` elements this way); `#` starts a comment.
//! * Faces (`f`), points (`p`), free-form curves (`cstype`, `curv`, ...),
//!   normals, texture coordinates, groups, objects, smoothing and material
//!   statements are ignored; what was ignored is listed in the notes.
//!
//! Errors name the 1-based line where the statement starts. OBJ carries no
//! unit and no up axis, so the decoder declares neither.
//!
//! # What the writer writes
//!
//! A comment header (`# knitvox <version>`, the unit and up axis of the
//! coordinates, counts), `o yarns`, one `v` line per point with the shortest
//! decimal form that reads back to the same `f64`, and one `l` per curve;
//! closed curves repeat their first index at the end. A curve with more than
//! [`MAX_LINE_INDICES`] indices is written as several `l` lines of at most
//! that many indices, each starting with the last index of the line before
//! (continued elements, above), because Blender's OBJ importer stops reading
//! a line at 262,144 characters and drops the rest of the curve.

use std::fmt::Write as _;

use super::bytes::{parse_finite, text_lines};
use super::{Decoded, FormatError, ReadOptions};
use crate::geom::{Units, UpAxis, Vec3, Yarns};

/// How a line element (OBJ `l`, `.poly` polygon) takes part in building curves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum PieceKind {
    /// Two different vertices: chained with other segments that share its ends.
    Segment,
    /// An open polyline taken as written.
    Open,
    /// A closed polyline (first vertex not repeated at the end).
    Closed,
}

/// One line element: `indices[start..end]` (0-based vertex indices), from `line`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Piece {
    pub start: usize,
    pub end: usize,
    pub line: usize,
    pub kind: PieceKind,
}

const NONE: usize = usize::MAX;

/// The most vertex indices the writer puts on one `l` line (a longer curve
/// continues on the next line, which repeats the last index). 2,001 indices
/// of up to 20 digits stay far below Blender's 262,144-character line limit.
pub const MAX_LINE_INDICES: usize = 2001;

/// Builds curves from line elements over `points`: open and closed pieces
/// become one curve each, segments are chained through shared vertices.
/// Curves come out in the order of their first element in the file. Every
/// index must already be `< points.len()`.
pub(crate) fn assemble(
    points: &[Vec3],
    indices: &[usize],
    pieces: &[Piece],
    radius: f64,
) -> Result<Yarns, FormatError> {
    let mut yarns = Yarns::new();
    // Segment graph: for each vertex, the (at most two) segments ending there.
    let seg_ids: Vec<usize> = (0..pieces.len())
        .filter(|&p| pieces[p].kind == PieceKind::Segment)
        .collect();
    let mut adj: Vec<[usize; 2]> = Vec::new();
    if !seg_ids.is_empty() {
        adj = vec![[NONE; 2]; points.len()];
        for &p in &seg_ids {
            let piece = &pieces[p];
            for &v in &indices[piece.start..piece.end] {
                let slot = &mut adj[v];
                if slot[0] == NONE {
                    slot[0] = p;
                } else if slot[1] == NONE {
                    slot[1] = p;
                } else {
                    return Err(FormatError::at_line(
                        piece.line,
                        format!(
                            "vertex {} is an end of more than two segments (lines {}, {} and {}): a yarn cannot branch",
                            v + 1,
                            pieces[slot[0]].line,
                            pieces[slot[1]].line,
                            piece.line
                        ),
                    ));
                }
            }
        }
    }
    let ends = |p: usize| (indices[pieces[p].start], indices[pieces[p].start + 1]);
    let other_end = |p: usize, v: usize| {
        let (a, b) = ends(p);
        if a == v {
            b
        } else {
            a
        }
    };
    // The segment at `v` other than `p`, if any.
    let next_seg = |v: usize, p: usize| {
        let [s0, s1] = adj[v];
        if s0 == p {
            (s1 != NONE).then_some(s1)
        } else {
            Some(s0)
        }
    };
    let mut visited = vec![false; pieces.len()];
    let mut buf: Vec<Vec3> = Vec::new();
    for (p, piece) in pieces.iter().enumerate() {
        match piece.kind {
            PieceKind::Open | PieceKind::Closed => {
                buf.clear();
                buf.extend(indices[piece.start..piece.end].iter().map(|&v| points[v]));
                if buf.len() < 2 {
                    return Err(FormatError::at_line(
                        piece.line,
                        format!(
                            "a curve needs at least 2 different vertices, this one has {}",
                            buf.len()
                        ),
                    ));
                }
                yarns.push_curve(&buf, piece.kind == PieceKind::Closed, radius);
            }
            PieceKind::Segment if visited[p] => {}
            PieceKind::Segment => {
                // Walk backwards from the segment's first vertex to the start of
                // its chain (or all the way round a loop), so that the chain
                // then runs in this segment's written direction.
                let (a, _) = ends(p);
                let (mut v, mut seg, mut closed) = (a, p, false);
                let mut steps = 0usize;
                while let Some(t) = next_seg(v, seg) {
                    if t == p {
                        closed = true;
                        break;
                    }
                    v = other_end(t, v);
                    seg = t;
                    steps += 1;
                    if steps > seg_ids.len() {
                        return Err(FormatError::at_line(
                            piece.line,
                            "internal error: segment chain does not end",
                        ));
                    }
                }
                let (start_v, start_seg) = if closed { (a, p) } else { (v, seg) };
                buf.clear();
                buf.push(points[start_v]);
                let (mut v, mut seg) = (start_v, start_seg);
                loop {
                    visited[seg] = true;
                    v = other_end(seg, v);
                    if closed && v == start_v {
                        break;
                    }
                    buf.push(points[v]);
                    match next_seg(v, seg) {
                        Some(t) if !visited[t] => seg = t,
                        _ => break,
                    }
                }
                yarns.push_curve(&buf, closed, radius);
            }
        }
    }
    Ok(yarns)
}

/// Joins physical lines continued with a trailing `\` and strips `#`
/// comments; yields `(first physical line, statement text)`.
fn statements(data: &[u8]) -> impl Iterator<Item = Result<(usize, String), FormatError>> + '_ {
    let mut lines = text_lines(data);
    std::iter::from_fn(move || {
        let mut acc: Option<(usize, String)> = None;
        loop {
            let Some(next) = lines.next() else {
                return acc.map(Ok);
            };
            let (ln, raw) = match next {
                Ok(x) => x,
                Err(e) => return Some(Err(e)),
            };
            let text = raw.split('#').next().unwrap_or("").trim_end();
            let (text, continues) = match text.strip_suffix('\\') {
                Some(t) => (t, true),
                None => (text, false),
            };
            let entry = acc.get_or_insert_with(|| (ln, String::new()));
            entry.1.push_str(text);
            entry.1.push(' ');
            if !continues {
                return acc.map(Ok);
            }
        }
    })
}

/// Decodes an OBJ file's `l` polylines (file units and axes; radii are placeholders).
pub fn decode(data: &[u8], opts: &ReadOptions) -> Result<Decoded, FormatError> {
    let mut points: Vec<Vec3> = Vec::new();
    let mut indices: Vec<usize> = Vec::new();
    let mut pieces: Vec<Piece> = Vec::new();
    // Positive indices may point forward; they are checked once all vertices are known.
    let mut forward_check: Vec<(usize, usize)> = Vec::new(); // (piece, max index)
    let mut faces = 0usize;
    let mut freeform = 0usize;
    let mut point_elems = 0usize;
    let mut unknown: Vec<String> = Vec::new();
    let mut unknown_count = 0usize;
    let mut header: Option<String> = None;
    // Whether the next `l` may continue the last piece (no `o`/`g` since it).
    let mut may_continue = false;
    let mut continued = 0usize;
    if let Some(Ok((_, first))) = text_lines(data).next() {
        if let Some(c) = first.trim().strip_prefix('#') {
            header = Some(c.trim().to_string());
        }
    }

    for st in statements(data) {
        let (ln, text) = st?;
        let mut tok = text.split_ascii_whitespace();
        let Some(kw) = tok.next() else { continue };
        match kw {
            "v" => {
                let mut p = [0.0; 3];
                for (k, name) in ["x", "y", "z"].iter().enumerate() {
                    let t = tok.next().ok_or_else(|| {
                        FormatError::at_line(ln, format!("vertex has no {name} coordinate"))
                    })?;
                    p[k] = parse_finite(t, ln, &format!("vertex {name}"))?;
                }
                for t in tok {
                    if t.parse::<f64>().is_err() {
                        return Err(FormatError::at_line(
                            ln,
                            format!(
                                "vertex: '{}' after the coordinates is not a number",
                                crate::geom::excerpt(t)
                            ),
                        ));
                    }
                }
                if points.len() as u64 >= opts.max_points {
                    return Err(FormatError::at_line(
                        ln,
                        format!(
                            "more than {} vertices (the reader's limit, max_points)",
                            opts.max_points
                        ),
                    ));
                }
                points.push(p);
            }
            "l" => {
                let start = indices.len();
                let mut max_forward = 0usize;
                for t in tok {
                    let vpart = t.split('/').next().unwrap_or("");
                    let i: i64 = vpart.parse().map_err(|_| {
                        FormatError::at_line(
                            ln,
                            format!(
                                "line element: '{}' is not a vertex index",
                                crate::geom::excerpt(t)
                            ),
                        )
                    })?;
                    let v = if i > 0 {
                        let v = (i - 1) as u64;
                        if v >= opts.max_points {
                            return Err(FormatError::at_line(
                                ln,
                                format!(
                                    "vertex index {i} is beyond the reader's limit of {} vertices",
                                    opts.max_points
                                ),
                            ));
                        }
                        max_forward = max_forward.max(v as usize + 1);
                        v as usize
                    } else if i < 0 {
                        let back = i.unsigned_abs();
                        if back > points.len() as u64 {
                            return Err(FormatError::at_line(
                                ln,
                                format!(
                                    "relative vertex index {i} reaches before the first vertex ({} defined so far)",
                                    points.len()
                                ),
                            ));
                        }
                        points.len() - back as usize
                    } else {
                        return Err(FormatError::at_line(
                            ln,
                            "vertex index 0 (OBJ indices start at 1)",
                        ));
                    };
                    if indices.len() as u64 >= opts.max_points {
                        return Err(FormatError::at_line(
                            ln,
                            format!(
                                "more than {} vertex references (the reader's limit, max_points)",
                                opts.max_points
                            ),
                        ));
                    }
                    indices.push(v);
                }
                let n = indices.len() - start;
                if n < 2 {
                    return Err(FormatError::at_line(
                        ln,
                        format!("a line element needs at least 2 vertex indices, this one has {n}"),
                    ));
                }
                // A continuation of the previous open polyline: drop the
                // repeated joint index and extend that piece.
                if may_continue {
                    if let Some(prev) = pieces.last_mut() {
                        if prev.kind == PieceKind::Open
                            && prev.end == start
                            && indices[start - 1] == indices[start]
                        {
                            indices.remove(start);
                            let first = indices[prev.start];
                            if indices.last() == Some(&first) {
                                indices.pop();
                                prev.kind = PieceKind::Closed;
                            }
                            prev.end = indices.len();
                            continued += 1;
                            if max_forward > points.len() {
                                forward_check.push((pieces.len() - 1, max_forward));
                            }
                            continue;
                        }
                    }
                }
                may_continue = true;
                let kind = if indices[start] == indices[indices.len() - 1] {
                    indices.pop(); // the repeated first index of a closed loop
                    PieceKind::Closed
                } else if n == 2 {
                    PieceKind::Segment
                } else {
                    PieceKind::Open
                };
                let end = indices.len();
                if max_forward > points.len() {
                    forward_check.push((pieces.len(), max_forward));
                }
                pieces.push(Piece {
                    start,
                    end,
                    line: ln,
                    kind,
                });
            }
            "f" | "fo" => faces += 1,
            "p" => point_elems += 1,
            "g" | "o" => may_continue = false,
            "vn" | "vt" | "vp" | "s" | "usemtl" | "mtllib" | "lod" | "maplib" | "usemap"
            | "shadow_obj" | "trace_obj" | "bevel" | "c_interp" | "d_interp" => {}
            "cstype" | "deg" | "bmat" | "step" | "curv" | "curv2" | "surf" | "parm" | "trim"
            | "hole" | "scrv" | "sp" | "end" | "con" | "ctech" | "stech" => freeform += 1,
            other => {
                unknown_count += 1;
                if unknown.len() < 5 && !unknown.iter().any(|u| u == other) {
                    unknown.push(other.chars().take(32).collect());
                }
            }
        }
    }

    for (p, max) in forward_check {
        if max > points.len() {
            return Err(FormatError::at_line(
                pieces[p].line,
                format!(
                    "vertex index {max} is out of range: the file has {} vertices",
                    points.len()
                ),
            ));
        }
    }
    if pieces.is_empty() {
        return Err(FormatError::whole_file(format!(
            "no polyline (`l`) elements: found {} vertices and {faces} faces; knitvox reads yarns from OBJ line elements",
            points.len()
        )));
    }

    let yarns = assemble(&points, &indices, &pieces, opts.radius)?;
    let mut notes = Vec::new();
    if let Some(h) = header {
        notes.push(format!("header comment: {h}"));
    }
    notes.push(format!(
        "{} vertices, {} line elements",
        points.len(),
        pieces.len() + continued
    ));
    if continued > 0 {
        notes.push(format!(
            "{continued} line elements continue the element before them (joined into one curve)"
        ));
    }
    let mut used = vec![false; points.len()];
    indices.iter().for_each(|&v| used[v] = true);
    let unused = used.iter().filter(|u| !**u).count();
    if unused > 0 {
        notes.push(format!("{unused} vertices are used by no line element"));
    }
    if faces > 0 {
        notes.push(format!(
            "ignored {faces} faces (knitvox reads only `l` polylines)"
        ));
    }
    if point_elems > 0 {
        notes.push(format!("ignored {point_elems} point (`p`) elements"));
    }
    if freeform > 0 {
        notes.push(format!("ignored {freeform} free-form curve/surface statements (knitvox reads only `l` polylines)"));
    }
    if unknown_count > 0 {
        notes.push(format!(
            "ignored {unknown_count} statements of unknown kinds ({})",
            unknown.join(", ")
        ));
    }
    let mut d = Decoded::plain(yarns);
    d.notes = notes;
    Ok(d)
}

/// Writes curves (already in the file's unit and axes) as OBJ `v` / `l`.
pub fn encode(yarns: &Yarns, units: Units, up: UpAxis) -> Result<Vec<u8>, FormatError> {
    let n = yarns.num_curves();
    if yarns.offsets.len() != n + 1
        || yarns.offsets.first() != Some(&0)
        || yarns.offsets[n] != yarns.points.len()
    {
        return Err(FormatError::whole_file(
            "inconsistent curve offsets; nothing written",
        ));
    }
    for c in 0..n {
        let (a, b) = (yarns.offsets[c], yarns.offsets[c + 1]);
        if b < a + 2 {
            return Err(FormatError::whole_file(format!(
                "curve {c} has fewer than 2 points; nothing written"
            )));
        }
        if let Some(i) = yarns.points[a..b]
            .iter()
            .position(|p| !p.iter().all(|x| x.is_finite()))
        {
            return Err(FormatError::whole_file(format!(
                "curve {c}, point {i} is not finite; nothing written"
            )));
        }
    }
    let np = yarns.points.len();
    // ~3 x 22 characters per vertex line, ~8 per index.
    let mut s = String::with_capacity(256 + np * 80 + n * 16);
    let _ = writeln!(s, "# knitvox {}", env!("CARGO_PKG_VERSION"));
    let _ = writeln!(
        s,
        "# yarn polylines: one `l` element per curve; a closed curve repeats its first vertex"
    );
    let _ = writeln!(
        s,
        "# a curve longer than {MAX_LINE_INDICES} indices continues on the next `l`, which starts with the last index"
    );
    let _ = writeln!(
        s,
        "# units: {} ({} m per unit), up axis: +{}",
        units, units.metres_per_unit, up
    );
    let _ = writeln!(
        s,
        "# {} curves ({} closed), {} vertices",
        n,
        yarns.num_closed(),
        np
    );
    s.push_str("o yarns\n");
    for p in &yarns.points {
        // `{:?}` on f64 prints the shortest text that parses back to the same value.
        let _ = writeln!(s, "v {:?} {:?} {:?}", p[0], p[1], p[2]);
    }
    for c in 0..n {
        let r = yarns.curve_range(c);
        // 1-based indices of the element; a closed curve repeats its first.
        let closing = yarns.closed[c].then_some(r.start + 1);
        s.push('l');
        let (mut on_line, mut last) = (0usize, 0usize);
        for i in (r.start + 1..r.end + 1).chain(closing) {
            if on_line == MAX_LINE_INDICES {
                // A new line that starts with the last index written continues the curve.
                s.push_str("\nl");
                push_index(&mut s, last);
                on_line = 1;
            }
            push_index(&mut s, i);
            on_line += 1;
            last = i;
        }
        s.push('\n');
    }
    Ok(s.into_bytes())
}

/// Appends `' '` and the decimal digits of `i` (faster than `write!`).
fn push_index(s: &mut String, mut i: usize) {
    let mut digits = [0u8; 20];
    let mut k = digits.len();
    loop {
        k -= 1;
        digits[k] = b'0' + (i % 10) as u8;
        i /= 10;
        if i == 0 {
            break;
        }
    }
    s.push(' ');
    // Only ASCII digits were written.
    s.push_str(std::str::from_utf8(&digits[k..]).unwrap_or_default());
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::Location;

    fn dec(s: &str) -> Result<Decoded, FormatError> {
        decode(s.as_bytes(), &ReadOptions::default())
    }

    fn curves(y: &Yarns) -> Vec<(Vec<Vec3>, bool)> {
        (0..y.num_curves())
            .map(|c| (y.curve(c).to_vec(), y.closed[c]))
            .collect()
    }

    const SQUARE: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n";

    #[test]
    fn polyline_and_closed_loop() {
        let d = dec(&format!("{SQUARE}l 1 2 3\nl 1 2 3 4 1\n")).unwrap();
        let c = curves(&d.yarns);
        assert_eq!(c.len(), 2);
        assert_eq!(
            c[0],
            (
                vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0]],
                false
            )
        );
        assert_eq!(c[1].0.len(), 4);
        assert!(c[1].1);
        assert_eq!(d.units, None);
        assert_eq!(d.up_axis, None);
        assert!(!d.radius_in_file);
    }

    #[test]
    fn negative_indices_and_slashes() {
        let d = dec("v 0 0 0\nv 1 0 0\nv 2 0 0\nl -3/1 -2/2 -1//7\n").unwrap();
        assert_eq!(
            d.yarns.curve(0),
            &[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]]
        );
    }

    #[test]
    fn segments_chain_into_polylines_and_loops() {
        // Out of order and reversed segments: 1-2, 3-2, 3-4 -> 1 2 3 4; and a triangle 5-6-7.
        let d = dec("v 0 0 0\nv 1 0 0\nv 2 0 0\nv 3 0 0\nv 0 5 0\nv 1 5 0\nv 1 6 0\nl 1 2\nl 6 7\nl 3 2\nl 5 6\nl 3 4\nl 7 5\n")
            .unwrap();
        let c = curves(&d.yarns);
        assert_eq!(c.len(), 2);
        assert_eq!(
            c[0],
            (
                vec![
                    [0.0, 0.0, 0.0],
                    [1.0, 0.0, 0.0],
                    [2.0, 0.0, 0.0],
                    [3.0, 0.0, 0.0]
                ],
                false
            )
        );
        assert_eq!(
            c[1],
            (
                vec![[1.0, 5.0, 0.0], [1.0, 6.0, 0.0], [0.0, 5.0, 0.0]],
                true
            )
        );
    }

    #[test]
    fn chain_starts_from_its_far_end() {
        // 2-3 written first, 1-2 later: chain is 1 2 3 (keeps 2->3 direction).
        let d = dec("v 0 0 0\nv 1 0 0\nv 2 0 0\nl 2 3\nl 1 2\n").unwrap();
        assert_eq!(
            d.yarns.curve(0),
            &[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]]
        );
    }

    #[test]
    fn continuation_comments_and_ignored_statements() {
        let d = dec("# made by hand\nmtllib x.mtl\no a\ng b\nv 0 0 0 1\nv 1 0 0 # c\nvn 0 0 1\nvt 0 0\nv 2 0 0\nf 1 2 3\nl 1 \\\n 2 \\\n  3\nfoo bar\n")
            .unwrap();
        assert_eq!(d.yarns.num_points(), 3);
        assert!(
            d.notes.iter().any(|n| n.contains("1 faces")),
            "{:?}",
            d.notes
        );
        assert!(d.notes.iter().any(|n| n.contains("foo")), "{:?}", d.notes);
        assert!(d.notes.iter().any(|n| n.contains("made by hand")));
    }

    #[test]
    fn forward_reference_allowed_but_checked() {
        assert!(dec("l 1 2\nv 0 0 0\nv 1 0 0\n").is_ok());
        let e = dec("v 0 0 0\nl 1 2\nv 1 0 0\nl 1 5\n").unwrap_err();
        assert_eq!(e.location, Location::Line(4));
        assert!(e.message.contains('5'), "{e}");
    }

    #[test]
    fn errors_name_lines() {
        let cases: &[(&str, usize, &str)] = &[
            ("v 0 0 0\nv 1 0 0\nl 0 1\n", 3, "index 0"),
            ("v 0 0 0\nv 1 0 0\nl 1\n", 3, "at least 2"),
            ("v 0 0 0\nv 1 0 0\nl 1 1\n", 3, "at least 2"),
            ("v 0 0 0\nl -2 1\n", 2, "before the first"),
            ("v 0 0\n", 1, "no z"),
            ("v 0 nan 0\n", 1, "not finite"),
            ("v 0 inf 0\n", 1, "not finite"),
            ("v 0 a 0\n", 1, "not a number"),
            ("v 0 0 0\nv 1 0 0\nl 1 x\n", 3, "not a vertex index"),
            (
                "v 0 0 0\nv 1 0 0\nv 2 0 0\nv 3 0 0\nl 1 2\nl 1 3\nl 1 4\n",
                7,
                "branch",
            ),
        ];
        for (src, line, what) in cases {
            let e = dec(src).unwrap_err();
            assert_eq!(e.location, Location::Line(*line), "{src:?}: {e}");
            assert!(e.message.contains(what), "{src:?}: {e}");
        }
        let e = dec("").unwrap_err();
        assert!(e.message.contains("no polyline"));
        let e = decode(b"v 0 0 0\nv 1 0 0\n\xff\n", &ReadOptions::default()).unwrap_err();
        assert_eq!(e.location, Location::Line(3));
    }

    #[test]
    fn max_points_guard() {
        let opts = ReadOptions {
            max_points: 2,
            ..Default::default()
        };
        assert!(decode(b"v 0 0 0\nv 1 0 0\nl 1 2\n", &opts).is_ok());
        let e = decode(b"v 0 0 0\nv 1 0 0\nv 2 0 0\nl 1 2\n", &opts).unwrap_err();
        assert_eq!(e.location, Location::Line(3));
        let e = decode(b"l 1 1152921504606846976\n", &ReadOptions::default()).unwrap_err();
        assert!(e.message.contains("limit"), "{e}");
    }

    #[test]
    fn encode_format_and_round_trip() {
        let mut y = Yarns::new();
        y.push_curve(&[[0.1, -2.5e-7, 3.0], [1e20, 0.3, -0.0]], false, 1.0);
        y.push_curve(
            &[[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]],
            true,
            1.0,
        );
        let bytes = encode(&y, Units::CENTIMETRES, UpAxis::Z).unwrap();
        let text = String::from_utf8(bytes.clone()).unwrap();
        assert!(text.starts_with("# knitvox "));
        assert!(text.contains("units: cm"));
        assert!(text.contains("up axis: +z"));
        assert!(text.contains("\nl 1 2\n"));
        assert!(text.contains("\nl 3 4 5 3\n"));
        let d = decode(&bytes, &ReadOptions::default()).unwrap();
        assert_eq!(d.yarns.points, y.points);
        assert!(d.yarns.same_topology(&y));
    }

    #[test]
    fn encode_refuses_bad_curves() {
        let mut y = Yarns::new();
        y.push_curve(&[[0.0; 3], [f64::NAN, 0.0, 0.0]], false, 1.0);
        assert!(encode(&y, Units::METRES, UpAxis::Y).is_err());
        let mut y = Yarns::new();
        y.push_curve(&[[0.0; 3]], false, 1.0);
        assert!(encode(&y, Units::METRES, UpAxis::Y).is_err());
    }

    #[test]
    fn index_digits() {
        let mut s = String::new();
        for i in [0, 7, 10, 12345, usize::MAX] {
            push_index(&mut s, i);
        }
        assert_eq!(s, format!(" 0 7 10 12345 {}", usize::MAX));
    }
}
