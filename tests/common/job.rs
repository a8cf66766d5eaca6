//! A small job folder for `knitvox run` tests: garment, scene, manifest.

use std::path::{Path, PathBuf};

use knitvox::io::{self, WriteOptions};
use knitvox::yarn::analytic::{knit_swatch, SwatchParams};

/// A small knit swatch (courses x 4 wales) as a BCC file.
pub fn write_garment(path: &Path, courses: usize) {
    let yarns = knit_swatch(&SwatchParams {
        courses,
        wales: 4,
        with_ring: false,
        points_per_loop: 12,
        ..SwatchParams::default()
    });
    io::write_path(path, &yarns, None, &WriteOptions::default()).unwrap();
}

/// A scene pinning one edge of the swatch, so a frame takes a few steps.
pub const SCENE: &str = r#"
[simulation]
fps = 24
dt = "1/48"
[garment]
rotate_deg = [-90, 0, 0]
[[pin]]
name = "edge"
box_min = [-1.0, -1.0, -1.0]
box_max = [1.0, 1.0, 0.0]
"#;

pub fn manifest(export_units: &str) -> String {
    format!(
        r#"
frames = "1-2"
[garment]
yarns = "swatch.bcc"
[shot]
scene = "scene.toml"
backend = "cpu"
[export]
format = "ply"
units = "{export_units}"
"#
    )
}

/// A job folder: garment, scene and manifest; returns the manifest path.
pub fn job_dir(dir: &Path) -> PathBuf {
    write_garment(&dir.join("swatch.bcc"), 3);
    std::fs::write(dir.join("scene.toml"), SCENE).unwrap();
    let job = dir.join("job.toml");
    std::fs::write(&job, manifest("m")).unwrap();
    job
}

/// A job folder that trains two poses on a relaxed 4 x 4 rib (made by
/// `knitvox pattern`) and fits the asset to them: stages embed, train (2
/// tasks), fit. Returns the manifest path.
pub fn training_job_dir(dir: &Path) -> PathBuf {
    let out = std::process::Command::new(super::knitvox_bin())
        .args(["pattern", "rib1x1", "--courses", "4", "--wales", "4", "-o"])
        .arg(dir.join("rib.h5"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let job = dir.join("job.toml");
    std::fs::write(
        &job,
        r#"
[garment]
yarns = "rib.h5"
[[train]]
kind = "stretch_courses"
amount = 0.1
steps = 2
[[train]]
kind = "bend_central"
amount = 0.3
steps = 2
[fit]
samples = 1
harmonic = [1]
joint = true
"#,
    )
    .unwrap();
    job
}
