//! PLY reader/writer: round trips, hand-written files in every encoding
//! (binary files built byte by byte, so expected values do not depend on the
//! writer), and a corpus of broken files that must each give a located error.
mod common;

use knitvox::geom::Yarns;
use knitvox::io::{self, ply, Format, FormatError, Location, ReadOptions};
use proptest::prelude::*;

fn opts() -> ReadOptions {
    ReadOptions::default()
}

fn decode(data: &[u8]) -> Result<io::Decoded, FormatError> {
    ply::decode(data, &opts())
}

/// Decodes and runs the same validation as `io::read_path` would.
fn decode_valid(data: &[u8]) -> Yarns {
    let d = decode(data).unwrap_or_else(|e| panic!("{e}"));
    io::finish(Format::Ply, d.clone(), &opts()).unwrap_or_else(|e| panic!("{e}"));
    d.yarns
}

fn err(data: &[u8]) -> FormatError {
    match decode(data) {
        Ok(d) => panic!("accepted: {} curves", d.yarns.num_curves()),
        Err(e) => {
            assert!(!e.message.is_empty());
            e
        }
    }
}

/// An ascii header with x y z and an edge element, then `body`.
fn ascii_edges(nv: usize, ne: usize, body: &str) -> String {
    format!(
        "ply\nformat ascii 1.0\nelement vertex {nv}\nproperty float x\nproperty float y\nproperty float z\n\
         element edge {ne}\nproperty int vertex1\nproperty int vertex2\nend_header\n{body}"
    )
}

// ---------------------------------------------------------------------------
// Round trips
// ---------------------------------------------------------------------------

fn arb_yarns() -> impl Strategy<Value = Yarns> {
    let curve = (any::<bool>(), 2usize..30).prop_flat_map(|(closed, n)| {
        let n = if closed { n.max(3) } else { n };
        (
            Just(closed),
            prop::collection::vec(prop::array::uniform3(-1.0f64..1.0), n),
            0.01f64..1.0,
        )
    });
    (
        prop::collection::vec(curve, 0..6),
        -3i32..3,
        any::<bool>(),
        any::<u64>(),
    )
        .prop_map(|(curves, exp, per_vertex, seed)| {
            let s = 10f64.powi(exp);
            let mut y = Yarns::new();
            for (closed, pts, r) in curves {
                let pts: Vec<_> = pts.iter().map(|p| [p[0] * s, p[1] * s, p[2] * s]).collect();
                y.push_curve(&pts, closed, r * s);
            }
            if per_vertex {
                let mut x = seed | 1;
                y.vertex_radius = Some(
                    (0..y.num_points())
                        .map(|_| {
                            x ^= x << 13;
                            x ^= x >> 7;
                            x ^= x << 17;
                            s * (0.01 + (x % 1000) as f64 / 1000.0)
                        })
                        .collect(),
                );
            }
            y
        })
}

fn assert_same(orig: &Yarns, got: &Yarns) -> Result<(), TestCaseError> {
    prop_assert_eq!(&got.offsets, &orig.offsets);
    prop_assert_eq!(&got.closed, &orig.closed);
    let scale = orig.bounds().map(|b| b.diagonal()).unwrap_or(1.0);
    for (i, (a, b)) in got.points.iter().zip(&orig.points).enumerate() {
        for k in 0..3 {
            prop_assert!(
                (a[k] - b[k]).abs() <= 1e-6 * scale,
                "point {} {:?} vs {:?}",
                i,
                a,
                b
            );
        }
    }
    for v in 0..orig.num_points() {
        let (a, b) = (got.radius_at(v), orig.radius_at(v));
        prop_assert!((a - b).abs() <= 2e-7 * b, "radius at {}: {} vs {}", v, a, b);
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    #[test]
    fn round_trip(y in arb_yarns()) {
        let bytes = ply::encode(&y).unwrap();
        let d = decode(&bytes).unwrap();
        prop_assert!(d.radius_in_file);
        prop_assert_eq!(d.units, None);
        prop_assert_eq!(d.up_axis, None);
        assert_same(&y, &d.yarns)?;
        // Through the format dispatch and validation as well.
        let r = io::finish(Format::Ply, io::decode(Format::Ply, &bytes, &opts(), &io::NoResources).unwrap(), &opts());
        prop_assert!(r.is_ok(), "{:?}", r.err());
    }

    /// Any single corrupted byte gives Ok (and then valid yarns) or an error: never a panic.
    #[test]
    fn corrupted_bytes_never_panic(y in arb_yarns(), at in any::<prop::sample::Index>(), byte in any::<u8>()) {
        let mut bytes = ply::encode(&y).unwrap();
        let i = at.index(bytes.len());
        bytes[i] = byte;
        if let Ok(d) = decode(&bytes) {
            prop_assert!(d.yarns.offsets.len() == d.yarns.num_curves() + 1);
        }
    }
}

#[test]
fn writer_layout_is_the_documented_one() {
    let mut y = Yarns::new();
    y.push_curve(&[[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]], false, 0.25);
    y.push_curve(&[[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], true, 0.5);
    let bytes = ply::encode(&y).unwrap();
    let header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment generated by knitvox {}\nelement vertex 5\n\
         property float x\nproperty float y\nproperty float z\nproperty float radius\nelement edge 4\n\
         property int vertex1\nproperty int vertex2\nend_header\n",
        env!("CARGO_PKG_VERSION")
    );
    assert!(bytes.starts_with(header.as_bytes()));
    let body = &bytes[header.len()..];
    assert_eq!(body.len(), 5 * 16 + 4 * 8);
    let f = |i: usize| f32::from_le_bytes(body[i * 4..i * 4 + 4].try_into().unwrap());
    assert_eq!([f(0), f(1), f(2), f(3)], [1.0, 2.0, 3.0, 0.25]);
    let edges: Vec<i32> = body[80..]
        .chunks(4)
        .map(|c| i32::from_le_bytes(c.try_into().unwrap()))
        .collect();
    assert_eq!(edges, vec![0, 1, 2, 3, 3, 4, 4, 2]);
}

/// The writer declares the unit and up axis in header comments, and the
/// reader takes them as declared by the file (not assumed).
#[test]
fn units_and_up_axis_comments_round_trip() {
    use knitvox::geom::{Units, UpAxis};
    use knitvox::io::Provenance;
    let mut y = Yarns::new();
    y.push_curve(&[[0.01, 0.02, 0.03], [0.5, -0.25, 0.125]], false, 0.001);
    y.push_curve(&[[0.0; 3], [0.1, 0.0, 0.0], [0.0, 0.2, 0.0]], true, 0.002);
    let (units, up) = (Units::CENTIMETRES, UpAxis::Z);
    let mut file = y.clone();
    file.internal_to_file(units, up);
    let bytes = ply::encode_in(&file, units, up).unwrap();
    let text = String::from_utf8_lossy(&bytes);
    assert!(text.contains("\ncomment knitvox units cm\n"), "{text}");
    assert!(text.contains("\ncomment knitvox up_axis z\n"), "{text}");

    // Read back without overrides: declared by the file, back in metres, +Y up.
    let ropts = opts();
    assert_eq!((ropts.units, ropts.up_axis), (None, None));
    let d = io::decode(Format::Ply, &bytes, &ropts, &io::NoResources).unwrap();
    assert_eq!(d.units, Some(Units::CENTIMETRES));
    assert_eq!(d.up_axis, Some(UpAxis::Z));
    let back = io::finish(Format::Ply, d, &ropts).unwrap();
    assert_eq!(back.units, (Units::CENTIMETRES, Provenance::File));
    assert_eq!(back.up_axis, (UpAxis::Z, Provenance::File));
    assert!(back.yarns.same_topology(&y));
    for (a, b) in back.yarns.points.iter().zip(&y.points) {
        for k in 0..3 {
            // float32 in the file.
            assert!((a[k] - b[k]).abs() <= 1e-7, "{a:?} vs {b:?}");
        }
    }
    assert!((back.yarns.radius[1] - 0.002).abs() < 1e-9);

    // Without the comments (plain `encode`) the frame is assumed, as before.
    let plain = ply::encode(&y).unwrap();
    let d = io::decode(Format::Ply, &plain, &ropts, &io::NoResources).unwrap();
    let back = io::finish(Format::Ply, d, &ropts).unwrap();
    assert_eq!(back.units.1, Provenance::Assumed);
    assert_eq!(back.up_axis.1, Provenance::Assumed);

    // A malformed declaration is an error, not a silent assumption.
    let bad = String::from_utf8_lossy(&bytes).replace("units cm", "units furlong");
    let e = io::decode(Format::Ply, bad.as_bytes(), &ropts, &io::NoResources).unwrap_err();
    assert!(e.message.contains("furlong"), "{e}");
}

#[test]
fn empty_set_round_trips() {
    let bytes = ply::encode(&Yarns::new()).unwrap();
    let y = decode_valid(&bytes);
    assert_eq!(y.num_curves(), 0);
}

#[test]
fn large_file_is_fast() {
    // 184K points: the size of a full garment.
    let mut y = Yarns::new();
    for c in 0..1840 {
        let pts: Vec<_> = (0..100)
            .map(|i| [i as f64 * 0.001, c as f64 * 0.002, (i % 7) as f64 * 1e-4])
            .collect();
        y.push_curve(&pts, c % 3 == 0, 1e-3);
    }
    let t = std::time::Instant::now();
    let bytes = ply::encode(&y).unwrap();
    let t_enc = t.elapsed();
    let mut t_dec = std::time::Duration::MAX;
    let mut d = None;
    for _ in 0..3 {
        let t = std::time::Instant::now();
        d = Some(decode(&bytes).unwrap());
        t_dec = t_dec.min(t.elapsed());
    }
    let d = d.unwrap();
    assert_eq!(d.yarns.offsets, y.offsets);
    assert_eq!(d.yarns.closed, y.closed);
    eprintln!(
        "ply 184K points: encode {t_enc:?}, decode {t_dec:?} ({} bytes)",
        bytes.len()
    );
    if !cfg!(debug_assertions) {
        assert!(
            t_enc.as_millis() < 100 && t_dec.as_millis() < 100,
            "{t_enc:?} {t_dec:?}"
        );
    }
}

// ---------------------------------------------------------------------------
// Hand-written files
// ---------------------------------------------------------------------------

#[test]
fn ascii_with_edges_comments_and_extra_properties() {
    let text = "ply\r\nformat ascii 1.0\r\ncomment made by hand\r\nobj_info nothing\r\n\
        element vertex 5\r\nproperty double x\r\nproperty float32 y\r\nproperty int8 z\r\n\
        property uchar red\r\nproperty float thickness\r\n\
        element edge 3\r\nproperty uint8 vertex1\r\nproperty uint16 vertex2\r\nproperty float weight\r\n\
        end_header\r\n\
        0.5 1.5 -2 255 0.1\r\n1 2 3 0 0.1\r\n2 2 3 0 0.3\r\n\r\n9 9 9 1 0.2\r\n8 8 8 1 0.2\r\n\
        0 1 1.0\r\n1 2 1.0\r\n4 3 0.5\r\n";
    let d = decode(text.as_bytes()).unwrap();
    let y = &d.yarns;
    assert_eq!(y.offsets, vec![0, 3, 5]);
    assert_eq!(y.closed, vec![false, false]);
    assert_eq!(y.points[0], [0.5, 1.5, -2.0]);
    assert_eq!(y.points[2], [2.0, 2.0, 3.0]);
    // Edge 4 -> 3: the chain starts at its source, vertex 4.
    assert_eq!(y.points[3], [8.0, 8.0, 8.0]);
    assert_eq!(y.points[4], [9.0, 9.0, 9.0]);
    assert!(d.radius_in_file);
    // Curve 0 has varying thickness: per-vertex radii kept, curve 1 uniform.
    let vr = y.vertex_radius.as_ref().unwrap();
    assert_eq!(vr.len(), 5);
    assert!((vr[2] - 0.3).abs() < 1e-7 && (vr[3] - 0.2).abs() < 1e-7);
    assert!((y.radius[1] - 0.2).abs() < 1e-7);
    assert!(
        d.notes.iter().any(|n| n.contains("made by hand")),
        "{:?}",
        d.notes
    );
    assert!(d.notes.iter().any(|n| n.contains("red")), "{:?}", d.notes);
    assert_eq!(d.units, None);
}

#[test]
fn ascii_closed_loop_keeps_start_and_direction() {
    // A loop 2 -> 0 -> 3 -> 1 -> 2 written with edges in scrambled order, plus an open curve.
    let body = "0 0 0\n1 0 0\n2 0 0\n3 0 0\n4 0 0\n5 0 0\n\
                3 1\n0 3\n5 4\n1 2\n2 0\n";
    let y = decode_valid(ascii_edges(6, 5, body).as_bytes());
    assert_eq!(y.offsets, vec![0, 4, 6]);
    assert_eq!(y.closed, vec![true, false]);
    let xs: Vec<f64> = y.points.iter().map(|p| p[0]).collect();
    // Loop starts at its lowest vertex (0) along the edge that leaves it (0 -> 3).
    assert_eq!(xs, vec![0.0, 3.0, 1.0, 2.0, 5.0, 4.0]);
}

#[test]
fn ascii_with_curve_ids() {
    let text = "ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\nproperty float z\n\
                property int strand_id\nproperty float radius\nend_header\n\
                0 0 0 7 1\n1 0 0 7 1\n2 0 0 7 1\n0 1 0 3 2\n1 1 0 3 2\n";
    let d = decode(text.as_bytes()).unwrap();
    assert_eq!(d.yarns.offsets, vec![0, 3, 5]);
    assert_eq!(d.yarns.closed, vec![false, false]);
    assert_eq!(d.yarns.radius, vec![1.0, 2.0]);
    assert_eq!(d.yarns.vertex_radius, None);
    assert!(
        d.notes.iter().any(|n| n.contains("strand_id")),
        "{:?}",
        d.notes
    );
}

#[test]
fn ascii_with_face_element_skipped() {
    let text = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
                element face 2\nproperty list uchar int vertex_indices\n\
                element edge 2\nproperty int vertex1\nproperty int vertex2\nend_header\n\
                0 0 0\n1 0 0\n1 1 0\n3 0 1 2\n0\n0 1\n1 2\n";
    let d = decode(text.as_bytes()).unwrap();
    assert_eq!(d.yarns.offsets, vec![0, 3]);
    assert!(
        d.notes
            .iter()
            .any(|n| n.contains("skipped element 'face' (2 records)")),
        "{:?}",
        d.notes
    );
    assert!(!d.radius_in_file);
}

/// Big-endian binary built byte by byte: mixed types, a face element with lists
/// between vertex and edge, and edges with different integer types.
fn big_endian_file() -> Vec<u8> {
    let mut b = b"ply\nformat binary_big_endian 1.0\nelement vertex 4\nproperty float64 x\nproperty float32 y\n\
                  property int16 z\nproperty float radius\nelement face 2\nproperty list uchar int vertex_indices\n\
                  element edge 3\nproperty ushort vertex1\nproperty uint vertex2\nend_header\n"
        .to_vec();
    let verts: [(f64, f32, i16, f32); 4] = [
        (0.5, -1.0, 3, 0.5),
        (1.5, -2.0, -4, 0.5),
        (2.5, 3.0, 5, 0.5),
        (-7.25, 0.125, 0, 0.5),
    ];
    for (x, y, z, r) in verts {
        b.extend_from_slice(&x.to_be_bytes());
        b.extend_from_slice(&y.to_be_bytes());
        b.extend_from_slice(&z.to_be_bytes());
        b.extend_from_slice(&r.to_be_bytes());
    }
    // face 0: 3 indices, face 1: empty list.
    b.push(3);
    for i in [0i32, 1, 2] {
        b.extend_from_slice(&i.to_be_bytes());
    }
    b.push(0);
    // Edges 3->2, 1->3, 0->1: one open chain 0 -> 1 -> 3 -> 2, written back to front.
    for (a, c) in [(3u16, 2u32), (1, 3), (0, 1)] {
        b.extend_from_slice(&a.to_be_bytes());
        b.extend_from_slice(&c.to_be_bytes());
    }
    b
}

#[test]
fn big_endian_binary_by_hand() {
    let bytes = big_endian_file();
    let d = decode(&bytes).unwrap();
    let y = &d.yarns;
    // Chain 0 -> 1 -> 3 -> 2: one open curve starting at vertex 0 (the source).
    assert_eq!(y.offsets, vec![0, 4]);
    assert_eq!(y.closed, vec![false]);
    assert_eq!(
        y.points,
        vec![
            [0.5, -1.0, 3.0],
            [1.5, -2.0, -4.0],
            [-7.25, 0.125, 0.0],
            [2.5, 3.0, 5.0]
        ]
    );
    assert_eq!(y.radius, vec![0.5]);
    assert!(d.notes.iter().any(|n| n.contains("binary_big_endian")));
    assert!(d.notes.iter().any(|n| n.contains("face")));
}

#[test]
fn little_endian_binary_with_curve_ids_and_trailing_bytes() {
    let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty float x\nproperty float y\n\
                  property float z\nproperty uchar curve\nend_header\n"
        .to_vec();
    for (i, c) in [(0, 1u8), (1, 1), (2, 2), (3, 2)] {
        for v in [i as f32, 0.0, 1.0] {
            b.extend_from_slice(&v.to_le_bytes());
        }
        b.push(c);
    }
    b.extend_from_slice(b"\n\n");
    let d = decode(&b).unwrap();
    assert_eq!(d.yarns.offsets, vec![0, 2, 4]);
    assert_eq!(d.yarns.points[3], [3.0, 0.0, 1.0]);
    assert!(
        d.notes.iter().any(|n| n.contains("2 bytes after")),
        "{:?}",
        d.notes
    );
}

// ---------------------------------------------------------------------------
// Broken files
// ---------------------------------------------------------------------------

#[test]
fn truncated_binary_files_at_every_length() {
    let mut y = Yarns::new();
    y.push_curve(&[[0.0; 3], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0]], true, 0.1);
    y.push_curve(&[[0.0; 3], [0.0, 0.0, 1.0]], false, 0.1);
    for (bytes, lists) in [(ply::encode(&y).unwrap(), false), (big_endian_file(), true)] {
        decode(&bytes).unwrap();
        let mut byte_errors = 0;
        for len in 0..bytes.len() {
            let e = err(&bytes[..len]);
            assert_ne!(e.location, Location::File, "cut at {len}: {e}");
            byte_errors += usize::from(matches!(e.location, Location::Byte(_)));
        }
        // Cuts in the header, or in files of fixed-size records, are found from the
        // header's counts (a header line); with variable-length lists the
        // shortfall shows only while reading (a byte offset).
        assert_eq!(byte_errors > 0, lists);
    }
    let bytes = big_endian_file();
    let header_len = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    // Vertices 72 bytes, faces 13 + 1, so edges start at 86: cut inside edge 1 (starting at 92), in its vertex2 (at 94).
    let e = err(&bytes[..header_len + 95]);
    assert_eq!(e.location, Location::Byte(header_len as u64 + 94), "{e}");
    assert!(
        e.message.contains("ends early") && e.message.contains("edge 1"),
        "{e}"
    );
}

#[test]
fn truncated_ascii_files() {
    let text = ascii_edges(3, 2, "0 0 0\n1 0 0\n2 0 0\n0 1\n1 2\n");
    decode(text.as_bytes()).unwrap();
    // Dropping only the final newline keeps the file whole; any shorter cut loses a value.
    for len in 0..text.len() - 1 {
        let e = err(&text.as_bytes()[..len]);
        assert!(matches!(e.location, Location::Line(_)), "cut at {len}: {e}");
    }
    // Counts the text could hold, but records missing.
    let e = err(ascii_edges(3, 2, "10.0 0 0\n11.0 0 0\n12.0 0 0\n0 1\n").as_bytes());
    assert_eq!(e.location, Location::Line(14), "{e}");
    assert!(e.message.contains("ends early"), "{e}");
    // Counts the text cannot hold.
    let e = err(ascii_edges(3, 2, "0 0 0\n1 0 0\n2 0 0\n0 1\n").as_bytes());
    assert_eq!(e.location, Location::Line(7), "{e}");
}

#[test]
fn huge_counts_are_refused_before_allocating() {
    let e = err(b"ply\nformat binary_little_endian 1.0\nelement vertex 1152921504606846976\nproperty float x\n\
                  property float y\nproperty float z\nelement edge 0\nproperty int vertex1\nproperty int vertex2\n\
                  end_header\n0123456789");
    assert_eq!(e.location, Location::Line(3));
    assert!(
        e.message.contains("1152921504606846976") && e.message.contains("only 10 remain"),
        "{e}"
    );
    // Same in ascii.
    let e = err(ascii_edges(1 << 60, 0, "0 0 0\n").as_bytes());
    assert_eq!(e.location, Location::Line(3), "{e}");
    // A count beyond u64.
    let e = err(ascii_edges(0, 0, "")
        .replace("vertex 0", "vertex 99999999999999999999999")
        .as_bytes());
    assert_eq!(e.location, Location::Line(3), "{e}");
    // A count the file can hold but above max_points.
    let text = ascii_edges(3, 2, "0 0 0\n1 0 0\n2 0 0\n0 1\n1 2\n");
    let e = ply::decode(
        text.as_bytes(),
        &ReadOptions {
            max_points: 2,
            ..opts()
        },
    )
    .unwrap_err();
    assert!(e.message.contains("max_points"), "{e}");
    // A skipped element claiming 2^60 records.
    let e = err(
        b"ply\nformat binary_little_endian 1.0\nelement vertex 0\nproperty float x\nproperty float y\n\
          property float z\nelement face 1152921504606846976\n\
          property list uchar int vertex_indices\nend_header\n\x00",
    );
    assert_eq!(e.location, Location::Line(7), "{e}");
    assert!(e.message.contains("'face'"), "{e}");
}

#[test]
fn huge_list_lengths() {
    let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\nproperty float y\n\
                  property float z\nproperty list uint int junk\nelement edge 1\nproperty int vertex1\n\
                  property int vertex2\nend_header\n"
        .to_vec();
    let start = b.len();
    b.extend_from_slice(&[0u8; 12]);
    b.extend_from_slice(&u32::MAX.to_le_bytes());
    b.extend_from_slice(&[0u8; 40]);
    let e = err(&b);
    assert_eq!(e.location, Location::Byte(start as u64 + 16), "{e}");
    assert!(
        e.message.contains("4294967295") && e.message.contains("junk"),
        "{e}"
    );
    // A negative list length of a signed count type.
    let mut b2 = b.clone();
    let text = String::from_utf8_lossy(&b2[..start]).replace("list uint int", "list int int");
    b2.splice(..start, text.bytes());
    let e = err(&b2);
    assert!(e.message.contains("negative"), "{e}");
    // Ascii: the items must be on the record's line.
    let text = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n\
                property list uint int junk\nelement edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n\
                0 0 0 4294967295 1 2\n1 0 0 0\n0 1\n";
    let e = err(text.as_bytes());
    assert_eq!(e.location, Location::Line(12), "{e}");
}

#[test]
fn edge_indices_out_of_range() {
    let e = err(ascii_edges(2, 1, "0 0 0\n1 0 0\n0 7\n").as_bytes());
    assert_eq!(e.location, Location::Line(13));
    assert!(
        e.message.contains("vertex2 = 7") && e.message.contains("out of range"),
        "{e}"
    );
    let e = err(ascii_edges(2, 1, "0 0 0\n1 0 0\n-1 1\n").as_bytes());
    assert_eq!(e.location, Location::Line(13));
    // Binary, int indices.
    let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\nproperty float y\n\
                  property float z\nelement edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n"
        .to_vec();
    b.extend_from_slice(&[0u8; 24]);
    let edge_at = b.len() as u64;
    b.extend_from_slice(&0i32.to_le_bytes());
    b.extend_from_slice(&i32::MIN.to_le_bytes());
    let e = err(&b);
    assert_eq!(e.location, Location::Byte(edge_at), "{e}");
}

#[test]
fn non_finite_coordinates() {
    for bad in ["nan", "NaN", "inf", "-inf", "1e999"] {
        let e = err(ascii_edges(2, 1, &format!("0 0 0\n1 {bad} 0\n0 1\n")).as_bytes());
        assert_eq!(e.location, Location::Line(12), "{bad}: {e}");
        assert!(
            e.message.contains("vertex 1") && e.message.contains("finite"),
            "{e}"
        );
    }
    let mut b = b"ply\nformat binary_big_endian 1.0\nelement vertex 2\nproperty float x\nproperty float y\n\
                  property float z\nelement edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n"
        .to_vec();
    b.extend_from_slice(&[0u8; 12]);
    let second = b.len() as u64;
    for v in [0.0f32, 0.0, f32::NAN] {
        b.extend_from_slice(&v.to_be_bytes());
    }
    b.extend_from_slice(&0i32.to_be_bytes());
    b.extend_from_slice(&1i32.to_be_bytes());
    let e = err(&b);
    assert_eq!(e.location, Location::Byte(second), "{e}");
    assert!(e.message.contains(" z "), "{e}");
    // Radius must be positive and finite.
    let text = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n\
                property float radius\nproperty int curve\nend_header\n0 0 0 1 0\n1 0 0 -1 0\n";
    let e = err(text.as_bytes());
    assert_eq!(e.location, Location::Line(11), "{e}");
}

#[test]
fn header_problems() {
    let cases: [(&[u8], usize, &str); 13] = [
        (b"", 1, "empty"),
        (b"\n", 1, "not a PLY"),
        (b"plx\nformat ascii 1.0\nend_header\n", 1, "not a PLY"),
        (
            b"ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\n",
            4,
            "end_header",
        ),
        (
            b"ply\nformat ascii 1.0\ncomment \xff\xfe\nend_header\n",
            3,
            "UTF-8",
        ),
        (
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty int64 x\nend_header\n",
            4,
            "int64",
        ),
        (b"ply\nformat ebcdic 1.0\nend_header\n", 2, "ebcdic"),
        (b"ply\nformat ascii 2.0\nend_header\n", 2, "version"),
        (
            b"ply\nformat ascii 1.0\nproperty float x\nend_header\n",
            3,
            "before any",
        ),
        (
            b"ply\nelement vertex 1\nformat ascii 1.0\nend_header\n",
            2,
            "format",
        ),
        (
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty list float int x\nend_header\n",
            4,
            "integer",
        ),
        (
            b"ply\nformat ascii 1.0\nelement vertex -3\nend_header\n",
            3,
            "non-negative",
        ),
        (
            b"ply\nformat ascii 1.0\nbogus line\nend_header\n",
            3,
            "bogus",
        ),
    ];
    for (bytes, line, word) in cases {
        let e = err(bytes);
        assert_eq!(
            e.location,
            Location::Line(line),
            "{:?}: {e}",
            String::from_utf8_lossy(bytes)
        );
        assert!(
            e.message.contains(word),
            "{:?}: {e}",
            String::from_utf8_lossy(bytes)
        );
    }
    // No format line at all.
    let e = err(b"ply\nend_header\n");
    assert!(e.message.contains("format"), "{e}");
    // Non-UTF-8 garbage after the magic.
    let e = err(b"ply\n\xc3\x28\x00\x01\xff garbage\n");
    assert_eq!(e.location, Location::Line(2), "{e}");
}

#[test]
fn vertex_and_edge_property_problems() {
    let vert = |props: &str| {
        format!("ply\nformat ascii 1.0\nelement vertex 2\n{props}element edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n0 0 0\n1 0 0\n0 1\n")
    };
    let e = err(vert("property float x\nproperty float y\nproperty float w\n").as_bytes());
    assert!(e.message.contains("'z'"), "{e}");
    let e =
        err(vert("property float x\nproperty float y\nproperty list uchar float z\n").as_bytes());
    assert_eq!(e.location, Location::Line(6), "{e}");
    let e = err(
        vert("property float x\nproperty float y\nproperty float z\nproperty float x\n").as_bytes(),
    );
    assert_eq!(e.location, Location::Line(7), "{e}");
    let e = err(ascii_edges(2, 1, "0 0 0\n1 0 0\n0 1\n")
        .replace("property int vertex2", "property float vertex2")
        .as_bytes());
    assert_eq!(e.location, Location::Line(9), "{e}");
    assert!(e.message.contains("integer"), "{e}");
    let e = err(ascii_edges(2, 1, "0 0 0\n1 0 0\n0 1\n")
        .replace("property int vertex2", "property int v2")
        .as_bytes());
    assert!(e.message.contains("vertex2"), "{e}");
    // Ascii values that do not fit their type, extra and missing values.
    let e = err(ascii_edges(2, 1, "0 0 0\n1 0 0\n0 1.5\n").as_bytes());
    assert_eq!(e.location, Location::Line(13), "{e}");
    let e = err(ascii_edges(2, 1, "0 0 0\n1 0 0 4\n0 1\n").as_bytes());
    assert_eq!(e.location, Location::Line(12), "{e}");
    let e = err(ascii_edges(2, 1, "0.0 0.0 0.0\n1.0 0.0\n0 1\n").as_bytes());
    assert_eq!(e.location, Location::Line(12), "{e}");
    let e = err(ascii_edges(2, 1, "0 0 0\n1 zero 0\n0 1\n").as_bytes());
    assert!(e.message.contains("zero"), "{e}");
    // Non-UTF-8 in the ascii payload.
    let mut b = ascii_edges(2, 1, "0 0 0\n1 0 0\n0 1\n").into_bytes();
    let at = b.len() - 3;
    b[at] = 0xff;
    let e = err(&b);
    assert_eq!(e.location, Location::Line(13), "{e}");
}

#[test]
fn topology_problems() {
    // Vertex of degree 3.
    let e = err(ascii_edges(4, 3, "0 0 0\n1 0 0\n2 0 0\n3 0 0\n0 1\n1 2\n1 3\n").as_bytes());
    assert_eq!(e.location, Location::Line(17), "{e}");
    assert!(
        e.message.contains("edge 2") && e.message.contains("vertex 1"),
        "{e}"
    );
    // More edges than vertices.
    let e = err(ascii_edges(2, 3, "0 0 0\n1 0 0\n0 1\n1 0\n0 1\n").as_bytes());
    assert_eq!(e.location, Location::Line(7), "{e}");
    // Self-loop, doubled edge.
    let e = err(ascii_edges(2, 1, "0 0 0\n1 0 0\n1 1\n").as_bytes());
    assert!(e.message.contains("itself"), "{e}");
    let e = err(ascii_edges(2, 2, "0 0 0\n1 0 0\n0 1\n1 0\n").as_bytes());
    assert!(e.message.contains("3 points"), "{e}");
    // A vertex on no edge: a one-point curve.
    let e = err(ascii_edges(3, 1, "0 0 0\n1 0 0\n2 0 0\n0 1\n").as_bytes());
    assert_eq!(e.location, Location::Line(13), "{e}");
    assert!(e.message.contains("vertex 2"), "{e}");
    // Curve ids with a one-point curve.
    let text = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
                property int curve_id\nend_header\n0 0 0 1\n1 0 0 2\n2 0 0 2\n";
    let e = err(text.as_bytes());
    assert_eq!(e.location, Location::Line(9), "{e}");
    // Neither edges nor curve ids.
    let text = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n\
                end_header\n0 0 0\n1 0 0\n";
    let e = err(text.as_bytes());
    assert!(
        e.message.contains("no edge element or curve-id property"),
        "{e}"
    );
    // No vertex element.
    let e = err(b"ply\nformat ascii 1.0\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n");
    assert!(e.message.contains("vertex"), "{e}");
}

#[test]
fn random_garbage_after_valid_headers() {
    let mut x = 0x9e3779b97f4a7c15u64;
    for enc in ["ascii", "binary_little_endian", "binary_big_endian"] {
        for n in 0..200 {
            let mut b = ascii_edges(4, 3, "").replace("ascii", enc).into_bytes();
            for _ in 0..(n % 90) {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                b.push(if enc == "ascii" {
                    b"0123 -\n.e"[(x % 9) as usize]
                } else {
                    x as u8
                });
            }
            if let Ok(d) = decode(&b) {
                // Whatever is accepted has located vertices and edges that validate.
                io::finish(Format::Ply, d, &opts()).unwrap();
            }
        }
    }
}
