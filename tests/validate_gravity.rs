//! `validate` where the material matters: the homogenized run
//! under gravity and colliders. A hang under gravity sags by an amount set
//! by the material's scale (a Dirichlet-only pose does not see it), and a
//! scene with a collider runs at both levels with the mesh's yarn vertices
//! kept outside the collider.
mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use knitvox::embed::EmbedParams;
use knitvox::geom::{Asset, Vec3};
use knitvox::io::{self, ReadOptions};
use knitvox::pipeline::asset::build_asset;
use knitvox::pipeline::validate::{homogenized_frames, yarn_mass};
use knitvox::yarn::poses::{PoseDriver, PoseKind, PoseParams};

fn knitvox(args: &[&str]) -> Output {
    Command::new(common::knitvox_bin())
        .args(args)
        .output()
        .unwrap()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A 4 x 4 stockinette (generated curves, not relaxed) laid flat in XZ
/// (normal +Y, the yls scene frame), embedded; written to `dir/flat.vtkhdf`.
fn flat_asset(dir: &Path) -> (PathBuf, Asset) {
    let mut y = common::flat_swatch("stockinette", 4, 4);
    y.map_points(|p| [p[0], p[2], -p[1]]);
    let yarns = dir.join("flat.h5");
    io::h5::write_file(&yarns, &y, None).unwrap();
    let (asset, _) = build_asset(
        &yarns,
        &ReadOptions::default(),
        &EmbedParams::default(),
        "test",
    )
    .unwrap();
    let path = dir.join("flat.vtkhdf");
    io::vtkhdf::write_asset(&path, &asset).unwrap();
    (path, asset)
}

/// Mean drop (m) of the V2Y yarn vertices at the last frame of a hang from
/// the two front corners under gravity, uniform material `gamma` (Pa).
fn hang_sag(asset: &Asset, gamma: f64) -> f64 {
    let driver = PoseDriver::new(
        &asset.rest_yarns.points,
        PoseParams::new(PoseKind::Hang, 0.0),
    )
    .unwrap();
    let ne = asset.mesh.num_tets();
    let m = knitvox::fit::elastic::MaterialFields::uniform(ne, gamma, gamma);
    let times = [0.0, 0.1, 0.25, 0.5, 1.0, 2.0];
    let run = homogenized_frames(asset, &m, &driver, [0.0, -9.81, 0.0], &times, &[]).unwrap();
    let last = run.frames.last().unwrap();
    let y = asset.embedding.v2y(&asset.mesh, last);
    let rest = &asset.rest_yarns.points;
    y.iter().zip(rest).map(|(a, b)| b[1] - a[1]).sum::<f64>() / y.len() as f64
}

#[test]
fn the_material_scale_sets_the_sag_of_a_homogenized_hang() {
    let tmp = tempfile::tempdir().unwrap();
    let (_, asset) = flat_asset(tmp.path());
    // The mass gravity acts on is the yarn's: linear density x length.
    let mesh_mass: f64 = asset.node_mass.iter().sum();
    let yarns = yarn_mass(&asset.rest_yarns, 120.0);
    assert!(
        (mesh_mass - yarns).abs() < 1e-9 * yarns,
        "{mesh_mass} vs {yarns}"
    );
    let soft = hang_sag(&asset, 1e3);
    let stiff = hang_sag(&asset, 1e4);
    eprintln!("mean sag: {soft:.4e} m at 1e3 Pa, {stiff:.4e} m at 1e4 Pa");
    assert!(stiff > 0.0, "the hang did not sag: {stiff}");
    assert!(
        soft > 3.0 * stiff,
        "10x stiffer should sag clearly less: {soft} vs {stiff}"
    );
}

#[test]
fn validate_with_a_sphere_collider_keeps_the_mesh_outside() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let (asset_path, asset) = flat_asset(d);
    let scene = d.join("drape.toml");
    // Free fall onto a small sphere under the centre (one yarn diameter
    // below the swatch): 3 frames of 1/30 s.
    std::fs::write(
        &scene,
        "name = \"drape\"\nduration = 0.1\nframe_rate = 30\n[pose]\nkind = \"free\"\n\
         [[colliders]]\ntype = \"sphere\"\nradius = 0.006\n",
    )
    .unwrap();
    let report = d.join("rep");
    let o = knitvox(&[
        "validate",
        s(&asset_path),
        "--scene",
        s(&scene),
        "--report",
        s(&report),
        "--json",
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    let r: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    eprintln!(
        "rms {} max {} floor {} contacts {} penetration {} m",
        r["rms_yarn_diameters"],
        r["max_yarn_diameters"],
        r["y2v_floor_rms_yarn_diameters"],
        r["max_contacts"],
        r["max_penetration_m"]
    );
    assert_eq!(r["frames"], 3);
    assert_eq!(r["colliders"], 1);
    // No terminal: a line per yarn-level frame on stderr, the report alone
    // on stdout (parsed above).
    for f in 1..=3 {
        let line = format!("validate: yarn level: frame {f} ({f}/3) ");
        assert!(err.contains(&line), "{line:?} not in {err}");
    }
    let radius = asset.rest_yarns.radius_at(0);
    assert!(r["max_contacts"].as_u64().unwrap() > 0, "{r}");
    assert!(
        r["max_penetration_m"].as_f64().unwrap() < 0.1 * radius,
        "{r}"
    );
    // No homogenized yarn vertex ends inside the sphere (centre as yls puts it).
    let read = |p: PathBuf| io::read_path(&p, &ReadOptions::default()).unwrap().yarns;
    let hm = read(report.join("homogenized.0003.ply"));
    let rest = &asset.rest_yarns;
    let (lo, hi) = rest.bounds().map(|b| (b.min, b.max)).unwrap();
    let centre: Vec3 = [
        0.5 * (lo[0] + hi[0]),
        lo[1] - 2.0 * radius - 0.006,
        0.5 * (lo[2] + hi[2]),
    ];
    let inside = hm
        .points
        .iter()
        .map(|p| knitvox::geom::dist(*p, centre))
        .fold(f64::INFINITY, f64::min);
    assert!(
        inside > 0.006 + 0.9 * radius,
        "closest to the centre: {inside}"
    );
    let floor = r["y2v_floor_rms_yarn_diameters"].as_f64().unwrap();
    assert!(floor.is_finite() && floor >= 0.0, "{r}");
    // The mass check found the asset's mass equal to the yarn-level one.
    let (mm, ym) = (
        r["mesh_mass_kg"].as_f64().unwrap(),
        r["yarn_mass_kg"].as_f64().unwrap(),
    );
    assert!((mm - ym).abs() < 1e-6 * ym, "{mm} vs {ym}");
}

#[test]
fn validate_runs_pd_by_default_and_takes_the_solver_and_its_step() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let (asset_path, _) = flat_asset(d);
    let scene = d.join("fall.toml");
    // 3 frames of 1/30 s in free fall.
    std::fs::write(
        &scene,
        "duration = 0.1\nframe_rate = 30\n[pose]\nkind = \"free\"\n",
    )
    .unwrap();
    let run = |extra: &[&str]| -> serde_json::Value {
        let mut args = vec!["validate", s(&asset_path), "--scene", s(&scene), "--json"];
        args.extend_from_slice(extra);
        let o = knitvox(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        serde_json::from_slice(&o.stdout).unwrap()
    };
    let pd = run(&[]);
    assert_eq!(pd["solver"], "pd");
    // 1/30 s frames in steps of at most 1/150 s.
    assert_eq!(pd["solver_steps"], 15, "{pd}");
    assert_eq!(pd["max_substeps"], 5, "{pd}");
    let coarse = run(&["--dt", "1/30"]);
    assert_eq!(coarse["solver_steps"], 3, "{coarse}");
    // Free fall has no contact: the PD iterations of a step stop at their
    // tolerance or at the limit; a limit of 1 is exactly one per step.
    let one = run(&["--pd-iterations", "1"]);
    assert_eq!(one["solver_iterations"], 15, "{one}");
    assert!(pd["solver_iterations"].as_u64().unwrap() > 15, "{pd}");
    for k in ["pd_local_s", "pd_global_s"] {
        assert!(pd[k].as_f64().unwrap() > 0.0, "{k}: {pd}");
    }
    assert_eq!(pd["pd_global_solver"], "direct", "{pd}");
    // The domain-decomposed global solve (exact interiors) gives the same run.
    let cpu = run(&["--backend", "cpu"]);
    assert_eq!(cpu["pd_backend"], "cpu", "{cpu}");
    let dd = run(&["--backend", "cpu", "--pd-solver", "dd"]);
    assert_eq!(dd["pd_global_solver"], "dd", "{dd}");
    let rms = |r: &serde_json::Value| r["rms_yarn_diameters"].as_f64().unwrap();
    assert!(
        (rms(&dd) - rms(&cpu)).abs() < 1e-3 * rms(&cpu),
        "dd {dd} vs direct {cpu}"
    );
    // The GPU backend (f32 local step): where wgpu finds an adapter (lavapipe
    // included) the same run to 1%; without one, exit 69 before the
    // yarn-level run.
    let mut args = vec!["validate", s(&asset_path), "--scene", s(&scene), "--json"];
    args.extend_from_slice(&["--backend", "gpu"]);
    let gpu = knitvox(&args);
    if knitvox::sim::gpu::GpuContext::new().is_ok() {
        assert!(
            gpu.status.success(),
            "{}",
            String::from_utf8_lossy(&gpu.stderr)
        );
        let g: serde_json::Value = serde_json::from_slice(&gpu.stdout).unwrap();
        assert_eq!(g["pd_backend"], "gpu", "{g}");
        assert!(
            (rms(&g) - rms(&cpu)).abs() < 1e-2 * rms(&cpu),
            "gpu {g} vs cpu {cpu}"
        );
    } else {
        assert_eq!(
            gpu.status.code(),
            Some(69),
            "{}",
            String::from_utf8_lossy(&gpu.stderr)
        );
    }
    let newton = run(&["--solver", "newton"]);
    assert_eq!(newton["solver"], "newton");
    assert_eq!(newton["solver_steps"], 3, "{newton}");
    // Free fall: implicit Euler lags the exact fall by g Δt² n / 2 after n
    // steps (one step of 1/30 s per frame: 8 diameters by frame 3; steps of
    // 1/150 s: 1.6), so PD at its default step tracks the yarn level
    // (explicit, tiny steps) far closer than one Newton step per frame.
    let rms = |r: &serde_json::Value| r["rms_yarn_diameters"].as_f64().unwrap();
    eprintln!("free fall RMS: PD {} Newton {}", rms(&pd), rms(&newton));
    assert!(rms(&pd) < 2.0, "{pd}");
    assert!(rms(&newton) > 2.0 * rms(&pd), "{newton}");
    for bad_option in [["--dt", "0"], ["--pd-iterations", "0"]] {
        let mut args = vec!["validate", s(&asset_path), "--scene", s(&scene)];
        args.extend_from_slice(&bad_option);
        let bad = knitvox(&args);
        assert_eq!(
            bad.status.code(),
            Some(2),
            "{bad_option:?}: {}",
            String::from_utf8_lossy(&bad.stderr)
        );
    }
}
