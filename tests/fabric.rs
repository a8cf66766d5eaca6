//! Fabric tests on yarn-level swatches: relaxation into contact with its
//! stored rest shape, the quasi-static stretch test, the frames' mechanics
//! in HDF5, and the `knitvox fabric-test` command.

mod common;

use knitvox::geom::Yarns;
use knitvox::io::{self, h5};
use knitvox::pipeline::fabric_test::{run, FabricTest, FabricTestJob, SwatchSource, TestFigures};
use knitvox::yarn::fabric::{
    relax_into_contact, stretch_test, Direction, Fabric, FabricParams, RelaxParams, Rig,
    StretchParams,
};

fn rib(courses: usize, wales: usize) -> Yarns {
    common::flat_swatch("rib1x1", courses, wales)
}

#[test]
fn relaxed_rib_is_held_by_contact_pulls_back_when_stretched_and_records_its_mechanics() {
    let fp = FabricParams::default();
    let generated = rib(6, 4);
    let before = Fabric::new(&generated, &fp).unwrap().contact_stats();
    let (relaxed, rs) = relax_into_contact(&generated, &fp, &RelaxParams::default()).unwrap();
    // Into contact: many more vertices touch a non-adjacent yarn than in the
    // loose generated swatch; nothing passes through.
    assert!(
        rs.contact.near_fraction >= 0.15 && rs.contact.near_fraction > 3.0 * before.near_fraction,
        "touching fraction {} (generated {})",
        rs.contact.near_fraction,
        before.near_fraction
    );
    assert!(rs.min_distance_ratio_seen > 0.75, "{rs:?}");
    assert!(rs.residual <= 1e-4, "{rs:?}");
    assert!(rs.size_after[0] < rs.size_before[0], "{rs:?}");
    // The stored rest shape is the scaled one (not the relaxed positions),
    // and the relaxed positions are its equilibrium.
    let rest = relaxed.rest.as_ref().unwrap();
    let generated_length = generated.total_length();
    let rest_length: f64 = rest.lengths.iter().sum();
    assert!(
        (rest_length / generated_length - RelaxParams::default().length_scale).abs() < 1e-9,
        "rest length {rest_length} m for {generated_length} m generated"
    );
    let mut with_rest = Fabric::new(&relaxed, &fp).unwrap();
    let gauge = with_rest.twist_gauge();
    let r_with = with_rest.static_residual(&gauge);
    assert!(
        r_with <= 1e-5,
        "relaxed state off equilibrium by {r_with} N"
    );

    // Stretch: the swatch pulls the moving clamp back, more at 10% than at
    // 5%, narrows in the middle, and the two clamps' forces balance.
    let sp = StretchParams {
        direction: Direction::Weft,
        max_stretch: 0.1,
        steps: 2,
        hold_steps: 2,
        ..StretchParams::default()
    };
    let mut balance = Vec::new();
    let rig = Rig::new(
        &relaxed.points,
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        sp.clamp_depth,
    );
    let r = stretch_test(&relaxed, &fp, &sp, &mut |f| {
        let sum = |mask: &[bool]| -> f64 {
            f.reactions
                .iter()
                .zip(mask)
                .filter(|(_, m)| **m)
                .map(|(r, _)| r[0])
                .sum()
        };
        balance.push((sum(&rig.low), sum(&rig.high)));
        Ok(())
    })
    .unwrap();
    let p = &r.points;
    assert_eq!(p.len(), 3);
    assert!(p[2].force_n > p[1].force_n && p[1].force_n > 0.0, "{p:?}");
    assert!(
        p[2].energy_j > p[1].energy_j && p[1].energy_j > p[0].energy_j,
        "{p:?}"
    );
    assert!(p[2].compression > 0.0, "{p:?}");
    assert!(r.min_distance_ratio > 0.75);
    assert!(
        r.hold_energy_change.abs() < 0.05,
        "{}",
        r.hold_energy_change
    );
    let (low, high) = balance[2];
    assert!(
        (low + high).abs() <= 0.02 * high.abs() + 1e-4,
        "clamp forces {low} N and {high} N do not balance"
    );
    assert!((high - p[2].force_n).abs() <= 1e-12 * high.abs().max(1.0));

    // The pipeline on the relaxed file: frames with energy and clamp
    // reactions in HDF5, the curve in CSV.
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("relaxed.h5");
    io::write_path(&input, &relaxed, None, &Default::default()).unwrap();
    let job = FabricTestJob {
        swatch: SwatchSource::Yarns(input.clone()),
        test: FabricTest::Stretch(StretchParams {
            max_stretch: 0.05,
            steps: 1,
            hold_steps: 0,
            ..StretchParams::default()
        }),
        fabric: fp.clone(),
        relax: RelaxParams::default(),
        output_dir: Some(dir.path().join("out")),
    };
    let report = run(&job).unwrap();
    assert!(
        report.relaxation.is_none(),
        "a file with a rest shape is not relaxed again"
    );
    let TestFigures::Stretch(s) = &report.figures else {
        panic!("not a stretch report")
    };
    let frames = dir.path().join("out/stretch.h5");
    let (shape, energy) = h5::read_dataset_f64(&frames, "frames/elastic_energy").unwrap();
    assert_eq!(shape, vec![2]);
    assert!((energy[1] - s.points[1].energy_j).abs() <= 1e-12 * energy[1].abs().max(1e-30));
    let (shape, reactions) = h5::read_dataset_f64(&frames, "frames/reaction_forces").unwrap();
    assert_eq!(shape, vec![2, relaxed.num_points(), 3]);
    let fx: f64 = (0..relaxed.num_points())
        .filter(|&v| rig.high[v])
        .map(|v| reactions[3 * (relaxed.num_points() + v)])
        .sum();
    assert!(
        (fx - s.points[1].force_n).abs() <= 1e-9 * fx.abs().max(1e-12),
        "{fx} vs {}",
        s.points[1].force_n
    );
    let csv = std::fs::read_to_string(dir.path().join("out/stretch.csv")).unwrap();
    assert_eq!(csv.lines().count(), 3, "{csv}");
}

#[test]
fn fabric_test_command_prints_the_stretch_curve_as_json() {
    let out = std::process::Command::new(common::knitvox_bin())
        .args([
            "fabric-test",
            "stretch",
            "--pattern",
            "rib1x1",
            "--width",
            "0.02",
            "--length",
            "0.035",
            "--max-stretch",
            "0.05",
            "--steps",
            "1",
            "--json",
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["test"], "stretch");
    assert_eq!(v["direction"], "weft");
    assert!(v["width_m"].as_f64().unwrap() > 0.0);
    let pts = v["points"].as_array().unwrap();
    assert_eq!(pts.len(), 2);
    assert!(pts[1]["force_n"].as_f64().unwrap() > 0.0, "{}", v);
    assert!(
        v["relaxation"]["contact"]["near_fraction"]
            .as_f64()
            .unwrap()
            > 0.0
    );
    // A bad parameter is a usage error naming it.
    let bad = std::process::Command::new(common::knitvox_bin())
        .args([
            "fabric-test",
            "stretch",
            "--pattern",
            "rib1x1",
            "--max-stretch=5",
        ])
        .output()
        .unwrap();
    assert_eq!(
        bad.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&bad.stderr)
    );
}

#[test]
fn friction_adds_hysteresis_to_a_stretch_and_release() {
    use knitvox::yarn::statics::FrictionParams;
    // Stretch a relaxed rib to 10% and release it to 0, with the default
    // yarn friction and without. Friction resists the loading (higher force
    // at 10%) and keeps the released swatch from springing back: at 0 the
    // clamp must hold a residual force, where the frictionless swatch
    // returns to (nearly) no force.
    let fp = FabricParams::default();
    assert!(fp.friction.mu > 0.0, "friction is on by default");
    let (relaxed, _) = relax_into_contact(&rib(6, 4), &fp, &RelaxParams::default()).unwrap();
    let sp = StretchParams {
        direction: Direction::Weft,
        max_stretch: 0.1,
        steps: 2,
        hold_steps: 0,
        release_steps: 2,
        ..StretchParams::default()
    };
    let mut runs = Vec::new();
    for friction in [fp.friction.clone(), FrictionParams::off()] {
        let p = FabricParams {
            friction,
            ..fp.clone()
        };
        let r = stretch_test(&relaxed, &p, &sp, &mut |_| Ok(())).unwrap();
        assert_eq!(r.release.len(), 2);
        assert!(r.release[1].stretch.abs() < 1e-12);
        let f: Vec<f64> = r
            .points
            .iter()
            .chain(&r.release)
            .map(|p| p.force_n)
            .collect();
        // Work in and out (N x stretch, trapezoids of 5%): their difference
        // is the loop's area.
        let work = |a: &[f64]| a.windows(2).map(|w| 0.025 * (w[0] + w[1])).sum::<f64>();
        let loop_area = work(&f[..3]) - work(&f[2..]);
        eprintln!(
            "mu {}: force at 0/5/10/5/0% {:?} N, loop area {loop_area:.3e}",
            p.friction.mu,
            f.iter().map(|x| format!("{x:.4e}")).collect::<Vec<_>>()
        );
        assert!(r.min_distance_ratio > 0.75);
        runs.push((f[2], f[4]));
    }
    let ((top_f, end_f), (top_0, end_0)) = (runs[0], runs[1]);
    assert!(top_f > 1.03 * top_0, "{runs:?}");
    assert!(
        end_f.abs() > 5.0 * end_0.abs() && end_f.abs() > 0.02 * top_f,
        "{runs:?}"
    );
}
