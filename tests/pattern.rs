//! Stitch-pattern generator (`yarn::pattern`) and `knitvox pattern`.

mod common;

use std::f64::consts::PI;
use std::process::Command;

use knitvox::geom::{dist, Yarns};
use knitvox::io::{self, ReadOptions};
use knitvox::yarn::pattern::{
    build_tile, builtin, lay_out, min_segment_distance, parse_grid, tile_periodic, Layout, Pattern,
    PatternError, PatternParams, BUILTIN_NAMES,
};

/// The clearance bound every built-in meets before relaxation: two
/// non-adjacent yarn segments are at least 0.95 yarn diameters apart
/// (centreline distance over the sum of their radii).
const BOUND: f64 = 0.95;

fn clearance(y: &Yarns, r: f64) -> f64 {
    min_segment_distance(y, PI * r, 4.0 * r).ratio
}

fn swatch(name: &str, courses: usize, wales: usize, tube: Option<f64>) -> Yarns {
    let p = PatternParams::default();
    let t = build_tile(&builtin(name).unwrap(), &p).unwrap();
    lay_out(
        &t,
        &Layout {
            courses,
            wales,
            tube_radius: tube,
            helix: false,
            separate_courses: false,
        },
    )
    .unwrap()
}

#[test]
fn every_builtin_builds_valid_tiles_and_swatches() {
    let p = PatternParams::default();
    for name in BUILTIN_NAMES {
        let pat = builtin(name).unwrap();
        let t = build_tile(&pat, &p).unwrap();
        t.tile.validate().unwrap();
        t.tile.yarns.validate().unwrap();
        let [cols, rows] = pat.repeat();
        // Lattice vectors are the tile size.
        assert!(
            (t.tile.lattice[0][0] - cols as f64 * t.pitch[0]).abs() < 1e-12,
            "{name}"
        );
        assert!(
            (t.tile.lattice[1][1] - rows as f64 * t.pitch[1]).abs() < 1e-12,
            "{name}"
        );
        let (n, m) = (5, 3);
        let layout = |separate_courses| Layout {
            courses: n,
            wales: m,
            tube_radius: None,
            helix: false,
            separate_courses,
        };
        let y = lay_out(&t, &layout(true)).unwrap();
        y.validate().unwrap();
        let expect = match pat {
            Pattern::Knit(_) => n,
            Pattern::Woven(_) => n + m,
        };
        assert_eq!(y.num_curves(), expect, "{name}");
        assert_eq!(y.num_closed(), 0);
        // By default the courses (wefts) are one yarn knitted back and forth:
        // course k's points in order (odd courses reversed), joined by turns
        // outside the edges.
        let joined = lay_out(&t, &layout(false)).unwrap();
        joined.validate().unwrap();
        assert_eq!(joined.num_curves(), expect - n + 1, "{name}");
        let one = joined.curve(0);
        let mut at = 0;
        for k in 0..n {
            let mut course = y.curve(k).to_vec();
            if k % 2 == 1 {
                course.reverse();
            }
            let start = one[at..]
                .windows(course.len())
                .position(|w| w == course.as_slice())
                .unwrap_or_else(|| panic!("{name}: course {k} is not in the joined yarn in order"));
            at += start + course.len();
        }
        assert_eq!(
            at,
            one.len(),
            "{name}: the joined yarn ends with the last course"
        );
        let (yb, jb) = (y.bounds().unwrap(), joined.bounds().unwrap());
        assert!(
            jb.min[0] < yb.min[0] && jb.max[0] > yb.max[0],
            "{name}: turns lie outside the edges"
        );
        assert!(
            joined.max_segment_length() < 1.6 * p.spacing * p.yarn_radius,
            "{name}"
        );
        // The swatch spans M pitches along x and N along y (to the loop sizes).
        let b = y.bounds().unwrap();
        assert!(
            (b.max[0] - b.min[0] - m as f64 * t.pitch[0]).abs() < 0.5 * t.pitch[0] + 1e-9,
            "{name} {b:?}"
        );
        // Segments never exceed about the documented spacing.
        assert!(
            y.max_segment_length() < 1.6 * p.spacing * p.yarn_radius,
            "{name}"
        );
    }
}

#[test]
fn tiles_tiled_3x3_give_continuous_yarns() {
    let p = PatternParams::default();
    let h = p.spacing * p.yarn_radius;
    for name in BUILTIN_NAMES {
        let t = build_tile(&builtin(name).unwrap(), &p).unwrap();
        let y = tile_periodic(&t.tile, [3, 3]).unwrap();
        y.validate().unwrap();
        // Every chain is continuous: consecutive points (including across tile
        // boundaries) are at the sampling distance, never a jump.
        for c in 0..y.num_curves() {
            for w in y.curve(c).windows(2) {
                let d = dist(w[0], w[1]);
                assert!(d > 0.2 * h && d < 1.6 * h, "{name}: curve {c} step {d}");
            }
        }
        // Knits: one yarn per course (3 tiles wide); wovens: wefts and warps.
        let [cols, rows] = t.repeat;
        let expect = match builtin(name).unwrap() {
            Pattern::Knit(_) => 3 * rows,
            Pattern::Woven(_) => 3 * rows + 3 * cols,
        };
        assert_eq!(y.num_curves(), expect, "{name}");
        let want = 3 * t.tile.yarns.num_points() * 3;
        assert_eq!(y.num_points(), want, "{name}");
    }
}

#[test]
fn every_builtin_keeps_clear_of_itself_before_relaxation() {
    let p = PatternParams::default();
    let r = p.yarn_radius;
    let mut report = Vec::new();
    for name in BUILTIN_NAMES {
        let t = build_tile(&builtin(name).unwrap(), &p).unwrap();
        // The periodic tile with all its neighbours.
        let tiled = tile_periodic(&t.tile, [3, 3]).unwrap();
        let tile_ratio = clearance(&tiled, r);
        // A small flat swatch that is not a multiple of the repeat.
        let flat = swatch(name, 7, 9, None);
        let flat_ratio = clearance(&flat, r);
        report.push(format!(
            "{name}: tile 3x3 {tile_ratio:.3}, swatch 7x9 {flat_ratio:.3}"
        ));
        assert!(tile_ratio >= BOUND, "{name}: tile clearance {tile_ratio}");
        assert!(flat_ratio >= BOUND, "{name}: swatch clearance {flat_ratio}");
    }
    eprintln!("{}", report.join("\n"));
}

#[test]
fn tubes_close_courses_into_rings_with_clearance() {
    let p = PatternParams::default();
    let r = p.yarn_radius;
    for name in ["stockinette", "rib1x1", "garter", "seed", "plain", "satin"] {
        let t = build_tile(&builtin(name).unwrap(), &p).unwrap();
        let wales = 20;
        let radius = wales as f64 * t.pitch[0] / (2.0 * PI);
        let layout = Layout {
            courses: 4,
            wales,
            tube_radius: Some(radius),
            helix: false,
            separate_courses: false,
        };
        assert!((layout.circumferential_stretch(&t) - 1.0).abs() < 1e-12);
        let y = lay_out(&t, &layout).unwrap();
        let woven = matches!(name, "plain" | "satin");
        assert_eq!(y.num_curves(), if woven { 4 + wales } else { 4 }, "{name}");
        assert_eq!(y.num_closed(), 4, "{name}");
        for c in 0..4 {
            let ring = y.curve(c);
            // Closed and continuous, including the closing segment.
            for k in 0..ring.len() {
                let d = dist(ring[k], ring[(k + 1) % ring.len()]);
                assert!(d < 1.6 * p.spacing * r, "{name}: ring {c} step {k}: {d}");
            }
            for q in ring {
                let rho = (q[0] * q[0] + q[2] * q[2]).sqrt();
                assert!((rho - radius).abs() < 2.0 * r, "{name}: rho {rho}");
            }
        }
        let ratio = clearance(&y, r);
        eprintln!("{name}: tube R = {radius:.4} m ({wales} wales) clearance {ratio:.3}");
        assert!(ratio >= BOUND, "{name}: tube clearance {ratio}");
    }
    // A tube needs whole repeats around.
    let t = build_tile(&builtin("rib2x2").unwrap(), &p).unwrap();
    let e = lay_out(
        &t,
        &Layout {
            courses: 2,
            wales: 6,
            tube_radius: Some(0.05),
            helix: false,
            separate_courses: false,
        },
    );
    assert!(matches!(
        e,
        Err(PatternError::BadParameter { name: "wales", .. })
    ));
}

#[test]
fn helix_tubes_are_one_rising_yarn() {
    let p = PatternParams::default();
    let r = p.yarn_radius;
    for name in ["stockinette", "rib1x1", "seed", "plain"] {
        let t = build_tile(&builtin(name).unwrap(), &p).unwrap();
        let wales = 20;
        let radius = wales as f64 * t.pitch[0] / (2.0 * PI);
        let layout = Layout {
            courses: 4,
            wales,
            tube_radius: Some(radius),
            helix: true,
            separate_courses: false,
        };
        let y = lay_out(&t, &layout).unwrap();
        let woven = name == "plain";
        assert_eq!(y.num_curves(), if woven { 1 + wales } else { 1 }, "{name}");
        let helix = y.curve(0);
        for w in helix.windows(2) {
            let d = dist(w[0], w[1]);
            assert!(d < 1.6 * p.spacing * r, "{name}: helix step {d}");
        }
        // It rises about one course per turn.
        let rise = helix.last().unwrap()[1] - helix[0][1];
        assert!(
            (rise - 4.0 * t.pitch[1]).abs() < 0.5 * t.pitch[1],
            "{name}: rise {rise}"
        );
        let ratio = clearance(&y, r);
        eprintln!("{name}: helix tube clearance {ratio:.3}");
        assert!(ratio >= BOUND, "{name}: helix clearance {ratio}");
    }
}

#[test]
fn generation_is_deterministic() {
    let a = swatch("seed", 4, 6, None);
    let b = swatch("seed", 4, 6, None);
    assert_eq!(a, b);
}

#[test]
fn grid_parse_errors_name_line_and_column() {
    match parse_grid("# rib\nKP\nKQ\n") {
        Err(PatternError::Grid { line, column, .. }) => assert_eq!((line, column), (3, 2)),
        other => panic!("{other:?}"),
    }
    match parse_grid("KPK\nKP\n") {
        Err(PatternError::Grid { line, column, .. }) => assert_eq!((line, column), (2, 3)),
        other => panic!("{other:?}"),
    }
    // A grid file and the matching built-in give the same curves.
    let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/examples/seed.grid"))
        .unwrap();
    assert_eq!(parse_grid(&text).unwrap(), builtin("seed").unwrap());
}

fn knitvox(args: &[&str]) -> std::process::Output {
    Command::new(common::knitvox_bin())
        .args(args)
        .output()
        .expect("run knitvox")
}

#[test]
fn cli_round_trip_h5_and_ply() {
    let dir = tempfile::tempdir().unwrap();
    for ext in ["h5", "ply"] {
        let out = dir.path().join(format!("rib.{ext}"));
        let o = knitvox(&[
            "pattern",
            "rib1x1",
            "--courses",
            "4",
            "--wales",
            "6",
            "--json",
            "-o",
            out.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        let d = io::read_path(&out, &ReadOptions::default()).unwrap();
        assert_eq!(d.yarns.num_curves() as u64, v["curves"].as_u64().unwrap());
        assert_eq!(d.yarns.num_points() as u64, v["vertices"].as_u64().unwrap());
        // One yarn knitted back and forth (the default for flat swatches).
        assert_eq!(d.yarns.num_curves(), 1);
        assert!(v["min_distance_ratio"].as_f64().unwrap() >= BOUND);
        // Relaxation into contact is on by default and reports the relaxed
        // size, contacts per vertex and the minimum distance ratio.
        assert_eq!(v["relaxed"], true);
        let x = &v["relaxation"];
        assert!(
            x["min_distance_ratio_seen"].as_f64().unwrap() >= 0.75,
            "{x}"
        );
        assert!(
            x["contact"]["contacts_per_vertex"].as_f64().unwrap() > 0.2,
            "{x}"
        );
        let (before, after) = (
            x["size_before"][0].as_f64().unwrap(),
            x["size_after"][0].as_f64().unwrap(),
        );
        assert!(after < 0.95 * before, "{x}");
        // HDF5 keeps the rest shape; PLY keeps positions only and says so.
        let stderr = String::from_utf8_lossy(&o.stderr);
        if ext == "h5" {
            assert!(d.yarns.rest.is_some());
            assert!(!stderr.contains("rest shape"), "{stderr}");
        } else {
            assert!(d.yarns.rest.is_none());
            assert!(stderr.contains("not their rest shape"), "{stderr}");
        }
    }
}

#[test]
fn cli_grid_file_tube_and_radius() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("tube.ply");
    let grid = concat!(env!("CARGO_MANIFEST_DIR"), "/examples/rib2x2.grid");
    let o = knitvox(&[
        "pattern",
        "--grid",
        grid,
        "--courses",
        "3",
        "--wales",
        "16",
        "--tube-radius",
        "0.02",
        "--yarn-radius",
        "0.0005",
        "--no-relax",
        "--json",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["curves"], 3);
    assert_eq!(v["yarn_radius"], 0.0005);
    let d = io::read_path(&out, &ReadOptions::default()).unwrap();
    assert_eq!(d.yarns.num_curves(), 3);
    assert!((d.yarns.radius[0] - 0.0005).abs() < 1e-9);
}

#[test]
fn cli_errors_have_clear_messages_and_codes() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.ply");
    let out = out.to_str().unwrap();
    // Unknown name: a usage error that lists the known patterns.
    let o = knitvox(&[
        "pattern",
        "cable",
        "--courses",
        "2",
        "--wales",
        "2",
        "-o",
        out,
    ]);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("cable") && err.contains("rib2x2") && err.contains("twill"),
        "{err}"
    );
    // Bad grid: bad input naming file:line:column.
    let bad = dir.path().join("bad.grid");
    std::fs::write(&bad, "KP\nK?\n").unwrap();
    let o = knitvox(&[
        "pattern",
        "--grid",
        bad.to_str().unwrap(),
        "--courses",
        "2",
        "--wales",
        "2",
        "-o",
        out,
    ]);
    assert_eq!(o.status.code(), Some(65));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains(&format!("{}:2:2", bad.display())), "{err}");
    // Missing grid file.
    let o = knitvox(&[
        "pattern",
        "--grid",
        "/nonexistent/x.grid",
        "--courses",
        "2",
        "--wales",
        "2",
        "-o",
        out,
    ]);
    assert_eq!(o.status.code(), Some(66));
    // Out-of-range sizes are usage errors naming the flag.
    let o = knitvox(&[
        "pattern",
        "seed",
        "--courses",
        "0",
        "--wales",
        "2",
        "-o",
        out,
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("courses"));
    let o = knitvox(&[
        "pattern",
        "rib2x2",
        "--courses",
        "2",
        "--wales",
        "6",
        "--tube-radius",
        "0.05",
        "-o",
        out,
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("multiple of 4"));
    // Neither a name nor a grid.
    let o = knitvox(&["pattern", "--courses", "2", "--wales", "2", "-o", out]);
    assert_eq!(o.status.code(), Some(2));
    // Nothing was written by the failures.
    assert!(!std::path::Path::new(out).exists());
}

/// Every built-in pattern relaxes into contact with the defaults: an
/// equilibrium (residual <= 1e-4 N) with the rest shape stored, no
/// pull-through at any round, and more of the yarn touching than before.
#[test]
fn every_builtin_relaxes_into_contact() {
    use knitvox::pipeline::pattern::{generate, PatternJob, PatternSource};
    for name in knitvox::yarn::pattern::BUILTIN_NAMES {
        let job = |relax| PatternJob {
            source: PatternSource::Builtin(name.to_string()),
            layout: knitvox::yarn::pattern::Layout {
                courses: 4,
                wales: 4,
                tube_radius: None,
                helix: false,
                separate_courses: false,
            },
            params: Default::default(),
            relax,
            material: knitvox::yarn::fabric::FabricParams::default().material(),
        };
        let (loose, _) = generate(&job(None)).unwrap();
        assert!(loose.rest.is_none());
        let (yarns, r) = generate(&job(Some(Default::default()))).unwrap();
        let relax = r.relaxation.expect("the relaxation ran");
        println!(
            "{name}: {} vertices, near {:.3}, cpv {:.2}, min {:.3}, size {:.4} x {:.4} (was {:.4} x {:.4}), {} its, {:.1} s",
            yarns.num_points(),
            relax.contact.near_fraction,
            relax.contact.contacts_per_vertex,
            relax.min_distance_ratio_seen,
            relax.size_after[0],
            relax.size_after[1],
            relax.size_before[0],
            relax.size_before[1],
            relax.newton_iterations,
            relax.seconds
        );
        assert!(yarns.rest.is_some(), "{name}");
        assert!(relax.residual <= 1e-4, "{name}: {relax:?}");
        assert!(relax.min_distance_ratio_seen >= 0.75, "{name}: {relax:?}");
        assert!(
            r.min_distance_ratio >= 0.75,
            "{name}: {}",
            r.min_distance_ratio
        );
        yarns.validate().unwrap();
    }
}

/// `--rest-curvature` sets how much of the generated loops' curvature the
/// yarn keeps at rest: at the default (1) a stockinette swatch lies flat,
/// at 0.8 its course ends roll to the back (the pattern's character).
#[test]
fn cli_rest_curvature_lets_stockinette_curl() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("s.h5");
    let side_curl = |extra: &[&str]| -> f64 {
        let mut args = vec![
            "pattern",
            "stockinette",
            "--courses",
            "6",
            "--wales",
            "6",
            "--json",
            "-o",
            out.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        let o = knitvox(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        v["character"]["side_curl_m"].as_f64().unwrap()
    };
    let d = 2.0 * PatternParams::default().yarn_radius;
    let flat = side_curl(&[]);
    let curled = side_curl(&["--rest-curvature", "0.8"]);
    assert!(flat.abs() < d, "default: side curl {flat} m");
    assert!(curled < -2.0 * d, "0.8: side curl {curled} m");
    for bad in ["1.5", "-0.1", "nan"] {
        let opt = format!("--rest-curvature={bad}");
        let o = knitvox(&[
            "pattern",
            "stockinette",
            "--courses",
            "2",
            "--wales",
            "2",
            &opt,
            "-o",
            out.to_str().unwrap(),
        ]);
        assert_eq!(o.status.code(), Some(2), "--rest-curvature {bad}");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains("--rest-curvature"), "{err}");
    }
}
