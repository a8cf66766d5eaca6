//! Writer -> reader round trips through the path API (atomic writes, unit and
//! axis handling) for every writable format, on random yarn sets.
mod common;

use knitvox::geom::{Units, UpAxis, YarnFrames, Yarns};
use knitvox::io::{read_path, write_path, Format, ReadOptions, WriteOptions};
use proptest::prelude::*;

/// Random yarns: 1-5 curves of 2-40 points (closed ones at least 3), coordinates
/// at a random scale, per-curve radii and sometimes per-vertex radii.
fn arb_yarns() -> impl Strategy<Value = Yarns> {
    let curve = (any::<bool>(), 2usize..40).prop_flat_map(|(closed, n)| {
        let n = if closed { n.max(3) } else { n };
        (
            Just(closed),
            prop::collection::vec(prop::array::uniform3(-1.0f64..1.0), n),
            0.01f64..1.0,
        )
    });
    (
        prop::collection::vec(curve, 1..5),
        -3i32..2,
        any::<bool>(),
        any::<u64>(),
    )
        .prop_map(|(curves, exp, per_vertex, seed)| {
            let s = 10f64.powi(exp);
            let mut y = Yarns::new();
            for (closed, pts, r) in curves {
                let pts: Vec<_> = pts.iter().map(|p| [p[0] * s, p[1] * s, p[2] * s]).collect();
                y.push_curve(&pts, closed, r * s * 0.1);
            }
            if per_vertex {
                let mut x = seed | 1;
                y.vertex_radius = Some(
                    (0..y.num_points())
                        .map(|_| {
                            x ^= x << 13;
                            x ^= x >> 7;
                            x ^= x << 17;
                            s * 0.01 * (1.0 + (x % 1000) as f64 / 1000.0)
                        })
                        .collect(),
                );
            }
            y
        })
}

/// Formats whose files store the radius.
fn keeps_radius(f: Format) -> bool {
    matches!(f, Format::Ply | Format::Gltf | Format::Glb | Format::Hdf5)
}

/// Relative precision of a format's coordinates.
fn precision(f: Format) -> f64 {
    match f {
        Format::Hdf5 => 0.0,
        Format::Obj => 1e-14,
        _ => 2e-7, // f32
    }
}

fn close(a: f64, b: f64, rel: f64, scale: f64) -> bool {
    (a - b).abs() <= rel * scale.max(b.abs()) + f64::MIN_POSITIVE
}

fn check_same(
    f: Format,
    orig: &Yarns,
    got: &Yarns,
    default_radius: f64,
) -> Result<(), TestCaseError> {
    prop_assert_eq!(&got.offsets, &orig.offsets, "{}: curve offsets", f);
    prop_assert_eq!(&got.closed, &orig.closed, "{}: closed flags", f);
    let scale = orig.bounds().unwrap().diagonal();
    let tol = precision(f);
    for (i, (a, b)) in got.points.iter().zip(&orig.points).enumerate() {
        for k in 0..3 {
            prop_assert!(
                close(a[k], b[k], tol, scale),
                "{}: point {} {:?} vs {:?}",
                f,
                i,
                a,
                b
            );
        }
    }
    for v in 0..orig.num_points() {
        let want = if keeps_radius(f) {
            orig.radius_at(v)
        } else {
            default_radius
        };
        prop_assert!(
            close(got.radius_at(v), want, tol.max(1e-15), 0.0),
            "{}: radius at {} {} vs {}",
            f,
            v,
            got.radius_at(v),
            want
        );
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 32, ..ProptestConfig::default() })]

    #[test]
    fn every_format_round_trips(y in arb_yarns()) {
        let dir = tempfile::tempdir().unwrap();
        let default_radius = 0.123;
        for f in Format::ALL.into_iter().filter(|f| f.is_writable()) {
            let path = dir.path().join(format!("rt.{}", f.extensions()[0]));
            write_path(&path, &y, None, &WriteOptions::default()).unwrap();
            let d = read_path(&path, &ReadOptions { radius: default_radius, units: Some(Units::METRES), ..ReadOptions::default() })
                .unwrap_or_else(|e| panic!("{e}"));
            check_same(f, &y, &d.yarns, default_radius)?;
        }
    }

    #[test]
    fn units_and_axes_round_trip(y in arb_yarns(), cm in any::<bool>(), z_up in any::<bool>()) {
        let dir = tempfile::tempdir().unwrap();
        let units = if cm { Units::CENTIMETRES } else { Units::MILLIMETRES };
        let up = if z_up { UpAxis::Z } else { UpAxis::Y };
        for f in [Format::Bcc, Format::Obj, Format::Ply] {
            let path = dir.path().join(format!("u.{}", f.extensions()[0]));
            write_path(&path, &y, None, &WriteOptions { units, up_axis: up, first_frame: 1 }).unwrap();
            let opts = ReadOptions { units: Some(units), up_axis: Some(up), radius: 0.5, ..ReadOptions::default() };
            let d = read_path(&path, &opts).unwrap();
            check_same(f, &y, &d.yarns, 0.5)?;
        }
    }
}

#[test]
fn frame_sequences_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let y = knitvox::yarn::analytic::knit_swatch(&Default::default());
    let frames = knitvox::pipeline::demo::demo_frames(&y, 3);
    for f in Format::ALL.into_iter().filter(|f| f.is_writable()) {
        let ext = f.extensions()[0];
        let path = if f.holds_frames() {
            dir.path().join(format!("seq.{ext}"))
        } else {
            dir.path().join(format!("seq.####.{ext}"))
        };
        let written = write_path(
            &path,
            &y,
            Some(&frames),
            &WriteOptions {
                first_frame: 1001,
                ..Default::default()
            },
        )
        .unwrap();
        let d = read_path(&path, &ReadOptions::default()).unwrap();
        let got: &YarnFrames = d
            .frames
            .as_ref()
            .unwrap_or_else(|| panic!("{f}: no frames read back"));
        assert_eq!(got.num_frames(), 3, "{f}");
        if !f.holds_frames() {
            assert_eq!(written.len(), 3);
            assert!(
                written[0].ends_with(format!("seq.1001.{ext}")),
                "{:?}",
                written[0]
            );
        }
        for i in 0..3 {
            for (a, b) in got.frame(i).iter().zip(frames.frame(i)) {
                for k in 0..3 {
                    assert!((a[k] - b[k]).abs() < 1e-6 * 0.05, "{f}: frame {i}");
                }
            }
        }
    }
}
