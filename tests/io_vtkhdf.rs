//! The homogenized asset file (`.vtkhdf`): round trips (bit for bit), VTK's
//! own vtkHDFReader on every time step (tests/validators/vtk_check.py), a
//! corpus of broken files, busy files, and the write / read times of a
//! garment-sized asset.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::str::FromStr;
use std::time::Instant;

use knitvox::geom::{
    Asset, AssetFibres, Embedding, InputFile, NodeSteps, Provenance, TetMesh, Vec3, VoxelGrid,
    Yarns,
};
use knitvox::io::vtkhdf::{self, read_asset, read_step, summary, write_asset};
use knitvox::io::{ErrorClass, IoError, Location};

// ---------------------------------------------------------------------------
// hand-made assets
// ---------------------------------------------------------------------------

/// The 6 tets of the Kuhn split of a voxel (corner offsets), every one around
/// the voxel diagonal (0,0,0)-(1,1,1); translation invariant, so neighbouring
/// voxels share their face diagonals.
fn kuhn_tets() -> Vec<[[i32; 3]; 4]> {
    let perms = [
        [0, 1, 2],
        [0, 2, 1],
        [1, 0, 2],
        [1, 2, 0],
        [2, 0, 1],
        [2, 1, 0],
    ];
    perms
        .iter()
        .map(|p| {
            let mut c = [[0i32; 3]; 4];
            for k in 0..3 {
                c[k + 1] = c[k];
                c[k + 1][p[k]] = 1;
            }
            c
        })
        .collect()
}

/// A box of `nx x ny x nz` voxels of edge `h`, 6 tets each, with a few yarns,
/// `steps` time steps and everything filled in.
fn box_asset(nx: i32, ny: i32, nz: i32, steps: usize) -> Asset {
    let h = 0.004;
    let origin = [-0.01, 0.02, 0.5];
    let (cx, cy) = (nx + 1, ny + 1);
    let node_of = |c: [i32; 3]| (c[0] + cx * (c[1] + cy * c[2])) as u32;
    let mut nodes = Vec::new();
    for k in 0..=nz {
        for j in 0..=ny {
            for i in 0..=nx {
                nodes.push([
                    origin[0] + h * i as f64,
                    origin[1] + h * j as f64,
                    origin[2] + h * k as f64,
                ]);
            }
        }
    }
    let mut voxels = Vec::new();
    let mut tets = Vec::new();
    let mut tet_voxel = Vec::new();
    let kuhn = kuhn_tets();
    for i in 0..nx {
        for j in 0..ny {
            for k in 0..nz {
                let v = voxels.len() as u32;
                voxels.push([i, j, k]);
                for corners in &kuhn {
                    let mut tet = corners.map(|c| node_of([i + c[0], j + c[1], k + c[2]]));
                    // Positive orientation: swap two nodes of a negative tet.
                    if signed_volume(&nodes, tet) < 0.0 {
                        tet.swap(2, 3);
                    }
                    tets.push(tet);
                    tet_voxel.push(v);
                }
            }
        }
    }
    let t = tets.len();
    let n = nodes.len();
    // Two yarns through the box, each vertex embedded in tet (vertex index mod t).
    let mut rest_yarns = Yarns::new();
    let a: Vec<Vec3> = (0..5)
        .map(|s| {
            [
                origin[0] + 0.3 * h * s as f64,
                origin[1] + 0.5 * h,
                origin[2] + 0.5 * h,
            ]
        })
        .collect();
    rest_yarns.push_curve(&a, false, 0.001);
    let b: Vec<Vec3> = (0..4)
        .map(|s| {
            [
                origin[0] + 0.5 * h,
                origin[1] + 0.2 * h * s as f64,
                origin[2] + 0.3 * h,
            ]
        })
        .collect();
    rest_yarns.push_curve(&b, true, 0.0012);
    rest_yarns.linear_density = Some(vec![2.5e-5, 3.0e-5]);
    rest_yarns.vertex_radius = Some((0..9).map(|i| 0.001 + 1e-5 * i as f64).collect());
    let m = rest_yarns.num_points();
    let embedding = Embedding {
        tet: (0..m).map(|i| (i % t) as u32).collect(),
        weights: (0..m)
            .map(|i| {
                let w = 0.1 + 0.01 * i as f64;
                [w, 0.2, 0.3, 1.0 - w - 0.5]
            })
            .collect(),
    };
    let mut st = NodeSteps::default();
    for s in 0..steps {
        st.times.push(s as f64 / 24.0 + 1.0 / 3.0);
        // Values with long mantissas, so a float32 detour anywhere would show.
        st.positions.extend(nodes.iter().enumerate().map(|(i, p)| {
            let w = (s as f64 + 1.0) * 1e-3 * (i as f64 * 0.7).sin();
            [
                p[0] + w,
                p[1] - w / 3.0,
                p[2] + std::f64::consts::PI * 1e-4 * s as f64,
            ]
        }));
        st.fit_error.push(1e-4 / (s as f64 + 1.0) / 7.0);
    }
    Asset {
        grid: VoxelGrid { origin, h, voxels },
        mesh: TetMesh { nodes, tets },
        tet_voxel,
        node_mass: (0..n)
            .map(|i| 1e-6 * (1.0 + (i % 7) as f64 / 3.0))
            .collect(),
        gamma_s: (0..t).map(|i| 1e4 * (1.0 + i as f64 / 11.0)).collect(),
        gamma_v: (0..t).map(|i| 2e4 / (1.0 + i as f64 / 13.0)).collect(),
        domain: (0..t).map(|i| (i % 3) as i32).collect(),
        fibres: None,
        embedding,
        rest_yarns,
        parameters: serde_json::json!({"voxel_size": h, "alpha": 0.1, "note": "écharpe ✓"}),
        provenance: Provenance {
            knitvox_version: "0.1.0".into(),
            command: "knitvox embed scarf.bcc -o scarf.vtkhdf".into(),
            inputs: vec![InputFile {
                path: "/data/scarf.bcc".into(),
                sha256: "ab".repeat(32),
            }],
        },
        steps: st,
    }
}

fn signed_volume(x: &[Vec3], t: [u32; 4]) -> f64 {
    let [a, b, c, d] = t.map(|i| x[i as usize]);
    let e = |p: Vec3| [p[0] - a[0], p[1] - a[1], p[2] - a[2]];
    let (e1, e2, e3) = (e(b), e(c), e(d));
    let cr = [
        e2[1] * e3[2] - e2[2] * e3[1],
        e2[2] * e3[0] - e2[0] * e3[2],
        e2[0] * e3[1] - e2[1] * e3[0],
    ];
    (e1[0] * cr[0] + e1[1] * cr[1] + e1[2] * cr[2]) / 6.0
}

fn bits(v: &[Vec3]) -> Vec<u64> {
    v.as_flattened().iter().map(|x| x.to_bits()).collect()
}

// ---------------------------------------------------------------------------
// round trips
// ---------------------------------------------------------------------------

#[test]
fn hand_made_mesh_is_a_valid_kuhn_split() {
    let a = box_asset(2, 1, 1, 0);
    assert_eq!(a.mesh.num_tets(), 12);
    assert_eq!(a.mesh.num_nodes(), 12);
    let total: f64 = (0..12).map(|t| a.mesh.volume(t)).sum();
    assert!((total - 2.0 * 0.004f64.powi(3)).abs() < 1e-15, "{total}");
    assert!((0..12).all(|t| a.mesh.volume(t) > 0.0));
}

#[test]
fn round_trip_without_steps_is_bit_identical() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("static.vtkhdf");
    let a = box_asset(2, 1, 1, 0);
    write_asset(&p, &a).unwrap();
    let b = read_asset(&p).unwrap();
    assert_eq!(b, a);
    assert_eq!(bits(&b.mesh.nodes), bits(&a.mesh.nodes));
    assert_eq!(b.steps.num_steps(), 0);
    // Nothing but the target in the directory (atomic write).
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    let e = read_step(&p, 0).unwrap_err();
    assert!(e.to_string().contains("static"), "{e}");
}

#[test]
fn round_trip_with_steps_is_bit_identical() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("steps.vtkhdf");
    let a = box_asset(2, 1, 1, 4);
    write_asset(&p, &a).unwrap();
    let b = read_asset(&p).unwrap();
    assert_eq!(b, a);
    assert_eq!(bits(&b.steps.positions), bits(&a.steps.positions));
    let n = a.mesh.num_nodes();
    for s in 0..4 {
        let got = read_step(&p, s).unwrap();
        assert_eq!(bits(&got), bits(a.steps.step(s, n)), "step {s}");
    }
    let e = read_step(&p, 4).unwrap_err();
    assert!(e.to_string().contains("4 step(s)"), "{e}");
    // Without fit errors, and rewriting over an existing file.
    let mut c = a.clone();
    c.steps.fit_error.clear();
    write_asset(&p, &c).unwrap();
    assert_eq!(read_asset(&p).unwrap(), c);
}

/// The same asset written twice, more than a second apart (libhdf5 stores
/// object times in whole seconds), is the same bytes: a farm compares a
/// rerun's outputs with `cmp`. So are the yarn and character HDF5 files,
/// written through the same `create_h5`.
#[test]
fn the_same_asset_written_twice_is_the_same_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let a = box_asset(2, 1, 1, 3);
    let (p, q) = (dir.path().join("a.vtkhdf"), dir.path().join("b.vtkhdf"));
    write_asset(&p, &a).unwrap();
    std::thread::sleep(std::time::Duration::from_millis(1100));
    write_asset(&q, &a).unwrap();
    let (x, y) = (std::fs::read(&p).unwrap(), std::fs::read(&q).unwrap());
    assert_eq!(x.len(), y.len());
    let first = x.iter().zip(&y).position(|(u, v)| u != v);
    assert_eq!(first, None, "files differ from byte {first:?}");
}

#[test]
fn empty_asset_round_trips() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("empty.vtkhdf");
    // Asset::default() has Yarns::default() (no offsets at all), which is not a
    // valid curve set; Yarns::new() is the empty one.
    let a = Asset {
        rest_yarns: Yarns::new(),
        ..Asset::default()
    };
    write_asset(&p, &a).unwrap();
    assert_eq!(read_asset(&p).unwrap(), a);
}

#[test]
fn summary_reports_the_asset() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("s.vtkhdf");
    let a = box_asset(3, 2, 1, 3);
    write_asset(&p, &a).unwrap();
    let s = summary(&p).unwrap();
    assert_eq!(s.nodes, 4 * 3 * 2);
    assert_eq!(s.tets, 36);
    assert_eq!(s.voxels, 6);
    assert_eq!(s.steps, 3);
    assert_eq!(s.time_range, Some([a.steps.times[0], a.steps.times[2]]));
    assert_eq!(s.voxel_size, 0.004);
    assert_eq!(s.yarn_curves, 2);
    assert_eq!(s.yarn_points, 9);
    assert_eq!(s.domains, 3);
    assert_eq!(s.total_mass, a.node_mass.iter().sum::<f64>());
    assert_eq!(s.provenance, a.provenance);
    assert_eq!(s.format_version, vtkhdf::FORMAT_VERSION);
    let [lo, hi] = s.rest_bounds.unwrap();
    assert_eq!(lo, a.mesh.nodes[0]);
    assert_eq!(hi, *a.mesh.nodes.last().unwrap());
    let json = serde_json::to_value(&s).unwrap();
    assert_eq!(json["tets"], 36);
    assert!(json["gamma_s_range"][1].as_f64().unwrap() > 1e4);
}

// ---------------------------------------------------------------------------
// VTK's own reader
// ---------------------------------------------------------------------------

fn python_vtk() -> bool {
    Command::new("python3")
        .args(["-c", "import vtk, numpy"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false)
}

fn vtk_check(p: &Path) -> serde_json::Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/validators/vtk_check.py");
    let out = Command::new("python3")
        .arg(&script)
        .arg(p)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "vtk_check.py failed on {}: {}",
        p.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

fn u64s(v: &serde_json::Value) -> Vec<u64> {
    v.as_array()
        .unwrap_or_else(|| panic!("not an array: {v}"))
        .iter()
        .map(|x| x.as_u64().unwrap())
        .collect()
}

/// What VTK shows at one step: counts, all cells VTK_TETRA, the arrays, and
/// the points and data bit for bit.
fn check_vtk_step(step: &serde_json::Value, a: &Asset, points: &[Vec3]) {
    let s = &step["step"];
    assert_eq!(step["points"], a.mesh.num_nodes(), "step {s}");
    assert_eq!(step["cells"], a.mesh.num_tets(), "step {s}");
    assert_eq!(step["all_tetra"], true, "step {s}");
    assert_eq!(step["cell_types"], serde_json::json!([10]), "step {s}");
    assert_eq!(
        step["cell_arrays"],
        serde_json::json!(["domain", "gamma_s", "gamma_v"]),
        "step {s}"
    );
    assert_eq!(
        step["point_arrays"],
        serde_json::json!(["mass"]),
        "step {s}"
    );
    assert_eq!(
        u64s(&step["point_bits"]),
        bits(points),
        "points of step {s}"
    );
    let gs: Vec<u64> = a.gamma_s.iter().map(|x| x.to_bits()).collect();
    assert_eq!(u64s(&step["gamma_s"]), gs, "gamma_s at step {s}");
    let m: Vec<u64> = a.node_mass.iter().map(|x| x.to_bits()).collect();
    assert_eq!(u64s(&step["mass"]), m, "mass at step {s}");
}

#[test]
fn vtk_reads_every_time_step() {
    if !common::require_tool(python_vtk(), "python3 with the vtk package") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("steps.vtkhdf");
    let a = box_asset(2, 1, 1, 4);
    write_asset(&p, &a).unwrap();
    let v = vtk_check(&p);
    assert_eq!(v["number_of_steps"], 4, "{v}");
    let times: Vec<f64> = v["time_values"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t.as_f64().unwrap())
        .collect();
    assert_eq!(times, a.steps.times);
    let steps = v["steps"].as_array().unwrap();
    assert_eq!(steps.len(), 4);
    let n = a.mesh.num_nodes();
    for (s, step) in steps.iter().enumerate() {
        assert_eq!(step["time"].as_f64().unwrap(), a.steps.times[s]);
        check_vtk_step(step, &a, a.steps.step(s, n));
    }
}

#[test]
fn vtk_reads_a_static_asset() {
    if !common::require_tool(python_vtk(), "python3 with the vtk package") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("static.vtkhdf");
    let a = box_asset(2, 2, 1, 0);
    write_asset(&p, &a).unwrap();
    let v = vtk_check(&p);
    // vtkHDFReader counts a static file as one step, with no time values.
    assert_eq!(v["number_of_steps"], 1, "{v}");
    assert_eq!(v["time_values"], serde_json::json!([]), "{v}");
    let steps = v["steps"].as_array().unwrap();
    assert_eq!(steps.len(), 1);
    check_vtk_step(&steps[0], &a, &a.mesh.nodes);
}

/// `box_asset` with course and wale fibres (tilted unit directions, varied
/// stiffnesses).
fn fibred_asset(steps: usize) -> Asset {
    let mut a = box_asset(2, 1, 1, steps);
    let t = a.mesh.num_tets();
    let unit = |v: Vec3| {
        let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        [v[0] / n, v[1] / n, v[2] / n]
    };
    a.fibres = Some(AssetFibres {
        course: (0..t).map(|i| unit([1.0, 0.1 * i as f64, 0.0])).collect(),
        wale: (0..t).map(|i| unit([-0.1 * i as f64, 1.0, 0.0])).collect(),
        gamma_course: (0..t).map(|i| 3e3 * (1.0 + i as f64)).collect(),
        gamma_wale: (0..t)
            .map(|i| if i == 0 { 0.0 } else { 5e3 / i as f64 })
            .collect(),
        beta_course: Vec::new(),
        beta_wale: Vec::new(),
    });
    a
}

/// The knit material's stiffenings travel with the fibres; one without the
/// other, or a negative one, is refused naming the dataset.
#[test]
fn stiffening_fibres_round_trip_and_half_of_them_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let mut a = fibred_asset(2);
    let t = a.mesh.num_tets();
    if let Some(f) = a.fibres.as_mut() {
        f.beta_course = (0..t).map(|i| 80.0 + i as f64).collect();
        f.beta_wale = vec![40.0; t];
    }
    let p = dir.path().join("knit.vtkhdf");
    write_asset(&p, &a).unwrap();
    assert_eq!(read_asset(&p).unwrap(), a);
    let sm = knitvox::io::vtkhdf::summary(&p).unwrap();
    assert_eq!(sm.beta_course_range, Some([80.0, 80.0 + (t - 1) as f64]));
    assert_eq!(sm.beta_wale_range, Some([40.0, 40.0]));
    let mut half = a.clone();
    if let Some(f) = half.fibres.as_mut() {
        f.beta_wale.clear();
    }
    assert!(write_asset(&dir.path().join("half.vtkhdf"), &half).is_err());
    let mut neg = a.clone();
    if let Some(f) = neg.fibres.as_mut() {
        f.beta_course[1] = -1.0;
    }
    let e = write_asset(&dir.path().join("neg.vtkhdf"), &neg)
        .unwrap_err()
        .to_string();
    assert!(e.contains("beta_course"), "{e}");
}

#[test]
fn fibres_round_trip_and_vtk_sees_them() {
    let dir = tempfile::tempdir().unwrap();
    for steps in [0, 3] {
        let p = dir.path().join(format!("fibres{steps}.vtkhdf"));
        let a = fibred_asset(steps);
        write_asset(&p, &a).unwrap();
        assert_eq!(read_asset(&p).unwrap(), a, "{steps} steps");
        let sm = summary(&p).unwrap();
        let t = a.mesh.num_tets() as f64;
        assert_eq!(sm.gamma_course_range, Some([3e3, 3e3 * t]));
        assert_eq!(sm.gamma_wale_range, Some([0.0, 5e3]));
    }
    assert_eq!(
        summary(&good_file(dir.path(), "plain.vtkhdf", 0))
            .unwrap()
            .gamma_course_range,
        None
    );
    if !common::require_tool(python_vtk(), "python3 with the vtk package") {
        return;
    }
    let v = vtk_check(&dir.path().join("fibres3.vtkhdf"));
    assert_eq!(v["number_of_steps"], 3, "{v}");
    for step in v["steps"].as_array().unwrap() {
        assert_eq!(
            step["cell_arrays"],
            serde_json::json!([
                "course_direction",
                "domain",
                "gamma_course",
                "gamma_s",
                "gamma_v",
                "gamma_wale",
                "wale_direction"
            ]),
            "{step}"
        );
    }
}

#[test]
fn broken_fibres_name_the_dataset() {
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("good.vtkhdf");
    let a = fibred_asset(0);
    write_asset(&good, &a).unwrap();
    let t = a.mesh.num_tets();
    let copy = |name: &str| {
        let p = dir.path().join(name);
        std::fs::copy(&good, &p).unwrap();
        p
    };
    let p = copy("long.vtkhdf");
    let mut d: Vec<f64> = a.fibres.as_ref().unwrap().course.as_flattened().to_vec();
    d[3] *= 1.5;
    replace(&p, "VTKHDF/CellData/course_direction", &[t, 3], &d);
    expect_at(&p, "/VTKHDF/CellData/course_direction", "unit vector");
    let p = copy("negative.vtkhdf");
    let mut g = a.fibres.as_ref().unwrap().gamma_wale.clone();
    g[2] = -1.0;
    replace(&p, "VTKHDF/CellData/gamma_wale", &[t], &g);
    expect_at(
        &p,
        "/VTKHDF/CellData/gamma_wale",
        "entry 2: stiffness -1e0 Pa is outside [0, 1e12] Pa",
    );
    let p = copy("half.vtkhdf");
    {
        let f = common::h5_edit(&p);
        f.unlink("VTKHDF/CellData/wale_direction").unwrap();
    }
    expect_at(&p, "/VTKHDF/CellData/wale_direction", "missing");
    // Writing refuses what it could not read back.
    let mut bad = a.clone();
    bad.fibres.as_mut().unwrap().gamma_course[1] = f64::NAN;
    assert!(write_asset(&dir.path().join("nan.vtkhdf"), &bad).is_err());
}

// ---------------------------------------------------------------------------
// broken files
// ---------------------------------------------------------------------------

fn good_file(dir: &Path, name: &str, steps: usize) -> PathBuf {
    let p = dir.join(name);
    write_asset(&p, &box_asset(2, 1, 1, steps)).unwrap();
    p
}

/// The error of reading `p`, which must be a Format error.
fn format_error(p: &Path) -> (Location, String) {
    match read_asset(p) {
        Err(IoError::Format { source, .. }) => (source.location, source.message),
        other => panic!("{}: expected a format error, got {other:?}", p.display()),
    }
}

/// Replaces dataset `name` of `p` by one of `shape` holding `data`.
fn replace<T: hdf5::H5Type>(p: &Path, name: &str, shape: &[usize], data: &[T]) {
    let f = common::h5_edit(p);
    f.unlink(name).unwrap();
    let ds = f
        .new_dataset::<T>()
        .shape(shape.to_vec())
        .create(name)
        .unwrap();
    if !data.is_empty() {
        ds.write_raw(data).unwrap();
    }
    // The dataset's handle keeps the file open (and locked) past `close`.
    drop(ds);
    f.close().unwrap();
}

fn expect_at(p: &Path, path: &str, words: &str) {
    let (loc, msg) = format_error(p);
    assert_eq!(loc, Location::Path(path.into()), "{msg}");
    assert!(msg.contains(words), "{path}: {msg:?} lacks {words:?}");
    let e = read_asset(p).unwrap_err();
    assert_eq!(e.class(), ErrorClass::BadInput, "{e}");
    assert!(!e.to_string().contains('\n'), "{e}");
}

#[test]
fn empty_truncated_and_foreign_files_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    let good = good_file(dir.path(), "good.vtkhdf", 2);
    let bytes = std::fs::read(&good).unwrap();

    let p = dir.path().join("empty.vtkhdf");
    std::fs::write(&p, b"").unwrap();
    let (loc, msg) = format_error(&p);
    assert_eq!(loc, Location::File);
    assert!(msg.contains("empty"), "{msg}");

    std::fs::write(&p, b"# vtk DataFile Version 3.0\nnot hdf5 at all\n").unwrap();
    assert!(format_error(&p).1.contains("not an HDF5 file"));

    // A sample of prefixes (every one would take minutes): all errors, none panics.
    let step = (bytes.len() / 97).max(1);
    for len in (1..bytes.len())
        .step_by(step)
        .chain([8, 512, bytes.len() - 1])
    {
        std::fs::write(&p, &bytes[..len]).unwrap();
        assert!(read_asset(&p).is_err(), "prefix of {len} bytes read fine");
        assert!(summary(&p).is_err());
        assert!(read_step(&p, 0).is_err());
    }

    // A knitvox yarns file: HDF5, but no /VTKHDF.
    let y = dir.path().join("yarns.h5");
    let mut yarns = Yarns::new();
    yarns.push_curve(&[[0.0; 3], [1.0, 0.0, 0.0]], false, 0.001);
    knitvox::io::h5::write_file(&y, &yarns, None).unwrap();
    let (loc, msg) = format_error(&y);
    assert_eq!(loc, Location::File);
    assert!(msg.contains("no /VTKHDF group"), "{msg}");
    assert!(msg.contains("group /yarns"), "{msg}");

    // A plain VTKHDF file (as ParaView writes): no /knitvox. A new file,
    // not `p` rewritten: HDF5 opens files without O_CLOEXEC, so a process
    // another test thread spawned while `p` was open can still hold its
    // lock (flock), and opening it for writing would fail (EAGAIN).
    let plain = dir.path().join("plain.vtkhdf");
    std::fs::copy(&good, &plain).unwrap();
    let f = common::h5_edit(&plain);
    f.unlink("knitvox").unwrap();
    f.close().unwrap();
    let (loc, msg) = format_error(&plain);
    assert_eq!(loc, Location::File);
    assert!(msg.contains("no /knitvox group"), "{msg}");

    // A directory and a missing file.
    assert!(matches!(
        read_asset(dir.path()),
        Err(IoError::NotRegular { .. })
    ));
    let e = read_asset(&dir.path().join("missing.vtkhdf")).unwrap_err();
    assert_eq!(e.class(), ErrorClass::MissingInput);
}

#[test]
fn wrong_shapes_and_values_name_the_dataset() {
    let dir = tempfile::tempdir().unwrap();
    let fresh = |name: &str| good_file(dir.path(), name, 3);
    // 2 voxels x 6 tets = 12 tets, 12 nodes, 9 yarn vertices, 3 steps.

    let p = fresh("conn_len.vtkhdf");
    replace(&p, "VTKHDF/Connectivity", &[47], &vec![0i64; 47]);
    expect_at(&p, "/VTKHDF/Connectivity", "not a whole number of tets");

    let p = fresh("conn_fewer.vtkhdf");
    replace(&p, "VTKHDF/Connectivity", &[44], &vec![0i64; 44]);
    expect_at(&p, "/VTKHDF/NumberOfCells", "expected 11");

    let p = fresh("conn_range.vtkhdf");
    let mut conn = vec![0i64; 48];
    conn[17] = 12;
    replace(&p, "VTKHDF/Connectivity", &[48], &conn);
    expect_at(&p, "/VTKHDF/Connectivity", "entry 17: 12 is out of range");

    let p = fresh("conn_negative.vtkhdf");
    conn[17] = -1;
    replace(&p, "VTKHDF/Connectivity", &[48], &conn);
    expect_at(&p, "/VTKHDF/Connectivity", "negative");

    let p = fresh("conn_float.vtkhdf");
    replace(&p, "VTKHDF/Connectivity", &[48], &vec![0.0f64; 48]);
    expect_at(&p, "/VTKHDF/Connectivity", "expected integers");

    let p = fresh("weights.vtkhdf");
    replace(&p, "knitvox/embedding/weights", &[9, 3], &vec![0.25f64; 27]);
    expect_at(&p, "/knitvox/embedding/weights", "9 x 4");

    let p = fresh("weights_nan.vtkhdf");
    let mut w = vec![0.25f64; 36];
    w[13] = f64::NAN;
    replace(&p, "knitvox/embedding/weights", &[9, 4], &w);
    expect_at(&p, "/knitvox/embedding/weights", "entry 3: value NaN");

    let p = fresh("emb_tet.vtkhdf");
    replace(
        &p,
        "knitvox/embedding/tet",
        &[9],
        &[0u32, 1, 2, 3, 4, 5, 6, 7, 12],
    );
    expect_at(&p, "/knitvox/embedding/tet", "entry 8: 12 is out of range");

    let p = fresh("types.vtkhdf");
    let mut types = vec![10u8; 12];
    types[5] = 12;
    replace(&p, "VTKHDF/Types", &[12], &types);
    expect_at(&p, "/VTKHDF/Types", "cell 5: type 12, expected 10");

    let p = fresh("offsets.vtkhdf");
    let off: Vec<i64> = (0..13).map(|i| 3 * i).collect();
    replace(&p, "VTKHDF/Offsets", &[13], &off);
    expect_at(&p, "/VTKHDF/Offsets", "entry 1: 3, expected 4");

    let p = fresh("points_rows.vtkhdf");
    replace(&p, "VTKHDF/Points", &[35, 3], &vec![0.0f64; 105]);
    expect_at(&p, "/VTKHDF/Points", "expected 3 steps x 12 nodes = 36");

    let p = fresh("points_nan.vtkhdf");
    let mut pts = vec![0.0f64; 108];
    pts[3 * 20 + 1] = f64::INFINITY;
    replace(&p, "VTKHDF/Points", &[36, 3], &pts);
    expect_at(&p, "/VTKHDF/Points", "entry 20: value inf");
    let e = read_step(&p, 1).unwrap_err();
    assert!(e.to_string().contains("step 1, node 8"), "{e}");
    assert_eq!(read_step(&p, 0).unwrap().len(), 12);

    let p = fresh("npoints.vtkhdf");
    replace(&p, "VTKHDF/NumberOfPoints", &[1], &[12i64]);
    expect_at(&p, "/VTKHDF/NumberOfPoints", "[3] (one entry per step)");

    let p = fresh("part_offsets.vtkhdf");
    replace(&p, "VTKHDF/Steps/PartOffsets", &[3], &[0i64, 1, 2]);
    expect_at(&p, "/VTKHDF/Steps/PartOffsets", "fixed topology");

    let p = fresh("point_offsets.vtkhdf");
    replace(&p, "VTKHDF/Steps/PointOffsets", &[3], &[0i64, 12, 12]);
    expect_at(&p, "/VTKHDF/Steps/PointOffsets", "step 2: 12, expected 24");
    assert!(read_step(&p, 2).is_err());

    let p = fresh("values.vtkhdf");
    replace(&p, "VTKHDF/Steps/Values", &[2], &[0.0f64, 1.0]);
    expect_at(&p, "/VTKHDF/Steps/Values", "NSteps");

    let p = fresh("gamma.vtkhdf");
    replace(&p, "VTKHDF/CellData/gamma_s", &[11], &[1.0f64; 11]);
    expect_at(&p, "/VTKHDF/CellData/gamma_s", "one per tet");

    // Stiffnesses beyond any material (or negative) are corruption: named
    // where they are, not found later as a singular PD matrix of the scene.
    for (name, bad, what) in [
        (
            "gamma_v",
            -1.0,
            "entry 7: stiffness -1e0 Pa is outside [0, 1e12] Pa",
        ),
        ("gamma_s", 1e300, "entry 7: stiffness 1e300 Pa is outside"),
    ] {
        let p = fresh(&format!("{name}_absurd.vtkhdf"));
        let mut g = vec![1e4f64; 12];
        g[7] = bad;
        replace(&p, &format!("VTKHDF/CellData/{name}"), &[12], &g);
        expect_at(&p, &format!("/VTKHDF/CellData/{name}"), what);
    }

    let p = fresh("domain.vtkhdf");
    replace(&p, "VTKHDF/CellData/domain", &[12], &[1i64 << 40; 12]);
    expect_at(&p, "/VTKHDF/CellData/domain", "does not fit in int32");

    let p = fresh("mass.vtkhdf");
    let mut m = vec![1.0f64; 12];
    m[4] = -1.0;
    replace(&p, "VTKHDF/PointData/mass", &[12], &m);
    expect_at(&p, "/VTKHDF/PointData/mass", "node 4: mass -1 is negative");

    let p = fresh("tet_voxel.vtkhdf");
    replace(&p, "knitvox/tet_voxel", &[12], &[2u32; 12]);
    expect_at(&p, "/knitvox/tet_voxel", "out of range");

    let p = fresh("params.vtkhdf");
    replace(&p, "knitvox/parameters", &[5], b"{\"a\":");
    expect_at(&p, "/knitvox/parameters", "invalid JSON");

    let p = fresh("provenance.vtkhdf");
    replace(&p, "knitvox/provenance", &[2], b"[]");
    expect_at(&p, "/knitvox/provenance", "invalid JSON");

    let p = fresh("yarn_offsets.vtkhdf");
    replace(&p, "knitvox/rest_yarns/offsets", &[3], &[0u64, 5, 10]);
    expect_at(&p, "/knitvox/rest_yarns/offsets", "past the 9 points");

    let p = fresh("no_mass.vtkhdf");
    let f = common::h5_edit(&p);
    f.unlink("VTKHDF/PointData/mass").unwrap();
    f.close().unwrap();
    expect_at(&p, "/VTKHDF/PointData/mass", "missing");
}

#[test]
fn wrong_attributes_and_absurd_claims_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    let fresh = |name: &str| good_file(dir.path(), name, 3);

    let set_attr_i64 = |p: &Path, group: &str, name: &str, v: i64| {
        let f = common::h5_edit(p);
        let g = f.group(group).unwrap();
        g.delete_attr(name).unwrap();
        g.new_attr::<i64>()
            .shape(())
            .create(name)
            .unwrap()
            .write_scalar(&v)
            .unwrap();
        f.close().unwrap();
    };

    let p = fresh("version.vtkhdf");
    set_attr_i64(&p, "knitvox", "knitvox_format_version", 99);
    expect_at(
        &p,
        "/knitvox@knitvox_format_version",
        "version 99 is not supported",
    );

    let p = fresh("vtk_version.vtkhdf");
    let f = common::h5_edit(&p);
    let g = f.group("VTKHDF").unwrap();
    g.delete_attr("Version").unwrap();
    g.new_attr::<i64>()
        .shape([2])
        .create("Version")
        .unwrap()
        .write_raw(&[1i64, 0])
        .unwrap();
    drop(g); // its handle would keep the file open past `close`
    f.close().unwrap();
    expect_at(&p, "/VTKHDF@Version", "version 1.0");

    let p = fresh("nsteps.vtkhdf");
    set_attr_i64(&p, "VTKHDF/Steps", "NSteps", 1 << 60);
    expect_at(&p, "/VTKHDF/Steps@NSteps", "expected 1 to");

    let p = fresh("nsteps_zero.vtkhdf");
    set_attr_i64(&p, "VTKHDF/Steps", "NSteps", 0);
    expect_at(&p, "/VTKHDF/Steps@NSteps", "0 steps");

    // 2^40 rest nodes claimed by a chunked dataset that stores nothing.
    let p = fresh("huge_nodes.vtkhdf");
    let f = common::h5_edit(&p);
    f.unlink("knitvox/rest_nodes").unwrap();
    f.new_dataset::<f64>()
        .chunk([1024, 3])
        .shape([1usize << 40, 3])
        .create("knitvox/rest_nodes")
        .unwrap();
    f.close().unwrap();
    expect_at(&p, "/knitvox/rest_nodes", "exceeds the limit");

    // 2^28 nodes (below the limit) claimed everywhere, but nothing stored:
    // refused before allocating 6 GiB.
    let p = dir.path().join("claims.vtkhdf");
    write_asset(&p, &box_asset(2, 1, 1, 0)).unwrap();
    let big = 1usize << 28;
    let f = common::h5_edit(&p);
    for name in ["knitvox/rest_nodes", "VTKHDF/Points"] {
        f.unlink(name).unwrap();
        f.new_dataset::<f64>()
            .chunk([4096, 3])
            .shape([big, 3])
            .create(name)
            .unwrap();
    }
    f.unlink("VTKHDF/NumberOfPoints").unwrap();
    f.new_dataset::<i64>()
        .shape([1])
        .create("VTKHDF/NumberOfPoints")
        .unwrap()
        .write_raw(&[big as i64])
        .unwrap();
    f.close().unwrap();
    expect_at(&p, "/knitvox/rest_nodes", "but the file stores only");

    let p = fresh("type.vtkhdf");
    let f = common::h5_edit(&p);
    let g = f.group("VTKHDF").unwrap();
    g.delete_attr("Type").unwrap();
    let v = hdf5::types::VarLenUnicode::from_str("PolyData").unwrap();
    g.new_attr::<hdf5::types::VarLenUnicode>()
        .shape(())
        .create("Type")
        .unwrap()
        .write_scalar(&v)
        .unwrap();
    drop(g);
    f.close().unwrap();
    expect_at(&p, "/VTKHDF@Type", "'PolyData'");
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
    let p = good_file(dir.path(), "locked.vtkhdf", 2);
    let mut child = Command::new("flock")
        .arg("-x")
        .arg(&p)
        .arg("cat")
        .stdin(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    let result = loop {
        match read_asset(&p) {
            Err(e @ IoError::Busy { .. }) => break Ok(e),
            other if start.elapsed() > std::time::Duration::from_secs(10) => break Err(other),
            _ => std::thread::sleep(std::time::Duration::from_millis(20)),
        }
    };
    let step = read_step(&p, 1);
    drop(child.stdin.take());
    let _ = child.wait();
    let e = result.unwrap_or_else(|other| panic!("never saw Busy while locked: {other:?}"));
    assert_eq!(e.class(), ErrorClass::Transient, "{e}");
    assert!(matches!(step, Err(IoError::Busy { .. })), "{step:?}");
    assert!(read_asset(&p).is_ok());
}

// ---------------------------------------------------------------------------
// performance
// ---------------------------------------------------------------------------

/// About 100K nodes, 500K tets, 4 steps: prints the write / read times
/// (`cargo test --release --test io_vtkhdf -- --nocapture garment`).
#[test]
fn garment_sized_asset_write_and_read_times() {
    let a = box_asset(40, 40, 52, 4);
    assert!(a.mesh.num_nodes() > 85_000 && a.mesh.num_tets() > 490_000);
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("big.vtkhdf");
    let t0 = Instant::now();
    write_asset(&p, &a).unwrap();
    let write = t0.elapsed();
    let t1 = Instant::now();
    let b = read_asset(&p).unwrap();
    let read = t1.elapsed();
    let t2 = Instant::now();
    let s3 = read_step(&p, 3).unwrap();
    let step = t2.elapsed();
    let t3 = Instant::now();
    let sum = summary(&p).unwrap();
    let summ = t3.elapsed();
    let size = std::fs::metadata(&p).unwrap().len();
    eprintln!(
        "vtkhdf: {} nodes, {} tets, {} steps, {:.1} MB: write {:.3} s, read {:.3} s, \
         read_step {:.4} s, summary {:.3} s",
        a.mesh.num_nodes(),
        a.mesh.num_tets(),
        a.steps.num_steps(),
        size as f64 / 1e6,
        write.as_secs_f64(),
        read.as_secs_f64(),
        step.as_secs_f64(),
        summ.as_secs_f64()
    );
    assert_eq!(b, a);
    assert_eq!(bits(&s3), bits(a.steps.step(3, a.mesh.num_nodes())));
    assert_eq!(sum.tets, a.mesh.num_tets());
}
