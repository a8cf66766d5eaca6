//! `validate`'s clamp forces: the yarn level records what each clamped band
//! holds the fabric with, and the homogenized runs are read against it. A
//! tensile tester's reading: the two clamps of a stretch pull equal and
//! opposite, the force grows with the stretch, and on the mesh it follows
//! the material's stiffness where the positions barely do.
mod common;

use std::path::Path;
use std::process::{Command, Output};

use knitvox::io;

fn knitvox(args: &[&str]) -> Output {
    Command::new(common::knitvox_bin())
        .args(args)
        .output()
        .unwrap()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

const SCENE: &str = r#"name = "force-stretch"
duration = 0.1
frame_rate = 50
gravity = [0.0, 0.0, 0.0]
model = "rods"
[pose]
kind = "stretch_courses"
amount = 0.1
ramp = 0.08
"#;

fn validate(args: &[&str]) -> (serde_json::Value, String) {
    let o = knitvox(args);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "{err}");
    (serde_json::from_slice(&o.stdout).unwrap(), err)
}

#[test]
fn clamp_forces_pull_equal_and_opposite_and_follow_the_material_stiffness() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let a1 = common::embedded_pattern(d, "a", "stockinette", 4, 4);
    let scene = d.join("stretch.toml");
    std::fs::write(&scene, SCENE).unwrap();
    let report = d.join("rep");
    let (v1, _) = validate(&[
        "validate",
        s(&a1),
        "--scene",
        s(&scene),
        "--report",
        s(&report),
        "--json",
    ]);
    eprintln!("{}", v1["verdict"]);

    // Yarn level: two bands, pulling apart along the courses (X), equal and
    // opposite once the ramp has stopped, and more at 10% than early on.
    let truth = report.join("yarn_level.h5");
    let f = io::h5::read_clamp_forces(&truth, 6).unwrap().unwrap();
    assert_eq!(f.len(), 6);
    assert!(f.iter().all(|b| b.len() == 2), "{f:?}");
    let last = &f[5];
    let (a, b) = (last[0][0], last[1][0]);
    eprintln!(
        "last frame: clamp forces along X {a:.4e} N and {b:.4e} N; early {:.4e} N",
        f[1][0][0]
    );
    assert!(a * b < 0.0, "the clamps do not pull apart: {last:?}");
    assert!(
        (a + b).abs() < 0.05 * a.abs().max(b.abs()),
        "the clamp forces are not equal and opposite: {last:?}"
    );
    assert!(
        a.abs() > 2.0 * f[1][0][0].abs(),
        "the force did not grow: {f:?}"
    );
    // The report names the peak and reads the asset against it.
    let peak = v1["clamp_force_n"].as_f64().unwrap();
    assert!(
        (peak - a.abs().max(b.abs())).abs() <= 0.2 * peak,
        "peak {peak} N, last frame {a} / {b} N"
    );
    // The embedded asset still has the 1e4 Pa placeholder material, far
    // stiffer than a knit at 10%: its clamps hold many times the force.
    let r1 = v1["clamp_force"]["peak_ratio"].as_f64().unwrap();
    assert!(r1.is_finite() && r1 > 10.0, "{v1}");
    let per_frame = v1["per_frame"].as_array().unwrap();
    assert!(per_frame
        .iter()
        .all(|e| e["clamp_force_n"].is_f64() && e["asset_clamp_force_n"].is_f64()));
    assert!(v1["verdict"]
        .as_str()
        .unwrap()
        .contains("the yarn level's force"));

    // The same asset twice as stiff: the clamp-driven positions hardly
    // change, the clamp force doubles.
    let mut asset = io::vtkhdf::read_asset(&a1).unwrap();
    asset.gamma_s.iter_mut().for_each(|g| *g *= 2.0);
    asset.gamma_v.iter_mut().for_each(|g| *g *= 2.0);
    if let Some(fb) = asset.fibres.as_mut() {
        fb.gamma_course.iter_mut().for_each(|g| *g *= 2.0);
        fb.gamma_wale.iter_mut().for_each(|g| *g *= 2.0);
    }
    let a2 = d.join("stiff.vtkhdf");
    io::vtkhdf::write_asset(&a2, &asset).unwrap();
    let (v2, _) = validate(&[
        "validate",
        s(&a2),
        "--scene",
        s(&scene),
        "--truth",
        s(&truth),
        "--json",
    ]);
    let r2 = v2["clamp_force"]["peak_ratio"].as_f64().unwrap();
    let (p1, p2) = (
        v1["rms_yarn_diameters"].as_f64().unwrap(),
        v2["rms_yarn_diameters"].as_f64().unwrap(),
    );
    eprintln!("force ratio {r1:.4} -> {r2:.4}; positions {p1:.4} -> {p2:.4} yarn diameters");
    assert!((r2 / r1 - 2.0).abs() < 0.1, "force ratio {r1} -> {r2}");
    assert!((p2 - p1).abs() < 0.1 * p1, "positions {p1} -> {p2}");
}
