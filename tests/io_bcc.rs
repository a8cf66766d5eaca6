//! BCC against the published yarn models in $KNITVOX_EXTERNAL_DATA/yarns.
mod common;

use knitvox::io::{bcc, decode, Format, NoResources, ReadOptions};

/// An independent minimal parse of a BCC body: (closed, control points) per curve.
fn raw_curves(data: &[u8]) -> Vec<(bool, Vec<[f32; 3]>)> {
    let curves = u64::from_le_bytes(data[8..16].try_into().unwrap()) as usize;
    let mut pos = 64;
    let mut out = Vec::new();
    for _ in 0..curves {
        let n = i32::from_le_bytes(data[pos..pos + 4].try_into().unwrap());
        pos += 4;
        let pts = (0..n.unsigned_abs() as usize)
            .map(|i| {
                let b = pos + 12 * i;
                std::array::from_fn(|k| {
                    f32::from_le_bytes(data[b + 4 * k..b + 4 * k + 4].try_into().unwrap())
                })
            })
            .collect();
        pos += 12 * n.unsigned_abs() as usize;
        out.push((n < 0, pts));
    }
    assert_eq!(pos, data.len());
    out
}

fn bcc_files() -> Vec<std::path::PathBuf> {
    let Some(dir) = common::external_data("yarns") else {
        return Vec::new();
    };
    let mut v: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "bcc"))
        .collect();
    v.sort();
    assert!(
        v.len() >= 8,
        "expected the 8 published BCC models, found {}",
        v.len()
    );
    v
}

#[test]
fn every_bcc_reads_with_header_point_count() {
    for path in bcc_files() {
        let data = std::fs::read(&path).unwrap();
        let header = bcc::read_header(&data).unwrap();
        let d = decode(Format::Bcc, &data, &ReadOptions::default(), &NoResources)
            .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        assert_eq!(
            d.yarns.num_points() as u64,
            header.point_count,
            "{}",
            path.display()
        );
        assert_eq!(
            d.yarns.num_curves() as u64,
            header.curve_count,
            "{}",
            path.display()
        );
        d.yarns.validate().unwrap();
    }
}

#[test]
fn catmull_rom_polylines_pass_through_control_points() {
    for path in bcc_files() {
        let data = std::fs::read(&path).unwrap();
        if &data[4..6] != b"C0" {
            continue;
        }
        let raw = raw_curves(&data);
        let k = 3;
        let opts = ReadOptions {
            spline_samples: Some(k),
            ..ReadOptions::default()
        };
        let d = decode(Format::Bcc, &data, &opts, &NoResources).unwrap();
        for (c, (closed, ctrl)) in raw.iter().enumerate() {
            let pts = d.yarns.curve(c);
            let spans = if *closed { ctrl.len() } else { ctrl.len() - 1 };
            assert_eq!(
                pts.len(),
                spans * k + usize::from(!closed),
                "{} curve {c}",
                path.display()
            );
            for (i, p) in ctrl.iter().enumerate() {
                let q = pts[i * k];
                assert_eq!(
                    q,
                    [p[0] as f64, p[1] as f64, p[2] as f64],
                    "{} curve {c} point {i}",
                    path.display()
                );
            }
        }
    }
}

#[test]
fn gloves_have_70_closed_curves() {
    let Some(dir) = common::external_data("yarns") else {
        return;
    };
    for name in ["qu2021_glove.bcc", "yuksel_glove.bcc"] {
        let d = knitvox::io::read_path(&dir.join(name), &ReadOptions::default()).unwrap();
        assert_eq!(d.yarns.num_curves(), 70, "{name}");
        assert_eq!(d.yarns.num_closed(), 70, "{name}");
    }
}

#[test]
fn bspline_tube_is_closed_and_smooth() {
    let Some(dir) = common::external_data("yarns") else {
        return;
    };
    let data = std::fs::read(dir.join("qu2021_knittubeinit.bcc")).unwrap();
    let raw = raw_curves(&data);
    let d = decode(Format::Bcc, &data, &ReadOptions::default(), &NoResources).unwrap();
    assert_eq!(d.yarns.num_closed(), 39);
    // A uniform cubic B-spline at a knot is (p[i-1] + 4 p[i] + p[i+1]) / 6.
    let (_, ctrl) = &raw[0];
    let n = ctrl.len();
    for i in [0, 1, n / 2, n - 1] {
        let (a, b, c) = (ctrl[(i + n - 1) % n], ctrl[i], ctrl[(i + 1) % n]);
        let q = d.yarns.curve(0)[i];
        for k in 0..3 {
            let expect = (a[k] as f64 + 4.0 * b[k] as f64 + c[k] as f64) / 6.0;
            assert!((q[k] - expect).abs() < 1e-9, "point {i}");
        }
    }
}

#[test]
fn bcc_round_trips_published_model() {
    let Some(dir) = common::external_data("yarns") else {
        return;
    };
    let data = std::fs::read(dir.join("yuksel_openwork_trellis_pattern.bcc")).unwrap();
    let d = decode(Format::Bcc, &data, &ReadOptions::default(), &NoResources).unwrap();
    let again = bcc::encode(&d.yarns, d.up_axis.unwrap()).unwrap();
    // PL of C0 control points: same payload as the input, only the type code and text differ.
    assert_eq!(again.len(), data.len());
    assert_eq!(&again[64..], &data[64..]);
    assert_eq!(&again[6..24], &data[6..24]);
}

/// Cem Yuksel's glove repeats 8 points (segments of length 0): read in
/// cm with a 0.25 mm yarn, they are welded, the curves keep every other
/// point, and no segment is shorter than the weld tolerance.
#[test]
fn the_yuksel_glove_welds_its_8_repeated_points() {
    let Some(dir) = common::external_data("yarns") else {
        return;
    };
    let path = dir.join("yuksel_glove.bcc");
    let opts = ReadOptions {
        units: Some(knitvox::geom::Units::CENTIMETRES),
        radius: 0.00025,
        ..ReadOptions::default()
    };
    let raw = decode(
        Format::Bcc,
        &std::fs::read(&path).unwrap(),
        &opts,
        &NoResources,
    )
    .unwrap();
    let d = knitvox::io::read_path(&path, &opts).unwrap();
    assert_eq!(d.weld.welded_points, 8);
    assert!(d.weld.dropped_curves.is_empty());
    assert_eq!(d.yarns.num_points(), raw.yarns.num_points() - 8);
    assert_eq!(d.yarns.num_curves(), 70);
    let shortest = d
        .yarns
        .segments()
        .map(|[a, b]| knitvox::geom::dist(d.yarns.points[a], d.yarns.points[b]))
        .fold(f64::INFINITY, f64::min);
    assert!(
        shortest > knitvox::geom::WELD_TOLERANCE_RADII * 0.00025,
        "{shortest}"
    );
    assert!(
        d.notes
            .iter()
            .any(|n| n.contains("welded 8 repeated point")),
        "{:?}",
        d.notes
    );
}
