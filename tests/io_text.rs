//! Text yarn formats: OBJ (read + write), YarnBall-style `.poly`, MADYPG `.pyp`.

mod common;

use std::path::Path;

use knitvox::geom::{Units, UpAxis, Vec3, Yarns};
use knitvox::io::{self, obj, poly, pyp, Format, Location, Provenance, ReadOptions, WriteOptions};
use proptest::prelude::*;

fn opts() -> ReadOptions {
    ReadOptions::default()
}

fn curves(y: &Yarns) -> Vec<(Vec<Vec3>, bool)> {
    (0..y.num_curves())
        .map(|c| (y.curve(c).to_vec(), y.closed[c]))
        .collect()
}

fn dist(a: Vec3, b: Vec3) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

// ---------------------------------------------------------------- OBJ

#[test]
fn obj_houdini_polyline_file() {
    let Some(dir) = common::external_data("yarns") else {
        return;
    };
    let path = dir.join("qu2021_houdiniobj_polyline.obj");
    let data = std::fs::read(&path).unwrap();
    let d = obj::decode(&data, &opts()).unwrap();
    let y = &d.yarns;
    assert_eq!(y.num_points(), 9600);
    assert_eq!(y.num_curves(), 2);
    assert_eq!(y.closed, vec![true, true]);
    assert_eq!(y.offsets, vec![0, 4800, 9600]);
    // Line 9608 is `l 1 4800 4799 ...`: the first curve starts at vertex 1 (0.5, 0, 0), then vertex 4800.
    assert_eq!(y.points[0], [0.5, 0.0, 0.0]);
    let v4800 = data.split(|&b| b == b'\n').nth(6 + 4799).unwrap();
    assert!(
        v4800.starts_with(b"v "),
        "{}",
        String::from_utf8_lossy(v4800)
    );
    let want: Vec<f64> = std::str::from_utf8(&v4800[2..])
        .unwrap()
        .split_whitespace()
        .map(|t| t.parse().unwrap())
        .collect();
    assert_eq!(y.points[1].to_vec(), want);
    assert_eq!(d.units, None);
    assert_eq!(d.up_axis, None);
    assert!(
        d.notes.iter().any(|n| n.contains("Houdini")),
        "{:?}",
        d.notes
    );
    // Bounds in the file's header comment.
    let b = y.bounds().unwrap();
    assert!(
        (b.min[0] + 1.0).abs() < 1e-9 && (b.max[0] - 1.0).abs() < 1e-9,
        "{b:?}"
    );
    assert!((b.max[1] - 0.99518472).abs() < 1e-9, "{b:?}");
    // The loops are sampled uniformly: every segment (closing one included)
    // has nearly the same length, so the vertex order is the file's.
    for c in 0..2 {
        let lens: Vec<f64> = y
            .segments_of(c)
            .map(|[a, b]| dist(y.points[a], y.points[b]))
            .collect();
        assert_eq!(lens.len(), 4800);
        let (lo, hi) = lens
            .iter()
            .fold((f64::MAX, 0.0f64), |(lo, hi), &l| (lo.min(l), hi.max(l)));
        assert!(hi < 1.01 * lo, "curve {c}: segments {lo} to {hi}");
    }

    // Through the path API: unitless, so metres and +Y are assumed.
    let yd = io::read_path(&path, &opts()).unwrap();
    assert_eq!(yd.format, Format::Obj);
    assert_eq!(yd.units, (Units::METRES, Provenance::Assumed));
    assert_eq!(yd.up_axis, (UpAxis::Y, Provenance::Assumed));
    assert_eq!(yd.yarns.num_points(), 9600);
}

#[test]
fn obj_hand_written_snippets() {
    let src = "\
# two yarns
v 0 0 0
v 1 0 0
v 2 0 0
v 0 1 0
v 1 1 0
v 1 2 0
vt 0 0
g yarn
l 1/1 2/1 3/1
l 4 5 6 4
";
    let d = obj::decode(src.as_bytes(), &opts()).unwrap();
    assert_eq!(
        curves(&d.yarns),
        vec![
            (
                vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]],
                false
            ),
            (
                vec![[0.0, 1.0, 0.0], [1.0, 1.0, 0.0], [1.0, 2.0, 0.0]],
                true
            ),
        ]
    );

    // One `l` per segment, as some exporters write it, with relative indices.
    let src = "v 0 0 0\nv 1 0 0\nl -2 -1\nv 2 0 0\nl -2 -1\nv 3 0 0\nl -2 -1\n";
    let d = obj::decode(src.as_bytes(), &opts()).unwrap();
    assert_eq!(
        curves(&d.yarns),
        vec![(
            vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [2.0, 0.0, 0.0],
                [3.0, 0.0, 0.0]
            ],
            false
        )]
    );

    // Segments closing a loop, written in scrambled order and orientation.
    let src = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nl 1 2\nl 4 3\nl 3 2\nl 1 4\n";
    let d = obj::decode(src.as_bytes(), &opts()).unwrap();
    assert_eq!(
        curves(&d.yarns),
        vec![(
            vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [1.0, 1.0, 0.0],
                [0.0, 1.0, 0.0]
            ],
            true
        )]
    );

    // CRLF line endings and a continued line.
    let src = "v 0 0 0\r\nv 1 0 0\r\nv 2 0 0\r\nl 1 \\\r\n2 3\r\n";
    let d = obj::decode(src.as_bytes(), &opts()).unwrap();
    assert_eq!(d.yarns.num_points(), 3);
}

/// A smooth helix of `n` points (distinct, finite).
fn helix(n: usize, phase: f64) -> Vec<Vec3> {
    (0..n)
        .map(|i| {
            let t = i as f64 * 0.01 + phase;
            [t.cos() * 0.05, t * 1.0e-3, t.sin() * 0.05]
        })
        .collect()
}

/// Long curves are written as several `l` lines of at most 2,001 indices that
/// continue each other (Blender's importer truncates lines at 262,144
/// characters), and read back as the same curves.
#[test]
fn obj_long_curves_split_into_continued_lines_and_join_back() {
    let mut y = Yarns::new();
    y.push_curve(&helix(10_000, 0.0), false, 1e-3);
    y.push_curve(&helix(10_000, 100.0), true, 1e-3);
    // Edge cases at the line limit: the closing index alone on the last line,
    // a closed curve that just fits one line, a short curve.
    y.push_curve(&helix(2_001, 200.0), true, 1e-3);
    y.push_curve(&helix(2_000, 300.0), true, 1e-3);
    y.push_curve(&helix(2_002, 400.0), false, 1e-3);
    y.push_curve(&helix(3, 500.0), false, 1e-3);
    let bytes = obj::encode(&y, Units::METRES, UpAxis::Y).unwrap();
    let text = std::str::from_utf8(&bytes).unwrap();
    let l_lines: Vec<Vec<usize>> = text
        .lines()
        .filter_map(|l| l.strip_prefix("l "))
        .map(|l| l.split(' ').map(|t| t.parse().unwrap()).collect())
        .collect();
    let longest = l_lines.iter().map(Vec::len).max().unwrap();
    assert!(
        longest <= obj::MAX_LINE_INDICES,
        "{longest} indices on one line"
    );
    assert_eq!(obj::MAX_LINE_INDICES, 2001);
    assert!(l_lines.iter().all(|l| l.len() >= 2));
    // 10,000 open: 5 lines; 10,001 closed: 5; 2,002 closed: 2; 2,001: 1; 2,002 open: 2; 1.
    assert_eq!(l_lines.len(), 5 + 5 + 2 + 1 + 2 + 1);
    for w in l_lines.windows(2) {
        // Every line of a continued curve starts where the line before ended.
        if w[1][0] != w[1][1] - 1 {
            assert_eq!(w[1][0], *w[0].last().unwrap());
        }
    }
    let max_chars = text.lines().map(str::len).max().unwrap();
    assert!(max_chars < 262_144, "{max_chars}");

    let d = obj::decode(&bytes, &opts()).unwrap();
    assert_eq!(d.yarns.num_curves(), y.num_curves());
    assert_eq!(d.yarns.offsets, y.offsets);
    assert_eq!(d.yarns.closed, y.closed);
    assert_eq!(d.yarns.points, y.points);
    assert!(
        d.notes
            .iter()
            .any(|n| n.contains("continue the element before")),
        "{:?}",
        d.notes
    );

    // The same through the io layer's frames (cm, Z up).
    let wopts = WriteOptions {
        units: Units::CENTIMETRES,
        up_axis: UpAxis::Z,
        first_frame: 1,
    };
    let bytes = io::encode(Format::Obj, &y, &wopts).unwrap();
    let ropts = ReadOptions {
        units: Some(Units::CENTIMETRES),
        up_axis: Some(UpAxis::Z),
        ..opts()
    };
    let d = io::decode(Format::Obj, &bytes, &ropts, &io::NoResources).unwrap();
    let back = io::finish(Format::Obj, d, &ropts).unwrap();
    assert!(back.yarns.same_topology(&y));
    for (a, b) in back.yarns.points.iter().zip(&y.points) {
        assert!(dist(*a, *b) <= 1e-12, "{a:?} vs {b:?}");
    }
}

/// Only a line that starts with the last index of the open polyline just
/// before it (same object and group) continues it; polylines that merely
/// share a vertex stay separate curves, as before.
#[test]
fn obj_polylines_sharing_an_index_are_not_joined() {
    let v = "v 0 0 0\nv 1 0 0\nv 2 0 0\nv 3 0 0\nv 4 0 0\nv 5 0 0\n";
    let count = |body: &str| {
        let d = obj::decode(format!("{v}{body}").as_bytes(), &opts()).unwrap();
        (d.yarns.num_curves(), d.yarns.closed.clone())
    };
    // Same end vertex, but the second does not start with it.
    assert_eq!(count("l 1 2 3\nl 4 5 3\n"), (2, vec![false, false]));
    // Same start vertex.
    assert_eq!(count("l 3 2 1\nl 3 4 5\n"), (2, vec![false, false]));
    // Not consecutive: another element in between.
    assert_eq!(count("l 1 2 3\nl 5 6\nl 3 4\n"), (3, vec![false; 3]));
    // A new group or object in between.
    assert_eq!(count("l 1 2 3\ng b\nl 3 4 5\n"), (2, vec![false, false]));
    assert_eq!(count("l 1 2 3\no b\nl 3 4 5\n"), (2, vec![false, false]));
    // A closed loop is never continued.
    assert_eq!(count("l 1 2 3 1\nl 1 4 5\n"), (2, vec![true, false]));
    // A two-index segment is chained only with segments, as before.
    assert_eq!(count("l 1 2\nl 2 3 4\n"), (2, vec![false, false]));
    // The continued form itself joins, and closes when it comes back.
    assert_eq!(count("l 1 2 3\nl 3 4 5\n"), (1, vec![false]));
    assert_eq!(count("l 1 2 3\nl 3 4\nl 4 5 1\n"), (1, vec![true]));
    let d = obj::decode(format!("{v}l 1 2 3\nl 3 4\nl 4 5 1\n").as_bytes(), &opts()).unwrap();
    assert_eq!(d.yarns.curve(0).len(), 5);
}

/// Random finite coordinates spanning many magnitudes (and both signs).
fn coord() -> impl Strategy<Value = f64> {
    prop_oneof![
        -1.0e3f64..1.0e3,
        (-300i32..300, -1.0f64..1.0).prop_map(|(e, m)| m * 10f64.powi(e)),
        Just(0.0),
        Just(-0.0),
    ]
}

fn yarn_set() -> impl Strategy<Value = Yarns> {
    prop::collection::vec(
        (
            prop::collection::vec([coord(), coord(), coord()], 2..40),
            any::<bool>(),
        ),
        1..6,
    )
    .prop_map(|cs| {
        let mut y = Yarns::new();
        for (pts, closed) in cs {
            // A closed yarn needs 3 points (Yarns::validate).
            y.push_curve(&pts, closed && pts.len() >= 3, 1.0e-3);
        }
        y
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    /// Decoding what the writer wrote gives back the same f64 values exactly.
    #[test]
    fn obj_round_trip_exact(y in yarn_set()) {
        let bytes = obj::encode(&y, Units::METRES, UpAxis::Y).unwrap();
        let d = obj::decode(&bytes, &opts()).unwrap();
        prop_assert_eq!(&d.yarns.offsets, &y.offsets);
        prop_assert_eq!(&d.yarns.closed, &y.closed);
        for (a, b) in d.yarns.points.iter().zip(&y.points) {
            for k in 0..3 {
                prop_assert!(a[k].to_bits() == b[k].to_bits(), "{:?} vs {:?}", a, b);
            }
        }
    }

    /// Through the unit/axis conversions of the io layer (cm, Z up).
    #[test]
    fn obj_round_trip_through_io_frames(y in yarn_set()) {
        let mut y = y;
        // Keep magnitudes sane so the unit scaling cannot overflow.
        y.map_points(|p| [p[0].clamp(-1e6, 1e6), p[1].clamp(-1e6, 1e6), p[2].clamp(-1e6, 1e6)]);
        let wopts = WriteOptions { units: Units::CENTIMETRES, up_axis: UpAxis::Z, first_frame: 1 };
        let bytes = io::encode(Format::Obj, &y, &wopts).unwrap();
        let ropts = ReadOptions { units: Some(Units::CENTIMETRES), up_axis: Some(UpAxis::Z), ..opts() };
        let d = io::decode(Format::Obj, &bytes, &ropts, &io::NoResources).unwrap();
        let back = io::finish(Format::Obj, d, &ropts).unwrap();
        // Reading welds repeated points (the generator makes them: zeros,
        // tiny magnitudes); the conversions are what is checked here.
        let y = y.weld().0;
        prop_assert!(back.yarns.same_topology(&y));
        for (a, b) in back.yarns.points.iter().zip(&y.points) {
            for k in 0..3 {
                prop_assert!((a[k] - b[k]).abs() <= 1e-12 * b[k].abs().max(1e-300), "{:?} vs {:?}", a, b);
            }
        }
    }
}

#[test]
fn obj_encode_is_fast() {
    // 184K points, the size of the largest garment in the test data.
    let mut y = Yarns::new();
    let mut pts = Vec::new();
    for c in 0..22 {
        pts.clear();
        for i in 0..8371 {
            let t = i as f64 * 0.001 + c as f64;
            pts.push([t.sin() * 0.123456789, t.cos() * 0.0987654321, t * 1.0e-3]);
        }
        y.push_curve(&pts, c % 2 == 0, 1e-3);
    }
    assert_eq!(y.num_points(), 184_162);
    let t0 = std::time::Instant::now();
    let bytes = obj::encode(&y, Units::METRES, UpAxis::Y).unwrap();
    let enc = t0.elapsed();
    let t0 = std::time::Instant::now();
    let d = obj::decode(&bytes, &opts()).unwrap();
    let dec = t0.elapsed();
    eprintln!(
        "obj: 184162 points, {} bytes: encode {:?}, decode {:?}",
        bytes.len(),
        enc,
        dec
    );
    assert_eq!(d.yarns.points, y.points);
    // Generous bound for unoptimised test builds on a shared machine; the
    // release figure is far lower.
    assert!(enc.as_secs_f64() < 2.0, "encode took {enc:?}");
}

// ---------------------------------------------------------------- .poly

#[test]
fn poly_hand_written_snippets() {
    // YarnBall style: one segment per polygon, Houdini open markers and colours.
    let src = "\
POINTS
1: 0 0 0 c(0, 0, 0, 1)
2: 1 0 0 c(0, 0, 0, 1)
3: 2 0 0
4: 3 0 0
5: 0 1 0
6: 1 1 0
7: 1 2 0
POLYS
1: 3 4 <
2: 1 2 <
3: 2 3 <
4: 5 6 7
5: 7 6 5 <
END
";
    let d = poly::decode(src.as_bytes(), &opts()).unwrap();
    assert_eq!(
        curves(&d.yarns),
        vec![
            // Chained from segments 3-4, 1-2, 2-3 starting at the far end of the first one's chain.
            (
                vec![
                    [0.0, 0.0, 0.0],
                    [1.0, 0.0, 0.0],
                    [2.0, 0.0, 0.0],
                    [3.0, 0.0, 0.0]
                ],
                false
            ),
            (
                vec![[0.0, 1.0, 0.0], [1.0, 1.0, 0.0], [1.0, 2.0, 0.0]],
                true
            ),
            (
                vec![[1.0, 2.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]],
                false
            ),
        ]
    );
    assert_eq!(d.units, None);
    assert!(d.notes.iter().any(|n| n.contains("attributes")));

    // Closed polygon with its first point repeated, blank lines, comments, CRLF, trailing text after END.
    let src = "# loop\r\nPOINTS\r\n\r\n1: 0 0 0\r\n2: 1 0 0\r\n3: 0 1 0\r\nPOLYS\r\n1: 1 2 3 1 c(1,0,0)\r\nEND\r\nwhatever\r\n";
    let d = poly::decode(src.as_bytes(), &opts()).unwrap();
    assert_eq!(
        curves(&d.yarns),
        vec![(
            vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
            true
        )]
    );
}

#[test]
fn poly_through_path_api() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("y.poly");
    std::fs::write(
        &p,
        "POINTS\n1: 0 0 0\n2: 100 0 0\n3: 100 100 0\nPOLYS\n1: 1 2\n2: 2 3\nEND\n",
    )
    .unwrap();
    let yd = io::read_path(
        &p,
        &ReadOptions {
            units: Some(Units::CENTIMETRES),
            ..opts()
        },
    )
    .unwrap();
    assert_eq!(yd.format, Format::Poly);
    assert_eq!(yd.yarns.num_curves(), 1);
    assert!((yd.yarns.total_length() - 2.0).abs() < 1e-12);
}

// ---------------------------------------------------------------- .pyp

struct Tile {
    n: usize,
    px: f64,
    py: f64,
    max_rest: f64,
}

/// Independent reading of the facts the tests need (n and the rest lengths).
fn tile_facts(text: &str) -> Tile {
    let mut sec = "";
    let (mut n, mut px, mut py) = (0, 0.0, 0.0);
    let mut max_rest = 0.0f64;
    for line in text.lines() {
        let l = line.split('#').next().unwrap().trim();
        if l.is_empty() {
            continue;
        }
        if l.starts_with('*') {
            sec = l;
            continue;
        }
        match sec {
            "*pattern" => {
                let t: Vec<&str> = l.split_whitespace().collect();
                (px, py, n) = (
                    t[0].parse().unwrap(),
                    t[1].parse().unwrap(),
                    t[3].parse().unwrap(),
                );
            }
            "*RL" => max_rest = max_rest.max(l.parse().unwrap()),
            _ => {}
        }
    }
    Tile {
        n,
        px,
        py,
        max_rest,
    }
}

fn pyp_files() -> Vec<std::path::PathBuf> {
    let Some(dir) = common::external_data("yarns") else {
        return Vec::new();
    };
    let mut v: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "pyp"))
        .collect();
    v.sort();
    assert_eq!(
        v.len(),
        6,
        "expected the six MADYPG tiles in {}",
        dir.display()
    );
    v
}

#[test]
fn pyp_madypg_tiles_read_and_tile_continuously() {
    for path in pyp_files() {
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        let data = std::fs::read(&path).unwrap();
        let facts = tile_facts(std::str::from_utf8(&data).unwrap());
        assert!(facts.n > 0 && facts.max_rest > 0.0, "{name}");

        let one = pyp::decode(&data, &opts()).unwrap();
        assert_eq!(
            one.yarns.num_points(),
            facts.n,
            "{name}: 1x1 keeps every vertex once"
        );
        assert!(one.yarns.validate().is_ok(), "{name}");
        assert_eq!(one.units, Some(Units::METRES));
        assert_eq!(one.up_axis, Some(UpAxis::Z));
        assert!(one.radius_in_file);

        let three = pyp::decode(
            &data,
            &ReadOptions {
                tile: [3, 3],
                ..opts()
            },
        )
        .unwrap();
        let y = &three.yarns;
        assert_eq!(
            y.num_points(),
            9 * facts.n,
            "{name}: every vertex copy exactly once"
        );
        assert!(y.validate().is_ok(), "{name}");
        // Continuity: no tiled segment is much longer than the tile's longest rest segment.
        let longest = y.max_segment_length();
        assert!(
            longest <= 1.5 * facts.max_rest,
            "{name}: segment {longest} vs rest {}",
            facts.max_rest
        );
        // Each vertex copy appears once: no two points coincide.
        let mut keys: Vec<[u64; 3]> = y
            .points
            .iter()
            .map(|p| p.map(|x| (x * 1e9).round() as i64 as u64))
            .collect();
        keys.sort_unstable();
        keys.dedup();
        assert_eq!(
            keys.len(),
            y.num_points(),
            "{name}: duplicate vertex copies"
        );
        // Tiling makes longer yarns, not just more of them: the 3x3 block holds
        // 9 tiles' worth of yarn in at most 9 x the pieces of one tile.
        assert!(y.num_curves() <= 9 * one.yarns.num_curves(), "{name}");
        assert!(
            (y.total_length() - 9.0 * one.yarns.total_length()) > 0.0,
            "{name}: tiling adds crossing segments"
        );
        // The block spans about 3 periods in x and y.
        let b = y.bounds().unwrap();
        let b1 = one.yarns.bounds().unwrap();
        assert!(
            (b.size()[0] - b1.size()[0] - 2.0 * facts.px).abs() < 1e-12,
            "{name}"
        );
        assert!(
            (b.size()[1] - b1.size()[1] - 2.0 * facts.py).abs() < 1e-12,
            "{name}"
        );
        assert!(
            (b.size()[2] - b1.size()[2]).abs() < 1e-12,
            "{name}: tiling does not change the thickness"
        );
    }
}

#[test]
fn pyp_path_api_lies_flat_in_metres() {
    let Some(dir) = common::external_data("yarns") else {
        return;
    };
    let yd = io::read_path(
        &dir.join("madypg_stockinette.pyp"),
        &ReadOptions {
            tile: [4, 4],
            ..opts()
        },
    )
    .unwrap();
    assert_eq!(yd.units, (Units::METRES, Provenance::File));
    assert_eq!(yd.up_axis, (UpAxis::Z, Provenance::File));
    assert_eq!(yd.radius, Provenance::File);
    // `*pattern` of madypg_stockinette.pyp: radius 0.001 m.
    assert!(
        yd.yarns.radius.iter().all(|r| (r - 0.001).abs() < 1e-15),
        "{:?}",
        &yd.yarns.radius[..1]
    );
    // Flat: the thickness (internal y after Z-up conversion) is the smallest extent.
    let s = yd.yarns.bounds().unwrap().size();
    assert!(s[1] < 0.2 * s[0] && s[1] < 0.2 * s[2], "{s:?}");
    // Roughly 4 periods of ~1 cm each way.
    assert!(
        s[0] > 0.03 && s[0] < 0.06 && s[2] > 0.03 && s[2] < 0.06,
        "{s:?}"
    );
}

// ---------------------------------------------------------------- broken inputs

type Decoder = fn(&[u8], &ReadOptions) -> Result<io::Decoded, io::FormatError>;

/// Decodes and requires an error (not a panic) with a sensible message.
fn expect_err(dec: Decoder, data: &[u8], what: &str) -> io::FormatError {
    match dec(data, &opts()) {
        Ok(d) => panic!(
            "{what}: expected an error, got {} curves",
            d.yarns.num_curves()
        ),
        Err(e) => {
            assert!(!e.message.is_empty(), "{what}");
            e
        }
    }
}

/// Every prefix must decode without panicking; those that succeed must be valid yarns.
fn all_prefixes(dec: Decoder, data: &[u8], ropts: &ReadOptions) -> (usize, usize) {
    let (mut ok, mut err) = (0, 0);
    for len in 0..data.len() {
        match dec(&data[..len], ropts) {
            Ok(d) => {
                ok += 1;
                assert!(
                    d.yarns.validate().is_ok(),
                    "prefix {len} decoded to invalid yarns"
                );
            }
            Err(e) => {
                err += 1;
                assert!(!e.message.is_empty());
                if let Location::Line(l) = e.location {
                    assert!(
                        l >= 1 && l <= data[..len].split(|&b| b == b'\n').count(),
                        "prefix {len}: line {l}"
                    );
                }
            }
        }
    }
    (ok, err)
}

const OBJ_OK: &[u8] = b"# hand\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nl 1 2 3 4 1\nl 1 3\n";
const POLY_OK: &[u8] = b"POINTS\n1: 0 0 0\n2: 1 0 0\n3: 1 1 0\nPOLYS\n1: 1 2\n2: 2 3\nEND\n";

#[test]
fn broken_obj_corpus() {
    let (ok, err) = all_prefixes(obj::decode, OBJ_OK, &opts());
    assert!(ok > 0 && err > 0, "{ok} {err}");
    let cases: &[(&[u8], &str, Option<usize>)] = &[
        (b"", "no polyline", None),
        (b"\n\n# only comments\n", "no polyline", None),
        (b"v 0 0 0\nv 1 1 1\nf 1 2 1\n", "no polyline", None),
        (b"v 0 0 0\n\xc3\x28\nl 1 1\n", "UTF-8", Some(2)),
        (b"v 0 0 NaN\nv 1 0 0\nl 1 2\n", "not finite", Some(1)),
        (b"v 0 0 0\nv 1 -inf 0\nl 1 2\n", "not finite", Some(2)),
        (b"v 0 0 0\nv 1e400 0 0\nl 1 2\n", "not finite", Some(2)),
        (b"v 0 0 0\nv 1 0 0\nl 0 2\n", "index 0", Some(3)),
        (b"v 0 0 0\nv 1 0 0\nl 1 3\n", "out of range", Some(3)),
        (b"v 0 0 0\nv 1 0 0\nl -3 1\n", "before the first", Some(3)),
        (b"v 0 0 0\nv 1 0 0\nl 2\n", "at least 2", Some(3)),
        (b"v 0 0 0\nv 1 0 0\nl\n", "at least 2", Some(3)),
        (
            b"v 0 0 0\nv 1 0 0\nl 1 1152921504606846976\n",
            "limit",
            Some(3),
        ),
        (
            b"v 0 0 0\nv 1 0 0\nl 1 99999999999999999999999\n",
            "not a vertex index",
            Some(3),
        ),
        (
            b"v 0 0 0\nv 1 0 0\nl 1 -9223372036854775808\n",
            "before the first",
            Some(3),
        ),
        (b"v 0 0\nl 1 2\n", "no z", Some(1)),
        (b"\x00\x01\x02binary\n", "no polyline", None),
        (
            b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nl 1 2\nl 1 3\nl 1 4\n",
            "branch",
            Some(7),
        ),
    ];
    for (data, what, line) in cases {
        let e = expect_err(obj::decode, data, what);
        assert!(
            e.message.contains(what),
            "{:?}: {e}",
            String::from_utf8_lossy(data)
        );
        match line {
            Some(l) => assert_eq!(e.location, Location::Line(*l), "{e}"),
            None => assert_eq!(e.location, Location::File, "{e}"),
        }
    }
}

#[test]
fn broken_poly_corpus() {
    let (ok, err) = all_prefixes(poly::decode, POLY_OK, &opts());
    // Only the prefix that drops the final newline still has its END.
    assert_eq!(ok, 1, "every shorter prefix lacks END");
    assert_eq!(err, POLY_OK.len() - 1);
    let cases: &[(&[u8], &str)] = &[
        (b"", "truncated"),
        (b"ply\nformat ascii 1.0\n", "expected POINTS"),
        (
            b"POINTS\n1: 0 0 0\n2: \xff 0 0\nPOLYS\n1: 1 2\nEND\n",
            "UTF-8",
        ),
        (
            b"POINTS\n1: 0 0 nan\n2: 1 0 0\nPOLYS\n1: 1 2\nEND\n",
            "not finite",
        ),
        (
            b"POINTS\n1: 0 0 0\n2: 1 0 inf\nPOLYS\n1: 1 2\nEND\n",
            "not finite",
        ),
        (
            b"POINTS\n1: 0 0 0\n2: 1 0 0\nPOLYS\n1: 0 2\nEND\n",
            "out of range",
        ),
        (
            b"POINTS\n1: 0 0 0\n2: 1 0 0\nPOLYS\n1: 1 3\nEND\n",
            "out of range",
        ),
        (
            b"POINTS\n1: 0 0 0\n2: 1 0 0\nPOLYS\n1: 1 1152921504606846976\nEND\n",
            "out of range",
        ),
        (
            b"POINTS\n1: 0 0 0\n2: 1 0 0\nPOLYS\n1: 2 <\nEND\n",
            "at least 2",
        ),
        (b"POINTS\n1152921504606846976: 0 0 0\n", "sequence"),
        (b"POINTS\n1: 0 0 0\n2: 1 0 0\nPOLYS\nEND\n", "no polygons"),
        (b"POINTS\n1: 0 0 0\n2: 1 0 0\nEND\n", "no polygons"),
        (
            b"POINTS\n1: 0 0 0\n2: 1 0 0\n3: 2 0 0\n4: 3 0 0\nPOLYS\n1: 1 2\n2: 1 3\n3: 1 4\nEND\n",
            "branch",
        ),
    ];
    for (data, what) in cases {
        let e = expect_err(poly::decode, data, what);
        assert!(
            e.message.contains(what),
            "{:?}: {e}",
            String::from_utf8_lossy(data)
        );
    }
}

#[test]
fn broken_pyp_corpus() {
    let Some(dir) = common::external_data("yarns") else {
        return;
    };
    let data = std::fs::read(dir.join("madypg_stocktiniest.pyp")).unwrap();
    let text = std::str::from_utf8(&data).unwrap();
    for tile in [[1, 1], [2, 3]] {
        let (ok, err) = all_prefixes(pyp::decode, &data, &ReadOptions { tile, ..opts() });
        assert!(ok > 0 && err > 0, "{ok} {err}");
    }
    // Cutting the file anywhere before the end of *E loses geometry: an error.
    let end_e = text.find("*RL").unwrap() - 2;
    for len in 0..end_e {
        assert!(pyp::decode(&data[..len], &opts()).is_err(), "prefix {len}");
    }
    // Later cuts either leave a short rest-state section (an error) or drop
    // whole optional sections, which the notes then report.
    let last_row = text.rfind("\n0.080871413").unwrap() + 1;
    for len in end_e..data.len() {
        if let Ok(d) = pyp::decode(&data[..len], &opts()) {
            let in_last_row = len > last_row; // the last *RefT value, possibly cut short
            assert!(
                in_last_row || d.notes.iter().any(|n| n.contains("absent")),
                "prefix {len}: {:?}",
                d.notes
            );
        }
    }

    let pattern_at = |s: &str| text.replacen("0.00072000001 0.00044 9.9999997e-05 13", s, 1);
    let cases: Vec<(String, &str)> = vec![
        (
            pattern_at("0.00072000001 0.00044 9.9999997e-05 1152921504606846976"),
            "limit",
        ),
        (
            pattern_at("0.00072000001 0.00044 9.9999997e-05 14"),
            "13 rows",
        ),
        (
            pattern_at("0.00072000001 0.00044 9.9999997e-05 -3"),
            "not a non-negative integer",
        ),
        (pattern_at("nan 0.00044 9.9999997e-05 13"), "not finite"),
        (pattern_at("0.00072000001 0.00044 0 13"), "positive"),
        (
            text.replacen("-0.00012523646 -0.00017114044", "-0.00012523646 inf", 1),
            "not finite",
        ),
        (text.replacen("12 0 0 1", "12 13 0 1", 1), "out of range"),
        (text.replacen("12 0 0 1", "12 1 0 1", 1), "second incoming"),
        (
            text.replacen("*E # edges: v0 v1 dx dy", "*F", 1),
            "missing section *E",
        ),
        (
            text.replacen("*Q # dofs: x y z t", "*Q2", 1),
            "missing section *Q",
        ),
        (text.replacen("*RL # rest lengths", "*RK", 1), "twice"),
        ("".into(), "missing section *pattern"),
        (
            "solid ascii\nfacet normal 0 0 1\n".into(),
            "before the first section",
        ),
    ];
    for (src, what) in cases {
        let e = expect_err(pyp::decode, src.as_bytes(), what);
        assert!(e.message.contains(what), "{what}: {e}");
    }
    let mut bad = data.clone();
    let at = text.find("*Q").unwrap() + 10;
    bad[at] = 0xff;
    let e = expect_err(pyp::decode, &bad, "non-UTF-8");
    assert!(e.message.contains("UTF-8"), "{e}");

    // 2^60 tiles: refused before allocating.
    let e = pyp::decode(
        &data,
        &ReadOptions {
            tile: [1 << 30, 1 << 30],
            ..opts()
        },
    )
    .unwrap_err();
    assert!(e.message.contains("limit"), "{e}");
}

#[test]
fn text_formats_are_not_written_except_obj() {
    let mut y = Yarns::new();
    y.push_curve(&[[0.0; 3], [1.0, 0.0, 0.0]], false, 1e-3);
    for f in [Format::Poly, Format::Pyp] {
        assert!(!f.is_writable());
        assert!(io::encode(f, &y, &WriteOptions::default()).is_err());
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("a.obj");
    io::write_path(&out, &y, None, &WriteOptions::default()).unwrap();
    let back = io::read_path(Path::new(&out), &opts()).unwrap();
    assert_eq!(back.yarns.points, y.points);
}
