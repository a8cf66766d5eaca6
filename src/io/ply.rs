//! Stanford PLY polylines: ascii, binary little-endian and binary big-endian.
//!
//! # What is read
//!
//! * A `vertex` element with scalar properties `x`, `y`, `z` (any PLY scalar
//!   type) and optionally a per-vertex radius named `radius` or `thickness`
//!   (no other names: `r` is a colour channel in many files).
//! * Curve topology from **either**
//!   - an `edge` element with integer properties `vertex1` and `vertex2`
//!     (the layout Blender and knitvox write). Edges are chained into
//!     polylines; a chain that returns to its start is a closed curve. A
//!     vertex on more than two edges is an error (yarns do not branch), and so
//!     is a vertex on no edge (a curve needs two points). Curves come out in
//!     the order of their lowest vertex index. An open chain starts at its end
//!     with no predecessor (the end that is `vertex1` of its edge; if the edge
//!     directions do not say, the lower-indexed end). A closed chain starts at
//!     its lowest vertex index and runs along the edge that leaves it (or, if
//!     the directions do not say, the edge written first). knitvox's own
//!     files therefore come back with identical curve order, starting points
//!     and closed flags;
//!   - or, without an `edge` element, a per-vertex curve id property named
//!     `curve`, `curve_id`, `strand` or `strand_id` (any scalar type):
//!     consecutive vertices with the same id form one open curve.
//!
//!   With both, the edges win (and a note says so). With neither, the file is
//!   refused: a bare point cloud does not say where one yarn ends.
//! * Every other element (`face`, ...) and every other property is skipped
//!   (binary lists included) and listed in [`Decoded::notes`].
//! * PLY declares no unit or up axis. Header comments `comment knitvox units
//!   <unit>` (`m`, `cm`, `mm` or metres per unit) and `comment knitvox up_axis
//!   <y|z>`, which knitvox writes, are read as declared by the file (like the
//!   BCC header's up axis); without them the result is unitless. A malformed
//!   `knitvox units` / `knitvox up_axis` comment is an error.
//!
//! # Why a hand-written parser instead of `ply-rs-bw`
//!
//! The format is small, and the reader must (a) refuse counts the file cannot
//! hold *before* allocating anything, (b) report every problem with a header
//! line, a payload line (ascii) or a byte offset (binary), and (c) decode
//! 10^5-10^6 vertices without per-value allocations. `ply-rs-bw` reads through
//! `std::io::Read` into per-element property maps (a `String`-keyed map per
//! vertex with `DefaultElement`) and reports `io::Error`s without offsets, so
//! it would need a second validation pass to give the locations above. The
//! hand parser below is one pass over the bytes with all arithmetic on
//! file-declared counts checked.
//!
//! # What is written
//!
//! `binary_little_endian 1.0`: `element vertex N` with `float x, y, z, radius`
//! and `element edge M` with `int vertex1, vertex2`, one edge per segment (a
//! closed yarn gets its closing edge). Blender imports this as loose edges.
//! [`encode_in`] adds `comment knitvox units <unit>` and `comment knitvox
//! up_axis <axis>` to the header so that knitvox reads the file back in the
//! frame it was written in.

use super::{Decoded, FormatError, Location, ReadOptions};
use crate::geom::{Units, UnknownUnit, UnknownUpAxis, UpAxis, Vec3, Yarns};

/// Property names read as the per-vertex radius.
pub const RADIUS_NAMES: [&str; 2] = ["radius", "thickness"];

/// Property names read as a per-vertex curve id (when there is no `edge` element).
pub const CURVE_ID_NAMES: [&str; 4] = ["curve", "curve_id", "strand", "strand_id"];

/// Header comment (after `comment`) declaring the unit of the coordinates.
pub const UNITS_COMMENT: &str = "knitvox units";

/// Header comment (after `comment`) declaring the up axis of the coordinates.
pub const UP_AXIS_COMMENT: &str = "knitvox up_axis";

/// The unit and up axis declared by knitvox header comments, if any.
fn declared_frame(comments: &[String]) -> Result<(Option<Units>, Option<UpAxis>), FormatError> {
    let mut units = None;
    let mut up = None;
    for c in comments {
        let mut tok = c.split_ascii_whitespace();
        if tok.next() != Some("knitvox") {
            continue;
        }
        let key = tok.next();
        if key != Some("units") && key != Some("up_axis") {
            continue;
        }
        let (Some(value), None) = (tok.next(), tok.next()) else {
            return Err(FormatError::whole_file(format!(
                "header comment '{}': expected exactly one value",
                clip(c)
            )));
        };
        if key == Some("units") {
            let u: Units = value.parse().map_err(|e: UnknownUnit| {
                FormatError::whole_file(format!("header comment '{}': {e}", clip(c)))
            })?;
            if units.is_some_and(|old| old != u) {
                return Err(FormatError::whole_file(
                    "header comments declare two different units",
                ));
            }
            units = Some(u);
        } else {
            let a: UpAxis = value.parse().map_err(|e: UnknownUpAxis| {
                FormatError::whole_file(format!("header comment '{}': {e}", clip(c)))
            })?;
            if up.is_some_and(|old| old != a) {
                return Err(FormatError::whole_file(
                    "header comments declare two different up axes",
                ));
            }
            up = Some(a);
        }
    }
    Ok((units, up))
}

/// At most this many header comments are copied into the notes.
const MAX_COMMENT_NOTES: usize = 16;

// ---------------------------------------------------------------------------
// Header model
// ---------------------------------------------------------------------------

/// The PLY scalar types.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    /// Both naming schemes of the PLY spec (`char` / `int8`, ...).
    fn parse(name: &str) -> Option<Scalar> {
        Some(match name {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    fn is_integer(self) -> bool {
        !matches!(self, Scalar::F32 | Scalar::F64)
    }

    fn name(self) -> &'static str {
        match self {
            Scalar::I8 => "char",
            Scalar::U8 => "uchar",
            Scalar::I16 => "short",
            Scalar::U16 => "ushort",
            Scalar::I32 => "int",
            Scalar::U32 => "uint",
            Scalar::F32 => "float",
            Scalar::F64 => "double",
        }
    }

    /// Range of an integer type (as i64).
    fn int_range(self) -> (i64, i64) {
        match self {
            Scalar::I8 => (i8::MIN as i64, i8::MAX as i64),
            Scalar::U8 => (0, u8::MAX as i64),
            Scalar::I16 => (i16::MIN as i64, i16::MAX as i64),
            Scalar::U16 => (0, u16::MAX as i64),
            Scalar::I32 => (i32::MIN as i64, i32::MAX as i64),
            Scalar::U32 => (0, u32::MAX as i64),
            Scalar::F32 | Scalar::F64 => (i64::MIN, i64::MAX),
        }
    }

    /// Decodes one binary value; `b` holds exactly `self.size()` bytes.
    /// Every PLY scalar converts to f64 exactly, so integer indices survive.
    #[inline]
    fn decode(self, b: &[u8], big: bool) -> f64 {
        macro_rules! get {
            ($t:ty, $n:expr) => {{
                let mut a = [0u8; $n];
                a.copy_from_slice(&b[..$n]);
                if big {
                    <$t>::from_be_bytes(a) as f64
                } else {
                    <$t>::from_le_bytes(a) as f64
                }
            }};
        }
        match self {
            Scalar::I8 => get!(i8, 1),
            Scalar::U8 => get!(u8, 1),
            Scalar::I16 => get!(i16, 2),
            Scalar::U16 => get!(u16, 2),
            Scalar::I32 => get!(i32, 4),
            Scalar::U32 => get!(u32, 4),
            Scalar::F32 => get!(f32, 4),
            Scalar::F64 => get!(f64, 8),
        }
    }

    /// Parses one ascii token as a value of this type.
    fn parse_token(self, tok: &str) -> Result<f64, TokenError> {
        if self.is_integer() {
            let v = match tok.parse::<i64>() {
                Ok(v) => v,
                // Some writers print integers as "3.0"; accept integral floats.
                Err(_) => match tok.parse::<f64>() {
                    Ok(f) if f.is_finite() && f.fract() == 0.0 && f.abs() < 9.0e15 => f as i64,
                    _ => {
                        return Err(TokenError::NotInteger {
                            token: clip(tok),
                            kind: self.name(),
                        })
                    }
                },
            };
            let (lo, hi) = self.int_range();
            if v < lo || v > hi {
                return Err(TokenError::OutOfRange {
                    value: v,
                    kind: self.name(),
                    lo,
                    hi,
                });
            }
            Ok(v as f64)
        } else {
            tok.parse::<f64>()
                .map_err(|_| TokenError::NotNumber { token: clip(tok) })
        }
    }
}

/// Why an ascii token is not a value of its property's type; `token` is
/// the token (cut to an excerpt), `kind` the PLY type name.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
enum TokenError {
    /// Not an integer (nor an integral float) for an integer type.
    #[error("'{token}' is not an integer ({kind})")]
    NotInteger { token: String, kind: &'static str },
    /// An integer outside the range `lo..=hi` of its type.
    #[error("{value} is out of range for {kind} ({lo}..={hi})")]
    OutOfRange {
        value: i64,
        kind: &'static str,
        lo: i64,
        hi: i64,
    },
    /// Not a number for a float type.
    #[error("'{token}' is not a number")]
    NotNumber { token: String },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

#[derive(Debug, Clone)]
struct Property {
    name: String,
    kind: Kind,
    line: usize,
}

#[derive(Debug, Clone)]
struct Element {
    name: String,
    count: u64,
    props: Vec<Property>,
    line: usize,
}

impl Element {
    /// Smallest size of one record in bytes (binary: lists with no items;
    /// ascii: one character and one separator per value).
    fn min_record_bytes(&self, ascii: bool) -> u128 {
        if ascii {
            return 2 * self.props.len() as u128;
        }
        self.props
            .iter()
            .map(|p| match p.kind {
                Kind::Scalar(t) => t.size() as u128,
                Kind::List { count, .. } => count.size() as u128,
            })
            .sum()
    }

    /// Record size when every property is a scalar.
    fn fixed_record_bytes(&self) -> Option<usize> {
        self.props
            .iter()
            .map(|p| match p.kind {
                Kind::Scalar(t) => Some(t.size()),
                Kind::List { .. } => None,
            })
            .sum()
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Encoding {
    Ascii,
    BinaryLe,
    BinaryBe,
}

impl Encoding {
    fn name(self) -> &'static str {
        match self {
            Encoding::Ascii => "ascii",
            Encoding::BinaryLe => "binary_little_endian",
            Encoding::BinaryBe => "binary_big_endian",
        }
    }
}

#[derive(Debug)]
struct Header {
    encoding: Encoding,
    elements: Vec<Element>,
    comments: Vec<String>,
    /// Byte offset of the first payload byte.
    payload_start: usize,
    /// Number of header lines (the payload's first ascii line is this + 1).
    lines: usize,
}

/// A piece of a line for error messages (see `geom::excerpt`).
fn clip(s: &str) -> String {
    crate::geom::excerpt(s)
}

/// The next line of `data` from `pos`: (line without `\r\n`, start of the next line).
fn next_line(data: &[u8], pos: usize) -> (&[u8], usize) {
    let rest = &data[pos.min(data.len())..];
    let (line, next) = match rest.iter().position(|&b| b == b'\n') {
        Some(i) => (&rest[..i], pos + i + 1),
        None => (rest, data.len()),
    };
    (line.strip_suffix(b"\r").unwrap_or(line), next)
}

fn parse_header(data: &[u8]) -> Result<Header, FormatError> {
    if data.is_empty() {
        return Err(FormatError::at_line(
            1,
            "empty file: a PLY file starts with the line 'ply'",
        ));
    }
    let (first, mut pos) = next_line(data, 0);
    if first.trim_ascii() != b"ply" {
        return Err(FormatError::at_line(
            1,
            format!(
                "not a PLY file: first line is '{}', expected 'ply'",
                clip(&String::from_utf8_lossy(first))
            ),
        ));
    }
    let mut line_no = 1;
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut comments = Vec::new();
    loop {
        if pos >= data.len() {
            return Err(FormatError::at_line(
                line_no,
                "header ends without an 'end_header' line (truncated file or not a PLY header)",
            ));
        }
        let (raw, next) = next_line(data, pos);
        pos = next;
        line_no += 1;
        let line = std::str::from_utf8(raw).map_err(|e| {
            FormatError::at_line(
                line_no,
                format!(
                    "header line is not text (invalid UTF-8 at column {})",
                    e.valid_up_to() + 1
                ),
            )
        })?;
        let mut tok = line.split_ascii_whitespace();
        let Some(keyword) = tok.next() else {
            continue; // tolerate blank header lines
        };
        let rest = line.trim_start().get(keyword.len()..).unwrap_or("").trim();
        match keyword {
            "comment" => comments.push(rest.to_string()),
            "obj_info" => comments.push(format!("obj_info {rest}")),
            "format" => {
                if encoding.is_some() {
                    return Err(FormatError::at_line(line_no, "second 'format' line"));
                }
                let (Some(enc), Some(version), None) = (tok.next(), tok.next(), tok.next()) else {
                    return Err(FormatError::at_line(
                        line_no,
                        format!("expected 'format ascii|binary_little_endian|binary_big_endian 1.0', found '{}'", clip(line)),
                    ));
                };
                encoding = Some(match enc {
                    "ascii" => Encoding::Ascii,
                    "binary_little_endian" => Encoding::BinaryLe,
                    "binary_big_endian" => Encoding::BinaryBe,
                    other => {
                        return Err(FormatError::at_line(
                            line_no,
                            format!(
                                "unknown PLY format '{}': expected ascii, binary_little_endian or binary_big_endian",
                                clip(other)
                            ),
                        ))
                    }
                });
                if version.parse::<f64>().ok() != Some(1.0) {
                    return Err(FormatError::at_line(
                        line_no,
                        format!("unsupported PLY version '{}' (only 1.0 exists)", clip(version)),
                    ));
                }
            }
            "element" => {
                if encoding.is_none() {
                    return Err(FormatError::at_line(line_no, "'element' before the 'format' line"));
                }
                let (Some(name), Some(count), None) = (tok.next(), tok.next(), tok.next()) else {
                    return Err(FormatError::at_line(
                        line_no,
                        format!("expected 'element NAME COUNT', found '{}'", clip(line)),
                    ));
                };
                let count = count.parse::<u64>().map_err(|_| {
                    FormatError::at_line(
                        line_no,
                        format!("element '{}': count '{}' is not a non-negative integer", clip(name), clip(count)),
                    )
                })?;
                if (name == "vertex" || name == "edge") && elements.iter().any(|e| e.name == name) {
                    return Err(FormatError::at_line(line_no, format!("second '{}' element", clip(name))));
                }
                elements.push(Element { name: clip(name), count, props: Vec::new(), line: line_no });
            }
            "property" => {
                let Some(el) = elements.last_mut() else {
                    return Err(FormatError::at_line(line_no, "'property' before any 'element' line"));
                };
                let parts: Vec<&str> = tok.collect();
                let ty = |s: &str| {
                    Scalar::parse(s).ok_or_else(|| {
                        FormatError::at_line(
                            line_no,
                            format!(
                                "unknown property type '{}' (PLY types: char uchar short ushort int uint float double, \
                                 or int8 uint8 int16 uint16 int32 uint32 float32 float64)",
                                clip(s)
                            ),
                        )
                    })
                };
                let (kind, name) = match parts.as_slice() {
                    ["list", count, item, name] => {
                        let count = ty(count)?;
                        if !count.is_integer() {
                            return Err(FormatError::at_line(
                                line_no,
                                format!("list '{}': count type {} is not an integer type", clip(name), count.name()),
                            ));
                        }
                        (Kind::List { count, item: ty(item)? }, *name)
                    }
                    ["list", ..] => {
                        return Err(FormatError::at_line(
                            line_no,
                            format!("expected 'property list COUNT_TYPE ITEM_TYPE NAME', found '{}'", clip(line)),
                        ))
                    }
                    [t, name] => (Kind::Scalar(ty(t)?), *name),
                    _ => {
                        return Err(FormatError::at_line(
                            line_no,
                            format!("expected 'property TYPE NAME', found '{}'", clip(line)),
                        ))
                    }
                };
                el.props.push(Property { name: clip(name), kind, line: line_no });
            }
            "end_header" => break,
            other => {
                return Err(FormatError::at_line(
                    line_no,
                    format!(
                        "unknown header keyword '{}' (expected format, comment, obj_info, element, property or end_header)",
                        clip(other)
                    ),
                ))
            }
        }
    }
    let Some(encoding) = encoding else {
        return Err(FormatError::at_line(line_no, "header has no 'format' line"));
    };
    Ok(Header {
        encoding,
        elements,
        comments,
        payload_start: pos,
        lines: line_no,
    })
}

/// Refuses element counts the payload cannot hold, before anything is allocated.
fn check_counts(h: &Header, available: usize) -> Result<(), FormatError> {
    let ascii = h.encoding == Encoding::Ascii;
    // ascii: the last value needs no separator after it.
    let limit = available as u128 + u128::from(ascii);
    let mut needed: u128 = 0;
    for el in &h.elements {
        let this = u128::from(el.count) * el.min_record_bytes(ascii);
        let already = needed;
        needed = needed.saturating_add(this);
        if needed > limit {
            let left = (available as u128).saturating_sub(already);
            return Err(FormatError::at_line(
                el.line,
                format!(
                    "element '{}' count {} needs at least {} bytes{} but only {} remain in the file",
                    el.name,
                    el.count,
                    this,
                    if ascii { " of ascii text" } else { "" },
                    left
                ),
            ));
        }
    }
    Ok(())
}

// ---------------------------------------------------------------------------
// Payload
// ---------------------------------------------------------------------------

/// What a decoded record's values are used for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Role {
    Vertex,
    Edge,
    Skip,
}

/// Slots of the values kept from one record.
const X: usize = 0;
const RADIUS: usize = 3;
const CURVE_ID: usize = 4;
const V1: usize = 0;
const V2: usize = 1;

/// Where a record was: a byte offset (binary) or a line (ascii).
#[derive(Debug, Clone, Copy)]
struct Pos {
    binary: bool,
    at: u64,
}

impl Pos {
    fn loc(self) -> Location {
        if self.binary {
            Location::Byte(self.at)
        } else {
            Location::Line(self.at as usize)
        }
    }
    fn err(self, message: impl Into<String>) -> FormatError {
        FormatError::new(self.loc(), message)
    }
}

/// One end of an edge seen from a vertex.
#[derive(Debug, Clone, Copy, Default)]
struct Link {
    other: usize,
    edge: usize,
    /// The vertex is `vertex1` of this edge (the edge leaves it).
    out: bool,
}

/// Collects vertices and edges as records are decoded.
struct Sink {
    nverts: usize,
    points: Vec<Vec3>,
    radius: Option<Vec<f64>>,
    ids: Option<Vec<f64>>,
    /// Where each vertex record was (for errors found after reading).
    vpos: Vec<u64>,
    /// Per vertex: up to two incident edges.
    adj: Vec<[Link; 2]>,
    deg: Vec<u8>,
}

impl Sink {
    fn vertex(&mut self, rec: u64, pos: Pos, v: &[f64; 5]) -> Result<(), FormatError> {
        for (k, axis) in ["x", "y", "z"].into_iter().enumerate() {
            if !v[X + k].is_finite() {
                return Err(pos.err(format!(
                    "vertex {rec}: {axis} is {} (coordinates must be finite)",
                    v[X + k]
                )));
            }
        }
        if let Some(r) = &mut self.radius {
            let value = v[RADIUS];
            if !(value.is_finite() && value > 0.0) {
                return Err(pos.err(format!(
                    "vertex {rec}: radius {value} is not a positive finite number"
                )));
            }
            r.push(value);
        }
        if let Some(ids) = &mut self.ids {
            if !v[CURVE_ID].is_finite() {
                return Err(pos.err(format!(
                    "vertex {rec}: curve id {} is not finite",
                    v[CURVE_ID]
                )));
            }
            ids.push(v[CURVE_ID]);
        }
        self.points.push([v[X], v[X + 1], v[X + 2]]);
        self.vpos.push(pos.at);
        Ok(())
    }

    fn edge(&mut self, rec: u64, pos: Pos, v: &[f64; 5]) -> Result<(), FormatError> {
        let n = self.nverts;
        let index = |x: f64, which: &str| {
            // Integer-typed by the header check, so `x` is an exact integer.
            if x >= 0.0 && x < n as f64 {
                Ok(x as usize)
            } else {
                Err(pos.err(format!(
                    "edge {rec}: {which} = {x} is out of range (the file has {n} vertices)"
                )))
            }
        };
        let a = index(v[V1], "vertex1")?;
        let b = index(v[V2], "vertex2")?;
        if a == b {
            return Err(pos.err(format!("edge {rec} connects vertex {a} to itself")));
        }
        if self.deg[a] == 1 && self.adj[a][0].other == b {
            // Two edges between the same vertices would make a 2-point loop.
            return Err(pos.err(format!(
                "edge {rec} joins vertices {a} and {b} a second time (first: edge {}); a closed curve needs at least 3 points",
                self.adj[a][0].edge
            )));
        }
        let edge = rec as usize;
        for (u, w, out) in [(a, b, true), (b, a, false)] {
            let d = self.deg[u] as usize;
            if d >= 2 {
                return Err(pos.err(format!(
                    "edge {rec}: vertex {u} is on more than 2 edges (degree 3); yarn polylines cannot branch"
                )));
            }
            self.adj[u][d] = Link {
                other: w,
                edge,
                out,
            };
            self.deg[u] += 1;
        }
        Ok(())
    }

    fn take(&mut self, role: Role, rec: u64, pos: Pos, v: &[f64; 5]) -> Result<(), FormatError> {
        match role {
            Role::Vertex => self.vertex(rec, pos, v),
            Role::Edge => self.edge(rec, pos, v),
            Role::Skip => Ok(()),
        }
    }
}

/// Binary payload of one element. `slots[i]` says where property `i` is kept.
fn read_binary_element(
    data: &[u8],
    pos: &mut usize,
    el: &Element,
    slots: &[Option<usize>],
    role: Role,
    big: bool,
    sink: &mut Sink,
) -> Result<(), FormatError> {
    if el.props.is_empty() || el.count == 0 {
        return Ok(());
    }
    if role == Role::Skip {
        if let Some(size) = el.fixed_record_bytes() {
            // Fixed-size records of an unused element: jump over them at once.
            let bytes = u128::from(el.count) * size as u128;
            let left = data.len() - *pos;
            if bytes > left as u128 {
                return Err(FormatError::at_byte(
                    *pos as u64,
                    format!(
                        "file ends early: element '{}' needs {bytes} bytes, only {left} left",
                        el.name
                    ),
                ));
            }
            *pos += bytes as usize;
            return Ok(());
        }
    }
    let mut vals = [0.0f64; 5];
    for rec in 0..el.count {
        let start = *pos;
        for (p, slot) in el.props.iter().zip(slots) {
            let left = data.len() - *pos;
            let ends_early = |need: u128| {
                FormatError::at_byte(
                    *pos as u64,
                    format!(
                        "file ends early: {} {rec}, property '{}' needs {need} bytes, only {left} left",
                        el.name, p.name
                    ),
                )
            };
            match p.kind {
                Kind::Scalar(t) => {
                    let n = t.size();
                    if n > left {
                        return Err(ends_early(n as u128));
                    }
                    if let Some(s) = slot {
                        vals[*s] = t.decode(&data[*pos..*pos + n], big);
                    }
                    *pos += n;
                }
                Kind::List { count, item } => {
                    let n = count.size();
                    if n > left {
                        return Err(ends_early(n as u128));
                    }
                    let len = count.decode(&data[*pos..*pos + n], big);
                    if len < 0.0 {
                        return Err(FormatError::at_byte(
                            *pos as u64,
                            format!(
                                "{} {rec}: list '{}' has negative length {len}",
                                el.name, p.name
                            ),
                        ));
                    }
                    *pos += n;
                    // `len` is an exact integer below 2^32; the product cannot overflow u128.
                    let bytes = len as u128 * item.size() as u128;
                    let left = data.len() - *pos;
                    if bytes > left as u128 {
                        return Err(FormatError::at_byte(
                            *pos as u64,
                            format!(
                                "{} {rec}: list '{}' of {len} {} items needs {bytes} bytes, only {left} left",
                                el.name,
                                p.name,
                                item.name()
                            ),
                        ));
                    }
                    *pos += bytes as usize;
                }
            }
        }
        sink.take(
            role,
            rec,
            Pos {
                binary: true,
                at: start as u64,
            },
            &vals,
        )?;
    }
    Ok(())
}

/// The ascii payload as numbered lines.
struct AsciiLines<'a> {
    data: &'a [u8],
    pos: usize,
    line: usize,
}

impl<'a> AsciiLines<'a> {
    /// The next line with any content, as (line number, text).
    fn next_record(&mut self) -> Option<Result<(usize, &'a str), FormatError>> {
        while self.pos < self.data.len() {
            let (raw, next) = next_line(self.data, self.pos);
            self.pos = next;
            self.line += 1;
            if raw.iter().all(u8::is_ascii_whitespace) {
                continue;
            }
            return Some(
                std::str::from_utf8(raw)
                    .map(|s| (self.line, s))
                    .map_err(|e| {
                        FormatError::at_line(
                            self.line,
                            format!("not text (invalid UTF-8 at column {})", e.valid_up_to() + 1),
                        )
                    }),
            );
        }
        None
    }
}

fn read_ascii_element(
    lines: &mut AsciiLines,
    el: &Element,
    slots: &[Option<usize>],
    role: Role,
    sink: &mut Sink,
) -> Result<(), FormatError> {
    if el.props.is_empty() {
        return Ok(()); // records without values take no text
    }
    let mut vals = [0.0f64; 5];
    for rec in 0..el.count {
        let Some(next) = lines.next_record() else {
            return Err(FormatError::at_line(
                lines.line.max(1),
                format!(
                    "file ends early: element '{}' declares {} records, found {rec}",
                    el.name, el.count
                ),
            ));
        };
        let (line_no, text) = next?;
        let at = |msg: String| FormatError::at_line(line_no, format!("{} {rec}: {msg}", el.name));
        let mut tok = text.split_ascii_whitespace();
        for (p, slot) in el.props.iter().zip(slots) {
            let mut value = |t: Scalar, what: &dyn Fn() -> String| -> Result<f64, FormatError> {
                let s = tok
                    .next()
                    .ok_or_else(|| at(format!("too few values: {} is missing", what())))?;
                t.parse_token(s).map_err(|m| at(format!("{}: {m}", what())))
            };
            match p.kind {
                Kind::Scalar(t) => {
                    let v = value(t, &|| format!("property '{}'", p.name))?;
                    if let Some(s) = slot {
                        vals[*s] = v;
                    }
                }
                Kind::List { count, item } => {
                    let len = value(count, &|| format!("length of list '{}'", p.name))?;
                    if len < 0.0 {
                        return Err(at(format!("list '{}' has negative length {len}", p.name)));
                    }
                    // Each item must be on this line, so the loop is bounded by the line's length.
                    for i in 0..len as u64 {
                        value(item, &|| {
                            format!("item {i} of list '{}' (length {len})", p.name)
                        })?;
                    }
                }
            }
        }
        if tok.next().is_some() {
            return Err(at(format!(
                "more values than the {} properties the header declares",
                el.props.len()
            )));
        }
        sink.take(
            role,
            rec,
            Pos {
                binary: false,
                at: line_no as u64,
            },
            &vals,
        )?;
    }
    Ok(())
}

/// Finds the scalar property named one of `names`; errors on lists and duplicates.
fn find_prop(el: &Element, names: &[&str], integer: bool) -> Result<Option<usize>, FormatError> {
    let mut found: Option<usize> = None;
    for (i, p) in el.props.iter().enumerate() {
        if !names.contains(&p.name.as_str()) {
            continue;
        }
        if let Some(j) = found {
            return Err(FormatError::at_line(
                p.line,
                format!(
                    "element '{}': property '{}' repeats what '{}' (line {}) already gives",
                    el.name, p.name, el.props[j].name, el.props[j].line
                ),
            ));
        }
        match p.kind {
            Kind::List { .. } => {
                return Err(FormatError::at_line(
                    p.line,
                    format!(
                        "element '{}': property '{}' is a list; expected a scalar",
                        el.name, p.name
                    ),
                ))
            }
            Kind::Scalar(t) if integer && !t.is_integer() => {
                return Err(FormatError::at_line(
                    p.line,
                    format!(
                    "element '{}': property '{}' is {}; vertex indices must have an integer type",
                    el.name,
                    p.name,
                    t.name()
                ),
                ))
            }
            Kind::Scalar(_) => found = Some(i),
        }
    }
    Ok(found)
}

/// Decodes a PLY file (ascii or binary) into curves; see the module docs for
/// what is read and how topology is found.
pub fn decode(data: &[u8], opts: &ReadOptions) -> Result<Decoded, FormatError> {
    let h = parse_header(data)?;
    let (units, up_axis) = declared_frame(&h.comments)?;

    let mut notes = vec![format!("PLY {} 1.0", h.encoding.name())];
    for c in h.comments.iter().take(MAX_COMMENT_NOTES) {
        notes.push(format!("comment: {c}"));
    }
    if h.comments.len() > MAX_COMMENT_NOTES {
        notes.push(format!(
            "... and {} more comments",
            h.comments.len() - MAX_COMMENT_NOTES
        ));
    }

    let Some(vi) = h.elements.iter().position(|e| e.name == "vertex") else {
        return Err(FormatError::at_line(
            h.lines,
            "the header declares no 'vertex' element: no curve points",
        ));
    };
    let vel = &h.elements[vi];
    // Vertex slots.
    let mut vslots = vec![None; vel.props.len()];
    for (k, axis) in ["x", "y", "z"].into_iter().enumerate() {
        match find_prop(vel, &[axis], false)? {
            Some(i) => vslots[i] = Some(X + k),
            None => {
                return Err(FormatError::at_line(
                    vel.line,
                    format!("element 'vertex' has no scalar property '{axis}'"),
                ))
            }
        }
    }
    let radius_prop = find_prop(vel, &RADIUS_NAMES, false)?;
    if let Some(i) = radius_prop {
        vslots[i] = Some(RADIUS);
    }
    let ei = h.elements.iter().position(|e| e.name == "edge");
    let id_prop = find_prop(vel, &CURVE_ID_NAMES, false)?;

    // Edge slots.
    let mut eslots = Vec::new();
    if let Some(ei) = ei {
        let eel = &h.elements[ei];
        eslots = vec![None; eel.props.len()];
        for (slot, name) in [(V1, "vertex1"), (V2, "vertex2")] {
            match find_prop(eel, &[name], true)? {
                Some(i) => eslots[i] = Some(slot),
                None => {
                    return Err(FormatError::at_line(
                        eel.line,
                        format!("element 'edge' has no integer property '{name}'"),
                    ))
                }
            }
        }
        // Sum of degrees is 2 * edges; with at most 2 per vertex, edges <= vertices.
        if eel.count > vel.count {
            return Err(FormatError::at_line(
                eel.line,
                format!(
                    "{} edges for {} vertices: unbranched polylines have at most one edge per vertex",
                    eel.count, vel.count
                ),
            ));
        }
        if let Some(i) = id_prop {
            notes.push(format!(
                "curve-id property '{}' ignored: the edge element gives the topology",
                vel.props[i].name
            ));
        }
    } else if let Some(i) = id_prop {
        vslots[i] = Some(CURVE_ID);
    } else if vel.count > 0 {
        return Err(FormatError::at_line(
            vel.line,
            format!(
                "PLY has vertices but no edge element or curve-id property ({}): cannot tell curves apart",
                CURVE_ID_NAMES.join(", ")
            ),
        ));
    }
    let ignored: Vec<&str> = vel
        .props
        .iter()
        .zip(&vslots)
        .filter(|(_, s)| s.is_none())
        .map(|(p, _)| p.name.as_str())
        .collect();
    if !ignored.is_empty() {
        notes.push(format!("vertex properties ignored: {}", ignored.join(", ")));
    }

    // Every count against the bytes that are left, before allocating for any.
    check_counts(&h, data.len() - h.payload_start)?;
    if vel.count > opts.max_points {
        return Err(FormatError::at_line(
            vel.line,
            format!(
                "vertex count {} exceeds the limit of {} points (max_points)",
                vel.count, opts.max_points
            ),
        ));
    }
    // Bounded by max_points and by the bytes check.
    let nverts = usize::try_from(vel.count).map_err(|_| {
        FormatError::at_line(
            vel.line,
            format!("vertex count {} does not fit in memory", vel.count),
        )
    })?;

    let with_edges = ei.is_some();
    let nadj = if with_edges { nverts } else { 0 };
    let mut sink = Sink {
        nverts,
        points: Vec::with_capacity(nverts),
        radius: radius_prop.map(|_| Vec::with_capacity(nverts)),
        ids: (!with_edges && id_prop.is_some()).then(|| Vec::with_capacity(nverts)),
        vpos: Vec::with_capacity(nverts),
        adj: vec![[Link::default(); 2]; nadj],
        deg: vec![0; nadj],
    };

    let binary = h.encoding != Encoding::Ascii;
    let big = h.encoding == Encoding::BinaryBe;
    let mut pos = h.payload_start;
    let mut lines = AsciiLines {
        data,
        pos: h.payload_start,
        line: h.lines,
    };
    let empty = Vec::new();
    for (i, el) in h.elements.iter().enumerate() {
        let (role, slots) = if i == vi {
            (Role::Vertex, &vslots)
        } else if Some(i) == ei {
            (Role::Edge, &eslots)
        } else {
            notes.push(format!(
                "skipped element '{}' ({} records)",
                el.name, el.count
            ));
            (Role::Skip, &empty)
        };
        let none;
        let slots = if slots.len() == el.props.len() {
            slots
        } else {
            none = vec![None; el.props.len()];
            &none
        };
        if binary {
            read_binary_element(data, &mut pos, el, slots, role, big, &mut sink)?;
        } else {
            read_ascii_element(&mut lines, el, slots, role, &mut sink)?;
        }
    }
    if binary {
        if pos < data.len() {
            notes.push(format!(
                "{} bytes after the last element ignored",
                data.len() - pos
            ));
        }
    } else if let Some(extra) = lines.next_record() {
        let line = extra.map(|(l, _)| l).unwrap_or_else(|e| match e.location {
            Location::Line(l) => l,
            _ => 0,
        });
        notes.push(format!(
            "text after the last element (from line {line}) ignored"
        ));
    }

    let pos_of = |v: usize| Pos {
        binary,
        at: sink.vpos.get(v).copied().unwrap_or(0),
    };
    // Curves as runs of vertex indices, in output order.
    let mut order: Vec<usize> = Vec::with_capacity(nverts);
    let mut offsets = vec![0usize];
    let mut closed = Vec::new();
    if with_edges {
        notes.push(format!(
            "{nverts} vertices, {} edges chained into polylines",
            h.elements[ei.unwrap_or(0)].count
        ));
        chain_edges(&sink, &mut order, &mut offsets, &mut closed, pos_of)?;
    } else if let Some(ids) = &sink.ids {
        notes.push(format!(
            "curves from the curve-id property '{}'",
            vel.props[id_prop.unwrap_or(0)].name
        ));
        let mut start = 0;
        for v in 0..=ids.len() {
            if v == ids.len() || (v > start && ids[v] != ids[start]) {
                if v - start < 2 && v > start {
                    return Err(pos_of(start).err(format!(
                        "vertex {start} is the only vertex of curve id {}: a curve needs at least 2 points",
                        ids[start]
                    )));
                }
                if v > start {
                    offsets.push(v);
                    closed.push(false);
                }
                start = v;
            }
        }
        order.extend(0..ids.len());
    }

    // Assemble the curves.
    let ncurves = closed.len();
    let mut yarns = Yarns {
        points: order.iter().map(|&v| sink.points[v]).collect(),
        offsets,
        closed,
        radius: vec![opts.radius; ncurves],
        vertex_radius: None,
        linear_density: None,
        rest: None,
    };
    let radius_in_file = sink.radius.is_some();
    if let Some(r) = &sink.radius {
        let vr: Vec<f64> = order.iter().map(|&v| r[v]).collect();
        let mut varies = false;
        for c in 0..ncurves {
            let run = &vr[yarns.offsets[c]..yarns.offsets[c + 1]];
            let first = run.first().copied().unwrap_or(opts.radius);
            if run.iter().all(|&x| x == first) {
                yarns.radius[c] = first;
            } else {
                varies = true;
                yarns.radius[c] = run.iter().sum::<f64>() / run.len() as f64;
            }
        }
        if varies {
            yarns.vertex_radius = Some(vr);
        }
    }
    Ok(Decoded {
        yarns,
        frames: None,
        units,
        up_axis,
        radius_in_file,
        notes,
    })
}

/// Chains the edges collected in `sink` into polylines (see the module docs
/// for the order rules). Appends vertex indices to `order`.
fn chain_edges(
    sink: &Sink,
    order: &mut Vec<usize>,
    offsets: &mut Vec<usize>,
    closed: &mut Vec<bool>,
    pos_of: impl Fn(usize) -> Pos,
) -> Result<(), FormatError> {
    let n = sink.nverts;
    let (adj, deg) = (&sink.adj, &sink.deg);
    // The edge at `v` other than `via` (None at the end of a chain).
    let step = |v: usize, via: usize| -> Option<Link> {
        adj[v][..deg[v] as usize]
            .iter()
            .copied()
            .find(|l| l.edge != via)
    };
    let broken = || FormatError::whole_file("internal error: edge chain walk did not terminate");
    let mut visited = vec![false; n];
    for v in 0..n {
        if visited[v] {
            continue;
        }
        let start_len = order.len();
        match deg[v] {
            0 => {
                return Err(pos_of(v).err(format!(
                    "vertex {v} is on no edge: every vertex must belong to a curve of at least 2 points"
                )))
            }
            1 | 2 => {
                // Is v on a cycle? Walk one way until an end or back to v.
                let mut end = v;
                let mut cycle = false;
                if deg[v] == 2 {
                    let (mut cur, mut via) = (adj[v][0].other, adj[v][0].edge);
                    let mut steps = 0usize;
                    loop {
                        if cur == v {
                            cycle = true;
                            break;
                        }
                        match step(cur, via) {
                            None => {
                                end = cur;
                                break;
                            }
                            Some(l) => {
                                cur = l.other;
                                via = l.edge;
                            }
                        }
                        steps += 1;
                        if steps > n {
                            return Err(broken());
                        }
                    }
                }
                if cycle {
                    // Start at v (its lowest index); leave along its outgoing edge.
                    let k = match (adj[v][0].out, adj[v][1].out) {
                        (true, false) => 0,
                        (false, true) => 1,
                        _ => usize::from(adj[v][1].edge < adj[v][0].edge),
                    };
                    order.push(v);
                    let (mut cur, mut via) = (adj[v][k].other, adj[v][k].edge);
                    while cur != v {
                        if order.len() - start_len > n {
                            return Err(broken());
                        }
                        order.push(cur);
                        let l = step(cur, via).ok_or_else(broken)?;
                        cur = l.other;
                        via = l.edge;
                    }
                    closed.push(true);
                } else {
                    // Open chain: walk from one end to the other.
                    order.push(end);
                    let (mut cur, mut via) = (end, usize::MAX);
                    while let Some(l) = step(cur, via) {
                        if order.len() - start_len > n {
                            return Err(broken());
                        }
                        order.push(l.other);
                        cur = l.other;
                        via = l.edge;
                    }
                    let other = cur;
                    let source = |e: usize| adj[e][0].out;
                    let reverse = match (source(end), source(other)) {
                        (true, false) => false,
                        (false, true) => true,
                        _ => other < end,
                    };
                    if reverse {
                        order[start_len..].reverse();
                    }
                    closed.push(false);
                }
            }
            d => return Err(pos_of(v).err(format!("internal error: vertex {v} has degree {d}"))),
        }
        for &u in &order[start_len..] {
            visited[u] = true;
        }
        offsets.push(order.len());
    }
    Ok(())
}

/// Encodes curves as binary little-endian PLY: `vertex` (float x y z radius)
/// and `edge` (int vertex1 vertex2), one edge per segment; closed yarns get
/// their closing edge.
///
/// The header declares no unit or up axis; see [`encode_in`].
pub fn encode(yarns: &Yarns) -> Result<Vec<u8>, FormatError> {
    encode_frame(yarns, None)
}

/// Like [`encode`], for curves already in `units` and `up` (file frame): the
/// header carries `comment knitvox units <unit>` and `comment knitvox
/// up_axis <axis>` after the `generated by` comment, and [`decode`] reports
/// them as declared by the file.
pub fn encode_in(yarns: &Yarns, units: Units, up: UpAxis) -> Result<Vec<u8>, FormatError> {
    encode_frame(yarns, Some((units, up)))
}

fn encode_frame(yarns: &Yarns, frame: Option<(Units, UpAxis)>) -> Result<Vec<u8>, FormatError> {
    yarns.validate()?;
    if let Some(c) =
        (0..yarns.num_curves()).find(|&c| yarns.closed[c] && yarns.curve_range(c).len() < 3)
    {
        return Err(FormatError::at_path(
            format!("curve {c}"),
            "a closed curve needs at least 3 points (PLY edges cannot encode a 2-point loop)",
        ));
    }
    let n = yarns.num_points();
    if n > i32::MAX as usize + 1 {
        return Err(FormatError::whole_file(format!(
            "{n} points do not fit PLY 'int' vertex indices (at most {})",
            i32::MAX as u64 + 1
        )));
    }
    let m = yarns.num_segments();
    let frame_comments = match frame {
        Some((u, a)) => format!("comment {UNITS_COMMENT} {u}\ncomment {UP_AXIS_COMMENT} {a}\n"),
        None => String::new(),
    };
    let header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment generated by knitvox {}\n{frame_comments}\
         element vertex {n}\nproperty float x\nproperty float y\nproperty float z\nproperty float radius\n\
         element edge {m}\nproperty int vertex1\nproperty int vertex2\nend_header\n",
        env!("CARGO_PKG_VERSION")
    );
    let size = n
        .checked_mul(16)
        .and_then(|a| m.checked_mul(8).and_then(|b| a.checked_add(b)))
        .and_then(|a| a.checked_add(header.len()))
        .ok_or_else(|| FormatError::whole_file("PLY file would be larger than memory"))?;
    let mut out = Vec::with_capacity(size);
    out.extend_from_slice(header.as_bytes());
    let to_f32 = |x: f64, what: &str, v: usize| -> Result<f32, FormatError> {
        let f = x as f32;
        if f.is_finite() {
            Ok(f)
        } else {
            Err(FormatError::at_path(
                format!("vertex {v}"),
                format!("{what} {x} does not fit a 32-bit float"),
            ))
        }
    };
    for c in 0..yarns.num_curves() {
        for v in yarns.curve_range(c) {
            let p = yarns.points[v];
            let r = match &yarns.vertex_radius {
                Some(vr) => vr[v],
                None => yarns.radius[c],
            };
            for (x, what) in [(p[0], "x"), (p[1], "y"), (p[2], "z"), (r, "radius")] {
                let f = to_f32(x, what, v)?;
                if what == "radius" && f <= 0.0 {
                    return Err(FormatError::at_path(
                        format!("vertex {v}"),
                        format!("radius {x} rounds to 0 as a float"),
                    ));
                }
                out.extend_from_slice(&f.to_le_bytes());
            }
        }
    }
    for [a, b] in yarns.segments() {
        // n <= 2^31, so every index fits i32.
        out.extend_from_slice(&(a as i32).to_le_bytes());
        out.extend_from_slice(&(b as i32).to_le_bytes());
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn opts() -> ReadOptions {
        ReadOptions::default()
    }

    fn dec(s: &str) -> Result<Decoded, FormatError> {
        decode(s.as_bytes(), &opts())
    }

    #[test]
    fn both_type_naming_schemes() {
        for (a, b) in [
            ("char", "int8"),
            ("uchar", "uint8"),
            ("short", "int16"),
            ("ushort", "uint16"),
            ("int", "int32"),
            ("uint", "uint32"),
            ("float", "float32"),
            ("double", "float64"),
        ] {
            assert_eq!(Scalar::parse(a), Scalar::parse(b));
            assert!(Scalar::parse(a).is_some());
        }
        assert_eq!(Scalar::parse("int64"), None);
    }

    #[test]
    fn scalar_decoding_both_endians() {
        assert_eq!(Scalar::I16.decode(&[0xff, 0xfe], true), -2.0);
        assert_eq!(Scalar::I16.decode(&[0xfe, 0xff], false), -2.0);
        assert_eq!(Scalar::U32.decode(&[0xff; 4], false), u32::MAX as f64);
        assert_eq!(Scalar::F32.decode(&1.5f32.to_be_bytes(), true), 1.5);
        assert_eq!(Scalar::F64.decode(&(-2.25f64).to_le_bytes(), false), -2.25);
        assert_eq!(Scalar::I8.decode(&[0x80], false), -128.0);
    }

    #[test]
    fn ascii_tokens() {
        assert_eq!(Scalar::U8.parse_token("255"), Ok(255.0));
        assert!(Scalar::U8.parse_token("256").is_err());
        assert!(Scalar::I32.parse_token("1.5").is_err());
        assert_eq!(Scalar::I32.parse_token("3.0"), Ok(3.0));
        assert!(Scalar::F32.parse_token("abc").is_err());
    }

    #[test]
    fn header_parse() {
        let h = parse_header(
            b"ply\r\nformat ascii 1.0\r\ncomment hi there\r\nelement vertex 2\r\nproperty float32 x\r\n\
              property list uint8 int32 vertex_indices\r\nend_header\r\n1 0\r\n",
        )
        .unwrap();
        assert_eq!(h.encoding, Encoding::Ascii);
        assert_eq!(h.comments, vec!["hi there".to_string()]);
        assert_eq!(
            h.elements[0].props[1].kind,
            Kind::List {
                count: Scalar::U8,
                item: Scalar::I32
            }
        );
        assert_eq!(h.lines, 7);
    }

    #[test]
    fn edge_chains_open_and_closed() {
        // Curve A: 3 -> 1 -> 0 (edges written backwards and out of order), loop B: 2 4 5.
        let d = dec("ply\nformat ascii 1.0\nelement vertex 6\nproperty float x\nproperty float y\nproperty float z\n\
                     element edge 5\nproperty int vertex1\nproperty int vertex2\nend_header\n\
                     0 0 0\n1 0 0\n2 0 0\n3 0 0\n4 0 0\n5 0 0\n\
                     1 0\n4 5\n3 1\n2 4\n5 2\n")
        .unwrap();
        let y = &d.yarns;
        assert_eq!(y.offsets, vec![0, 3, 6]);
        assert_eq!(y.closed, vec![false, true]);
        let xs: Vec<f64> = y.points.iter().map(|p| p[0]).collect();
        assert_eq!(xs, vec![3.0, 1.0, 0.0, 2.0, 4.0, 5.0]);
        assert!(!d.radius_in_file);
    }

    #[test]
    fn two_point_loop_is_refused() {
        let e = dec("ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n\
                     element edge 2\nproperty uchar vertex1\nproperty uchar vertex2\nend_header\n\
                     0 0 0\n1 0 0\n0 1\n1 0\n")
        .unwrap_err();
        assert_eq!(e.location, Location::Line(14));
        assert!(e.message.contains("second time"), "{e}");
    }

    #[test]
    fn counts_guarded_before_allocation() {
        let e = dec(
            "ply\nformat binary_little_endian 1.0\nelement vertex 1152921504606846976\n\
                     property float x\nproperty float y\nproperty float z\nproperty int strand\n\
                     end_header\n",
        )
        .unwrap_err();
        assert_eq!(e.location, Location::Line(3));
        assert!(e.message.contains("18446744073709551616 bytes"), "{e}");
    }

    #[test]
    fn encode_writes_closing_edge() {
        let mut y = Yarns::new();
        y.push_curve(&[[0.0; 3], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0]], true, 0.5);
        let b = encode(&y).unwrap();
        let text = String::from_utf8_lossy(&b);
        assert!(text.contains("element edge 3\n"));
        assert!(text.contains("comment generated by knitvox"));
        let d = decode(&b, &opts()).unwrap();
        assert_eq!(d.yarns.closed, vec![true]);
        assert_eq!(d.yarns.radius, vec![0.5]);
        assert!(d.radius_in_file);
    }

    #[test]
    fn encode_refuses_unrepresentable_values() {
        let mut y = Yarns::new();
        y.push_curve(&[[0.0; 3], [1e300, 0.0, 0.0]], false, 0.5);
        let e = encode(&y).unwrap_err();
        assert!(e.message.contains("32-bit"), "{e}");
        let mut y = Yarns::new();
        y.push_curve(&[[0.0; 3]], false, 0.5);
        assert!(encode(&y).is_err());
    }
}
