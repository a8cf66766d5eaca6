//! glTF 2.0 / GLB yarn curves: reference files from Khronos and the glTF
//! asset generator, round trips, a corpus of broken files, and the Khronos
//! glTF-Validator on what knitvox writes.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use base64::Engine;
use knitvox::geom::{Units, UpAxis, Yarns};
use knitvox::io::{
    self, decode, read_path, write_path, DirResources, Format, FormatError, Location, NoResources,
    Provenance, ReadOptions, WriteOptions,
};
use proptest::prelude::*;
use serde_json::{json, Value};

const B64: base64::engine::GeneralPurpose = base64::engine::general_purpose::STANDARD;

fn opts() -> ReadOptions {
    ReadOptions::default()
}

// ---------------------------------------------------------------------------
// Reference files
// ---------------------------------------------------------------------------

/// Khronos MeshPrimitiveModes: seven meshes over one 7-vertex hexagon fan
/// (centre + 6 rim vertices), one per mode 0..6, each on its own node.
/// From the JSON: LINES indices [0,1, 0,2, 0,3, 0,4, 0,5, 0,6] on a node at
/// (-2,0,0): consecutive segments never continue each other (each starts at
/// the centre), so six open 2-point spokes. LINE_LOOP indices 0..6 at the
/// origin: one closed 7-point curve. LINE_STRIP indices 0..6 at (2,0,0): one
/// open 7-point curve (6 != 0). POINTS and the three triangle modes are skipped.
#[test]
fn khronos_mesh_primitive_modes() {
    let Some(dir) = common::external_data("anim") else {
        return;
    };
    let path = dir.join("Khronos_MeshPrimitiveModes_glTF-Embedded.gltf");
    let data = std::fs::read(&path).unwrap();
    let d = decode(Format::Gltf, &data, &opts(), &NoResources).unwrap();
    let y = &d.yarns;
    assert_eq!(y.num_curves(), 8);
    let sizes: Vec<usize> = (0..8).map(|c| y.curve_range(c).len()).collect();
    assert_eq!(sizes, vec![2, 2, 2, 2, 2, 2, 7, 7]);
    assert_eq!(
        y.closed,
        vec![false, false, false, false, false, false, true, false]
    );
    let hex: [[f64; 3]; 7] = [
        [0.0, 0.0, 0.0],
        [0.866, -0.5, 0.0],
        [0.866, 0.5, 0.0],
        [0.0, 1.0, 0.0],
        [-0.866, 0.5, 0.0],
        [-0.866, -0.5, 0.0],
        [0.0, -1.0, 0.0],
    ];
    let close = |a: [f64; 3], b: [f64; 3]| (0..3).all(|k| (a[k] - b[k]).abs() < 1e-6);
    for k in 0..6 {
        let c = y.curve(k);
        assert!(
            close(c[0], [-2.0, 0.0, 0.0]),
            "spoke {k} starts at the centre: {:?}",
            c[0]
        );
        let rim = hex[k + 1];
        assert!(
            close(c[1], [rim[0] - 2.0, rim[1], rim[2]]),
            "spoke {k}: {:?}",
            c[1]
        );
    }
    for (i, p) in y.curve(6).iter().enumerate() {
        assert!(close(*p, hex[i]), "loop vertex {i}: {p:?}");
    }
    for (i, p) in y.curve(7).iter().enumerate() {
        assert!(
            close(*p, [hex[i][0] + 2.0, hex[i][1], hex[i][2]]),
            "strip vertex {i}: {p:?}"
        );
    }
    assert!(!d.radius_in_file);
    assert!(
        d.notes
            .iter()
            .any(|n| n.contains("1 POINTS") && n.contains("3 triangle")),
        "{:?}",
        d.notes
    );
    // The path API gives the same curves, with glTF's declared frame.
    let r = read_path(&path, &opts()).unwrap();
    assert_eq!(r.units, (Units::METRES, Provenance::File));
    assert_eq!(r.up_axis, (UpAxis::Y, Provenance::File));
    assert!(r.yarns.same_topology(y));
}

/// glTF-Asset-Generator Mesh_PrimitiveMode: the README's figure is one quad
/// outline; positions from the .bin files are A=(0.5,-0.5), B=(-0.5,-0.5),
/// C=(-0.5,0.5), D=(0.5,0.3) (z = 0).
/// * 01 LINES, no indices: 8 vertices A B, B C, C D, D A -> segments continue
///   each other through repeated (bit-identical) vertices and the chain returns
///   to A: closed [A B C D].
/// * 02 LINE_LOOP, no indices: A D C B -> closed [A D C B].
/// * 03 LINE_STRIP, no indices: A D C B A -> ends where it started: closed [A D C B].
/// * 08 LINES, indices [0,3, 3,2, 2,1, 1,0] over [A B C D] -> closed [A D C B].
/// * 09 LINE_LOOP, indices [0,3,2,1] -> closed [A D C B].
/// * 10 LINE_STRIP, indices [0,3,2,1,0] -> ends on index 0 again: closed [A D C B].
#[test]
fn asset_generator_primitive_modes() {
    let Some(dir) = common::external_data("anim/asset_generator_Mesh_PrimitiveMode") else {
        return;
    };
    let a = [0.5, -0.5, 0.0];
    let b = [-0.5, -0.5, 0.0];
    let c = [-0.5, 0.5, 0.0];
    let d = [0.5, f64::from(0.3f32), 0.0];
    let cases: [(&str, [[f64; 3]; 4]); 6] = [
        ("01", [a, b, c, d]),
        ("02", [a, d, c, b]),
        ("03", [a, d, c, b]),
        ("08", [a, d, c, b]),
        ("09", [a, d, c, b]),
        ("10", [a, d, c, b]),
    ];
    for (num, expected) in cases {
        let path = dir.join(format!("Mesh_PrimitiveMode_{num}.gltf"));
        let r = read_path(&path, &opts()).unwrap_or_else(|e| panic!("{num}: {e}"));
        assert_eq!(r.yarns.num_curves(), 1, "{num}");
        assert_eq!(r.yarns.closed, vec![true], "{num}");
        assert_eq!(r.yarns.points, expected.to_vec(), "{num}");
        // The external .bin cannot be reached from bytes alone: the error names the buffer's uri.
        let e = decode(
            Format::Gltf,
            &std::fs::read(&path).unwrap(),
            &opts(),
            &NoResources,
        )
        .unwrap_err();
        assert_eq!(
            e.location,
            Location::Path("/buffers/0/uri".into()),
            "{num}: {e}"
        );
        assert!(
            e.message.contains(&format!("Mesh_PrimitiveMode_{num}.bin")),
            "{e}"
        );
    }
}

// ---------------------------------------------------------------------------
// Round trips
// ---------------------------------------------------------------------------

fn yarns_strategy() -> impl Strategy<Value = Yarns> {
    let curve = (
        prop::collection::vec(prop::array::uniform3(-10.0f64..10.0), 2..20),
        any::<bool>(),
        1e-4f64..1e-2,
    );
    (
        prop::collection::vec(curve, 1..8),
        any::<bool>(),
        any::<u64>(),
    )
        .prop_map(|(curves, per_vertex, seed)| {
            let mut y = Yarns::new();
            for (pts, closed, r) in curves {
                // A closed yarn needs 3 points (Yarns::validate).
                y.push_curve(&pts, closed && pts.len() >= 3, r);
            }
            if per_vertex {
                let mut s = seed;
                let vr = (0..y.num_points())
                    .map(|_| {
                        s = s
                            .wrapping_mul(6364136223846793005)
                            .wrapping_add(1442695040888963407);
                        1e-4 + (s >> 40) as f64 / (1u64 << 24) as f64 * 1e-2
                    })
                    .collect();
                y.vertex_radius = Some(vr);
            }
            y
        })
}

/// Positions within f32 precision of the bbox, identical structure, radii within f32.
fn assert_same(a: &Yarns, b: &Yarns) {
    assert_eq!(a.offsets, b.offsets);
    assert_eq!(a.closed, b.closed);
    let size = a.bounds().map_or(1.0, |bb| bb.diagonal()).max(1e-12);
    for (p, q) in a.points.iter().zip(&b.points) {
        for k in 0..3 {
            assert!((p[k] - q[k]).abs() <= 1e-6 * size, "{p:?} vs {q:?}");
        }
    }
    for v in 0..a.num_points() {
        let (ra, rb) = (a.radius_at(v), b.radius_at(v));
        assert!(
            (ra - rb).abs() <= 1e-6 * ra,
            "vertex {v}: radius {ra} vs {rb}"
        );
    }
    for c in 0..a.num_curves() {
        let ra =
            a.curve_range(c).map(|v| a.radius_at(v)).sum::<f64>() / a.curve_range(c).len() as f64;
        assert!(
            (ra - b.radius[c]).abs() <= 1e-6 * ra,
            "curve {c}: mean radius {ra} vs {}",
            b.radius[c]
        );
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn round_trip_gltf_and_glb(y in yarns_strategy()) {
        for format in [Format::Gltf, Format::Glb] {
            let bytes = io::encode(format, &y, &WriteOptions::default()).unwrap();
            let d = decode(format, &bytes, &opts(), &NoResources).unwrap();
            prop_assert!(d.radius_in_file);
            let back = io::finish(format, d, &opts()).unwrap();
            assert_same(&y, &back.yarns);
        }
    }
}

/// The path API writes atomically and reads back with glTF's declared frame,
/// or with units the caller forces.
#[test]
fn path_api_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let y = mixed_yarns();
    for name in ["y.gltf", "y.glb"] {
        let p = dir.path().join(name);
        assert_eq!(
            write_path(&p, &y, None, &WriteOptions::default()).unwrap(),
            vec![p.clone()]
        );
        let r = read_path(&p, &opts()).unwrap();
        assert_eq!(r.units, (Units::METRES, Provenance::File));
        assert_eq!(r.up_axis, (UpAxis::Y, Provenance::File));
        assert_eq!(r.radius, Provenance::File);
        assert_same(&y, &r.yarns);
        // Caller overrides: centimetres and +Z up are applied on top of the file's numbers.
        let o = ReadOptions {
            units: Some(Units::CENTIMETRES),
            up_axis: Some(UpAxis::Z),
            ..opts()
        };
        let r = read_path(&p, &o).unwrap();
        assert_eq!(r.units, (Units::CENTIMETRES, Provenance::Option));
        let p0 = y.points[1];
        let q = r.yarns.points[1];
        let want = [p0[0] * 0.01, p0[2] * 0.01, -p0[1] * 0.01];
        for k in 0..3 {
            assert!((q[k] - want[k]).abs() < 1e-8, "{q:?} vs {want:?}");
        }
        assert!((r.yarns.radius[0] - y.radius[0] * 0.01).abs() < 1e-9);
    }
}

fn mixed_yarns() -> Yarns {
    let mut y = Yarns::new();
    let ring: Vec<[f64; 3]> = (0..12)
        .map(|i| {
            let t = i as f64 / 12.0 * std::f64::consts::TAU;
            [0.05 * t.cos(), 0.01 * i as f64, 0.05 * t.sin()]
        })
        .collect();
    y.push_curve(&ring, true, 0.0008);
    y.push_curve(
        &[[0.0, 0.0, 0.0], [0.01, 0.002, 0.0], [0.02, 0.0, 0.001]],
        false,
        0.001,
    );
    y.push_curve(
        &[[0.1, 0.1, 0.1], [0.2, 0.1, 0.1], [0.2, 0.2, 0.1]],
        true,
        0.0012,
    );
    // An open yarn whose ends coincide stays open (its strip never repeats an index).
    y.push_curve(
        &[
            [0.3, 0.0, 0.0],
            [0.4, 0.0, 0.0],
            [0.35, 0.05, 0.0],
            [0.3, 0.0, 0.0],
        ],
        false,
        0.001,
    );
    y
}

#[test]
fn coincident_ends_and_per_vertex_radius_survive() {
    let mut y = mixed_yarns();
    y.vertex_radius = Some(
        (0..y.num_points())
            .map(|v| 0.001 + v as f64 * 1e-5)
            .collect(),
    );
    for format in [Format::Gltf, Format::Glb] {
        let bytes = io::encode(format, &y, &WriteOptions::default()).unwrap();
        let d = decode(format, &bytes, &opts(), &NoResources).unwrap();
        assert_eq!(d.yarns.closed, vec![true, false, true, false]);
        assert!(d.yarns.vertex_radius.is_some());
        assert_same(&y, &d.yarns);
    }
}

// ---------------------------------------------------------------------------
// Broken files
// ---------------------------------------------------------------------------

fn small_yarns() -> Yarns {
    let mut y = Yarns::new();
    y.push_curve(
        &[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0]],
        false,
        0.01,
    );
    y.push_curve(
        &[[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [1.0, 1.0, 1.0]],
        true,
        0.02,
    );
    y
}

/// A valid .gltf as JSON plus its decoded buffer, to be broken and re-assembled.
fn parts() -> (Value, Vec<u8>) {
    let bytes = knitvox::io::gltf::encode(&small_yarns(), false).unwrap();
    let v: Value = serde_json::from_slice(&bytes).unwrap();
    let uri = v["buffers"][0]["uri"].as_str().unwrap();
    let bin = B64.decode(uri.split_once(',').unwrap().1).unwrap();
    (v, bin)
}

fn assemble(mut v: Value, bin: &[u8]) -> Vec<u8> {
    v["buffers"][0]["uri"] = json!(format!(
        "data:application/octet-stream;base64,{}",
        B64.encode(bin)
    ));
    serde_json::to_vec(&v).unwrap()
}

fn err(data: &[u8]) -> FormatError {
    match decode(Format::Gltf, data, &opts(), &NoResources) {
        Ok(d) => panic!("expected an error, decoded {} curves", d.yarns.num_curves()),
        Err(e) => e,
    }
}

fn path_of(e: &FormatError) -> &str {
    match &e.location {
        Location::Path(p) => p,
        other => panic!("expected a JSON path location, got {other:?} ({e})"),
    }
}

#[test]
fn corpus_framing_and_text() {
    let glb = knitvox::io::gltf::encode(&small_yarns(), true).unwrap();
    let gltf = knitvox::io::gltf::encode(&small_yarns(), false).unwrap();
    assert!(decode(Format::Glb, &glb, &opts(), &NoResources).is_ok());

    // Empty file.
    let e = err(b"");
    assert!(e.message.contains("empty"), "{e}");

    // Every prefix of the GLB and of the JSON (sampled) fails cleanly.
    for n in 0..glb.len() {
        let e = decode(Format::Glb, &glb[..n], &opts(), &NoResources).unwrap_err();
        assert!(!e.message.is_empty());
        if n >= 12 {
            assert_eq!(
                e.location,
                Location::Byte(8),
                "prefix {n}: the header length no longer matches: {e}"
            );
        }
    }
    for n in (0..gltf.len()).step_by(7) {
        let e = decode(Format::Gltf, &gltf[..n], &opts(), &NoResources).unwrap_err();
        assert!(
            matches!(
                e.location,
                Location::Line(_) | Location::File | Location::Path(_)
            ),
            "{e}"
        );
    }

    // GLB header length larger than the file.
    let mut bad = glb.clone();
    bad[8..12].copy_from_slice(&(glb.len() as u32 * 2).to_le_bytes());
    let e = decode(Format::Glb, &bad, &opts(), &NoResources).unwrap_err();
    assert_eq!(e.location, Location::Byte(8));
    assert!(e.message.contains(&format!("{}", glb.len() * 2)), "{e}");

    // JSON chunk length 2^31 (header length kept consistent).
    let mut bad = glb.clone();
    bad[12..16].copy_from_slice(&(1u32 << 31).to_le_bytes());
    let e = decode(Format::Glb, &bad, &opts(), &NoResources).unwrap_err();
    assert_eq!(e.location, Location::Byte(20), "{e}");
    assert!(e.message.contains("2147483648"), "{e}");

    // BIN chunk length 2^31.
    let json_len = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    let bin_at = 20 + json_len;
    let mut bad = glb.clone();
    bad[bin_at..bin_at + 4].copy_from_slice(&(1u32 << 31).to_le_bytes());
    let e = decode(Format::Glb, &bad, &opts(), &NoResources).unwrap_err();
    assert_eq!(e.location, Location::Byte(bin_at as u64 + 8), "{e}");

    // Wrong GLB version, wrong first chunk type.
    let mut bad = glb.clone();
    bad[4] = 1;
    assert_eq!(
        decode(Format::Glb, &bad, &opts(), &NoResources)
            .unwrap_err()
            .location,
        Location::Byte(4)
    );
    let mut bad = glb.clone();
    bad[16..20].copy_from_slice(b"BIN\0");
    let e = decode(Format::Glb, &bad, &opts(), &NoResources).unwrap_err();
    assert_eq!(e.location, Location::Byte(16), "{e}");

    // Wrong magic: not GLB, so it must be JSON, which it is not.
    let mut bad = glb.clone();
    bad[..4].copy_from_slice(b"glTX");
    let e = decode(Format::Glb, &bad, &opts(), &NoResources).unwrap_err();
    assert!(matches!(e.location, Location::Line(1)), "{e}");

    // Non-UTF-8 JSON text and GLB JSON chunk.
    let mut bad = gltf.clone();
    bad.splice(1..1, [b'\n', 0xFF, 0xFE]);
    let e = err(&bad);
    assert_eq!(e.location, Location::Line(2), "{e}");
    assert!(e.message.contains("UTF-8"), "{e}");
    let mut bad = glb.clone();
    bad[21] = 0xFF;
    let e = decode(Format::Glb, &bad, &opts(), &NoResources).unwrap_err();
    assert_eq!(e.location, Location::Byte(21), "{e}");

    // JSON that is not glTF.
    let e = err(b"{\"asset\": 3}");
    assert_eq!(e.location, Location::Line(1));
    let e = err(b"{\"asset\": {\"version\": \"1.0\"}}");
    assert_eq!(path_of(&e), "/asset/version");
    let e = err(br#"{"asset": {"version": "2.0"}, "extensionsRequired": ["KHR_draco_mesh_compression"], "extensionsUsed": ["KHR_draco_mesh_compression"]}"#);
    assert_eq!(path_of(&e), "/extensionsRequired/0");
}

#[test]
fn corpus_accessors_and_buffers() {
    // Accessor count 2^60: over the point limit, and with no limit, over the bufferView.
    let (mut v, bin) = parts();
    v["accessors"][0]["count"] = json!(1u64 << 60);
    let bad = assemble(v, &bin);
    let e = err(&bad);
    assert_eq!(path_of(&e), "/accessors/0/count");
    assert!(e.message.contains("1152921504606846976"), "{e}");
    let unlimited = ReadOptions {
        max_points: u64::MAX,
        ..opts()
    };
    let e = decode(Format::Gltf, &bad, &unlimited, &NoResources).unwrap_err();
    assert_eq!(path_of(&e), "/accessors/0");
    assert!(
        e.message.contains("needs") && e.message.contains("bufferView 0 has"),
        "{e}"
    );

    // bufferView past the end of its buffer.
    let (mut v, bin) = parts();
    let last = v["bufferViews"][2]["byteOffset"].as_u64().unwrap();
    v["bufferViews"][2]["byteOffset"] = json!(last + 8);
    let e = err(&assemble(v, &bin));
    assert_eq!(path_of(&e), "/bufferViews/2");
    assert!(e.message.contains("past the end of buffer 0"), "{e}");

    // Buffer declares more bytes than its data holds.
    let (mut v, bin) = parts();
    v["buffers"][0]["byteLength"] = json!(bin.len() + 4);
    let e = err(&assemble(v, &bin));
    assert_eq!(path_of(&e), "/buffers/0/byteLength");

    // Index out of range (first index of the second curve).
    let (v, mut bin) = parts();
    let idx_at = v["bufferViews"][2]["byteOffset"].as_u64().unwrap() as usize;
    let idx1 = idx_at + v["accessors"][5]["byteOffset"].as_u64().unwrap() as usize;
    bin[idx1..idx1 + 4].copy_from_slice(&7u32.to_le_bytes());
    let e = err(&assemble(v, &bin));
    assert_eq!(path_of(&e), "/accessors/5");
    assert!(
        e.message.contains("index 7") && e.message.contains("3 vertices"),
        "{e}"
    );

    // NaN and infinite positions.
    for (x, name) in [(f32::NAN, "NaN"), (f32::INFINITY, "inf")] {
        let (v, mut bin) = parts();
        bin[16..20].copy_from_slice(&x.to_le_bytes()); // vertex 1, y
        let e = err(&assemble(v, &bin));
        assert_eq!(path_of(&e), "/accessors/0");
        assert!(
            e.message.contains("element 1 component 1") && e.message.contains(name),
            "{e}"
        );
    }

    // Non-positive radius.
    let (v, mut bin) = parts();
    let r_at = v["bufferViews"][1]["byteOffset"].as_u64().unwrap() as usize;
    bin[r_at..r_at + 4].copy_from_slice(&(-1.0f32).to_le_bytes());
    let e = err(&assemble(v, &bin));
    assert_eq!(path_of(&e), "/accessors/1");

    // Data URI with bad base64; a non-base64 data URI.
    let (mut v, _) = parts();
    v["buffers"][0]["uri"] = json!("data:application/octet-stream;base64,AAAA!!!!");
    let e = err(&serde_json::to_vec(&v).unwrap());
    assert_eq!(path_of(&e), "/buffers/0/uri");
    assert!(e.message.contains("base64"), "{e}");
    let (mut v, _) = parts();
    v["buffers"][0]["uri"] = json!("data:application/octet-stream,AAAA");
    assert_eq!(
        path_of(&err(&serde_json::to_vec(&v).unwrap())),
        "/buffers/0/uri"
    );

    // External URI that does not exist.
    let dir = tempfile::tempdir().unwrap();
    let (mut v, _) = parts();
    v["buffers"][0]["uri"] = json!("missing.bin");
    let e = decode(
        Format::Gltf,
        &serde_json::to_vec(&v).unwrap(),
        &opts(),
        &DirResources(dir.path().into()),
    )
    .unwrap_err();
    assert_eq!(path_of(&e), "/buffers/0/uri");
    assert!(e.message.contains("missing.bin"), "{e}");
    // ... and one that does.
    let (mut v, bin) = parts();
    std::fs::write(dir.path().join("ok.bin"), &bin).unwrap();
    v["buffers"][0]["uri"] = json!("ok.bin");
    let d = decode(
        Format::Gltf,
        &serde_json::to_vec(&v).unwrap(),
        &opts(),
        &DirResources(dir.path().into()),
    )
    .unwrap();
    assert_eq!(d.yarns.num_curves(), 2);

    // Positions of the wrong type: unsigned short VEC3, float VEC2, normalized.
    let (mut v, bin) = parts();
    v["accessors"][0]["componentType"] = json!(5123);
    let e = err(&assemble(v, &bin));
    assert_eq!(path_of(&e), "/accessors/0");
    assert!(
        e.message.contains("POSITION") && e.message.contains("float VEC3"),
        "{e}"
    );
    let (mut v, bin) = parts();
    v["accessors"][0]["type"] = json!("VEC2");
    assert_eq!(path_of(&err(&assemble(v, &bin))), "/accessors/0");
    // Float indices are refused too.
    let (mut v, bin) = parts();
    v["accessors"][2]["componentType"] = json!(5126);
    let e = err(&assemble(v, &bin));
    assert!(e.message.contains("indices"), "{e}");
    // Normalized integer radius.
    let (mut v, bin) = parts();
    v["accessors"][1]["componentType"] = json!(5121);
    v["accessors"][1]["normalized"] = json!(true);
    let e = err(&assemble(v, &bin));
    assert!(
        e.message.contains("_RADIUS") && e.message.contains("normalized"),
        "{e}"
    );

    // Stride smaller than the element.
    let (mut v, bin) = parts();
    v["bufferViews"][0]["byteStride"] = json!(8);
    assert_eq!(
        path_of(&err(&assemble(v, &bin))),
        "/bufferViews/0/byteStride"
    );

    // Accessor without a bufferView.
    let (mut v, bin) = parts();
    v["accessors"][0]
        .as_object_mut()
        .unwrap()
        .remove("bufferView");
    assert_eq!(path_of(&err(&assemble(v, &bin))), "/accessors/0");

    // References to things that do not exist.
    let (mut v, bin) = parts();
    v["meshes"][0]["primitives"][0]["attributes"]["POSITION"] = json!(99);
    let e = err(&assemble(v, &bin));
    assert_eq!(path_of(&e), "/meshes/0/primitives/0/attributes/POSITION");
    let (mut v, bin) = parts();
    v["scene"] = json!(4);
    assert_eq!(path_of(&err(&assemble(v, &bin))), "/scene");
}

#[test]
fn corpus_topology_and_scene_graph() {
    // A strip with one vertex: a curve needs two.
    let (mut v, bin) = parts();
    v["accessors"][2]["count"] = json!(1);
    let e = err(&assemble(v, &bin));
    assert_eq!(path_of(&e), "/meshes/0/primitives/0");
    assert!(e.message.contains("at least 2"), "{e}");

    // LINES with an odd vertex count.
    let (mut v, bin) = parts();
    v["meshes"][0]["primitives"][0]["mode"] = json!(1);
    let e = err(&assemble(v, &bin));
    assert_eq!(path_of(&e), "/meshes/0/primitives/0");
    assert!(e.message.contains("odd"), "{e}");

    // Unknown mode.
    let (mut v, bin) = parts();
    v["meshes"][0]["primitives"][0]["mode"] = json!(9);
    assert_eq!(
        path_of(&err(&assemble(v, &bin))),
        "/meshes/0/primitives/0/mode"
    );

    // Node hierarchy with a cycle, and a node with two parents.
    let (mut v, bin) = parts();
    v["nodes"] = json!([{ "mesh": 0, "children": [1] }, { "children": [0] }]);
    let e = err(&assemble(v, &bin));
    assert!(e.message.contains("cycle"), "{e}");
    let (mut v, bin) = parts();
    v["nodes"] = json!([{ "children": [1, 2] }, { "children": [2] }, { "mesh": 0 }]);
    assert!(err(&assemble(v, &bin)).message.contains("two parents"));

    // Matrix values that overflow f32 become infinite: refused with their place.
    let (mut v, bin) = parts();
    v["nodes"][0]["matrix"] = json!([1e39, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]);
    assert_eq!(path_of(&err(&assemble(v, &bin))), "/nodes/0/matrix/0");

    // Instancing beyond max_points.
    let (mut v, bin) = parts();
    v["nodes"] = json!([{ "mesh": 0 }, { "mesh": 0 }, { "mesh": 0 }]);
    v["scenes"][0]["nodes"] = json!([0, 1, 2]);
    let bad = assemble(v, &bin);
    let small = ReadOptions {
        max_points: 12,
        ..opts()
    };
    let e = decode(Format::Gltf, &bad, &small, &NoResources).unwrap_err();
    assert!(e.message.contains("more than 12 points"), "{e}");
    assert_eq!(
        decode(Format::Gltf, &bad, &opts(), &NoResources)
            .unwrap()
            .yarns
            .num_curves(),
        6
    );
}

/// A sparse accessor replaces chosen elements of its base data.
#[test]
fn sparse_positions_are_applied() {
    let (mut v, mut bin) = parts();
    let at = bin.len();
    bin.extend_from_slice(&1u32.to_le_bytes()); // sparse index: vertex 1
    for x in [5.0f32, 6.0, 7.0] {
        bin.extend_from_slice(&x.to_le_bytes());
    }
    v["buffers"][0]["byteLength"] = json!(bin.len());
    v["bufferViews"]
        .as_array_mut()
        .unwrap()
        .push(json!({ "buffer": 0, "byteOffset": at, "byteLength": 16 }));
    v["accessors"][0]["sparse"] = json!({
        "count": 1,
        "indices": { "bufferView": 3, "componentType": 5125 },
        "values": { "bufferView": 3, "byteOffset": 4 },
    });
    let d = decode(
        Format::Gltf,
        &assemble(v.clone(), &bin),
        &opts(),
        &NoResources,
    )
    .unwrap();
    assert_eq!(d.yarns.points[1], [5.0, 6.0, 7.0]);
    assert_eq!(d.yarns.points[0], [0.0, 0.0, 0.0]);
    // Sparse index past the accessor count.
    bin[at..at + 4].copy_from_slice(&3u32.to_le_bytes());
    let e = err(&assemble(v, &bin));
    assert_eq!(path_of(&e), "/accessors/0/sparse/indices");
}

/// Deterministic random byte damage to a valid GLB and .gltf: never a panic.
#[test]
fn corpus_random_damage_never_panics() {
    let glb = knitvox::io::gltf::encode(&small_yarns(), true).unwrap();
    let gltf = knitvox::io::gltf::encode(&small_yarns(), false).unwrap();
    let mut s: u64 = 0x9E37_79B9_7F4A_7C15;
    let mut next = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        s
    };
    let small = ReadOptions {
        max_points: 1 << 20,
        ..opts()
    };
    for base in [&glb, &gltf] {
        for _ in 0..2000 {
            let mut d = base.clone();
            for _ in 0..1 + next() % 4 {
                let i = (next() % d.len() as u64) as usize;
                d[i] = next() as u8;
            }
            let _ = decode(Format::Glb, &d, &small, &NoResources);
        }
    }
}

// ---------------------------------------------------------------------------
// Khronos glTF-Validator
// ---------------------------------------------------------------------------

fn validator_script() -> Option<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let script = root.join("tests/validators/validate.js");
    let installed = root
        .join("tests/validators/node_modules/gltf-validator")
        .is_dir();
    let node = Command::new("node")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    common::require_tool(
        node && installed,
        "node with gltf-validator in tests/validators/node_modules",
    )
    .then_some(script)
}

fn random_yarns(seed: u64, curves: usize) -> Yarns {
    let mut s = seed | 1;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut y = Yarns::new();
    for c in 0..curves {
        let n = 2 + (next() * 40.0) as usize;
        let pts: Vec<[f64; 3]> = (0..n)
            .map(|_| [next() - 0.5, next() * 0.3, next() * 0.1 - 0.05])
            .collect();
        y.push_curve(&pts, c % 3 == 1 && n >= 3, 5e-4 + next() * 1e-3);
    }
    y
}

#[test]
fn khronos_validator_accepts_written_files() {
    let Some(script) = validator_script() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let mut single = Yarns::new();
    single.push_curve(
        &[[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.02, 0.01, 0.0]],
        false,
        0.001,
    );
    let mut per_vertex = random_yarns(7, 5);
    per_vertex.vertex_radius = Some(
        (0..per_vertex.num_points())
            .map(|v| 1e-3 + v as f64 * 1e-6)
            .collect(),
    );
    let sets = [
        ("random", random_yarns(42, 30)),
        ("mixed", mixed_yarns()),
        ("single", single),
        ("vertex_radius", per_vertex),
        ("empty", Yarns::new()),
    ];
    let mut files = Vec::new();
    for (name, y) in &sets {
        for ext in ["gltf", "glb"] {
            let p = dir.path().join(format!("{name}.{ext}"));
            write_path(&p, y, None, &WriteOptions::default()).unwrap();
            // What we validate is also what we read.
            assert_eq!(
                read_path(&p, &opts()).unwrap().yarns.num_curves(),
                y.num_curves()
            );
            files.push(p);
        }
    }
    let out = Command::new("node")
        .arg(&script)
        .arg("--strict")
        .args(&files)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    eprintln!("{text}{}", String::from_utf8_lossy(&out.stderr));
    assert!(
        out.status.success(),
        "glTF-Validator reported problems:\n{text}"
    );
    assert_eq!(
        text.matches("errors=0 warnings=0").count(),
        files.len(),
        "{text}"
    );
}

/// The validator helper itself fails on a broken file (so the test above can fail).
#[test]
fn khronos_validator_rejects_broken_file() {
    let Some(script) = validator_script() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (mut v, bin) = parts();
    v["accessors"][0]["min"] = json!([5.0, 5.0, 5.0]); // wrong bounds are a validator error
    let p = dir.path().join("broken.gltf");
    std::fs::write(&p, assemble(v, &bin)).unwrap();
    let out = Command::new("node").arg(&script).arg(&p).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(!out.status.success(), "{text}");
    assert!(text.contains("ACCESSOR_MIN_MISMATCH"), "{text}");
}

/// Character files (skinned triangle meshes, GLB and embedded) hold no lines:
/// they read as zero curves with a note, not as an error.
#[test]
fn triangle_only_files_read_as_no_curves() {
    let Some(dir) = common::external_data("anim") else {
        return;
    };
    for name in [
        "Fox.glb",
        "CesiumMan_lab0copy.glb",
        "Khronos_SimpleSkin_glTF-Embedded.gltf",
    ] {
        let path = dir.join(name);
        let r = read_path(&path, &opts()).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(r.yarns.num_curves(), 0, "{name}");
        assert!(
            r.notes.iter().any(|n| n.contains("triangle")),
            "{name}: {:?}",
            r.notes
        );
    }
}

/// Every number in the JSON (counts, offsets, strides, indices, modes, types)
/// replaced in turn by hostile values: errors or curves, never a panic, hang
/// or huge allocation.
#[test]
fn corpus_hostile_json_numbers() {
    let (v, bin) = parts();
    let hostile = [
        json!(0),
        json!(1),
        json!(3),
        json!(-1),
        json!(4294967295u64),
        json!(4294967296u64),
        json!(1u64 << 60),
        json!(u64::MAX),
        json!(1e39),
        json!(0.5),
    ];
    fn pointers(v: &Value, at: String, out: &mut Vec<String>) {
        match v {
            Value::Number(_) => out.push(at),
            Value::Array(a) => a
                .iter()
                .enumerate()
                .for_each(|(i, x)| pointers(x, format!("{at}/{i}"), out)),
            Value::Object(o) => o
                .iter()
                .for_each(|(k, x)| pointers(x, format!("{at}/{k}"), out)),
            _ => {}
        }
    }
    let mut ptrs = Vec::new();
    pointers(&v, String::new(), &mut ptrs);
    assert!(ptrs.len() > 50, "{}", ptrs.len());
    let small = ReadOptions {
        max_points: 1 << 20,
        ..opts()
    };
    let mut failures = 0;
    for p in &ptrs {
        for h in &hostile {
            let mut w = v.clone();
            *w.pointer_mut(p).unwrap() = h.clone();
            let bytes = assemble(w, &bin);
            if decode(Format::Gltf, &bytes, &small, &NoResources).is_err() {
                failures += 1;
            }
        }
    }
    // Most damage must be noticed (min/max and names are the only harmless numbers).
    assert!(
        failures > ptrs.len() * hostile.len() / 2,
        "{failures} of {}",
        ptrs.len() * hostile.len()
    );
}
