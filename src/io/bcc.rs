//! BCC, Cem Yuksel's "binary curve collection".
//!
//! Layout (little endian): a 64-byte header — `"BCC"` and `0x44` (4-byte ints
//! and floats), 2 chars curve type (`PL` polyline, `C0` uniform Catmull-Rom,
//! `BS` uniform cubic B-spline), 1 byte dimensions (3), 1 byte up axis
//! (1 = +Y, 2 = +Z as in the published models), u64 curve count, u64 total
//! control points, 40 bytes of free text — then per curve an `i32` control
//! point count (negative: closed loop) and that many `f32` triples.
//!
//! Splines are sampled to polylines with `K` samples per span between
//! consecutive control points (`ReadOptions::spline_samples`, default 1). With
//! K = 1 a C0 curve keeps exactly its control points; a BS curve gets one
//! point per control point, at the spline's value there. Open curves clamp the
//! missing neighbour of an end span to the end point; closed curves wrap.

use super::bytes::ByteReader;
use super::{Decoded, FormatError, ReadOptions};
use crate::geom::{UpAxis, Vec3, Yarns};

/// Default polyline samples per spline span: 1 keeps exactly the C0 control points.
pub const DEFAULT_SPLINE_SAMPLES: usize = 1;

/// Largest accepted samples per span: more is never useful for yarn curves.
pub const MAX_SPLINE_SAMPLES: usize = 64;

const HEADER_LEN: usize = 64;
const POINT_BYTES: usize = 12;

/// The curve type of a BCC file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CurveType {
    Polyline,
    CatmullRom,
    BSpline,
}

impl CurveType {
    fn code(self) -> &'static [u8; 2] {
        match self {
            CurveType::Polyline => b"PL",
            CurveType::CatmullRom => b"C0",
            CurveType::BSpline => b"BS",
        }
    }
}

/// The parsed 64-byte header.
#[derive(Debug, Clone, PartialEq)]
pub struct Header {
    pub curve_type: CurveType,
    pub up_axis: Option<UpAxis>,
    pub curve_count: u64,
    pub point_count: u64,
    pub info: String,
}

fn parse_header(r: &mut ByteReader) -> Result<Header, FormatError> {
    if r.remaining() == 0 {
        return Err(FormatError::at_byte(
            0,
            "empty file: a BCC file starts with a 64-byte header",
        ));
    }
    let magic = r.array::<4>("the BCC signature")?;
    if &magic[..3] != b"BCC" {
        return Err(FormatError::at_byte(
            0,
            format!(
                "not a BCC file: signature is {:?}, expected \"BCC\"",
                lossy(&magic[..3])
            ),
        ));
    }
    if magic[3] != 0x44 {
        return Err(FormatError::at_byte(
            3,
            format!(
                "unsupported BCC size byte 0x{:02x}: only 0x44 (4-byte integers and floats) exists",
                magic[3]
            ),
        ));
    }
    let code = r.array::<2>("the curve type")?;
    let curve_type = match &code {
        b"PL" => CurveType::Polyline,
        b"C0" => CurveType::CatmullRom,
        b"BS" => CurveType::BSpline,
        _ => {
            return Err(FormatError::at_byte(
                4,
                format!(
                    "unknown curve type {:?}: expected PL, C0 or BS",
                    lossy(&code)
                ),
            ))
        }
    };
    let dims = r.u8("the dimension count")?;
    if dims != 3 {
        return Err(FormatError::at_byte(
            6,
            format!("{dims}-dimensional curves are not supported: expected 3"),
        ));
    }
    let up = r.u8("the up axis")?;
    let up_axis = match up {
        1 => Some(UpAxis::Y),
        2 => Some(UpAxis::Z),
        _ => None,
    };
    let curve_count = r.u64_le("the curve count")?;
    let point_count = r.u64_le("the control point count")?;
    let text = r.array::<40>("the header text")?;
    let end = text.iter().position(|&b| b == 0).unwrap_or(text.len());
    // Some writers leave uninitialised memory in the text: keep only printable ASCII.
    let info: String = text[..end]
        .iter()
        .take_while(|b| b.is_ascii_graphic() || **b == b' ')
        .map(|&b| b as char)
        .collect();
    Ok(Header {
        curve_type,
        up_axis,
        curve_count,
        point_count,
        info: info.trim().to_string(),
    })
}

fn lossy(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// Reads only the header (for `inspect`).
pub fn read_header(data: &[u8]) -> Result<Header, FormatError> {
    parse_header(&mut ByteReader::new(data))
}

/// Decodes a BCC file into polylines (file units and axes).
pub fn decode(data: &[u8], opts: &ReadOptions) -> Result<Decoded, FormatError> {
    let mut r = ByteReader::new(data);
    let h = parse_header(&mut r)?;
    let samples = opts.spline_samples.unwrap_or(DEFAULT_SPLINE_SAMPLES);
    if samples == 0 || samples > MAX_SPLINE_SAMPLES {
        return Err(FormatError::whole_file(format!(
            "spline samples per span must be between 1 and {MAX_SPLINE_SAMPLES}, got {samples}"
        )));
    }
    let samples = if h.curve_type == CurveType::Polyline {
        1
    } else {
        samples
    };
    // Every curve needs at least its 4-byte count, every point 12 bytes.
    let body = (data.len() - HEADER_LEN) as u64;
    if h.curve_count > body / 4 {
        return Err(FormatError::at_byte(
            8,
            format!(
                "header claims {} curves but the {} bytes after the header hold at most {}",
                h.curve_count,
                body,
                body / 4
            ),
        ));
    }
    if h.point_count > body / POINT_BYTES as u64 {
        return Err(FormatError::at_byte(
            16,
            format!(
                "header claims {} control points ({} bytes) but only {} bytes follow the header",
                h.point_count,
                h.point_count.saturating_mul(POINT_BYTES as u64),
                body
            ),
        ));
    }
    let out_points = h.point_count.saturating_mul(samples as u64);
    if out_points > opts.max_points {
        return Err(FormatError::at_byte(
            16,
            format!(
                "{} polyline points after sampling exceed the limit of {}",
                out_points, opts.max_points
            ),
        ));
    }
    let mut yarns = Yarns::new();
    yarns.points.reserve(out_points as usize);
    yarns.offsets.reserve(h.curve_count as usize);
    let mut control: Vec<Vec3> = Vec::new();
    let mut total: u64 = 0;
    for c in 0..h.curve_count {
        let at = r.pos() as u64;
        let n = r.i32_le(&format!("the point count of curve {c}"))?;
        let closed = n < 0;
        let count = (n as i64).unsigned_abs();
        if count < 2 || (closed && count < 3) {
            return Err(FormatError::at_byte(
                at,
                format!("curve {c} has {count} control point(s); an open yarn needs at least 2, a closed one 3"),
            ));
        }
        total += count;
        if total > h.point_count {
            return Err(FormatError::at_byte(
                at,
                format!("curve {c} brings the control point total to {total}, more than the header's {}", h.point_count),
            ));
        }
        let start = r.pos();
        let raw = r.take(
            count as usize * POINT_BYTES,
            &format!("the {count} points of curve {c}"),
        )?;
        control.clear();
        for (i, chunk) in raw.chunks_exact(POINT_BYTES).enumerate() {
            let f = |k: usize| {
                f32::from_le_bytes([
                    chunk[4 * k],
                    chunk[4 * k + 1],
                    chunk[4 * k + 2],
                    chunk[4 * k + 3],
                ])
            };
            let p = [f(0) as f64, f(1) as f64, f(2) as f64];
            if !p.iter().all(|x| x.is_finite()) {
                return Err(FormatError::at_byte(
                    (start + i * POINT_BYTES) as u64,
                    format!("curve {c}, point {i}: coordinate is not finite ({p:?})"),
                ));
            }
            control.push(p);
        }
        let before = yarns.points.len();
        sample_curve(h.curve_type, &control, closed, samples, &mut yarns.points);
        yarns.offsets.push(yarns.points.len());
        yarns.closed.push(closed);
        yarns.radius.push(1.0);
        debug_assert!(yarns.points.len() > before);
    }
    if total != h.point_count {
        return Err(FormatError::at_byte(
            16,
            format!(
                "header claims {} control points but the curves hold {total}",
                h.point_count
            ),
        ));
    }
    if !r.is_at_end() {
        return Err(FormatError::at_byte(
            r.pos() as u64,
            format!("{} unexpected bytes after the last curve", r.remaining()),
        ));
    }
    let kind = match h.curve_type {
        CurveType::Polyline => "polylines (PL)".to_string(),
        CurveType::CatmullRom => format!("uniform Catmull-Rom (C0), {samples} sample(s) per span"),
        CurveType::BSpline => format!("uniform cubic B-spline (BS), {samples} sample(s) per span"),
    };
    let mut notes = vec![
        format!("curve type: {kind}"),
        format!("control points: {}", h.point_count),
    ];
    if !h.info.is_empty() {
        notes.push(format!("header text: {}", h.info));
    }
    Ok(Decoded {
        yarns,
        frames: None,
        units: None,
        up_axis: h.up_axis,
        radius_in_file: false,
        notes,
    })
}

/// Appends the polyline of one curve: `samples` points per span between
/// consecutive control points, plus the last control point of an open curve.
fn sample_curve(kind: CurveType, p: &[Vec3], closed: bool, samples: usize, out: &mut Vec<Vec3>) {
    let n = p.len();
    if kind == CurveType::Polyline {
        out.extend_from_slice(p);
        return;
    }
    // Neighbour index: wrap for loops, clamp to the end points for open curves.
    let at = |i: isize| -> Vec3 {
        let j = if closed {
            i.rem_euclid(n as isize)
        } else {
            i.clamp(0, n as isize - 1)
        };
        p[j as usize]
    };
    let spans = if closed { n } else { n - 1 };
    for s in 0..spans {
        let s = s as isize;
        let (p0, p1, p2, p3) = (at(s - 1), at(s), at(s + 1), at(s + 2));
        for k in 0..samples {
            let t = k as f64 / samples as f64;
            out.push(match kind {
                CurveType::CatmullRom => catmull_rom(p0, p1, p2, p3, t),
                _ => bspline(p0, p1, p2, p3, t),
            });
        }
    }
    if !closed {
        let s = n as isize - 1;
        out.push(match kind {
            CurveType::CatmullRom => p[n - 1],
            _ => bspline(at(s - 1), at(s), at(s + 1), at(s + 2), 0.0),
        });
    }
}

/// Uniform Catmull-Rom segment between p1 (t = 0) and p2 (t = 1); exactly p1 at t = 0.
fn catmull_rom(p0: Vec3, p1: Vec3, p2: Vec3, p3: Vec3, t: f64) -> Vec3 {
    if t == 0.0 {
        return p1;
    }
    let (t2, t3) = (t * t, t * t * t);
    std::array::from_fn(|k| {
        0.5 * (2.0 * p1[k]
            + (-p0[k] + p2[k]) * t
            + (2.0 * p0[k] - 5.0 * p1[k] + 4.0 * p2[k] - p3[k]) * t2
            + (-p0[k] + 3.0 * p1[k] - 3.0 * p2[k] + p3[k]) * t3)
    })
}

/// Uniform cubic B-spline segment with control points p0..p3.
fn bspline(p0: Vec3, p1: Vec3, p2: Vec3, p3: Vec3, t: f64) -> Vec3 {
    let (t2, t3) = (t * t, t * t * t);
    let u = 1.0 - t;
    let w = [
        u * u * u,
        3.0 * t3 - 6.0 * t2 + 4.0,
        -3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0,
        t3,
    ];
    std::array::from_fn(|k| (w[0] * p0[k] + w[1] * p1[k] + w[2] * p2[k] + w[3] * p3[k]) / 6.0)
}

/// Encodes polylines (file units and axes) as a PL BCC file with `up` in the header.
pub fn encode(yarns: &Yarns, up: UpAxis) -> Result<Vec<u8>, FormatError> {
    let mut out =
        Vec::with_capacity(HEADER_LEN + yarns.num_curves() * 4 + yarns.num_points() * POINT_BYTES);
    out.extend_from_slice(b"BCC\x44");
    out.extend_from_slice(CurveType::Polyline.code());
    out.push(3);
    out.push(match up {
        UpAxis::Y => 1,
        UpAxis::Z => 2,
    });
    out.extend_from_slice(&(yarns.num_curves() as u64).to_le_bytes());
    out.extend_from_slice(&(yarns.num_points() as u64).to_le_bytes());
    let mut text = [0u8; 40];
    let info = format!("knitvox {}", env!("CARGO_PKG_VERSION"));
    text[..info.len().min(39)].copy_from_slice(&info.as_bytes()[..info.len().min(39)]);
    out.extend_from_slice(&text);
    for c in 0..yarns.num_curves() {
        let pts = yarns.curve(c);
        let n = i32::try_from(pts.len()).map_err(|_| {
            FormatError::whole_file(format!(
                "curve {c} has {} points; BCC allows at most {}",
                pts.len(),
                i32::MAX
            ))
        })?;
        out.extend_from_slice(&(if yarns.closed[c] { -n } else { n }).to_le_bytes());
        for p in pts {
            for x in p {
                out.extend_from_slice(&(*x as f32).to_le_bytes());
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header(code: &[u8; 2], up: u8, curves: u64, points: u64) -> Vec<u8> {
        let mut h = b"BCC\x44".to_vec();
        h.extend_from_slice(code);
        h.push(3);
        h.push(up);
        h.extend_from_slice(&curves.to_le_bytes());
        h.extend_from_slice(&points.to_le_bytes());
        h.extend_from_slice(&[0u8; 40]);
        h
    }

    fn curve(bytes: &mut Vec<u8>, n: i32, pts: &[[f32; 3]]) {
        bytes.extend_from_slice(&n.to_le_bytes());
        for p in pts {
            for x in p {
                bytes.extend_from_slice(&x.to_le_bytes());
            }
        }
    }

    fn square() -> Vec<[f32; 3]> {
        vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
        ]
    }

    #[test]
    fn catmull_rom_interpolates_and_bspline_averages() {
        let mut f = header(b"C0", 2, 1, 4);
        curve(&mut f, -4, &square());
        let opts = ReadOptions {
            spline_samples: Some(4),
            ..Default::default()
        };
        let d = decode(&f, &opts).unwrap();
        assert_eq!(d.yarns.num_points(), 16);
        assert!(d.yarns.closed[0]);
        assert_eq!(d.up_axis, Some(UpAxis::Z));
        for (i, p) in square().iter().enumerate() {
            assert_eq!(
                d.yarns.points[4 * i],
                [p[0] as f64, p[1] as f64, p[2] as f64]
            );
        }
        // Closed uniform B-spline of a unit square: at a control point the value is (p- + 4p + p+)/6.
        let mut f = header(b"BS", 1, 1, 4);
        curve(&mut f, -4, &square());
        let d = decode(&f, &ReadOptions::default()).unwrap();
        assert_eq!(d.yarns.num_points(), 4);
        // Point 0: (p3 + 4 p0 + p1) / 6 = ((0,1) + (1,0)) / 6.
        let got = d.yarns.points[0];
        assert!(
            (got[0] - 1.0 / 6.0).abs() < 1e-12 && (got[1] - 1.0 / 6.0).abs() < 1e-12,
            "{got:?}"
        );
    }

    #[test]
    fn bspline_reproduces_lines() {
        // A cubic B-spline of collinear, evenly spaced control points is that line.
        let pts: Vec<[f32; 3]> = (0..6).map(|i| [i as f32, 2.0 * i as f32, 0.0]).collect();
        let mut f = header(b"BS", 1, 1, 6);
        curve(&mut f, 6, &pts);
        let opts = ReadOptions {
            spline_samples: Some(3),
            ..Default::default()
        };
        let d = decode(&f, &opts).unwrap();
        for p in &d.yarns.points[3..d.yarns.num_points() - 3] {
            assert!((p[1] - 2.0 * p[0]).abs() < 1e-12);
        }
    }

    #[test]
    fn round_trip() {
        let mut y = Yarns::new();
        y.push_curve(
            &[[0.5, 1.5, -2.0], [1.0, 2.0, 3.0], [4.0, 5.0, 6.0]],
            true,
            1.0,
        );
        y.push_curve(&[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], false, 1.0);
        let bytes = encode(&y, UpAxis::Z).unwrap();
        let d = decode(&bytes, &ReadOptions::default()).unwrap();
        assert_eq!(d.yarns.points, y.points);
        assert_eq!(d.yarns.offsets, y.offsets);
        assert_eq!(d.yarns.closed, y.closed);
        assert_eq!(d.up_axis, Some(UpAxis::Z));
    }

    #[test]
    fn broken_inputs_are_errors() {
        let mut good = header(b"PL", 1, 1, 2);
        curve(&mut good, 2, &[[0.0; 3], [1.0; 3]]);
        assert!(decode(&good, &ReadOptions::default()).is_ok());
        for len in 0..good.len() {
            assert!(
                decode(&good[..len], &ReadOptions::default()).is_err(),
                "prefix {len} accepted"
            );
        }
        let mut huge = header(b"PL", 1, 1, 1 << 60);
        curve(&mut huge, 2, &[[0.0; 3], [1.0; 3]]);
        let e = decode(&huge, &ReadOptions::default()).unwrap_err();
        assert_eq!(e.location, super::super::Location::Byte(16));
        let mut bad = good.clone();
        bad[0] = b'X';
        assert!(decode(&bad, &ReadOptions::default())
            .unwrap_err()
            .message
            .contains("not a BCC"));
        let mut bad = good.clone();
        bad[4..6].copy_from_slice(b"XX");
        assert!(decode(&bad, &ReadOptions::default())
            .unwrap_err()
            .message
            .contains("curve type"));
        let mut nan = header(b"PL", 1, 1, 2);
        curve(&mut nan, 2, &[[0.0; 3], [f32::NAN, 0.0, 0.0]]);
        let e = decode(&nan, &ReadOptions::default()).unwrap_err();
        assert_eq!(e.location, super::super::Location::Byte(64 + 4 + 12));
        let mut one = header(b"PL", 1, 1, 1);
        curve(&mut one, 1, &[[0.0; 3]]);
        assert!(decode(&one, &ReadOptions::default())
            .unwrap_err()
            .message
            .contains("at least 2"));
        let mut minimum = header(b"PL", 1, 1, 2);
        curve(&mut minimum, i32::MIN, &[[0.0; 3], [1.0; 3]]);
        assert!(decode(&minimum, &ReadOptions::default()).is_err());
        let mut trailing = good.clone();
        trailing.push(0);
        assert!(decode(&trailing, &ReadOptions::default())
            .unwrap_err()
            .message
            .contains("unexpected bytes"));
    }
}
