//! HDF5 character caches (schemas/character-hdf5.md): a
//! cache written independently with h5py, in centimetres and Z up with
//! 32-bit floats and 64-bit triangle indices, reads into knitvox's metres,
//! +Y up; hostile variants are refused with the dataset named.

mod common;

use std::process::Command;

use knitvox::io::character_h5::{is_character_cache, read_character_cache};

/// A 2-triangle quad in the x-y plane of a Z-up world, 100 cm wide, moving
/// up (+Z) by 10 cm per frame at 24 fps, written with h5py.
const WRITE_CACHE: &str = r#"
import h5py, numpy as np
quad = np.array([[0, 0, 0], [100, 0, 0], [100, 100, 0], [0, 100, 0]], "f4")
frames = np.stack([quad + [0, 0, 10 * f] for f in range(3)]).astype("f4")
with h5py.File("body.h5", "w") as f:
    f.attrs["knitvox_format"] = "character"
    f.attrs["knitvox_format_version"] = np.int64(1)
    f.attrs["units"] = "cm"
    f.attrs["up_axis"] = "z"
    f.attrs["generator"] = "h5py test"
    g = f.create_group("character")
    g["triangles"] = np.array([[0, 1, 2], [0, 2, 3]], "i8")
    g["times"] = np.arange(3) / 24.0
    g.create_dataset("points", data=frames, chunks=(1, 4, 3), compression="gzip")
"#;

#[test]
fn h5py_cache_reads_in_metres_y_up() {
    if !common::have_h5py() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    common::python(dir.path(), WRITE_CACHE);
    let p = dir.path().join("body.h5");
    assert!(is_character_cache(&p));
    let c = read_character_cache(&p, 1 << 30).unwrap();
    let cache = &c.cache;
    assert_eq!(cache.num_frames(), 3);
    assert_eq!(cache.triangles, vec![[0, 1, 2], [0, 2, 3]]);
    // Z up -> Y up: (x, y, z) -> (x, z, -y); cm -> m.
    let f2 = cache.frame(2);
    let expect = [
        [0.0, 0.2, 0.0],
        [1.0, 0.2, 0.0],
        [1.0, 0.2, -1.0],
        [0.0, 0.2, -1.0],
    ];
    for (a, b) in f2.iter().zip(expect) {
        for k in 0..3 {
            assert!((a[k] - b[k]).abs() < 1e-6, "{a:?} vs {b:?}");
        }
    }
    // Half-way between frames 0 and 1 the body is 5 cm up.
    let mid = cache.positions_at(0.5 / 24.0);
    assert!((mid[0][1] - 0.05).abs() < 1e-6, "{:?}", mid[0]);
    // No rest pose stored: the first frame is the rest.
    assert_eq!(cache.rest_positions(), cache.frame(0));
}

#[test]
fn hostile_caches_are_refused_naming_the_dataset() {
    if !common::have_h5py() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    common::python(dir.path(), WRITE_CACHE);
    std::fs::write(dir.path().join("secret.raw"), vec![0u8; 288]).unwrap();
    common::python(
        dir.path(),
        r#"
import h5py, shutil, numpy as np
for name in ["ext", "badtri", "backwards", "huge", "nan"]:
    shutil.copy("body.h5", name + ".h5")
with h5py.File("ext.h5", "a") as f:
    del f["character/points"]
    f["character"].create_dataset("points", (3, 4, 3), "f8", external=[("secret.raw", 0, 288)])
with h5py.File("badtri.h5", "a") as f:
    f["character/triangles"][1, 2] = 7
with h5py.File("backwards.h5", "a") as f:
    f["character/times"][2] = 0.0
with h5py.File("huge.h5", "a") as f:
    del f["character/points"]
    f["character"].create_dataset("points", (3, 10**9, 3), "f4", chunks=(1, 1000, 3), compression="gzip")
with h5py.File("nan.h5", "a") as f:
    f["character/points"][1, 2, 0] = np.nan
"#,
    );
    for (file, needles) in [
        ("ext.h5", &["/character/points", "external"][..]),
        ("badtri.h5", &["/character/triangles/1", "out of range"][..]),
        ("backwards.h5", &["/character/times/2", "increase"][..]),
        ("huge.h5", &["/character/points", "memory budget"][..]),
        ("nan.h5", &["/character/points/1/2", "not finite"][..]),
    ] {
        let e = read_character_cache(&dir.path().join(file), 1 << 30)
            .unwrap_err()
            .to_string();
        assert!(e.contains(file), "{file}: {e}");
        for n in needles {
            assert!(e.contains(n), "{file}: expected '{n}' in: {e}");
        }
    }
}

/// A bake samples the skinned body exactly, and between samples the cache
/// is within the linear-interpolation error of the motion (Fox.glb's Walk,
/// ~80 units tall, baked at 600 fps: well under 0.01 units).
#[test]
fn bake_of_fox_matches_skinning_between_samples() {
    use knitvox::anim::cache::BodyCache;
    let fox = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("examples/Fox.glb");
    let ch = knitvox::io::gltf_skin::read_character(&fox).unwrap();
    let anim = ch.animation_index("Walk");
    let duration = ch.duration(anim.unwrap());
    let times: Vec<f64> = (0..=(duration * 600.0).ceil() as usize)
        .map(|k| (k as f64 / 600.0).min(duration))
        .collect();
    let cache = BodyCache::bake(&ch, anim, &times);
    let mut worst = 0.0f64;
    for i in 0..50 {
        let t = duration * (i as f64 + 0.37) / 50.0;
        let a = cache.positions_at(t);
        let b = ch.skinned_positions(anim, t);
        for (p, q) in a.iter().zip(&b) {
            worst = worst.max((0..3).map(|k| (p[k] - q[k]).abs()).fold(0.0, f64::max));
        }
    }
    eprintln!("largest interpolation error {worst:.3e} units");
    assert!(worst < 1e-2, "{worst}");
    assert_eq!(
        cache.positions_at(times[7]),
        ch.skinned_positions(anim, times[7])
    );
}

/// `knitvox inspect CHAR.h5` recognises a character cache and summarises it;
/// a hostile one is an error naming the dataset (exit 65).
#[test]
fn inspect_summarises_a_character_cache() {
    if !common::have_h5py() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    common::python(dir.path(), WRITE_CACHE);
    let o = Command::new(common::knitvox_bin())
        .args(["inspect", "body.h5", "--json"])
        .current_dir(dir.path())
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v[0]["format"], "character-hdf5", "{v}");
    assert_eq!(v[0]["frames"], 3);
    assert_eq!(v[0]["vertices"], 4);
    assert_eq!(v[0]["triangles"], 2);
    assert!((v[0]["duration_s"].as_f64().unwrap() - 2.0 / 24.0).abs() < 1e-12);
    common::python(
        dir.path(),
        r#"
import h5py
with h5py.File("body.h5", "a") as f:
    f["character/triangles"][0, 0] = 9
"#,
    );
    let o = Command::new(common::knitvox_bin())
        .args(["inspect", "body.h5"])
        .current_dir(dir.path())
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(65), "{e}");
    assert!(e.contains("/character/triangles/0"), "{e}");
}
