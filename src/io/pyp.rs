//! MADYPG / HYLC periodic yarn tiles (`.pyp`), tiled into continuous yarns.
//!
//! # Format
//!
//! Text; `#` starts a comment; a line starting with `*` opens a section and
//! the non-blank lines after it are that section's rows:
//!
//! | section | rows | columns |
//! |---|---|---|
//! | `*pattern` | 1 | `px py radius n`: the tile's periods along x and y, the yarn radius (m), the vertex count |
//! | `*Q` | n | `x y z twist` per vertex (m; the twist DOF is not used) |
//! | `*E` | n | `v0 v1 di dj`: an edge from vertex `v0` to vertex `v1` of the tile shifted by (`di`, `dj`) periods (0-based vertex numbers) |
//! | `*RL` | n | rest length |
//! | `*RK` | n | rest curvature (2 values) |
//! | `*RT` | n | rest twist |
//! | `*RefD1` | n | reference director (3 values) |
//! | `*RefT` | n | reference twist |
//!
//! `*pattern`, `*Q` and `*E` are required. The rest-state sections are
//! optional (MADYPG itself reads only `*RL` of them); where present they are
//! checked for row count, column count and finite values, but not used.
//! Unknown sections are skipped and listed in the notes.
//!
//! Edges are directed: every vertex must lie on at least one edge, and have
//! at most one outgoing and one incoming edge (so every vertex copy in the
//! tiled graph has degree <= 2 and the yarn direction is consistent).
//!
//! # Tiling
//!
//! [`ReadOptions::tile`] = `[N, M]` repeats the tile N times along x and M
//! times along y: vertex `v` of tile `(i, j)` sits at `q_v + (i px, j py, 0)`,
//! and edge `(v0, v1, di, dj)` joins `v0` in tile `(i, j)` to `v1` in tile
//! `(i + di, j + dj)`. Edges that leave the N x M block are dropped (the
//! block is not wrapped round), so yarns end there as open curves; edge
//! cycles that stay inside the block (net offset zero) become closed curves.
//! Curves are chained by following the edges and come out in order of their
//! first vertex copy (tile-major, row by row). A yarn piece that would keep a
//! single vertex copy at the block boundary is dropped (and counted in the
//! notes); every other vertex copy appears exactly once.
//!
//! # Frame
//!
//! Units are SI metres, declared as such; the radius comes from `*pattern`.
//! The tile lies in the file's x-y plane with z across the fabric's
//! thickness, so the file is declared **+Z up**: after conversion to
//! knitvox's +Y-up frame the swatch lies flat (in the x-z plane, fabric
//! normal +Y), like the flat Z-up swatches of Cem Yuksel's BCC models. Pass
//! an explicit up axis to stand it up instead.

use super::bytes::{parse_finite, text_lines};
use super::{Decoded, FormatError, ReadOptions};
use crate::geom::{Units, UpAxis, Vec3, Yarns};

/// One section: its header line and its data rows `(line, text)`.
struct SectionRows<'a> {
    line: usize,
    rows: Vec<(usize, &'a str)>,
}

/// Rest-state sections: name and number of values per row.
const REST_SECTIONS: [(&str, usize); 5] = [
    ("*RL", 1),
    ("*RK", 2),
    ("*RT", 1),
    ("*RefD1", 3),
    ("*RefT", 1),
];

fn section<'s, 'a>(
    sections: &'s [(&'a str, SectionRows<'a>)],
    name: &str,
) -> Option<&'s SectionRows<'a>> {
    sections.iter().find(|(n, _)| *n == name).map(|(_, s)| s)
}

/// Splits a row into exactly `cols` tokens.
fn columns<'a>(
    text: &'a str,
    ln: usize,
    what: &str,
    cols: usize,
) -> Result<Vec<&'a str>, FormatError> {
    let t: Vec<&str> = text.split_ascii_whitespace().take(cols + 1).collect();
    if t.len() != cols {
        return Err(FormatError::at_line(
            ln,
            format!(
                "{what} row needs {cols} values, found {}",
                if t.len() > cols {
                    "more".to_string()
                } else {
                    t.len().to_string()
                }
            ),
        ));
    }
    Ok(t)
}

fn check_rows(s: &SectionRows<'_>, name: &str, n: u64) -> Result<(), FormatError> {
    if s.rows.len() as u64 != n {
        return Err(FormatError::at_line(
            s.line,
            format!("{name} has {} rows but *pattern declares {n} vertices (truncated or mismatched section?)", s.rows.len()),
        ));
    }
    Ok(())
}

/// Decodes a `.pyp` tile and tiles it `opts.tile` times (metres, file axes).
pub fn decode(data: &[u8], opts: &ReadOptions) -> Result<Decoded, FormatError> {
    // Group lines into sections.
    let mut sections: Vec<(&str, SectionRows<'_>)> = Vec::new();
    for item in text_lines(data) {
        let (ln, raw) = item?;
        let text = raw.split('#').next().unwrap_or("").trim();
        if text.is_empty() {
            continue;
        }
        if text.starts_with('*') {
            let name = text.split_ascii_whitespace().next().unwrap_or(text);
            if let Some((_, prev)) = sections.iter().find(|(n, _)| *n == name) {
                return Err(FormatError::at_line(
                    ln,
                    format!("section {name} appears twice (first at line {})", prev.line),
                ));
            }
            sections.push((
                name,
                SectionRows {
                    line: ln,
                    rows: Vec::new(),
                },
            ));
            continue;
        }
        match sections.last_mut() {
            Some((_, s)) => s.rows.push((ln, text)),
            None => {
                return Err(FormatError::at_line(
                    ln,
                    "data before the first section header (a .pyp file starts with '*pattern')",
                ))
            }
        }
    }
    if let Some((name, s)) = sections.iter().find(|(_, s)| s.rows.is_empty()) {
        return Err(FormatError::at_line(
            s.line,
            format!("section {name} has no rows (truncated file?)"),
        ));
    }
    let require = |name: &str| {
        section(&sections, name).ok_or_else(|| {
            FormatError::whole_file(format!(
                "missing section {name} (not a .pyp file, or truncated?)"
            ))
        })
    };

    // *pattern: px py radius n
    let pat = require("*pattern")?;
    let &(pl, ptext) = pat
        .rows
        .first()
        .ok_or_else(|| FormatError::at_line(pat.line, "*pattern has no 'px py radius n' row"))?;
    if let Some(&(l2, _)) = pat.rows.get(1) {
        return Err(FormatError::at_line(l2, "*pattern has more than one row"));
    }
    let t = columns(ptext, pl, "*pattern", 4)?;
    let px = parse_finite(t[0], pl, "period px")?;
    let py = parse_finite(t[1], pl, "period py")?;
    let radius = parse_finite(t[2], pl, "radius")?;
    for (v, name) in [(px, "period px"), (py, "period py"), (radius, "radius")] {
        if v <= 0.0 {
            return Err(FormatError::at_line(
                pl,
                format!("{name} must be positive, got {v}"),
            ));
        }
    }
    let n: u64 = t[3].parse().map_err(|_| {
        FormatError::at_line(
            pl,
            format!(
                "vertex count '{}' is not a non-negative integer",
                crate::geom::excerpt(t[3])
            ),
        )
    })?;
    if n == 0 {
        return Err(FormatError::at_line(
            pl,
            "vertex count is 0: the tile has no yarn",
        ));
    }
    if n > opts.max_points {
        return Err(FormatError::at_line(
            pl,
            format!(
                "vertex count {n} exceeds the reader's limit of {} points (max_points)",
                opts.max_points
            ),
        ));
    }
    let [tn, tm] = opts.tile;
    if tn == 0 || tm == 0 {
        return Err(FormatError::whole_file(format!(
            "tile counts must be at least 1, got {tn} x {tm}"
        )));
    }
    let total = (tn as u64)
        .checked_mul(tm as u64)
        .and_then(|b| b.checked_mul(n))
        .filter(|&t| t <= opts.max_points)
        .ok_or_else(|| {
            FormatError::at_line(
                pl,
                format!(
                    "tiling {tn} x {tm} copies of {n} vertices exceeds the reader's limit of {} points (max_points)",
                    opts.max_points
                ),
            )
        })?;
    // The tiled copy is built in memory: 32 bytes a point (position, and
    // the per-vertex slot of the curves) against the memory budget.
    let bytes = total.saturating_mul(32);
    if bytes > opts.max_memory {
        return Err(FormatError::at_line(
            pl,
            format!(
                "tiling {tn} x {tm} copies of {n} vertices needs about {bytes} bytes, more than the memory budget of {} bytes (--max-memory)",
                opts.max_memory
            ),
        ));
    }

    // *Q: one row per vertex. Row counts are compared before anything is
    // allocated from n, so n never drives allocation beyond the file's rows.
    let qs = require("*Q")?;
    check_rows(qs, "*Q", n)?;
    let mut q: Vec<Vec3> = Vec::with_capacity(qs.rows.len());
    for &(ln, text) in &qs.rows {
        let t = columns(text, ln, "*Q", 4)?;
        let mut p = [0.0; 3];
        for k in 0..3 {
            p[k] = parse_finite(t[k], ln, ["x", "y", "z"][k])?;
        }
        parse_finite(t[3], ln, "twist")?;
        q.push(p);
    }
    let n = q.len();

    // *E: directed edges with periodic offsets.
    let es = require("*E")?;
    check_rows(es, "*E", n as u64)?;
    const NONE: usize = usize::MAX;
    let mut out_edge = vec![NONE; n]; // vertex -> edge leaving it
    let mut in_edge = vec![NONE; n]; // vertex -> edge arriving at it
    let mut edges: Vec<(usize, usize, i64, i64)> = Vec::with_capacity(n);
    for (e, &(ln, text)) in es.rows.iter().enumerate() {
        let t = columns(text, ln, "*E", 4)?;
        let mut vs = [0usize; 2];
        for k in 0..2 {
            let v: u64 = t[k].parse().map_err(|_| {
                FormatError::at_line(
                    ln,
                    format!(
                        "edge vertex '{}' is not a non-negative integer",
                        crate::geom::excerpt(t[k])
                    ),
                )
            })?;
            if v >= n as u64 {
                return Err(FormatError::at_line(
                    ln,
                    format!(
                        "edge vertex {v} is out of range: the tile has vertices 0 to {}",
                        n - 1
                    ),
                ));
            }
            vs[k] = v as usize;
        }
        let mut d = [0i64; 2];
        for k in 0..2 {
            d[k] = t[k + 2].parse().map_err(|_| {
                FormatError::at_line(
                    ln,
                    format!(
                        "edge offset '{}' is not an integer",
                        crate::geom::excerpt(t[k + 2])
                    ),
                )
            })?;
        }
        let (v0, v1) = (vs[0], vs[1]);
        if v0 == v1 && d == [0, 0] {
            return Err(FormatError::at_line(
                ln,
                format!("edge from vertex {v0} to itself in the same tile"),
            ));
        }
        if out_edge[v0] != NONE {
            return Err(FormatError::at_line(
                ln,
                format!("vertex {v0} has a second outgoing edge (the first is on line {}): yarns cannot branch", es.rows[out_edge[v0]].0),
            ));
        }
        if in_edge[v1] != NONE {
            return Err(FormatError::at_line(
                ln,
                format!("vertex {v1} has a second incoming edge (the first is on line {}): yarns cannot branch", es.rows[in_edge[v1]].0),
            ));
        }
        out_edge[v0] = e;
        in_edge[v1] = e;
        edges.push((v0, v1, d[0], d[1]));
    }
    if let Some(v) = (0..n).find(|&v| out_edge[v] == NONE && in_edge[v] == NONE) {
        return Err(FormatError::at_line(
            es.line,
            format!("vertex {v} lies on no edge"),
        ));
    }

    // Rest-state sections: validated, not used.
    let mut notes = Vec::new();
    let mut missing = Vec::new();
    for (name, cols) in REST_SECTIONS {
        match section(&sections, name) {
            None => missing.push(name),
            Some(s) => {
                check_rows(s, name, n as u64)?;
                for &(ln, text) in &s.rows {
                    for tok in columns(text, ln, name, cols)? {
                        parse_finite(tok, ln, &format!("{name} value"))?;
                    }
                }
            }
        }
    }
    let known = ["*pattern", "*Q", "*E"];
    let unknown: Vec<&str> = sections
        .iter()
        .map(|(nm, _)| *nm)
        .filter(|nm| !known.contains(nm) && !REST_SECTIONS.iter().any(|(r, _)| r == nm))
        .collect();

    // Tile: copy c = (j * N + i) * n + v.
    let total = total as usize;
    let copy = |v: usize, i: usize, j: usize| (j * tn + i) * n + v;
    let mut next = vec![NONE; total];
    let mut has_prev = vec![false; total];
    for j in 0..tm {
        for i in 0..tn {
            for &(v0, v1, di, dj) in &edges {
                let ii = (i as i64)
                    .checked_add(di)
                    .filter(|&x| x >= 0 && x < tn as i64);
                let jj = (j as i64)
                    .checked_add(dj)
                    .filter(|&x| x >= 0 && x < tm as i64);
                if let (Some(ii), Some(jj)) = (ii, jj) {
                    let (a, b) = (copy(v0, i, j), copy(v1, ii as usize, jj as usize));
                    next[a] = b;
                    has_prev[b] = true;
                }
            }
        }
    }
    let pos = |c: usize| {
        let v = c % n;
        let t = c / n;
        let (i, j) = (t % tn, t / tn);
        let p = q[v];
        [p[0] + i as f64 * px, p[1] + j as f64 * py, p[2]]
    };
    let mut yarns = Yarns::new();
    yarns.points.reserve(total);
    let mut visited = vec![false; total];
    let mut buf: Vec<Vec3> = Vec::new();
    let mut dropped = 0usize;
    // Open yarns first (they start at a copy with no predecessor), then the
    // cycles left over.
    for pass_open in [true, false] {
        for c0 in 0..total {
            if visited[c0] || (pass_open && has_prev[c0]) {
                continue;
            }
            buf.clear();
            let mut c = c0;
            while c != NONE && !visited[c] {
                visited[c] = true;
                buf.push(pos(c));
                c = next[c];
            }
            if buf.len() < 2 {
                dropped += buf.len();
                continue;
            }
            yarns.push_curve(&buf, !pass_open, radius);
        }
    }

    notes.push(format!(
        "periodic tile {px} x {py} m, {n} vertices, yarn radius {radius} m; tiled {tn} x {tm} into {} yarns ({} closed)",
        yarns.num_curves(),
        yarns.num_closed()
    ));
    notes.push(
        "tile plane x-y with z across the fabric: declared +Z up, so the swatch lies flat".into(),
    );
    if dropped > 0 {
        notes.push(format!(
            "dropped {dropped} single-vertex yarn pieces cut off at the block boundary"
        ));
    }
    if !missing.is_empty() {
        notes.push(format!("rest-state sections absent: {}", missing.join(" ")));
    }
    if !unknown.is_empty() {
        notes.push(format!("ignored unknown sections: {}", unknown.join(" ")));
    }
    Ok(Decoded {
        yarns,
        frames: None,
        units: Some(Units::METRES),
        up_axis: Some(UpAxis::Z),
        radius_in_file: true,
        notes,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::Location;

    /// Two straight yarns along x in a 1 x 1 tile: vertices 0,1 (y = 0.25)
    /// and 2,3 (y = 0.75); 1 -> 0 and 3 -> 2 cross into the next tile.
    const TILE: &str = "*pattern # px py radius n\n1 1 0.1 4\n\n*Q\n0 0.25 0 0\n0.5 0.25 0 0\n0 0.75 0 0\n0.5 0.75 0 0\n\n*E\n0 1 0 0\n1 0 1 0\n2 3 0 0\n3 2 1 0\n";

    fn dec_tiled(src: &str, tile: [usize; 2]) -> Result<Decoded, FormatError> {
        decode(
            src.as_bytes(),
            &ReadOptions {
                tile,
                ..Default::default()
            },
        )
    }

    #[test]
    fn tiles_straight_yarns() {
        let d = dec_tiled(TILE, [3, 2]).unwrap();
        let y = &d.yarns;
        assert_eq!(y.num_curves(), 4); // 2 yarns per tile row, 2 rows
        assert_eq!(y.num_points(), 24);
        assert_eq!(
            y.curve(0),
            &[
                [0.0, 0.25, 0.0],
                [0.5, 0.25, 0.0],
                [1.0, 0.25, 0.0],
                [1.5, 0.25, 0.0],
                [2.0, 0.25, 0.0],
                [2.5, 0.25, 0.0]
            ]
        );
        assert_eq!(y.curve(3)[0], [0.0, 1.75, 0.0]);
        assert!(y.closed.iter().all(|c| !c));
        assert_eq!(y.radius, vec![0.1; 4]);
        assert_eq!(d.units, Some(Units::METRES));
        assert_eq!(d.up_axis, Some(UpAxis::Z));
        assert!(d.radius_in_file);
        assert!(d.notes.iter().any(|n| n.contains("absent")));
    }

    #[test]
    fn closed_loop_inside_tile() {
        let src = "*pattern\n1 1 0.1 3\n*Q\n0 0 0 0\n0.5 0 0 0\n0 0.5 0 0\n*E\n0 1 0 0\n1 2 0 0\n2 0 0 0\n";
        let d = dec_tiled(src, [2, 1]).unwrap();
        assert_eq!(d.yarns.num_curves(), 2);
        assert!(d.yarns.closed.iter().all(|c| *c));
        assert_eq!(d.yarns.curve(1)[0], [1.0, 0.0, 0.0]);
    }

    #[test]
    fn errors() {
        let with_e = |e: &str| format!("*pattern\n1 1 0.1 2\n*Q\n0 0 0 0\n0.5 0 0 0\n*E\n{e}");
        let cases: Vec<(String, Location, &str)> = vec![
            (
                with_e("0 1 0 0\n0 1 1 0\n"),
                Location::Line(8),
                "second outgoing",
            ),
            (
                with_e("0 1 0 0\n1 1 1 0\n"),
                Location::Line(8),
                "second incoming",
            ),
            (
                with_e("0 2 0 0\n1 0 1 0\n"),
                Location::Line(7),
                "out of range",
            ),
            (with_e("0 0 0 0\n1 1 1 0\n"), Location::Line(7), "itself"),
            (with_e("0 1 0 0\n"), Location::Line(6), "1 rows"),
            (with_e("0 1 0\n1 0 1 0\n"), Location::Line(7), "needs 4"),
            (
                with_e("0 1 0 0\n1 0 x 0\n"),
                Location::Line(8),
                "not an integer",
            ),
            (
                "*pattern\n1 1 0.1 1152921504606846976\n".into(),
                Location::Line(2),
                "limit",
            ),
            (
                "*pattern\n1 1 0.1 0\n".into(),
                Location::Line(2),
                "count is 0",
            ),
            (
                "*pattern\n1 -1 0.1 2\n".into(),
                Location::Line(2),
                "positive",
            ),
            (
                "*pattern\n1 nan 0.1 2\n".into(),
                Location::Line(2),
                "not finite",
            ),
            (
                "*pattern\n1 1 0.1 2\n*Q\n0 0 0 0\n0 inf 0 0\n".into(),
                Location::Line(5),
                "not finite",
            ),
            (
                "1 1 0.1 2\n".into(),
                Location::Line(1),
                "before the first section",
            ),
            (
                "*pattern\n1 1 0.1 2\n*pattern\n".into(),
                Location::Line(3),
                "twice",
            ),
            (
                "*pattern\n1 1 0.1 2\n*Q\n0 0 0 0\n0.5 0 0 0\n".into(),
                Location::File,
                "missing section *E",
            ),
            (
                "*pattern\n1 1 0.1 2\n*Q\n0 0 0 0\n0.5 0 0 0\n*E\n".into(),
                Location::Line(6),
                "no rows",
            ),
            ("".into(), Location::File, "missing section *pattern"),
        ];
        for (src, loc, what) in cases {
            let e = dec_tiled(&src, [1, 1]).unwrap_err();
            assert_eq!(e.location, loc, "{src:?}: {e}");
            assert!(e.message.contains(what), "{src:?}: {e}");
        }
        let src = format!("{TILE}*RL\n1\n1\n1\n");
        let e = dec_tiled(&src, [1, 1]).unwrap_err();
        assert!(e.message.contains("*RL has 3 rows"), "{e}");
        let e = dec_tiled(TILE, [0, 1]).unwrap_err();
        assert!(e.message.contains("at least 1"), "{e}");
        let e = decode(
            TILE.as_bytes(),
            &ReadOptions {
                tile: [usize::MAX, 2],
                ..Default::default()
            },
        )
        .unwrap_err();
        assert!(e.message.contains("limit"), "{e}");
    }

    #[test]
    fn single_vertex_pieces_are_dropped() {
        let src = "*pattern\n1 1 0.1 3\n*Q\n0 0 0 0\n0.5 0 0 0\n0.7 0 0 0\n*E\n0 1 0 0\n1 0 1 0\n2 2 1 0\n";
        assert!(dec_tiled(src, [1, 1]).is_ok()); // 2 -> 2 across tiles: a one-vertex-per-tile yarn
        let d = dec_tiled(src, [1, 1]).unwrap();
        assert!(
            d.notes.iter().any(|n| n.contains("dropped 1")),
            "{:?}",
            d.notes
        );
    }
}
