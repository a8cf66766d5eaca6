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
