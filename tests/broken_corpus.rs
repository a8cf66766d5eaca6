//! A generated corpus of broken files for every reader, through the path API:
//! every one must give an error that names the file (never a panic), with the
//! bad-input class.
mod common;

use std::path::Path;

use knitvox::io::{read_path, write_path, ErrorClass, Format, ReadOptions, WriteOptions};
use knitvox::yarn::analytic::{knit_swatch, SwatchParams};

fn expect_bad(path: &Path, what: &str) {
    match read_path(path, &ReadOptions::default()) {
        Ok(d) => panic!(
            "{what}: {} was accepted ({} curves)",
            path.display(),
            d.yarns.num_curves()
        ),
        Err(e) => {
            let msg = e.to_string();
            let name = path.file_name().unwrap().to_str().unwrap();
            assert!(
                msg.contains(name),
                "{what}: error does not name the file: {msg}"
            );
            assert!(
                matches!(e.class(), ErrorClass::BadInput | ErrorClass::Transient),
                "{what}: {} classed as {:?}: {msg}",
                path.display(),
                e.class()
            );
        }
    }
}

fn all_extensions() -> Vec<&'static str> {
    Format::ALL.iter().map(|f| f.extensions()[0]).collect()
}

#[test]
fn empty_garbage_and_non_utf8_files() {
    let dir = tempfile::tempdir().unwrap();
    for ext in all_extensions() {
        let cases: [(&str, Vec<u8>); 4] = [
            ("empty", Vec::new()),
            ("one-byte", vec![b'\n']),
            (
                "garbage",
                (0..4096u32)
                    .map(|i| (i.wrapping_mul(2654435761) >> 13) as u8)
                    .collect(),
            ),
            ("non-utf8", b"\xff\xfe\xfd not text \xc3\x28\n".repeat(20)),
        ];
        for (what, bytes) in cases {
            let p = dir.path().join(format!("{what}.{ext}"));
            std::fs::write(&p, &bytes).unwrap();
            expect_bad(&p, &format!("{what} .{ext}"));
        }
    }
}

#[test]
fn truncated_binary_files() {
    let dir = tempfile::tempdir().unwrap();
    let y = knit_swatch(&SwatchParams {
        courses: 2,
        wales: 2,
        points_per_loop: 6,
        ..Default::default()
    });
    for f in [Format::Bcc, Format::Ply, Format::Glb, Format::Hdf5] {
        let good = dir.path().join(format!("good.{}", f.extensions()[0]));
        write_path(&good, &y, None, &WriteOptions::default()).unwrap();
        read_path(&good, &ReadOptions::default()).unwrap();
        let bytes = std::fs::read(&good).unwrap();
        let step = (bytes.len() / 97).max(1);
        for len in (0..bytes.len()).step_by(step).chain([bytes.len() - 1]) {
            let p = dir.path().join(format!("cut{len}.{}", f.extensions()[0]));
            std::fs::write(&p, &bytes[..len]).unwrap();
            expect_bad(&p, &format!("{f} cut at {len} of {}", bytes.len()));
        }
    }
}

#[test]
fn truncated_text_files_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    let y = knit_swatch(&SwatchParams {
        courses: 2,
        wales: 2,
        points_per_loop: 6,
        ..Default::default()
    });
    for f in [Format::Obj, Format::Gltf] {
        let good = dir.path().join(format!("good.{}", f.extensions()[0]));
        write_path(&good, &y, None, &WriteOptions::default()).unwrap();
        let bytes = std::fs::read(&good).unwrap();
        for len in (0..bytes.len()).step_by((bytes.len() / 61).max(1)) {
            let p = dir.path().join(format!("cut{len}.{}", f.extensions()[0]));
            std::fs::write(&p, &bytes[..len]).unwrap();
            // A text file cut at a line end can still be valid; anything accepted must validate.
            match read_path(&p, &ReadOptions::default()) {
                Ok(d) => d.yarns.validate().unwrap(),
                Err(e) => assert!(e
                    .to_string()
                    .contains(p.file_name().unwrap().to_str().unwrap())),
            }
        }
    }
}

#[test]
fn nan_coordinates_are_rejected_everywhere() {
    let dir = tempfile::tempdir().unwrap();
    let obj = dir.path().join("nan.obj");
    std::fs::write(&obj, "v 0 0 0\nv nan 1 1\nl 1 2\n").unwrap();
    expect_bad(&obj, "obj NaN");
    let inf = dir.path().join("inf.obj");
    std::fs::write(&inf, "v 0 0 0\nv 1 inf 1\nl 1 2\n").unwrap();
    expect_bad(&inf, "obj Inf");
    let ply = dir.path().join("nan.ply");
    std::fs::write(&ply, "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nelement edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n0 0 0\nNaN 0 0\n0 1\n").unwrap();
    expect_bad(&ply, "ply NaN");
    let poly = dir.path().join("nan.poly");
    std::fs::write(&poly, "POINTS\n1: 0 0 0\n2: nan 0 0\nPOLYS\n1: 1 2\nEND\n").unwrap();
    expect_bad(&poly, "poly NaN");
}

#[test]
fn indices_out_of_range_and_short_curves() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        ("range.obj", "v 0 0 0\nv 1 0 0\nl 1 3\n"),
        ("zero.obj", "v 0 0 0\nv 1 0 0\nl 0 1\n"),
        ("single.obj", "v 0 0 0\nv 1 0 0\nl 1\n"),
        ("range.ply", "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nelement edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n0 0 0\n1 0 0\n0 7\n"),
        ("range.poly", "POINTS\n1: 0 0 0\n2: 1 0 0\nPOLYS\n1: 1 9\nEND\n"),
    ];
    for (name, text) in cases {
        let p = dir.path().join(name);
        std::fs::write(&p, text).unwrap();
        expect_bad(&p, name);
    }
}
