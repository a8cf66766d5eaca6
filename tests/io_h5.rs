//! knitvox HDF5 yarns files: round trips, on-disk layout (checked with the
//! hdf5 crate and with h5py), files from other HDF5 writers, busy files, and a
//! corpus of broken files.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use knitvox::geom::{Units, UpAxis, Vec3, YarnFrames, Yarns};
use knitvox::io::h5::{self, FrameWriter};
use knitvox::io::{self, ErrorClass, FormatError, IoError, Location, ReadOptions};
use proptest::prelude::*;

// ---------------------------------------------------------------------------
// helpers
// ---------------------------------------------------------------------------

fn sample_yarns() -> Yarns {
    let mut y = Yarns::new();
    y.push_curve(
        &[[0.0, 0.0, 0.0], [0.01, 0.002, -0.003], [0.02, 0.001, 0.0]],
        false,
        0.001,
    );
    y.push_curve(
        &[
            [0.1, 0.2, 0.3],
            [0.4, 0.5, 0.6],
            [0.7, 0.8, 0.9],
            [1.0, 1.1, 1.2],
        ],
        true,
        0.0015,
    );
    y
}

fn sample_frames(y: &Yarns, count: usize) -> YarnFrames {
    let mut fr = YarnFrames::new(y.num_points());
    for f in 0..count {
        let pts: Vec<Vec3> = y
            .points
            .iter()
            .map(|p| [p[0] + 0.1 * f as f64, p[1], p[2] - 1e-3 * f as f64])
            .collect();
        fr.push_frame(f as f64 / 30.0, &pts).unwrap();
    }
    fr
}

/// The checksum of tests/validators/h5_check.py: sum (i + 1) * bits(x_i) mod 2^64.
fn checksum_bits(bits: impl Iterator<Item = u64>) -> u64 {
    bits.enumerate().fold(0u64, |acc, (i, b)| {
        acc.wrapping_add(b.wrapping_mul(i as u64 + 1))
    })
}

fn checksum_f64(v: &[f64]) -> u64 {
    checksum_bits(v.iter().map(|x| x.to_bits()))
}

fn format_error(r: Result<io::Decoded, IoError>) -> FormatError {
    match r {
        Err(IoError::Format { source, .. }) => source,
        Err(other) => panic!("expected a format error, got {other}"),
        Ok(_) => panic!("expected a format error, the file was accepted"),
    }
}

fn path_loc(e: &FormatError) -> &str {
    match &e.location {
        Location::Path(p) => p,
        other => panic!("expected a dataset path location, got {other:?} ({e})"),
    }
}

fn python_h5py() -> bool {
    Command::new("python3")
        .args(["-c", "import h5py"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false)
}

// ---------------------------------------------------------------------------
// round trips
// ---------------------------------------------------------------------------

fn arb_yarns() -> impl Strategy<Value = (Yarns, Option<YarnFrames>)> {
    let coord = -1.0e3f64..1.0e3;
    let curve = (
        prop::collection::vec([coord.clone(), coord.clone(), coord], 2..12),
        any::<bool>(),
        1e-5f64..1e-2,
    );
    (
        prop::collection::vec(curve, 0..6),
        any::<bool>(),
        any::<bool>(),
        0usize..4,
        any::<bool>(),
        any::<u64>(),
    )
        .prop_map(
            |(curves, with_density, with_vertex_radius, nframes, with_frames, seed)| {
                let mut y = Yarns::new();
                for (pts, closed, r) in &curves {
                    y.push_curve(pts, *closed && pts.len() >= 3, *r);
                }
                if with_density {
                    y.linear_density = Some(
                        (0..y.num_curves())
                            .map(|c| 1e-3 * (c as f64 + 0.5))
                            .collect(),
                    );
                }
                if with_vertex_radius {
                    y.vertex_radius = Some(
                        (0..y.num_points())
                            .map(|v| 1e-4 + 1e-6 * v as f64)
                            .collect(),
                    );
                }
                let frames = with_frames.then(|| {
                    let mut fr = YarnFrames::new(y.num_points());
                    for f in 0..nframes {
                        // Values with every mantissa bit in use, to catch any lossy step.
                        let pts: Vec<Vec3> = y
                            .points
                            .iter()
                            .enumerate()
                            .map(|(i, p)| {
                                let k = (seed ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15))
                                    as f64
                                    / u64::MAX as f64;
                                [
                                    p[0] * 1.000_000_1 + k,
                                    p[1] - k / 3.0,
                                    p[2] + f as f64 * std::f64::consts::PI,
                                ]
                            })
                            .collect();
                        fr.push_frame(f as f64 * 0.041_666_666_666_666_664, &pts)
                            .unwrap();
                    }
                    fr
                });
                (y, frames)
            },
        )
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    #[test]
    fn round_trip_is_bit_identical((y, frames) in arb_yarns()) {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("rt.h5");
        h5::write_file(&p, &y, frames.as_ref()).unwrap();
        let d = h5::read_file(&p, &ReadOptions::default()).unwrap();
        prop_assert_eq!(&d.yarns.offsets, &y.offsets);
        prop_assert_eq!(&d.yarns.closed, &y.closed);
        let bits = |v: &[Vec3]| v.iter().flat_map(|p| p.map(f64::to_bits)).collect::<Vec<_>>();
        prop_assert_eq!(bits(&d.yarns.points), bits(&y.points));
        prop_assert_eq!(&d.yarns, &y);
        prop_assert_eq!(&d.frames, &frames);
        prop_assert!(d.radius_in_file);
        // The bytes decode to the same thing as the path.
        let d2 = h5::decode(&std::fs::read(&p).unwrap(), &ReadOptions::default()).unwrap();
        prop_assert_eq!(&d2, &d);
        if let Some(fr) = &frames {
            prop_assert_eq!(h5::frame_count(&p).unwrap(), fr.num_frames());
            if fr.num_frames() > 0 {
                let last = fr.num_frames() - 1;
                prop_assert_eq!(h5::read_frame(&p, last).unwrap(), fr.frame(last).to_vec());
            }
        }
    }
}

/// A file whose rest yarns repeat a point has its frames welded by the
/// rest yarns' map (their numbering follows the rest yarns'), even in a
/// frame that moved the repeat away.
#[test]
fn frames_are_welded_by_the_rest_yarns_map() {
    let dir = tempfile::tempdir().unwrap();
    let mut y = Yarns::new();
    let pts = [
        [0.0, 0.0, 0.0],
        [0.01, 0.0, 0.0],
        [0.01, 0.0, 0.0],
        [0.02, 0.0, 0.0],
    ];
    y.push_curve(&pts, false, 0.001);
    y.vertex_radius = Some(vec![1e-3, 2e-3, 3e-3, 4e-3]);
    let mut fr = YarnFrames::new(4);
    fr.push_frame(0.0, &pts).unwrap();
    let apart = [
        [0.0, 0.0, 0.0],
        [0.01, 0.0, 0.0],
        [0.015, 0.0, 0.0],
        [0.02, 0.0, 0.0],
    ];
    fr.push_frame(0.1, &apart).unwrap();
    let p = dir.path().join("dup.h5");
    h5::write_file(&p, &y, Some(&fr)).unwrap();
    let d = io::read_path(&p, &ReadOptions::default()).unwrap();
    assert_eq!(d.weld.welded_points, 1);
    assert_eq!(d.yarns.num_points(), 3);
    assert_eq!(
        d.yarns.vertex_radius.as_deref(),
        Some(&[1e-3, 2e-3, 4e-3][..])
    );
    let f = d.frames.unwrap();
    assert_eq!(f.num_vertices, 3);
    assert_eq!(f.frame(1), [apart[0], apart[1], apart[3]]);
}

#[test]
fn write_path_and_read_path_dispatch_to_hdf5() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("g.hdf5");
    let y = sample_yarns();
    let fr = sample_frames(&y, 2);
    let written = io::write_path(&p, &y, Some(&fr), &io::WriteOptions::default()).unwrap();
    assert_eq!(written, vec![p.clone()]);
    let data = io::read_path(&p, &ReadOptions::default()).unwrap();
    assert_eq!(data.yarns, y);
    assert_eq!(data.frames.unwrap(), fr);
    assert_eq!(data.units, (Units::METRES, io::Provenance::File));
    assert_eq!(data.up_axis, (UpAxis::Y, io::Provenance::File));
    assert_eq!(data.radius, io::Provenance::File);
    // Through the generic byte decoder too.
    let d = io::decode(
        io::Format::Hdf5,
        &std::fs::read(&p).unwrap(),
        &ReadOptions::default(),
        &io::NoResources,
    )
    .unwrap();
    assert_eq!(d.yarns, y);
}

#[test]
fn streamed_frames_equal_whole_file_frames() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (dir.path().join("whole.h5"), dir.path().join("streamed.h5"));
    let y = sample_yarns();
    let fr = sample_frames(&y, 5);
    h5::write_file(&a, &y, Some(&fr)).unwrap();
    let mut w = FrameWriter::create(&b, &y).unwrap();
    for f in 0..fr.num_frames() {
        w.push(fr.times[f], fr.frame(f)).unwrap();
    }
    w.finish().unwrap();
    let (da, db) = (
        h5::read_file(&a, &ReadOptions::default()).unwrap(),
        h5::read_file(&b, &ReadOptions::default()).unwrap(),
    );
    assert_eq!(da, db);
    for f in 0..5 {
        assert_eq!(h5::read_frame(&b, f).unwrap(), fr.frame(f));
    }
}

// ---------------------------------------------------------------------------
// on-disk layout
// ---------------------------------------------------------------------------

#[test]
fn frames_are_chunked_one_frame_per_chunk_with_shuffle_and_gzip() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("c.h5");
    let y = sample_yarns();
    let n = y.num_points();
    h5::write_file(&p, &y, Some(&sample_frames(&y, 3))).unwrap();

    let f = hdf5::File::open(&p).unwrap();
    let ds = f.dataset("frames/points").unwrap();
    assert_eq!(ds.shape(), vec![3, n, 3]);
    assert_eq!(ds.chunk(), Some(vec![1, n, 3]));
    assert_eq!(
        ds.filters(),
        vec![
            hdf5::filters::Filter::Shuffle,
            hdf5::filters::Filter::Deflate(h5::FRAME_DEFLATE_LEVEL)
        ]
    );
    assert!(ds.is_resizable());
    let yp = f.dataset("yarns/points").unwrap();
    assert_eq!(yp.shape(), vec![n, 3]);
    assert!(yp.dtype().unwrap().is::<f64>());
    assert!(f
        .dataset("yarns/offsets")
        .unwrap()
        .dtype()
        .unwrap()
        .is::<u64>());
    assert!(f
        .dataset("yarns/closed")
        .unwrap()
        .dtype()
        .unwrap()
        .is::<u8>());
    drop((ds, yp, f));

    // The generic inspection API sees the same.
    let list = h5::list_datasets(&p).unwrap();
    let fp = list
        .iter()
        .find(|d| d.path == "/frames/points")
        .expect("frames listed");
    assert_eq!(fp.chunks, Some(vec![1, n, 3]));
    assert_eq!(
        fp.filters,
        vec![
            "shuffle".to_string(),
            format!("gzip({})", h5::FRAME_DEFLATE_LEVEL)
        ]
    );
    assert_eq!(fp.dtype, "float64");
    let names: Vec<&str> = list.iter().map(|d| d.path.as_str()).collect();
    for want in [
        "/yarns/points",
        "/yarns/offsets",
        "/yarns/closed",
        "/yarns/radius",
        "/frames/times",
    ] {
        assert!(names.contains(&want), "{want} missing from {names:?}");
    }
}

#[test]
fn h5py_reads_what_knitvox_writes() {
    if !common::require_tool(python_h5py(), "python3 with h5py") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("py.h5");
    let mut y = sample_yarns();
    y.linear_density = Some(vec![2.5e-4, 3.0e-4]);
    let fr = sample_frames(&y, 3);
    h5::write_file(&p, &y, Some(&fr)).unwrap();

    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/validators/h5_check.py");
    let out = Command::new("python3")
        .arg(&script)
        .arg(&p)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "h5_check.py failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();

    assert_eq!(j["attrs"]["knitvox_format"], "yarns");
    assert_eq!(j["attrs"]["knitvox_format_version"], 1);
    assert_eq!(j["attrs"]["units"], "m");
    assert_eq!(j["attrs"]["up_axis"], "y");
    assert!(j["attrs"]["generator"]
        .as_str()
        .unwrap()
        .starts_with("knitvox "));

    let ds = &j["datasets"];
    let n = y.num_points() as u64;
    let shape = |name: &str| {
        ds[name]["shape"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_u64().unwrap())
            .collect::<Vec<_>>()
    };
    assert_eq!(shape("/yarns/points"), vec![n, 3]);
    assert_eq!(ds["/yarns/points"]["dtype"], "float64");
    assert_eq!(ds["/yarns/points"]["attrs"]["units"], "m");
    assert_eq!(shape("/yarns/offsets"), vec![3]);
    assert_eq!(ds["/yarns/offsets"]["dtype"], "uint64");
    assert_eq!(ds["/yarns/closed"]["dtype"], "uint8");
    assert_eq!(ds["/yarns/radius"]["dtype"], "float64");
    assert_eq!(ds["/yarns/linear_density"]["attrs"]["units"], "kg/m");
    assert_eq!(shape("/frames/points"), vec![3, n, 3]);
    assert_eq!(ds["/frames/points"]["chunks"], serde_json::json!([1, n, 3]));
    assert_eq!(ds["/frames/points"]["compression"], "gzip");
    assert_eq!(
        ds["/frames/points"]["compression_opts"],
        h5::FRAME_DEFLATE_LEVEL as u64
    );
    assert_eq!(ds["/frames/points"]["shuffle"], true);
    assert_eq!(ds["/frames/times"]["attrs"]["units"], "s");

    // Exact values, through IEEE bit patterns.
    let sum = |name: &str| ds[name]["checksum"].as_u64().unwrap();
    assert_eq!(sum("/yarns/points"), checksum_f64(y.points.as_flattened()));
    assert_eq!(
        sum("/frames/points"),
        checksum_f64(fr.points.as_flattened())
    );
    assert_eq!(sum("/frames/times"), checksum_f64(&fr.times));
    assert_eq!(sum("/yarns/radius"), checksum_f64(&y.radius));
    assert_eq!(
        sum("/yarns/linear_density"),
        checksum_f64(y.linear_density.as_ref().unwrap())
    );
    assert_eq!(
        sum("/yarns/offsets"),
        checksum_bits(y.offsets.iter().map(|&o| o as u64))
    );
    assert_eq!(
        sum("/yarns/closed"),
        checksum_bits(y.closed.iter().map(|&c| c as u64))
    );
    let first: Vec<u64> = ds["/yarns/points"]["first_bits"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64().unwrap())
        .collect();
    let want: Vec<u64> = y.points.as_flattened()[..6]
        .iter()
        .map(|x| x.to_bits())
        .collect();
    assert_eq!(first, want);
}

/// A yarns file written by h5py the way another tool would: centimetres,
/// Z up, h5py booleans for `closed`, int32 offsets, float32 points, no
/// knitvox attributes except units/up_axis, no radius.
#[test]
fn file_from_h5py_in_other_units_is_converted() {
    if !common::require_tool(python_h5py(), "python3 with h5py") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("foreign.h5");
    let script = r#"
import sys, h5py, numpy as np
with h5py.File(sys.argv[1], "w") as f:
    f.attrs["units"] = "cm"
    f.attrs["up_axis"] = "z"
    g = f.create_group("yarns")
    g["points"] = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 0, 5], [0, 0, 6]], dtype="f4")
    g["offsets"] = np.array([0, 3, 5], dtype="i4")
    g["closed"] = np.array([True, False])
"#;
    let out = Command::new("python3")
        .args(["-c", script])
        .arg(&p)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let d = h5::read_file(&p, &ReadOptions::default()).unwrap();
    assert_eq!(d.units, Some(Units::CENTIMETRES));
    assert_eq!(d.up_axis, Some(UpAxis::Z));
    assert_eq!(d.yarns.closed, vec![true, false]);
    assert!(!d.radius_in_file);
    let data = io::read_path(&p, &ReadOptions::default()).unwrap();
    // (0, 0, 5) cm, Z up -> (0, 0.05, 0) m, Y up.
    let q = data.yarns.points[3];
    assert!(
        (q[1] - 0.05).abs() < 1e-12 && q[0] == 0.0 && q[2].abs() < 1e-12,
        "{q:?}"
    );
    assert_eq!(data.radius, io::Provenance::Assumed);
}

// ---------------------------------------------------------------------------
// files written by other HDF5 writers
// ---------------------------------------------------------------------------

fn arange(n: usize) -> Vec<f64> {
    (0..n).map(|i| i as f64).collect()
}

fn assert_arange(file: &Path, name: &str, shape: &[usize]) {
    let (s, v) = h5::read_dataset_f64(file, name).unwrap_or_else(|e| panic!("{name}: {e}"));
    assert_eq!(s, shape, "{}:{name}", file.display());
    assert_eq!(
        v,
        arange(shape.iter().product()),
        "{}:{name}",
        file.display()
    );
}

fn external(name: &str) -> Option<PathBuf> {
    let dir = common::external_data("hdf5")?;
    Some(dir.join(name))
}

#[test]
fn every_external_hdf5_file_is_listed_and_is_not_yarns() {
    let Some(dir) = common::external_data("hdf5") else {
        return;
    };
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| matches!(p.extension().and_then(|e| e.to_str()), Some("h5" | "hdf5")))
        .collect();
    files.sort();
    assert!(
        files.len() >= 9,
        "expected the hdf5 corpus, found {files:?}"
    );
    for f in &files {
        let is_write_flagged =
            f.file_name().unwrap() == "jhdf_test_byteshuffle_compressed_datasets_latest.hdf5";
        let listed = h5::list_datasets(f);
        let read = h5::read_file(f, &ReadOptions::default());
        if is_write_flagged {
            for e in [listed.unwrap_err(), read.unwrap_err()] {
                assert!(matches!(e, IoError::Busy { .. }), "{}: {e}", f.display());
                assert_eq!(e.class(), ErrorClass::Transient);
                let msg = e.to_string();
                assert!(
                    msg.contains("open for write") && msg.contains("h5clear -s"),
                    "{msg}"
                );
            }
            // From bytes: a format error saying the same.
            let e = h5::decode(&std::fs::read(f).unwrap(), &ReadOptions::default()).unwrap_err();
            assert!(e.message.contains("open for write"), "{e}");
            continue;
        }
        let list = listed.unwrap_or_else(|e| panic!("{}: {e}", f.display()));
        assert!(!list.is_empty(), "{}: no datasets", f.display());
        // Every numeric dataset reads (or fails cleanly, e.g. lzf is not built in).
        for d in &list {
            match h5::read_dataset_f64(f, &d.path) {
                Ok((shape, v)) => {
                    assert!(d.numeric);
                    assert_eq!(shape, d.shape);
                    assert_eq!(v.len(), shape.iter().product::<usize>());
                }
                Err(e) => {
                    assert!(matches!(e, IoError::Format { .. }), "{e}");
                    assert!(
                        !d.numeric || d.filters.iter().any(|f| f == "lzf"),
                        "{}: {}: {e}",
                        f.display(),
                        d.path
                    );
                }
            }
        }
        let e = format_error(read);
        assert!(
            e.message.contains("not a knitvox yarns file"),
            "{}: {e}",
            f.display()
        );
        assert!(e.message.contains("top level holds"), "{e}");
        // Same from bytes.
        let e = h5::decode(&std::fs::read(f).unwrap(), &ReadOptions::default()).unwrap_err();
        assert!(e.message.contains("not a knitvox yarns file"), "{e}");
    }
}

#[test]
fn jhdf_compressed_and_shuffled_datasets_hold_their_arange() {
    for name in [
        "jhdf_test_compressed_chunked_datasets_earliest.hdf5",
        "jhdf_test_compressed_chunked_datasets_latest.hdf5",
        "jhdf_test_byteshuffle_compressed_datasets_earliest.hdf5",
    ] {
        let Some(f) = external(name) else { return };
        for ds in [
            "/float/float32",
            "/float/float64",
            "/int/int8",
            "/int/int16",
            "/int/int32",
        ] {
            assert_arange(&f, ds, &[7, 5]);
        }
    }
    let Some(f) = external("jhdf_test_byteshuffle_compressed_datasets_earliest.hdf5") else {
        return;
    };
    let list = h5::list_datasets(&f).unwrap();
    let d = list.iter().find(|d| d.path == "/int/int32").unwrap();
    assert_eq!(d.chunks, Some(vec![1, 3]));
    assert_eq!(
        d.filters,
        vec!["shuffle".to_string(), "gzip(7)".to_string()]
    );
    assert_eq!(d.dtype, "int32");
    // lzf is a plugin filter: its arange where the plugin is installed, else an
    // error naming the dataset (never a crash).
    let Some(f) = external("jhdf_test_compressed_chunked_datasets_latest.hdf5") else {
        return;
    };
    match h5::read_dataset_f64(&f, "/float/float32lzf") {
        Ok((shape, v)) => assert_eq!((shape, v), (vec![7, 5], arange(35))),
        Err(e) => assert!(e.to_string().contains("/float/float32lzf"), "{e}"),
    }
}

#[test]
fn jhdf_chunked_datasets_hold_their_arange() {
    let Some(f) = external("jhdf_test_chunked_datasets_latest.hdf5") else {
        return;
    };
    for ds in [
        "/float/float16",
        "/float/float32",
        "/float/float64",
        "/int/int8",
        "/int/int16",
        "/int/int32",
    ] {
        assert_arange(&f, ds, &[7, 5, 3]);
    }
    assert_arange(&f, "/int/large_int8", &[100]);
    let list = h5::list_datasets(&f).unwrap();
    assert_eq!(
        list.iter()
            .find(|d| d.path == "/float/float16")
            .unwrap()
            .dtype,
        "float16"
    );
}

#[test]
fn jhdf_v4_chunk_indexes_hold_their_arange() {
    let Some(f) = external("jhdf_chunked_v4_datasets.hdf5") else {
        return;
    };
    for group in [
        "single_chunk",
        "filtered_single_chunk",
        "fixed_array",
        "filtered_fixed_array",
        "extensible_array",
        "filtered_extensible_array",
        "btree_v2",
        "filtered_btree_v2",
    ] {
        for ds in ["int8", "int16", "int32", "float32", "float64"] {
            assert_arange(&f, &format!("/{group}/{ds}"), &[5, 3]);
        }
        // Strings are listed but are not numbers.
        let e = h5::read_dataset_f64(&f, &format!("/{group}/string")).unwrap_err();
        assert!(e.to_string().contains("not numeric"), "{e}");
    }
    for group in [
        "extensible_array",
        "filtered_extensible_array",
        "btree_v2",
        "filtered_btree_v2",
    ] {
        assert_arange(&f, &format!("/{group}/large_int16"), &[200, 5, 10]);
    }
    let e = h5::read_dataset_f64(&f, "/no/such/dataset").unwrap_err();
    assert!(e.to_string().contains("no such dataset"), "{e}");
}

#[test]
fn pyfive_datasets_hold_their_arange() {
    let Some(f) = external("pyfive_chunked.hdf5") else {
        return;
    };
    assert_arange(&f, "dataset1", &[21, 16]);
    let Some(f) = external("pyfive_compressed.hdf5") else {
        return;
    };
    for ds in ["dataset1", "dataset2", "dataset3"] {
        assert_arange(&f, ds, &[21, 16]);
    }
    let list = h5::list_datasets(&f).unwrap();
    let d2 = list.iter().find(|d| d.path == "/dataset2").unwrap();
    assert_eq!(d2.chunks, Some(vec![4, 4]));
    assert!(
        d2.filters.contains(&"shuffle".to_string())
            && d2.filters.iter().any(|f| f.starts_with("gzip"))
    );
    assert_eq!(
        list.iter().find(|d| d.path == "/dataset1").unwrap().dtype,
        "uint16"
    );
}

#[test]
fn openpmd_simulation_output_is_inspectable() {
    let Some(f) = external("openpmd_example-femm-thetaMode.h5") else {
        return;
    };
    let list = h5::list_datasets(&f).unwrap();
    let numeric: Vec<_> = list
        .iter()
        .filter(|d| d.numeric && !d.shape.is_empty())
        .collect();
    assert!(!numeric.is_empty(), "{list:?}");
    for d in numeric {
        let (shape, v) = h5::read_dataset_f64(&f, &d.path).unwrap();
        assert_eq!(v.len(), shape.iter().product::<usize>());
        assert!(v.iter().all(|x| x.is_finite()), "{}", d.path);
    }
}

// ---------------------------------------------------------------------------
// busy files
// ---------------------------------------------------------------------------

#[test]
fn file_with_write_flag_from_a_dead_writer_is_busy() {
    if !common::require_tool(python_h5py(), "python3 with h5py") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("crashed.h5");
    // A writer that dies without closing: the superblock's write flag stays set.
    let script = "import sys, os, h5py\nf = h5py.File(sys.argv[1], 'w', libver='latest')\nf['yarns/points'] = [[0.0, 0, 0]]\nf.flush()\nos._exit(0)\n";
    let out = Command::new("python3")
        .args(["-c", script])
        .arg(&p)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let e = h5::read_file(&p, &ReadOptions::default()).unwrap_err();
    assert!(matches!(e, IoError::Busy { .. }), "{e}");
    assert!(e.to_string().contains("h5clear -s"), "{e}");
    let e = io::read_path(&p, &ReadOptions::default()).unwrap_err();
    assert_eq!(e.class(), ErrorClass::Transient, "{e}");
}

#[test]
fn file_locked_by_another_process_is_busy() {
    let flock_ok = Command::new("flock")
        .arg("--version")
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if !common::require_tool(flock_ok, "flock (util-linux)") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("locked.h5");
    h5::write_file(&p, &sample_yarns(), None).unwrap();
    // libhdf5 takes flock(2) locks; hold an exclusive one from another process.
    // `cat` holds the lock until its stdin closes, so dropping the pipe ends it cleanly.
    let mut child = Command::new("flock")
        .arg("-x")
        .arg(&p)
        .arg("cat")
        .stdin(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let start = std::time::Instant::now();
    let result = loop {
        match h5::read_file(&p, &ReadOptions::default()) {
            Err(e @ IoError::Busy { .. }) => break Ok(e),
            other if start.elapsed() > std::time::Duration::from_secs(10) => break Err(other),
            _ => std::thread::sleep(std::time::Duration::from_millis(20)),
        }
    };
    drop(child.stdin.take());
    let _ = child.wait();
    let e = result.unwrap_or_else(|other| panic!("never saw Busy while locked: {other:?}"));
    assert!(e.to_string().contains("lock"), "{e}");
    assert_eq!(e.class(), ErrorClass::Transient);
    // Released: readable again.
    assert!(h5::read_file(&p, &ReadOptions::default()).is_ok());
}

// ---------------------------------------------------------------------------
// broken files
// ---------------------------------------------------------------------------

#[test]
fn empty_random_and_truncated_files_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    let o = ReadOptions::default();
    let p = dir.path().join("empty.h5");
    std::fs::write(&p, b"").unwrap();
    assert!(format_error(h5::read_file(&p, &o))
        .message
        .contains("empty"));
    assert!(matches!(h5::list_datasets(&p), Err(IoError::Format { .. })));

    // Random bytes, with and without the HDF5 signature in front.
    let mut state = 0x2545_F491_4F6C_DD1Du64;
    let mut rnd = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 24) as u8
    };
    for len in [1usize, 8, 100, 4096] {
        let noise: Vec<u8> = (0..len).map(|_| rnd()).collect();
        assert!(h5::decode(&noise, &o).is_err());
        let mut signed = b"\x89HDF\r\n\x1a\n".to_vec();
        signed.extend(&noise);
        assert!(h5::decode(&signed, &o).is_err());
        std::fs::write(&p, &signed).unwrap();
        assert!(matches!(h5::read_file(&p, &o), Err(IoError::Format { .. })));
    }

    // Every prefix of a real knitvox file (step 1 at the start, then sampled).
    let full = dir.path().join("full.h5");
    let y = sample_yarns();
    h5::write_file(&full, &y, Some(&sample_frames(&y, 2))).unwrap();
    let bytes = std::fs::read(&full).unwrap();
    assert!(h5::decode(&bytes, &o).is_ok());
    let mut lengths: Vec<usize> = (0..bytes.len().min(256)).collect();
    lengths.extend((256..bytes.len()).step_by(61));
    lengths.push(bytes.len() - 1);
    for len in lengths {
        let e = h5::decode(&bytes[..len], &o).expect_err("a truncated file must not decode");
        assert!(!e.message.is_empty());
    }
    std::fs::write(&p, &bytes[..bytes.len() / 2]).unwrap();
    let e = format_error(h5::read_file(&p, &o));
    assert!(e.message.contains("truncated"), "{e}");
}

#[test]
fn corrupted_bytes_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    let full = dir.path().join("full.h5");
    let y = sample_yarns();
    h5::write_file(&full, &y, Some(&sample_frames(&y, 2))).unwrap();
    let bytes = std::fs::read(&full).unwrap();
    let o = ReadOptions::default();
    let mut rejected = 0;
    for pos in 0..bytes.len() {
        let k = pos;
        let mut b = bytes.clone();
        b[pos] ^= 1 << (k % 8);
        // Ok (slack space, or raw data that no checksum covers) or Err; never a
        // panic, and never a layout that breaks the invariants.
        match h5::decode(&b, &o) {
            Ok(d) => {
                assert!(d.yarns.validate().is_ok(), "flip at byte {pos}");
                assert_eq!(
                    d.yarns.num_points(),
                    y.num_points(),
                    "flip at byte {pos}: checksummed shape changed"
                );
            }
            Err(e) => {
                assert!(!e.message.is_empty());
                rejected += 1;
            }
        }
    }
    // The metadata is checksummed (v1.10 object formats), so most flips are caught.
    assert!(rejected > 0);
}

/// Writes a file with hand-made datasets through the hdf5 crate.
struct Builder {
    path: PathBuf,
    file: hdf5::File,
}

impl Builder {
    fn new(dir: &Path, name: &str) -> Builder {
        let path = dir.join(name);
        let file = hdf5::File::create(&path).unwrap();
        Builder { path, file }
    }
    fn parent(&self, name: &str) {
        if let Some((g, _)) = name.rsplit_once('/') {
            if !self.file.link_exists(g) {
                self.file.create_group(g).unwrap();
            }
        }
    }
    fn f64s(self, name: &str, shape: &[usize], data: &[f64]) -> Self {
        self.parent(name);
        let ds = self
            .file
            .new_dataset::<f64>()
            .shape(shape)
            .create(name)
            .unwrap();
        if !data.is_empty() {
            ds.write_raw(data).unwrap();
        }
        self
    }
    fn ints<T: hdf5::H5Type + Copy>(self, name: &str, data: &[T]) -> Self {
        self.parent(name);
        let ds = self
            .file
            .new_dataset::<T>()
            .shape([data.len()])
            .create(name)
            .unwrap();
        if !data.is_empty() {
            ds.write_raw(data).unwrap();
        }
        self
    }
    fn str_attr(self, name: &str, value: &str) -> Self {
        let v: hdf5::types::VarLenUnicode = value.parse().unwrap();
        self.file
            .new_attr::<hdf5::types::VarLenUnicode>()
            .shape(())
            .create(name)
            .unwrap()
            .write_scalar(&v)
            .unwrap();
        self
    }
    fn int_attr(self, name: &str, value: i64) -> Self {
        self.file
            .new_attr::<i64>()
            .shape(())
            .create(name)
            .unwrap()
            .write_scalar(&value)
            .unwrap();
        self
    }
    fn done(self) -> PathBuf {
        self.file.close().unwrap();
        self.path
    }
}

const PTS5: [f64; 15] = [0., 0., 0., 1., 0., 0., 2., 0., 0., 0., 1., 0., 0., 2., 0.];

/// A valid 2-curve file (3 + 2 points), with `tweak` applied before closing.
fn valid(dir: &Path, name: &str, tweak: impl FnOnce(Builder) -> Builder) -> PathBuf {
    let b = Builder::new(dir, name);
    b.file.create_group("yarns").unwrap();
    tweak(b).done()
}

fn base(b: Builder) -> Builder {
    b.f64s("yarns/points", &[5, 3], &PTS5)
        .ints::<u64>("yarns/offsets", &[0, 3, 5])
        .ints::<u8>("yarns/closed", &[0, 1])
}

#[test]
fn hand_made_minimal_file_is_accepted() {
    let dir = tempfile::tempdir().unwrap();
    let p = valid(dir.path(), "ok.h5", base);
    let d = h5::read_file(&p, &ReadOptions::default()).unwrap();
    assert_eq!(d.yarns.offsets, vec![0, 3, 5]);
    assert_eq!(d.yarns.closed, vec![false, true]);
    assert!(!d.radius_in_file);
    assert_eq!(d.units, None);
    assert_eq!(d.yarns.radius, vec![io::DEFAULT_RADIUS_M; 2]);
}

#[test]
fn wrong_layouts_are_errors_naming_the_dataset() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let o = ReadOptions::default();
    type Tweak = Box<dyn FnOnce(Builder) -> Builder>;
    let cases: Vec<(&str, Tweak, &str, &str)> = vec![
        (
            "missing points",
            Box::new(|b: Builder| b.ints::<u64>("yarns/offsets", &[0, 3, 5])),
            "/yarns/points",
            "missing",
        ),
        (
            "points N x 2",
            Box::new(|b: Builder| {
                b.f64s("yarns/points", &[5, 2], &PTS5[..10])
                    .ints::<u64>("yarns/offsets", &[0, 5])
            }),
            "/yarns/points",
            "expected N x 3",
        ),
        (
            "points as integers",
            Box::new(|b: Builder| {
                b.ints::<i32>("yarns/points", &[0, 1, 2])
                    .ints::<u64>("yarns/offsets", &[0, 3])
            }),
            "/yarns/points",
            "shape",
        ),
        (
            "offsets not monotone",
            Box::new(|b: Builder| {
                b.f64s("yarns/points", &[5, 3], &PTS5)
                    .ints::<u64>("yarns/offsets", &[0, 4, 2])
                    .ints::<u8>("yarns/closed", &[0, 0])
            }),
            "/yarns/offsets",
            "decrease",
        ),
        (
            "offsets not ending at N",
            Box::new(|b: Builder| {
                b.f64s("yarns/points", &[5, 3], &PTS5)
                    .ints::<u64>("yarns/offsets", &[0, 2, 4])
            }),
            "/yarns/offsets",
            "expected the point count 5",
        ),
        (
            "offsets past N",
            Box::new(|b: Builder| {
                b.f64s("yarns/points", &[5, 3], &PTS5)
                    .ints::<u64>("yarns/offsets", &[0, 3, 9])
            }),
            "/yarns/offsets",
            "past the 5 points",
        ),
        (
            "offsets not starting at 0",
            Box::new(|b: Builder| {
                b.f64s("yarns/points", &[5, 3], &PTS5)
                    .ints::<u64>("yarns/offsets", &[1, 5])
            }),
            "/yarns/offsets",
            "must start at 0",
        ),
        (
            "negative offsets",
            Box::new(|b: Builder| {
                b.f64s("yarns/points", &[5, 3], &PTS5)
                    .ints::<i64>("yarns/offsets", &[0, -3, 5])
            }),
            "/yarns/offsets",
            "negative",
        ),
        (
            "float offsets",
            Box::new(|b: Builder| {
                b.f64s("yarns/points", &[5, 3], &PTS5)
                    .f64s("yarns/offsets", &[3], &[0., 3., 5.])
            }),
            "/yarns/offsets",
            "expected integers",
        ),
        (
            "curve with 1 point",
            Box::new(|b: Builder| {
                b.f64s("yarns/points", &[5, 3], &PTS5)
                    .ints::<u64>("yarns/offsets", &[0, 1, 5])
                    .ints::<u8>("yarns/closed", &[0, 0])
            }),
            "/yarns/offsets",
            "curve 0 has 1 point",
        ),
        (
            "more curves than points",
            Box::new(|b: Builder| {
                b.f64s("yarns/points", &[1, 3], &PTS5[..3])
                    .ints::<u64>("yarns/offsets", &[0, 0, 0, 1])
            }),
            "/yarns/offsets",
            "more curves than points",
        ),
        (
            "closed length mismatch",
            Box::new(|b: Builder| {
                b.f64s("yarns/points", &[5, 3], &PTS5)
                    .ints::<u64>("yarns/offsets", &[0, 3, 5])
                    .ints::<u8>("yarns/closed", &[0])
            }),
            "/yarns/closed",
            "one flag per curve",
        ),
        (
            "closed flag 7",
            Box::new(|b: Builder| {
                b.f64s("yarns/points", &[5, 3], &PTS5)
                    .ints::<u64>("yarns/offsets", &[0, 3, 5])
                    .ints::<u8>("yarns/closed", &[0, 7])
            }),
            "/yarns/closed",
            "curve 1: flag 7",
        ),
        (
            "NaN point",
            Box::new(|b: Builder| {
                let mut p = PTS5;
                p[10] = f64::NAN;
                b.f64s("yarns/points", &[5, 3], &p)
                    .ints::<u64>("yarns/offsets", &[0, 3, 5])
                    .ints::<u8>("yarns/closed", &[0, 1])
            }),
            "/yarns/points",
            "vertex 3 (curve 1, point 0)",
        ),
        (
            "infinite point",
            Box::new(|b: Builder| {
                let mut p = PTS5;
                p[0] = f64::NEG_INFINITY;
                b.f64s("yarns/points", &[5, 3], &p)
                    .ints::<u64>("yarns/offsets", &[0, 3, 5])
                    .ints::<u8>("yarns/closed", &[0, 1])
            }),
            "/yarns/points",
            "not finite",
        ),
        (
            "zero radius",
            Box::new(|b: Builder| base(b).f64s("yarns/radius", &[2], &[0.001, 0.0])),
            "/yarns/radius",
            "curve 1",
        ),
        (
            "radius length",
            Box::new(|b: Builder| base(b).f64s("yarns/radius", &[3], &[1., 1., 1.])),
            "/yarns/radius",
            "[2]",
        ),
        (
            "NaN vertex radius",
            Box::new(|b: Builder| {
                base(b).f64s("yarns/vertex_radius", &[5], &[1., 1., f64::NAN, 1., 1.])
            }),
            "/yarns/vertex_radius",
            "vertex 2",
        ),
        (
            "negative linear density",
            Box::new(|b: Builder| base(b).f64s("yarns/linear_density", &[2], &[1., -1.])),
            "/yarns/linear_density",
            "curve 1",
        ),
        (
            "frames with other N",
            Box::new(|b: Builder| {
                base(b).f64s("frames/points", &[1, 4, 3], &[0.0; 12]).f64s(
                    "frames/times",
                    &[1],
                    &[0.0],
                )
            }),
            "/frames/points",
            "4 vertices",
        ),
        (
            "frames without times",
            Box::new(|b: Builder| base(b).f64s("frames/points", &[1, 5, 3], &[0.0; 15])),
            "/frames/times",
            "missing",
        ),
        (
            "times length mismatch",
            Box::new(|b: Builder| {
                base(b).f64s("frames/points", &[2, 5, 3], &[0.0; 30]).f64s(
                    "frames/times",
                    &[1],
                    &[0.0],
                )
            }),
            "/frames/times",
            "one time per frame",
        ),
        (
            "NaN in a frame",
            Box::new(|b: Builder| {
                let mut v = [0.0; 30];
                v[29] = f64::NAN;
                base(b).f64s("frames/points", &[2, 5, 3], &v).f64s(
                    "frames/times",
                    &[2],
                    &[0.0, 1.0],
                )
            }),
            "/frames/points",
            "frame 1, vertex 4",
        ),
        (
            "NaN time",
            Box::new(|b: Builder| {
                base(b).f64s("frames/points", &[1, 5, 3], &[0.0; 15]).f64s(
                    "frames/times",
                    &[1],
                    &[f64::NAN],
                )
            }),
            "/frames/times",
            "frame 0",
        ),
        (
            "unknown units",
            Box::new(|b: Builder| base(b).str_attr("units", "furlong")),
            "/@units",
            "furlong",
        ),
        (
            "unknown up axis",
            Box::new(|b: Builder| base(b).str_attr("up_axis", "w")),
            "/@up_axis",
            "up axis",
        ),
        (
            "newer version",
            Box::new(|b: Builder| base(b).int_attr("knitvox_format_version", 2)),
            "/@knitvox_format_version",
            "version 2",
        ),
        (
            "other knitvox kind",
            Box::new(|b: Builder| base(b).str_attr("knitvox_format", "tets")),
            "/@knitvox_format",
            "'tets'",
        ),
        (
            "version as string",
            Box::new(|b: Builder| base(b).str_attr("knitvox_format_version", "1")),
            "/@knitvox_format_version",
            "integer",
        ),
    ];
    for (i, (what, tweak, loc, needle)) in cases.into_iter().enumerate() {
        let p = valid(d, &format!("case{i}.h5"), tweak);
        let e = format_error(h5::read_file(&p, &o));
        assert_eq!(path_loc(&e), loc, "{what}: {e}");
        assert!(
            e.message.contains(needle),
            "{what}: '{e}' should mention '{needle}'"
        );
        // Same answer from the bytes.
        let e2 = h5::decode(&std::fs::read(&p).unwrap(), &o).unwrap_err();
        assert_eq!(e2, e, "{what}");
    }

    // /yarns that is a dataset, not a group.
    let b = Builder::new(d, "yarns-dataset.h5").f64s("yarns", &[1], &[0.0]);
    let e = format_error(h5::read_file(&b.done(), &o));
    assert_eq!(path_loc(&e), "/yarns");
    // No /yarns: lists what is there.
    let b = Builder::new(d, "other.h5").f64s("temperature", &[2], &[1.0, 2.0]);
    b.file.create_group("mesh").unwrap();
    let e = format_error(h5::read_file(&b.done(), &o));
    assert_eq!(e.location, Location::File);
    assert!(e.message.contains("not a knitvox yarns file"), "{e}");
    assert!(
        e.message.contains("dataset /temperature") && e.message.contains("group /mesh"),
        "{e}"
    );
    let e = format_error(h5::read_file(&Builder::new(d, "void.h5").done(), &o));
    assert!(e.message.contains("no groups or datasets"), "{e}");
}

#[test]
fn max_points_guards_points_and_frames() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("g.h5");
    let y = sample_yarns(); // 7 points
    h5::write_file(&p, &y, Some(&sample_frames(&y, 3))).unwrap();
    let small = ReadOptions {
        max_points: 6,
        ..ReadOptions::default()
    };
    let e = format_error(h5::read_file(&p, &small));
    assert_eq!(path_loc(&e), "/yarns/points");
    assert!(e.message.contains("limit of 6"), "{e}");
    // 7 points pass, 3 x 7 frame positions do not.
    let mid = ReadOptions {
        max_points: 20,
        ..ReadOptions::default()
    };
    let e = format_error(h5::read_file(&p, &mid));
    assert_eq!(path_loc(&e), "/frames/points");
    assert!(e.message.contains("3 frames x 7 vertices"), "{e}");
    assert!(h5::read_file(
        &p,
        &ReadOptions {
            max_points: 21,
            ..ReadOptions::default()
        }
    )
    .is_ok());
}

#[test]
fn missing_file_and_directory_are_read_errors() {
    let dir = tempfile::tempdir().unwrap();
    let e = h5::read_file(&dir.path().join("nope.h5"), &ReadOptions::default()).unwrap_err();
    assert!(matches!(e, IoError::Read { .. }));
    assert_eq!(e.class(), ErrorClass::MissingInput);
    // A directory is refused before libhdf5 sees it.
    assert!(matches!(
        h5::list_datasets(dir.path()),
        Err(IoError::NotRegular { .. })
    ));
}

#[test]
fn big_garment_writes_and_reads_quickly() {
    // The size of the tea cozy: 22 closed curves, 184,159 points.
    let mut y = Yarns::new();
    let per = 184_159 / 22;
    for c in 0..22 {
        let count = if c == 21 { 184_159 - per * 21 } else { per };
        let pts: Vec<Vec3> = (0..count)
            .map(|i| {
                [
                    i as f64 * 1e-4,
                    c as f64 * 1e-3,
                    (i as f64 * 0.01).sin() * 1e-3,
                ]
            })
            .collect();
        y.push_curve(&pts, true, 8e-4);
    }
    assert_eq!(y.num_points(), 184_159);
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("big.h5");
    let t = std::time::Instant::now();
    h5::write_file(&p, &y, None).unwrap();
    let d = h5::read_file(&p, &ReadOptions::default()).unwrap();
    let elapsed = t.elapsed();
    assert_eq!(d.yarns, y);
    eprintln!("write + read of 184,159 points: {elapsed:?}");
    // Generous for unoptimised test builds; release is far below (see the schema doc).
    assert!(elapsed < std::time::Duration::from_secs(3), "{elapsed:?}");

    // Streaming frames of that size (gzip): report the rate, check one back.
    let q = dir.path().join("frames.h5");
    let t = std::time::Instant::now();
    let mut w = FrameWriter::create(&q, &y).unwrap();
    for f in 0..3 {
        let moved: Vec<Vec3> = y
            .points
            .iter()
            .map(|p| [p[0], p[1] + f as f64 * 1e-3, p[2]])
            .collect();
        w.push(f as f64, &moved).unwrap();
    }
    w.finish().unwrap();
    eprintln!("3 streamed frames of 184,159 points: {:?}", t.elapsed());
    let t = std::time::Instant::now();
    let f2 = h5::read_frame(&q, 2).unwrap();
    eprintln!("read_frame of one frame: {:?}", t.elapsed());
    assert_eq!(
        f2[5],
        [y.points[5][0], y.points[5][1] + 2e-3, y.points[5][2]]
    );
}

/// A child process spawned while knitvox writes an HDF5 file inherits
/// libhdf5's descriptor (no O_CLOEXEC). With a lock on that descriptor the
/// finished file would read as busy for the child's whole life; knitvox's
/// writes take no lock, so the file reads at once.
#[test]
fn child_spawned_during_a_write_does_not_lock_the_output() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("spawned.h5");
    let y = sample_yarns();
    let mut w = FrameWriter::create(&path, &y).unwrap();
    w.push(0.0, &y.points).unwrap();
    let mut child = Command::new("sleep").arg("5").spawn().expect("spawn sleep");
    w.finish().unwrap();
    let read = io::read_path(&path, &ReadOptions::default());
    let _ = child.kill();
    let _ = child.wait();
    let d = read.unwrap_or_else(|e| panic!("finished file unreadable while the child lives: {e}"));
    assert_eq!(d.frames.unwrap().num_frames(), 1);
}

#[test]
fn frame_writer_stores_metadata_text() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("meta.h5");
    let mut y = knitvox::geom::Yarns::new();
    y.push_curve(&[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], false, 0.01);
    let mut w = knitvox::io::h5::FrameWriter::create(&path, &y).unwrap();
    let scene = "name = \"stretch\" # 30 % — UTF-8\n";
    w.add_text("scene_toml", scene).unwrap();
    w.add_text("empty", "").unwrap();
    assert!(w.add_text("scene_toml", "again").is_err(), "duplicate name");
    assert!(w.add_text("../x", "bad").is_err(), "not an identifier");
    w.push(0.0, &y.points).unwrap();
    w.finish().unwrap();
    assert_eq!(
        knitvox::io::h5::read_text(&path, "scene_toml")
            .unwrap()
            .as_deref(),
        Some(scene)
    );
    assert_eq!(
        knitvox::io::h5::read_text(&path, "empty")
            .unwrap()
            .as_deref(),
        Some("")
    );
    assert_eq!(knitvox::io::h5::read_text(&path, "missing").unwrap(), None);
    // The yarn reader ignores the extra group.
    let back = knitvox::io::read_path(&path, &Default::default()).unwrap();
    assert_eq!(back.yarns.num_points(), 2);
}
