//! The real binary on temporary folders: commands, outputs, exit codes.
mod common;

use std::path::Path;
use std::process::{Command, Output};

fn knitvox(args: &[&str]) -> Output {
    Command::new(common::knitvox_bin())
        .args(args)
        .output()
        .expect("run knitvox")
}

fn p(path: &Path) -> &str {
    path.to_str().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[test]
fn help_on_every_subcommand() {
    for args in [
        &["--help"][..],
        &["inspect", "--help"],
        &["convert", "--help"],
        &["bench", "--help"],
        &["bench", "io", "--help"],
        &["demo", "--help"],
        &["completions", "--help"],
    ] {
        let o = knitvox(args);
        assert!(o.status.success(), "{args:?}: {}", stderr(&o));
        assert!(
            String::from_utf8_lossy(&o.stdout).contains("Usage"),
            "{args:?}"
        );
    }
}

#[test]
fn completions_for_bash() {
    let o = knitvox(&["completions", "bash"]);
    assert!(o.status.success());
    let s = String::from_utf8_lossy(&o.stdout);
    assert!(s.contains("knitvox") && s.contains("convert"));
}

#[test]
fn usage_errors_exit_2() {
    assert_eq!(knitvox(&["convert"]).status.code(), Some(2));
    assert_eq!(
        knitvox(&["inspect", "x.bcc", "--tile", "0x0"])
            .status
            .code(),
        Some(2)
    );
    assert_eq!(
        knitvox(&["inspect", "x.bcc", "--units", "parsec"])
            .status
            .code(),
        Some(2)
    );
}

#[test]
fn demo_then_inspect_and_convert_everything() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    let o = knitvox(&["demo", "--out", p(&out), "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let outputs = report["outputs"].as_array().unwrap();
    // Every writable format, once as a single file and once as frames.
    for ext in ["bcc", "obj", "ply", "gltf", "glb", "h5"] {
        assert!(
            outputs
                .iter()
                .any(|v| v.as_str().unwrap().ends_with(&format!("swatch.{ext}"))),
            "{ext}"
        );
    }
    for f in outputs {
        let f = f.as_str().unwrap();
        assert!(Path::new(f).is_file(), "{f}");
    }
    let input = out.join("example_swatch.bcc");
    let o = knitvox(&[
        "inspect",
        "--json",
        p(&input),
        p(&out.join("swatch.glb")),
        p(&out.join("swatch_frames.####.ply")),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let reports = v.as_array().unwrap();
    assert_eq!(reports.len(), 3);
    assert_eq!(reports[0]["curves"], 9);
    assert_eq!(reports[0]["closed_curves"], 1);
    assert_eq!(reports[0]["units_source"], "assumed");
    assert_eq!(reports[1]["units_source"], "file");
    assert_eq!(reports[2]["frames"], 5);
    assert_eq!(reports[0]["points"], reports[1]["points"]);

    // Convert BCC (say it is in cm, Z up) to OBJ in mm: coordinates scale by 10.
    let obj = dir.path().join("x.obj");
    let o = knitvox(&[
        "convert",
        p(&input),
        p(&obj),
        "--units",
        "cm",
        "--up-axis",
        "z",
        "--out-units",
        "mm",
        "--out-up-axis",
        "z",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let a = knitvox::io::read_path(&input, &Default::default()).unwrap();
    let b = knitvox::io::read_path(&obj, &Default::default()).unwrap();
    let (pa, pb) = (a.yarns.points[5], b.yarns.points[5]);
    // a was read as m +Y up; in the file it is (x, y, z) = cm +Z up -> written as mm +Z up
    // -> read back as m +Y up: x scales by 10, and file (y, z) -> internal (z, -y).
    assert!((pb[0] - 10.0 * pa[0]).abs() < 1e-9 * pa[0].abs().max(1.0));
}

#[test]
fn bad_input_exit_codes() {
    let dir = tempfile::tempdir().unwrap();
    let empty = dir.path().join("empty.bcc");
    std::fs::write(&empty, b"").unwrap();
    let o = knitvox(&["inspect", p(&empty)]);
    assert_eq!(o.status.code(), Some(65), "{}", stderr(&o));
    assert!(stderr(&o).contains("empty.bcc"), "{}", stderr(&o));

    let unknown = dir.path().join("curves.xyz");
    std::fs::write(&unknown, b"1 2 3").unwrap();
    let o = knitvox(&["inspect", p(&unknown)]);
    assert_eq!(o.status.code(), Some(65));
    assert!(stderr(&o).contains("unknown file type"), "{}", stderr(&o));

    let o = knitvox(&["inspect", p(&dir.path().join("missing.ply"))]);
    assert_eq!(o.status.code(), Some(66), "{}", stderr(&o));

    let garbage = dir.path().join("garbage.glb");
    std::fs::write(&garbage, [0xffu8; 100]).unwrap();
    let o = knitvox(&["convert", p(&garbage), p(&dir.path().join("o.ply"))]);
    assert_eq!(o.status.code(), Some(65), "{}", stderr(&o));
    assert!(!dir.path().join("o.ply").exists());

    // Output into a folder that does not exist: an output failure.
    knitvox(&["demo", "--out", p(&dir.path().join("d"))]);
    let o = knitvox(&[
        "convert",
        p(&dir.path().join("d/example_swatch.bcc")),
        "/nonexistent-knitvox/out.ply",
    ]);
    assert_eq!(o.status.code(), Some(74), "{}", stderr(&o));
    // Writing a read-only format.
    let o = knitvox(&[
        "convert",
        p(&dir.path().join("d/example_swatch.bcc")),
        p(&dir.path().join("o.pyp")),
    ]);
    assert_eq!(o.status.code(), Some(65), "{}", stderr(&o));
}

#[test]
fn bench_io_json_shape() {
    let o = knitvox(&["bench", "io", "--points", "2000", "--runs", "3", "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["bench"], "io");
    for f in ["bcc", "obj", "ply", "gltf", "glb", "hdf5"] {
        let t = &v["formats"][f];
        assert!(t["write_ms"].as_f64().unwrap() > 0.0, "{f}");
        assert!(t["read_ms"].as_f64().unwrap() > 0.0, "{f}");
        assert!(t["bytes"].as_u64().unwrap() > 0, "{f}");
    }
}

#[test]
fn inspect_foreign_and_busy_hdf5() {
    let Some(dir) = common::external_data("hdf5") else {
        return;
    };
    let o = knitvox(&["inspect", "--json", p(&dir.join("pyfive_chunked.hdf5"))]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v[0]["knitvox_yarns"], false);
    assert_eq!(v[0]["datasets"][0]["path"], "/dataset1");
    // Its "open for write" flag is set: transient (75) with the h5clear advice, not a crash.
    let o = knitvox(&[
        "inspect",
        p(&dir.join("jhdf_test_byteshuffle_compressed_datasets_latest.hdf5")),
    ]);
    assert_eq!(o.status.code(), Some(75), "{}", stderr(&o));
    assert!(stderr(&o).contains("h5clear"), "{}", stderr(&o));
}

/// Issue 13 item 6: a missing input's OS error is printed once (library
/// errors embed their cause and also return it as `source()`), and the code
/// is 66.
#[test]
fn missing_input_prints_its_cause_once() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nope.bcc");
    for args in [
        vec!["inspect", p(&missing)],
        vec!["convert", p(&missing), "out.ply"],
        vec!["embed", p(&missing), "-o", "out.vtkhdf"],
    ] {
        let o = knitvox(&args);
        assert_eq!(o.status.code(), Some(66), "{args:?}: {}", stderr(&o));
        let err = stderr(&o);
        let cause = std::io::Error::from_raw_os_error(2).to_string(); // ENOENT
        assert_eq!(err.matches(&cause).count(), 1, "{args:?}: {err}");
        assert!(err.contains("nope.bcc"), "{err}");
    }
}
