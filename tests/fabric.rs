//! Fabric tests on yarn-level swatches: relaxation into contact with its
//! stored rest shape, the quasi-static stretch test, the frames' mechanics
//! in HDF5, and the `knitvox fabric-test` command.

mod common;

use knitvox::geom::Yarns;
use knitvox::io::{self, h5};
use knitvox::pipeline::fabric_test::{run, FabricTest, FabricTestJob, SwatchSource, TestFigures};
use knitvox::yarn::fabric::{
    relax_into_contact, stretch_test, Direction, Fabric, FabricParams, RelaxIntoContactStats,
    RelaxParams, Rig, StretchParams,
};

fn rib(courses: usize, wales: usize) -> Yarns {
    common::flat_swatch("rib1x1", courses, wales)
}

/// The 6 x 4 rib relaxed into contact with the default fabric and
/// relaxation, computed once for the tests that load it.
fn relaxed_rib_6x4() -> &'static (Yarns, RelaxIntoContactStats) {
    static RELAXED: std::sync::OnceLock<(Yarns, RelaxIntoContactStats)> =
        std::sync::OnceLock::new();
    RELAXED.get_or_init(|| {
        relax_into_contact(
            &rib(6, 4),
            &FabricParams::default(),
            &RelaxParams::default(),
        )
        .unwrap()
    })
}

#[test]
fn relaxed_rib_is_held_by_contact_pulls_back_when_stretched_and_records_its_mechanics() {
    let fp = FabricParams::default();
    let generated = rib(6, 4);
    let before = Fabric::new(&generated, &fp).unwrap().contact_stats();
    let (relaxed, rs) = relaxed_rib_6x4();
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
    assert_eq!(
        rest.material,
        Some(fp.material()),
        "recorded with the shape"
    );
    let generated_length = generated.total_length();
    let rest_length: f64 = rest.lengths.iter().sum();
    assert!(
        (rest_length / generated_length - RelaxParams::default().length_scale).abs() < 1e-9,
        "rest length {rest_length} m for {generated_length} m generated"
    );
    let mut with_rest = Fabric::new(relaxed, &fp).unwrap();
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
    let r = stretch_test(relaxed, &fp, &sp, &mut |f| {
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
    io::write_path(&input, relaxed, None, &Default::default()).unwrap();
    let job = FabricTestJob {
        swatch: SwatchSource::Yarns(input.clone()),
        test: FabricTest::Stretch(StretchParams {
            max_stretch: 0.05,
            steps: 1,
            hold_steps: 0,
            ..StretchParams::default()
        }),
        fabric: fp.clone(),
        material: Default::default(),
        relax: RelaxParams::default(),
        output_dir: Some(dir.path().join("out")),
    };
    let report = run(&job).unwrap();
    assert!(
        report.relaxation.is_none(),
        "a file with a rest shape is not relaxed again"
    );
    assert_eq!(report.material.source, "yarn file");
    assert_eq!(report.material.material, fp.material());
    assert!(report.material.rest_material.is_none() && report.warnings.is_empty());
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

    // A field replaced on the file's material: the test runs under it and
    // says the stored state is not at rest under it.
    let softer = FabricTestJob {
        material: knitvox::geom::MaterialOverrides {
            bend_scale: Some(0.5),
            ..Default::default()
        },
        output_dir: None,
        ..job
    };
    struct Heard(Vec<String>);
    impl knitvox::pipeline::Observer for Heard {
        fn warning(&mut self, message: &str) {
            self.0.push(message.to_string());
        }
    }
    let mut heard = Heard(Vec::new());
    let report = knitvox::pipeline::fabric_test::run_observed(&softer, &mut heard).unwrap();
    assert_eq!(
        heard.0, report.warnings,
        "the observer hears the report's warnings"
    );
    let c = &report.material;
    assert_eq!(c.material.bend_scale, 0.5);
    assert_eq!(c.material.young_modulus, fp.rods.young_modulus);
    assert_eq!(c.overridden, ["bend_scale"]);
    assert_eq!(c.rest_material, Some(fp.material()));
    assert!(
        report.warnings.len() == 1 && report.warnings[0].contains("settles first"),
        "{:?}",
        report.warnings
    );
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
    // No terminal: a line per frame (0 and 1 of 1) on stderr, for farm logs.
    let err = String::from_utf8_lossy(&out.stderr);
    for line in [
        "fabric-test stretch: frame 0 (0/1) ",
        "fabric-test stretch: frame 1 (1/1) ",
    ] {
        assert!(err.contains(line), "{line:?} not in {err}");
    }
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
    // So is a stick distance that is not a positive length, and an absurd
    // yarn material: refused before anything is relaxed, naming the flag.
    for (flag, value) in [
        ("--stick-distance", "0"),
        ("--stick-distance", "-1e-5"),
        ("--stick-distance", "nan"),
        ("--young-modulus", "1e300"),
        ("--young-modulus", "0"),
        ("--shear-modulus", "1"),
        ("--bend-scale", "100"),
        ("--contact-stiffness", "inf"),
    ] {
        let bad = std::process::Command::new(common::knitvox_bin())
            .args(["fabric-test", "stretch", "--pattern", "rib1x1"])
            .arg(format!("{flag}={value}"))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&bad.stderr);
        assert_eq!(bad.status.code(), Some(2), "{flag} {value}: {err}");
        assert!(err.contains(flag), "{flag} {value}: {err}");
    }
}

#[test]
fn the_yarn_material_travels_with_the_rest_shape_from_pattern_to_fabric_test() {
    let dir = tempfile::tempdir().unwrap();
    let cmd = |args: &[&str]| {
        std::process::Command::new(common::knitvox_bin())
            .args(args)
            .output()
            .unwrap()
    };
    let json = |out: &std::process::Output| -> serde_json::Value {
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        serde_json::from_slice(&out.stdout).unwrap()
    };
    let file = dir.path().join("rib.h5");
    let f = file.to_str().unwrap();
    let p = json(&cmd(&[
        "pattern",
        "rib1x1",
        "--courses",
        "2",
        "--wales",
        "4",
        "--young-modulus",
        "5e6",
        "--bend-scale",
        "0.1",
        "-o",
        f,
        "--json",
    ]));
    assert_eq!(p["material"]["young_modulus"], 5e6, "{p}");
    assert_eq!(p["material"]["bend_scale"], 0.1, "{p}");
    assert_eq!(p["material"]["shear_modulus"], 2e5, "{p}");
    let inspect = cmd(&["inspect", f]);
    let text = String::from_utf8_lossy(&inspect.stdout);
    assert!(
        text.contains("relaxed under E 5e6 Pa, G 2e5 Pa, bend scale 0.1"),
        "{text}"
    );
    // The test runs under the recorded yarn without being told; an option
    // replaces one field and is reported.
    let t = json(&cmd(&[
        "fabric-test",
        "stretch",
        f,
        "--max-stretch",
        "0.05",
        "--steps",
        "1",
        "--json",
    ]));
    assert_eq!(t["material"]["source"], "yarn file", "{t}");
    assert_eq!(t["material"]["material"]["young_modulus"], 5e6, "{t}");
    assert!(t["material"].get("rest_material").is_none(), "{t}");
    let out = cmd(&[
        "fabric-test",
        "stretch",
        f,
        "--max-stretch",
        "0.05",
        "--steps",
        "1",
        "--json",
        "--contact-stiffness",
        "120",
    ]);
    let t = json(&out);
    assert_eq!(t["material"]["material"]["contact_stiffness"], 120.0, "{t}");
    assert_eq!(
        t["material"]["rest_material"]["contact_stiffness"], 60.0,
        "{t}"
    );
    assert!(String::from_utf8_lossy(&out.stderr).contains("settles first"));
    // No rest shape, no material to record it with.
    let loose = dir.path().join("loose.h5");
    let out = cmd(&[
        "pattern",
        "rib1x1",
        "--courses",
        "2",
        "--wales",
        "4",
        "--no-relax",
        "--young-modulus",
        "5e6",
        "-o",
        loose.to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(!loose.exists());
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
    let (relaxed, _) = relaxed_rib_6x4();
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
        let r = stretch_test(relaxed, &p, &sp, &mut |_| Ok(())).unwrap();
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
    // Released, the frictionless swatch lands in one of several nearby
    // equilibria: -4.4e-5 N from the affine predictor's 10% state, -1.7e-4
    // N from the secant's, whose force there differs by 0.1%. Either is
    // under 1% of the peak; friction holds about 3%.
    assert!(end_0.abs() < 0.01 * top_0, "{runs:?}");
    assert!(
        end_f.abs() > 3.0 * end_0.abs() && end_f.abs() > 0.02 * top_f,
        "{runs:?}"
    );
}

#[test]
fn secant_predictor_reaches_the_affine_predictors_equilibria_in_fewer_iterations() {
    // The same frictionless loading started from the affine stretch and
    // from the last step's motion: the equilibria agree (forces to 2%,
    // widths to 0.3% of the swatch) and the secant needs fewer Newton
    // iterations after the first step (which both start affinely).
    let mut fp = FabricParams::default();
    fp.friction.mu = 0.0;
    let (relaxed, _) = relaxed_rib_6x4();
    let run = |secant: bool| {
        let sp = StretchParams {
            direction: Direction::Weft,
            max_stretch: 0.2,
            steps: 4,
            hold_steps: 0,
            secant_predictor: secant,
            ..StretchParams::default()
        };
        stretch_test(relaxed, &fp, &sp, &mut |_| Ok(())).unwrap()
    };
    let (affine, secant) = (run(false), run(true));
    for (a, s) in affine.points.iter().zip(&secant.points) {
        assert!(
            (a.force_n - s.force_n).abs() <= 0.02 * a.force_n.abs() + 1e-4,
            "{a:?} {s:?}"
        );
        assert!((a.compression - s.compression).abs() <= 3e-3, "{a:?} {s:?}");
    }
    let iterations = |r: &knitvox::yarn::fabric::StretchResult| -> usize {
        r.points[2..].iter().map(|p| p.newton_iterations).sum()
    };
    assert!(
        iterations(&secant) < iterations(&affine),
        "secant {} against affine {} Newton iterations",
        iterations(&secant),
        iterations(&affine)
    );
}

#[test]
fn conditioning_cycles_run_before_the_measured_loading_and_return_to_rest() {
    // One conditioning cycle (10% and back in 2 steps each way) before the
    // measured loading of a relaxed rib with friction. The cycle must end
    // with the clamp back at 0 and (nearly) no force, unload below its own
    // loading (friction), and leave a swatch whose measured loading repeats
    // the cycle's: friction in this model does not ratchet the swatch.
    let fp = FabricParams::default();
    let (relaxed, _) = relaxed_rib_6x4();
    let sp = StretchParams {
        direction: Direction::Weft,
        max_stretch: 0.1,
        steps: 2,
        hold_steps: 0,
        conditioning_cycles: 1,
        ..StretchParams::default()
    };
    let mut frames = 0;
    let r = stretch_test(relaxed, &fp, &sp, &mut |_| {
        frames += 1;
        Ok(())
    })
    .unwrap();
    assert_eq!(frames, 3, "conditioning frames are not handed on");
    assert_eq!(r.conditioning.len(), 1);
    let c = &r.conditioning[0];
    let stretches: Vec<f64> = c.iter().map(|p| p.stretch).collect();
    assert_eq!(stretches.len(), 4);
    for (s, want) in stretches.iter().zip([0.05, 0.1, 0.05, 0.0]) {
        assert!((s - want).abs() < 1e-12, "{stretches:?}");
    }
    let top = c[1].force_n;
    assert!(top > 0.0);
    assert!(
        c[2].force_n < c[0].force_n,
        "unloading below loading: {c:?}"
    );
    assert!(c[3].force_n.abs() < 0.2 * top, "{c:?}");
    assert_eq!(r.points.len(), 3);
    let again = r.points[2].force_n;
    assert!((again - top).abs() <= 0.05 * top, "{again} against {top}");
    assert!(r.min_distance_ratio > 0.75);
}

/// Checks a PNG written by `-o DIR`: signature, IHDR size, decodes, and is
/// not blank (white background plus at least axes and a coloured series).
fn check_png(path: &std::path::Path, size: (u32, u32)) {
    let bytes = std::fs::read(path).unwrap();
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "{}", path.display());
    assert_eq!(&bytes[12..16], b"IHDR");
    let w = u32::from_be_bytes(bytes[16..20].try_into().unwrap());
    let h = u32::from_be_bytes(bytes[20..24].try_into().unwrap());
    assert_eq!((w, h), size, "{}", path.display());
    let mut reader = png::Decoder::new(std::io::Cursor::new(bytes))
        .read_info()
        .unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgb);
    let pixels: std::collections::HashSet<&[u8]> = buf[..info.buffer_size()].chunks(3).collect();
    assert!(pixels.len() > 3, "{} colours", pixels.len());
    // Some pixel is strongly coloured (a series), not only grey text/axes.
    assert!(
        pixels
            .iter()
            .any(|p| p.iter().max().unwrap() - p.iter().min().unwrap() > 100),
        "no coloured series in {}",
        path.display()
    );
}

#[test]
fn stretch_writes_a_force_and_compression_plot() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let run = std::process::Command::new(common::knitvox_bin())
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
            "0.04",
            "--steps",
            "2",
            "--cycles",
            "1",
            "--release-steps",
            "1",
            "-o",
        ])
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    check_png(&out.join("stretch.png"), (800, 900));
    // Header, the conditioning cycle (2 steps up, 2 down), the measured
    // loading (0, 2, 4%) and the release (back to 0), each row with its phase.
    let csv = std::fs::read_to_string(out.join("stretch.csv")).unwrap();
    let phases: Vec<&str> = csv
        .lines()
        .skip(1)
        .map(|l| l.rsplit(',').next().unwrap())
        .collect();
    let mut want = vec!["conditioning 1"; 4];
    want.extend(["load"; 3]);
    want.push("release");
    assert_eq!(phases, want, "{csv}");
    assert!(csv.starts_with("stretch,force_n,compression,"), "{csv}");
}

#[test]
fn bias_test_piece_is_a_rectangle_cut_at_45_degrees_clamped_across_its_ends() {
    use knitvox::yarn::fabric::rig::cut_rectangle;
    let sheet = rib(24, 24);
    let (axis, transverse) = Direction::Bias.axes();
    let (length, width) = (0.05, 0.02);
    let piece = cut_rectangle(&sheet, axis, transverse, length, width, 8).unwrap();
    piece.validate().unwrap();
    assert!(piece.num_curves() > 1, "the courses are cut");
    let b = piece.bounds().unwrap();
    let s: Vec<f64> = piece
        .points
        .iter()
        .map(|p| p[0] * axis[0] + p[1] * axis[1])
        .collect();
    let t: Vec<f64> = piece
        .points
        .iter()
        .map(|p| p[0] * transverse[0] + p[1] * transverse[1])
        .collect();
    let extent = |v: &[f64]| {
        v.iter().copied().fold(f64::NEG_INFINITY, f64::max)
            - v.iter().copied().fold(f64::INFINITY, f64::min)
    };
    // Inside the rotated rectangle, and filling it.
    assert!(
        extent(&s) <= length + 1e-12 && extent(&s) > 0.9 * length,
        "{}",
        extent(&s)
    );
    assert!(
        extent(&t) <= width + 1e-12 && extent(&t) > 0.9 * width,
        "{}",
        extent(&t)
    );
    assert!(b.size()[0] > width, "turned by 45 degrees: {:?}", b.size());
    // The rig's clamps are bands across the whole width at both ends, not
    // corners of the sheet.
    let rig = Rig::new(&piece.points, axis, transverse, 8e-3);
    for mask in [&rig.low, &rig.high] {
        let held: Vec<f64> = t
            .iter()
            .zip(mask.iter())
            .filter(|(_, m)| **m)
            .map(|(t, _)| *t)
            .collect();
        assert!(held.len() > 20, "{} vertices clamped", held.len());
        assert!(extent(&held) > 0.8 * width, "clamp spans {}", extent(&held));
    }
    assert!((rig.gauge() - (extent(&s) - 0.016)).abs() < 1e-12);
}

#[test]
fn bias_stretch_cuts_relaxes_and_pulls_back() {
    use knitvox::pipeline::pattern::PatternSource;
    let job = FabricTestJob {
        swatch: SwatchSource::Pattern {
            source: PatternSource::Builtin("rib1x1".into()),
            size: [0.02, 0.035],
        },
        test: FabricTest::Stretch(StretchParams {
            direction: Direction::Bias,
            max_stretch: 0.1,
            steps: 2,
            hold_steps: 1,
            ..StretchParams::default()
        }),
        fabric: FabricParams::default(),
        material: Default::default(),
        relax: RelaxParams::default(),
        output_dir: None,
    };
    let rep = run(&job).unwrap();
    let TestFigures::Stretch(s) = &rep.figures else {
        panic!("not a stretch report")
    };
    println!("bias: {} {:?}", rep.swatch, s.points);
    // The cut piece is about the asked size (relaxation shrinks it by
    // about the rest-length scale it was laid out for).
    assert!((0.6..1.4).contains(&(s.width_m / 0.02)), "{}", s.width_m);
    assert!((0.6..1.4).contains(&(s.length_m / 0.035)), "{}", s.length_m);
    let p = &s.points;
    assert!(p[2].force_n > p[1].force_n && p[1].force_n > 0.0, "{p:?}");
    assert!(s.min_distance_ratio > 0.75);
}

#[test]
fn pear_loop_elongates_as_the_clamps_close_and_is_rounder_when_stiffer() {
    use knitvox::pipeline::pattern::PatternSource;
    use knitvox::yarn::fabric::bend::{bend_test, BendParams};
    let fp = FabricParams::default();
    let bp = BendParams {
        max_distance: 0.018,
        min_distance: 0.010,
        steps: 2,
        ..BendParams::default()
    };
    let job = FabricTestJob {
        swatch: SwatchSource::Pattern {
            source: PatternSource::Builtin("rib1x1".into()),
            size: [0.02, 0.05],
        },
        test: FabricTest::Bend(bp.clone()),
        fabric: fp.clone(),
        material: Default::default(),
        relax: RelaxParams::default(),
        output_dir: None,
    };
    let relaxed = knitvox::pipeline::fabric_test::swatch(&job).unwrap().yarns;
    let mut up = Vec::new();
    let stiff = bend_test(&relaxed, &fp, &bp, &mut |f| {
        up.push(f.reactions.iter().map(|r| r[2]).sum::<f64>());
        Ok(())
    })
    .unwrap();
    let p = &stiff.points;
    println!("stiff: {p:#?}");
    assert_eq!(p.len(), 3);
    // Closing the clamps lengthens the loop relative to its width (Sperl
    // 2022 Fig. 8: r falls with d).
    for w in p.windows(2) {
        assert!(
            w[1].aspect_ratio > w[0].aspect_ratio,
            "h/p {} at d = {} m, {} at {} m",
            w[0].aspect_ratio,
            w[0].clamp_distance_m,
            w[1].aspect_ratio,
            w[1].clamp_distance_m
        );
    }
    for q in p {
        assert!(
            q.aspect_ratio.is_finite() && q.width_m > q.clamp_distance_m,
            "{q:?}"
        );
        // The clamps carry the weight, and hold the legs together against
        // the loop's bending with equal and opposite axial forces.
        let vertical = q.low_clamp_force_n[1] + q.high_clamp_force_n[1];
        assert!(
            (vertical - stiff.weight_n).abs() <= 0.02 * stiff.weight_n,
            "clamps carry {vertical} N of {} N",
            stiff.weight_n
        );
        let axial = q.low_clamp_force_n[0] + q.high_clamp_force_n[0];
        assert!(axial.abs() <= 0.02 * stiff.weight_n + 1e-6, "{q:?}");
        assert!(q.low_clamp_force_n[0] > 0.0, "{q:?}");
        assert!(q.energy_j > 0.0 && q.min_distance_ratio > 0.75, "{q:?}");
    }
    assert!(up
        .iter()
        .all(|v| (v - stiff.weight_n).abs() <= 0.02 * stiff.weight_n));
    // Gravity pulls the loop down against bending (Peirce 1930: the
    // loop's drop grows as the bending length shrinks); a yarn ten times
    // less stiff in bending gives a longer, narrower loop.
    let mut soft_fp = fp.clone();
    soft_fp.rods.bend_scale *= 0.1;
    let soft = bend_test(&relaxed, &soft_fp, &bp, &mut |_| Ok(())).unwrap();
    println!(
        "h/p stiff {:?}, soft {:?}",
        p.iter().map(|q| q.aspect_ratio).collect::<Vec<_>>(),
        soft.points
            .iter()
            .map(|q| q.aspect_ratio)
            .collect::<Vec<_>>()
    );
    for (s, f) in soft.points.iter().zip(p) {
        assert!(
            s.aspect_ratio > f.aspect_ratio,
            "at d = {} m: soft h/p {}, stiff {}",
            f.clamp_distance_m,
            s.aspect_ratio,
            f.aspect_ratio
        );
    }
}

/// `fabric-test bend` on a 2 x 5 cm rib with the clamps from 18 mm to
/// `min_distance` (m).
fn small_rib_bend(min_distance: &str) -> std::process::Command {
    let mut c = std::process::Command::new(common::knitvox_bin());
    c.args([
        "fabric-test",
        "bend",
        "--pattern",
        "rib1x1",
        "--width",
        "0.02",
        "--length",
        "0.05",
        "--max-distance",
        "0.018",
        "--min-distance",
        min_distance,
    ]);
    c
}

#[test]
fn fabric_test_bend_prints_the_loop_and_writes_csv_frames_and_plot() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("out");
    let out = small_rib_bend("0.014")
        .args(["--steps", "1", "--json", "--no-progress", "-o"])
        .arg(&out_dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        !String::from_utf8_lossy(&out.stderr).contains("fabric-test bend: frame"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["test"], "bend");
    assert_eq!(v["direction"], "weft");
    assert!(v["width_m"].as_f64().unwrap() > 0.0 && v["length_m"].as_f64().unwrap() > 0.03);
    let pts = v["points"].as_array().unwrap();
    assert_eq!(pts.len(), 2);
    for (p, d) in pts.iter().zip([0.018, 0.014]) {
        assert!((p["clamp_distance_m"].as_f64().unwrap() - d).abs() < 1e-12);
        let (h, w, r) = (
            p["height_m"].as_f64().unwrap(),
            p["width_m"].as_f64().unwrap(),
            p["aspect_ratio"].as_f64().unwrap(),
        );
        assert!(h > 0.0 && w > 0.0 && (r - h / w).abs() < 1e-12, "{p}");
    }
    let csv = std::fs::read_to_string(out_dir.join("bend.csv")).unwrap();
    assert_eq!(csv.lines().count(), 3, "{csv}");
    assert!(csv.starts_with("clamp_distance_m,height_m,width_m,aspect_ratio,"));
    let (shape, _) =
        h5::read_dataset_f64(&out_dir.join("bend.h5"), "frames/elastic_energy").unwrap();
    assert_eq!(shape, vec![2]);
    check_png(&out_dir.join("bend.png"), (800, 500));
    // A clamp distance under the swatch's thickness is a usage error.
    let bad = small_rib_bend("0.001").output().unwrap();
    assert_eq!(
        bad.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&bad.stderr)
    );
    assert!(String::from_utf8_lossy(&bad.stderr).contains("thickness"));
}
