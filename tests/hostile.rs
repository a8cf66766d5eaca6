//! Hostile inputs: reads stay in the input's folder,
//! declared sizes are bounded by the memory budget, counts are bounded,
//! outputs never overwrite inputs. Every input is generated here; every run
//! has a deadline.
mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// Runs knitvox with a deadline (a hang is a failure, not a stuck test).
fn knitvox_in(dir: &Path, args: &[&str], deadline: Duration) -> (Output, Duration) {
    let t0 = Instant::now();
    let mut child = Command::new(common::knitvox_bin())
        .args(args)
        .current_dir(dir)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run knitvox");
    loop {
        if child.try_wait().expect("wait").is_some() {
            break;
        }
        if t0.elapsed() > deadline {
            let _ = child.kill();
            let o = child.wait_with_output().unwrap();
            panic!(
                "knitvox {args:?} still running after {deadline:?}: {}",
                String::from_utf8_lossy(&o.stderr)
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let elapsed = t0.elapsed();
    (child.wait_with_output().unwrap(), elapsed)
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("knitvox-hostile-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// 4 float32 points (48 bytes) whose values are recognisable in an output.
const MARK: [f32; 12] = [
    1.25, 2.5, 3.75, 4.5, 5.25, 6.75, 7.5, 8.25, 9.75, 10.5, 11.25, 12.75,
];

fn mark_bytes() -> Vec<u8> {
    MARK.iter().flat_map(|f| f.to_le_bytes()).collect()
}

/// A glTF with one LINE_STRIP of 4 points in buffer 0 at `uri`.
fn gltf_with_uri(uri: &str) -> String {
    serde_json::json!({
        "asset": {"version": "2.0"},
        "scenes": [{"nodes": [0]}], "scene": 0,
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "mode": 3}]}],
        "buffers": [{"byteLength": 48, "uri": uri}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 48}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
                       "min": [1.25, 2.5, 3.75], "max": [10.5, 11.25, 12.75]}]
    })
    .to_string()
}

#[test]
fn gltf_uris_stay_in_the_folder() {
    let root = scratch("uri");
    let input = root.join("in");
    std::fs::create_dir_all(&input).unwrap();
    let secret = root.join("secret.bin");
    std::fs::write(&secret, mark_bytes()).unwrap();
    std::fs::write(input.join("ok.bin"), mark_bytes()).unwrap();
    std::os::unix::fs::symlink(&secret, input.join("link.bin")).unwrap();
    std::os::unix::fs::symlink("/dev/zero", input.join("zero.bin")).unwrap();
    let fifo = input.join("fifo.bin");
    let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o644) }, 0);

    // Control: a URI inside the folder is read (the test can fail).
    std::fs::write(input.join("a.gltf"), gltf_with_uri("ok.bin")).unwrap();
    let (o, _) = knitvox_in(
        &input,
        &["convert", "a.gltf", "ok.obj"],
        Duration::from_secs(20),
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(std::fs::read_to_string(input.join("ok.obj"))
        .unwrap()
        .contains("1.25"));

    let abs = secret.to_str().unwrap().to_string();
    let abs_encoded = abs.replace('/', "%2F");
    let cases: Vec<(String, &str)> = vec![
        ("../secret.bin".into(), "outside the file's folder"),
        ("..%2Fsecret.bin".into(), "outside the file's folder"),
        ("%2E%2E/secret.bin".into(), "outside the file's folder"),
        (abs.clone(), "absolute"),
        (abs_encoded, "absolute"),
        ("%2Fetc%2Fpasswd".into(), "absolute"),
        (format!("file://{abs}"), "scheme"),
        ("link.bin".into(), "outside the file's folder"),
        ("fifo.bin".into(), "FIFO"),
        ("zero.bin".into(), "outside the file's folder"),
        ("/dev/zero".into(), "absolute"),
        (".".into(), "not a regular file"),
    ];
    for (i, (uri, why)) in cases.iter().enumerate() {
        let name = format!("h{i}.gltf");
        std::fs::write(input.join(&name), gltf_with_uri(uri)).unwrap();
        let out = format!("h{i}.obj");
        let (o, t) = knitvox_in(&input, &["convert", &name, &out], Duration::from_secs(20));
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(65), "{uri}: {e}");
        assert!(
            e.contains(&name) && e.contains("/buffers/0/uri") && e.contains(why),
            "{uri}: {e}"
        );
        assert!(t < Duration::from_secs(10), "{uri}: took {t:?}");
        assert!(!input.join(&out).exists(), "{uri}: output written");
    }
    // No byte from outside the folder in any output.
    for entry in std::fs::read_dir(&input).unwrap() {
        let p = entry.unwrap().path();
        if p.extension().is_some_and(|e| e == "obj") && p.file_name().unwrap() != "ok.obj" {
            panic!("unexpected output {}", p.display());
        }
    }
    std::fs::remove_dir_all(&root).unwrap();
}

#[test]
fn gltf_buffer_reads_at_most_byte_length() {
    let root = scratch("short");
    // Declares 48 bytes, file holds 20: refused with both numbers.
    std::fs::write(root.join("short.bin"), &mark_bytes()[..20]).unwrap();
    std::fs::write(root.join("a.gltf"), gltf_with_uri("short.bin")).unwrap();
    let (o, _) = knitvox_in(&root, &["inspect", "a.gltf"], Duration::from_secs(20));
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(65), "{e}");
    assert!(e.contains("20 bytes") && e.contains("48"), "{e}");
    // Declares more than the memory budget: refused before reading.
    let big = gltf_with_uri("short.bin").replace(
        "\"byteLength\":48,\"uri\"",
        "\"byteLength\":1000000000000,\"uri\"",
    );
    assert!(big.contains("1000000000000"), "{big}");
    std::fs::write(root.join("b.gltf"), big).unwrap();
    let (o, _) = knitvox_in(
        &root,
        &["inspect", "--max-memory", "1G", "b.gltf"],
        Duration::from_secs(20),
    );
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(65), "{e}");
    assert!(
        e.contains("b.gltf") && e.contains("/buffers/0/byteLength") && e.contains("1073741824"),
        "{e}"
    );
    std::fs::remove_dir_all(&root).unwrap();
}

/// A valid knitvox yarns file `base.h5` in `dir` (made by the binary).
fn yarns_h5(dir: &Path) {
    std::fs::write(dir.join("ok.bin"), mark_bytes()).unwrap();
    std::fs::write(dir.join("src.gltf"), gltf_with_uri("ok.bin")).unwrap();
    let (o, _) = knitvox_in(
        dir,
        &["convert", "src.gltf", "base.h5"],
        Duration::from_secs(20),
    );
    assert!(o.status.success(), "{}", stderr(&o));
}

#[test]
fn hdf5_data_outside_the_file_is_refused() {
    if !common::have_h5py() {
        return;
    }
    let dir = scratch("h5ext");
    yarns_h5(&dir);
    // Control: the base file reads.
    let (o, _) = knitvox_in(&dir, &["inspect", "base.h5"], Duration::from_secs(20));
    assert!(o.status.success(), "{}", stderr(&o));
    std::fs::write(dir.join("secret.raw"), vec![0u8; 96]).unwrap();
    common::python(
        &dir,
        r#"
import h5py, shutil, numpy as np
for name in ["ext", "link", "virt"]:
    shutil.copy("base.h5", name + ".h5")
with h5py.File("ext.h5", "a") as f:
    del f["yarns/points"]
    f["yarns"].create_dataset("points", (4, 3), "f8", external=[("secret.raw", 0, 96)])
with h5py.File("other.h5", "w") as g:
    g["data"] = np.zeros((4, 3))
with h5py.File("link.h5", "a") as f:
    del f["yarns/points"]
    f["yarns/points"] = h5py.ExternalLink("other.h5", "/data")
with h5py.File("virt.h5", "a") as f:
    del f["yarns/points"]
    lay = h5py.VirtualLayout(shape=(4, 3), dtype="f8")
    lay[:] = h5py.VirtualSource("other.h5", "data", shape=(4, 3))
    f["yarns"].create_virtual_dataset("points", lay)
"#,
    );
    for (file, why) in [
        ("ext.h5", "external file"),
        ("link.h5", "external link"),
        ("virt.h5", "virtual dataset"),
    ] {
        // `inspect` lists hard links only; `convert` reads the yarns.
        let (o, _) = knitvox_in(&dir, &["convert", file, "out.obj"], Duration::from_secs(20));
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(65), "{file}: {e}");
        assert!(!dir.join("out.obj").exists());
        assert!(
            e.contains(file) && e.contains("/yarns/points") && e.contains(why),
            "{file}: {e}"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn decompression_bomb_is_refused_under_the_budget() {
    if !common::have_h5py() {
        return;
    }
    let dir = scratch("bomb");
    yarns_h5(&dir);
    // 180M points declared (4.3 GB of f64), gzip, one chunk written: a 4 MB file.
    common::python(
        &dir,
        r#"
import h5py, shutil, numpy as np
shutil.copy("base.h5", "bomb.h5")
with h5py.File("bomb.h5", "a") as f:
    n = 180_000_000
    for k in ["points", "offsets", "closed", "radius"]:
        if k in f["yarns"]:
            del f["yarns"][k]
    d = f["yarns"].create_dataset("points", (n, 3), "f8", chunks=(1 << 20, 3), compression="gzip")
    # About 4 MB of incompressible data: the file could plausibly expand
    # (gzip ratio) to what it declares, so only the budget refuses it.
    d[:200_000] = np.random.default_rng(1).random((200_000, 3))
    f["yarns"].create_dataset("offsets", data=np.array([0, n], dtype="i8"))
    f["yarns"].create_dataset("closed", data=np.array([0], dtype="u1"))
    f["yarns"].create_dataset("radius", data=np.array([0.001]))
"#,
    );
    let size = std::fs::metadata(dir.join("bomb.h5")).unwrap().len();
    assert!(size < 5 << 20, "bomb file is {size} bytes");
    let (o, t) = knitvox_in(
        &dir,
        &["inspect", "--max-memory", "1G", "bomb.h5"],
        Duration::from_secs(20),
    );
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(65), "{e}");
    assert!(
        e.contains("bomb.h5")
            && e.contains("/yarns/points")
            && e.contains("4320000000 bytes")
            && e.contains("1073741824"),
        "{e}"
    );
    eprintln!("bomb of {size} bytes refused in {t:?}");
    assert!(t < Duration::from_secs(5), "took {t:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn overflowing_counts_are_usage_errors() {
    let dir = scratch("counts");
    std::fs::write(dir.join("s.toml"), "[simulation]\n").unwrap();
    for (args, want) in [
        (
            &[
                "export",
                "a.vtkhdf",
                "--frames",
                "9223372036854775807",
                "-o",
                "d",
            ][..],
            "9223372036854775807",
        ),
        (
            &[
                "export",
                "a.vtkhdf",
                "--frames=-9223372036854775808-9223372036854775807",
                "-o",
                "d",
            ],
            "1000000000",
        ),
        (
            &[
                "convert",
                "a.obj",
                "b.obj",
                "--first-frame",
                "9223372036854775807",
            ],
            "first-frame",
        ),
        (
            &["embed", "a.obj", "-o", "a.vtkhdf", "--max-memory", "12Q"],
            "max-memory",
        ),
        (
            &[
                "simulate",
                "a.vtkhdf",
                "--scene",
                "s.toml",
                "--frames",
                "1-1000000",
                "--dt",
                "1e-6",
                "-o",
                "o.vtkhdf",
            ],
            "more than the limit of 10000000",
        ),
        (
            &[
                "simulate", "a.vtkhdf", "--scene", "s.toml", "--frames", "1-2", "--fps", "1e-300",
                "-o", "o.vtkhdf",
            ],
            "more than the limit of 10000000",
        ),
    ] {
        let (o, t) = knitvox_in(&dir, args, Duration::from_secs(10));
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {e}");
        assert!(e.contains(want), "{args:?}: {e}");
        assert!(t < Duration::from_secs(5));
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn outputs_never_overwrite_inputs() {
    let dir = scratch("overwrite");
    let obj = "v 0 0 0\nv 0.01 0 0\nv 0.02 0.01 0\nl 1 2 3\n";
    std::fs::write(dir.join("a.obj"), obj).unwrap();
    std::os::unix::fs::symlink(dir.join("a.obj"), dir.join("alias.obj")).unwrap();
    std::fs::create_dir_all(dir.join("sub")).unwrap();
    for args in [
        &["convert", "a.obj", "a.obj"][..],
        &["convert", "a.obj", "./a.obj"],
        &["convert", "a.obj", "alias.obj"],
        &["convert", "a.obj", "sub/../a.obj"],
        &["embed", "a.obj", "-o", "./alias.obj"],
        &[
            "pattern",
            "--grid",
            "a.obj",
            "--courses",
            "2",
            "--wales",
            "2",
            "-o",
            "a.obj",
        ],
    ] {
        let (o, _) = knitvox_in(&dir, args, Duration::from_secs(20));
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {e}");
        assert!(
            e.contains("never overwrites an input") && e.contains("a.obj"),
            "{args:?}: {e}"
        );
        assert_eq!(
            std::fs::read_to_string(dir.join("a.obj")).unwrap(),
            obj,
            "{args:?}"
        );
    }
    // Control: another name converts.
    let (o, _) = knitvox_in(
        &dir,
        &["convert", "a.obj", "b.obj"],
        Duration::from_secs(20),
    );
    assert!(o.status.success(), "{}", stderr(&o));
    for name in ["../x", "a/b", ".."] {
        let (o, _) = knitvox_in(
            &dir,
            &["export", "a.vtkhdf", "-o", "sub", "--name", name],
            Duration::from_secs(10),
        );
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{name}: {e}");
        assert!(e.contains("--name"), "{name}: {e}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn sigterm_mid_write_leaves_no_temporary() {
    let dir = scratch("sigterm");
    // A long yarn-level run streams its frames into a temporary HDF5 file.
    std::fs::write(
        dir.join("long.toml"),
        "name = \"long\"\nduration = 100.0\nframe_rate = 60\ngravity = [0.0, 0.0, 0.0]\n\
         [swatch]\npattern = \"rib1x1\"\ncourses = 4\nwales = 4\n\
         [pose]\nkind = \"biaxial\"\namount = 0.2\n",
    )
    .unwrap();
    let mut child = Command::new(common::knitvox_bin())
        .args(["yls", "long.toml", "-o", "out.h5", "--no-progress"])
        .current_dir(&dir)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let temps = |dir: &Path| -> Vec<String> {
        std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.ends_with(".tmp"))
            .collect()
    };
    // Wait until the temporary exists (the write is in flight).
    let t0 = Instant::now();
    while temps(&dir).is_empty() {
        if let Some(s) = child.try_wait().unwrap() {
            panic!(
                "yls ended early ({s}): {:?}",
                child.wait_with_output().unwrap().stderr
            );
        }
        if t0.elapsed() > Duration::from_secs(120) {
            // Never leave the run behind a failed test.
            let _ = child.kill();
            let _ = child.wait();
            panic!("no temporary file appeared in 120 s");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGTERM) };
    let t1 = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if t1.elapsed() > Duration::from_secs(10) {
            let _ = child.kill();
            let _ = child.wait();
            panic!("SIGTERM did not end the run");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    use std::os::unix::process::ExitStatusExt;
    assert_eq!(status.signal(), Some(libc::SIGTERM), "{status}");
    assert!(temps(&dir).is_empty(), "left behind: {:?}", temps(&dir));
    assert!(!dir.join("out.h5").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn scene_counts_are_bounded_and_name_the_key() {
    let dir = scratch("scenes");
    std::fs::write(
        dir.join("it.toml"),
        "[simulation]\nmax_iterations = 4000000000\n",
    )
    .unwrap();
    std::fs::write(
        dir.join("folds.toml"),
        "name = \"f\"\nduration = 1.0\nframe_rate = 60\n[swatch]\npattern = \"rib1x1\"\ncourses = 4\nwales = 4\n\
         [pose]\nkind = \"multi_fold\"\namount = 0.1\nfolds = 4000000000\n",
    )
    .unwrap();
    std::fs::write(
        dir.join("frames.toml"),
        "name = \"f\"\nduration = 1e300\nframe_rate = 1e300\n[swatch]\npattern = \"rib1x1\"\ncourses = 4\nwales = 4\n\
         [pose]\nkind = \"biaxial\"\namount = 0.1\n",
    )
    .unwrap();
    for (args, words) in [
        (
            &[
                "simulate", "a.vtkhdf", "--scene", "it.toml", "--frames", "1-2", "-o", "o.vtkhdf",
            ][..],
            &["it.toml", "max_iterations", "10000"][..],
        ),
        (&["yls", "folds.toml", "-o", "o.h5"], &["folds", "10000"]),
        (
            &["yls", "frames.toml", "-o", "o.h5"],
            &["frames.toml", "duration", "1000000"],
        ),
    ] {
        let (o, t) = knitvox_in(&dir, args, Duration::from_secs(20));
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(65), "{args:?}: {e}");
        for w in words {
            assert!(e.contains(w), "{args:?}: {e} lacks {w}");
        }
        assert!(t < Duration::from_secs(5), "{args:?}: {t:?}");
        assert!(!dir.join("o.h5").exists() && !dir.join("o.vtkhdf").exists());
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// An error quotes at most a short piece of one line of the
/// input (a 5,000-character token, a multi-line TOML error, a long URI), so
/// the message is one line that a farm log and a failed-job file can hold.
#[test]
fn messages_quote_at_most_one_short_line_of_the_input() {
    let dir = scratch("excerpt");
    let long = "q".repeat(5000);
    let files = [
        ("a.obj", format!("v 0 0 0\nv 1 0 0\nl 1 2 {long}\n")),
        ("b.poly", format!("POINTS\n1: 0 0 {long}\n")),
        (
            "c.ply",
            format!("ply\nformat ascii 1.0\nelement {long} 1\nproperty float x\nend_header\n1\n"),
        ),
        ("d.gltf", gltf_with_uri(&format!("{long}.bin"))),
        (
            "e.gltf",
            gltf_with_uri("x.bin").replace("\"2.0\"", &format!("\"{long}\"")),
        ),
    ];
    let mut runs: Vec<(Vec<String>, i32)> = Vec::new();
    for (name, text) in &files {
        std::fs::write(dir.join(name), text).unwrap();
        runs.push((vec!["inspect".into(), name.to_string()], 65));
    }
    std::fs::write(dir.join("a.vtkhdf"), b"").unwrap();
    for (name, text) in [
        ("s1.toml", "[simulation]\ndt = \"abc\nfps = 3\n".to_string()),
        ("s2.toml", format!("[simulation]\nfps = \"{long}\"\n")),
    ] {
        std::fs::write(dir.join(name), text).unwrap();
        runs.push((
            [
                "simulate", "a.vtkhdf", "--scene", name, "--frames", "1-2", "-o", "o.vtkhdf",
            ]
            .map(String::from)
            .to_vec(),
            65,
        ));
    }
    for (args, code) in &runs {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let (o, _) = knitvox_in(&dir, &args, Duration::from_secs(10));
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(*code), "{args:?}: {e}");
        assert_eq!(e.trim_end().lines().count(), 1, "{:?}: {e}", &args[..2]);
        assert!(!e.contains(&"q".repeat(100)), "{:?}: {e}", &args[..2]);
        assert!(e.len() < 800, "{:?}: {} bytes: {e}", &args[..2], e.len());
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A small swatch asset (4 x 4 loops, 2.5 mm voxels) at `dir/name`, made
/// through the library (no steps).
fn small_asset(dir: &Path, name: &str) -> PathBuf {
    use knitvox::io::{vtkhdf, ReadOptions, WriteOptions};
    use knitvox::yarn::analytic::{knit_swatch, SwatchParams};
    let yarns = knit_swatch(&SwatchParams {
        courses: 4,
        wales: 4,
        with_ring: false,
        points_per_loop: 12,
        ..SwatchParams::default()
    });
    let bcc = dir.join("swatch.bcc");
    knitvox::io::write_path(&bcc, &yarns, None, &WriteOptions::default()).unwrap();
    let read = ReadOptions {
        radius: yarns.radius[0],
        ..ReadOptions::default()
    };
    let params = knitvox::embed::EmbedParams {
        voxel_size: Some(2.5e-3),
        ..Default::default()
    };
    let (asset, _) = knitvox::pipeline::asset::build_asset(&bcc, &read, &params, "test").unwrap();
    let path = dir.join(name);
    vtkhdf::write_asset(&path, &asset).unwrap();
    path
}

/// Replaces `group/name` of `file` by an (rows x 3) f64 dataset, gzip in
/// chunks of 2^20 rows, with only its first `written` rows stored
/// (pseudo-random, so they do not compress away).
fn h5_bomb_dataset(file: &hdf5::File, group: &str, name: &str, rows: usize, written: usize) {
    let g = file.group(group).unwrap();
    g.unlink(name).unwrap();
    let ds = g
        .new_dataset::<f64>()
        .shape((rows, 3))
        .chunk((1 << 20, 3))
        .deflate(6)
        .create(name)
        .unwrap();
    if written > 0 {
        let mut x: u64 = 0x9e37_79b9_7f4a_7c15;
        let v: Vec<f64> = (0..written * 3)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                (x >> 11) as f64 / (1u64 << 53) as f64
            })
            .collect();
        let a = ndarray::Array2::from_shape_vec((written, 3), v).unwrap();
        ds.write_slice(&a, ndarray::s![0..written, ..]).unwrap();
    }
}

#[test]
fn vtkhdf_bomb_is_refused_under_the_budget() {
    let dir = scratch("vtkbomb");
    let n: usize = 180_000_000;
    for (file, written) in [("bomb.vtkhdf", 200_000), ("empty.vtkhdf", 0)] {
        let path = small_asset(&dir, file);
        // 180M nodes declared (4.32 GB of f64 each for the rest nodes and
        // the points); bomb.vtkhdf stores ~4 MB of them, enough for the
        // gzip ratio to make the claim plausible, so only the budget
        // refuses it; empty.vtkhdf stores nothing.
        let f = common::h5_edit(&path);
        h5_bomb_dataset(&f, "knitvox", "rest_nodes", n, written);
        h5_bomb_dataset(&f, "VTKHDF", "Points", n, 0);
        {
            let vtk = f.group("VTKHDF").unwrap();
            vtk.unlink("NumberOfPoints").unwrap();
            vtk.new_dataset_builder()
                .with_data(&[n as i64])
                .create("NumberOfPoints")
                .unwrap();
        }
        // Every handle is dropped: closing really releases the file's lock.
        f.close().unwrap();
        let size = std::fs::metadata(&path).unwrap().len();
        assert!(size < 6 << 20, "{file} is {size} bytes");
        for cmd in [&["inspect", file][..], &["export", file, "-o", "out"]] {
            let args: Vec<&str> = [cmd, &["--max-memory", "1G"]].concat();
            let (o, t) = knitvox_in(&dir, &args, Duration::from_secs(20));
            let e = stderr(&o);
            assert_eq!(o.status.code(), Some(65), "{args:?}: {e}");
            assert!(
                e.contains(file)
                    && e.contains("/knitvox/rest_nodes")
                    && e.contains("4320000000 bytes"),
                "{args:?}: {e}"
            );
            if written > 0 {
                assert!(e.contains("memory budget of 1073741824 bytes"), "{e}");
            } else {
                assert!(e.contains("stores only 0 bytes"), "{e}");
            }
            eprintln!("{file} ({size} bytes): {:?} refused in {t:?}", cmd[0]);
            assert!(t < Duration::from_secs(5), "took {t:?}");
            assert!(
                !dir.join("out").exists()
                    || std::fs::read_dir(dir.join("out")).unwrap().count() == 0
            );
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn vtkhdf_arrays_together_stay_under_the_budget() {
    let dir = scratch("vtktotal");
    // 20M nodes: the rest nodes alone (480 MB) fit a 600 MB budget, the
    // nodes' arrays together (640 MB) do not.
    let n: usize = 20_000_000;
    let path = small_asset(&dir, "big.vtkhdf");
    let f = common::h5_edit(&path);
    h5_bomb_dataset(&f, "knitvox", "rest_nodes", n, 100_000);
    h5_bomb_dataset(&f, "VTKHDF", "Points", n, 0);
    {
        let vtk = f.group("VTKHDF").unwrap();
        vtk.unlink("NumberOfPoints").unwrap();
        vtk.new_dataset_builder()
            .with_data(&[n as i64])
            .create("NumberOfPoints")
            .unwrap();
    }
    f.close().unwrap();
    let (o, t) = knitvox_in(
        &dir,
        &["inspect", "--max-memory", "600M", "big.vtkhdf"],
        Duration::from_secs(20),
    );
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(65), "{e}");
    assert!(
        e.contains("big.vtkhdf")
            && e.contains("20000000 nodes")
            && e.contains("memory budget of 629145600 bytes"),
        "{e}"
    );
    eprintln!("20M-node asset refused in {t:?}");
    assert!(t < Duration::from_secs(5), "took {t:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Runs `args` in `dir` and asserts a usage error (exit 2) naming the
/// output and `input`, with `input` byte-identical afterwards.
fn assert_refused_overwrite(dir: &Path, args: &[&str], input: &str) {
    let before = std::fs::read(dir.join(input)).unwrap();
    let (o, _) = knitvox_in(dir, args, Duration::from_secs(30));
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{args:?}: {e}");
    assert!(
        e.contains("never overwrites an input") && e.contains(input),
        "{args:?}: {e}"
    );
    assert_eq!(std::fs::read(dir.join(input)).unwrap(), before, "{args:?}");
}

#[test]
fn inputs_named_by_scenes_sequences_and_links_are_never_outputs() {
    let dir = scratch("overwrite2");
    let obj = "v 0 0 0\nv 0.01 0 0\nv 0.02 0.01 0\nl 1 2 3\n";
    std::fs::write(dir.join("a.obj"), obj).unwrap();
    std::fs::hard_link(dir.join("a.obj"), dir.join("hard.obj")).unwrap();
    std::fs::write(dir.join("s.0001.obj"), obj).unwrap();
    // Hard link; an output sequence that would write the input frame; an
    // output frame of an input sequence.
    assert_refused_overwrite(&dir, &["convert", "a.obj", "hard.obj"], "a.obj");
    assert_refused_overwrite(&dir, &["convert", "s.0001.obj", "s.####.obj"], "s.0001.obj");
    assert_refused_overwrite(&dir, &["convert", "s.####.obj", "s.0001.obj"], "s.0001.obj");
    // simulate: the character the scene names is an input.
    small_asset(&dir, "a.vtkhdf");
    let fox = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("examples/Fox.glb");
    std::fs::copy(fox, dir.join("char.0001.glb")).unwrap();
    std::fs::write(
        dir.join("shot.toml"),
        "[character]\nfile = \"char.0001.glb\"\n",
    )
    .unwrap();
    assert_refused_overwrite(
        &dir,
        &[
            "simulate",
            "a.vtkhdf",
            "--scene",
            "shot.toml",
            "--frames",
            "1",
            "-o",
            "o.vtkhdf",
            "--yarns-out",
            "char.####.glb",
        ],
        "char.0001.glb",
    );
    assert!(!dir.join("o.vtkhdf").exists());
    // yls: the swatch file the scene names.
    knitvox::io::write_path(
        &dir.join("sw.h5"),
        &knitvox::io::read_path(&dir.join("a.obj"), &Default::default())
            .unwrap()
            .yarns,
        None,
        &Default::default(),
    )
    .unwrap();
    std::fs::write(
        dir.join("y.toml"),
        "name = \"y\"\nduration = 0.1\nframe_rate = 30\n[swatch]\nfile = \"sw.h5\"\n\
         [pose]\nkind = \"biaxial\"\namount = 0.1\n",
    )
    .unwrap();
    assert_refused_overwrite(&dir, &["yls", "y.toml", "-o", "./sw.h5"], "sw.h5");
    // fabric-test: the output folder's stretch.h5 is the input.
    std::fs::copy(dir.join("sw.h5"), dir.join("stretch.h5")).unwrap();
    assert_refused_overwrite(
        &dir,
        &["fabric-test", "stretch", "stretch.h5", "-o", "."],
        "stretch.h5",
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Files in `dir` (not recursive) whose names show a temporary of
/// io::atomic: `.NAME.XXXX.tmp` or a moved-aside `.NAME.XXXX.old`.
fn leftovers(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .map(|r| {
            r.map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .filter(|n| n.ends_with(".tmp") || n.ends_with(".old"))
                .collect()
        })
        .unwrap_or_default()
}

#[test]
fn simulate_with_a_failing_yarns_out_leaves_every_output_as_it_was() {
    let dir = scratch("allornothing");
    small_asset(&dir, "a.vtkhdf");
    std::fs::write(dir.join("s.toml"), "[simulation]\n").unwrap();
    // Outputs of an earlier run, and a folder where frame 2 would go: every
    // file writes, the rename of frame 2 fails.
    std::fs::write(dir.join("o.vtkhdf"), b"earlier asset").unwrap();
    std::fs::create_dir_all(dir.join("y/f.0002.ply")).unwrap();
    std::fs::write(dir.join("y/f.0001.ply"), b"earlier frame").unwrap();
    let args = [
        "simulate",
        "a.vtkhdf",
        "--scene",
        "s.toml",
        "--frames",
        "1-3",
        "-o",
        "o.vtkhdf",
        "--yarns-out",
        "y/f.####.ply",
        // All or nothing: without checkpoints (a resumable shot names
        // each frame as it is done; tests/chunks.rs).
        "--checkpoint-every",
        "0",
    ];
    let (o, _) = knitvox_in(&dir, &args, Duration::from_secs(60));
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(74), "{e}");
    assert!(e.contains("f.0002.ply"), "{e}");
    assert_eq!(
        std::fs::read(dir.join("o.vtkhdf")).unwrap(),
        b"earlier asset"
    );
    assert_eq!(
        std::fs::read(dir.join("y/f.0001.ply")).unwrap(),
        b"earlier frame"
    );
    assert!(!dir.join("y/f.0003.ply").exists());
    assert!(leftovers(&dir).is_empty() && leftovers(&dir.join("y")).is_empty());
    // Control: without the obstacle every output is replaced.
    std::fs::remove_dir(dir.join("y/f.0002.ply")).unwrap();
    let (o, _) = knitvox_in(&dir, &args, Duration::from_secs(60));
    assert!(o.status.success(), "{}", stderr(&o));
    assert_ne!(
        std::fs::read(dir.join("o.vtkhdf")).unwrap(),
        b"earlier asset"
    );
    assert!(dir.join("y/f.0003.ply").is_file());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn sigterm_while_simulate_writes_leaves_nothing() {
    let dir = scratch("sigterm-sim");
    small_asset(&dir, "a.vtkhdf");
    std::fs::write(dir.join("s.toml"), "[simulation]\n").unwrap();
    // One step per frame, many frames: the write phase (one staged file
    // per frame) lasts long enough to be interrupted.
    let mut child = Command::new(common::knitvox_bin())
        .args([
            "simulate",
            "a.vtkhdf",
            "--scene",
            "s.toml",
            "--frames",
            "1-4000",
            "--fps",
            "1000",
            "--dt",
            "0.001",
            "-o",
            "o.vtkhdf",
            "--yarns-out",
            "y/f.####.ply",
            // All or nothing: without checkpoints SIGTERM removes the
            // staged frames and ends the process (with checkpoints it
            // checkpoints and exits 75; tests/chunks.rs).
            "--checkpoint-every",
            "0",
        ])
        .current_dir(&dir)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let y = dir.join("y");
    let t0 = Instant::now();
    // More temporaries than the signal handler's first versions could hold.
    while leftovers(&y).len() < 300 {
        if let Some(s) = child.try_wait().unwrap() {
            panic!(
                "simulate ended early ({s}): {:?}",
                child.wait_with_output().unwrap().stderr
            );
        }
        assert!(
            t0.elapsed() < Duration::from_secs(120),
            "no temporary file appeared"
        );
        std::thread::sleep(Duration::from_millis(2));
    }
    let seen = leftovers(&y).len();
    unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGTERM) };
    let status = child.wait().unwrap();
    eprintln!("SIGTERM with {seen} temporaries in flight");
    use std::os::unix::process::ExitStatusExt;
    assert_eq!(status.signal(), Some(libc::SIGTERM), "{status}");
    for d in [&dir, &y] {
        let left = leftovers(d);
        assert!(
            left.is_empty(),
            "{} left, e.g. {:?}",
            left.len(),
            left.first()
        );
    }
    let finals: Vec<_> = std::fs::read_dir(&y).unwrap().collect();
    assert!(
        finals.is_empty() && !dir.join("o.vtkhdf").exists(),
        "{finals:?}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Names a scene gives for the character's animation and
/// fit joint are quoted cut to one short line when they are not found.
#[test]
fn unknown_scene_animation_and_joint_are_quoted_short() {
    let dir = scratch("scene-names");
    small_asset(&dir, "a.vtkhdf");
    std::fs::copy(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/Fox.glb"),
        dir.join("Fox.glb"),
    )
    .unwrap();
    let long = "q".repeat(5000);
    for key in ["animation", "fit_joint"] {
        let scene =
            format!("[character]\nfile = \"Fox.glb\"\nscale = 0.0025\n{key} = \"{long}\"\n");
        std::fs::write(dir.join("s.toml"), scene).unwrap();
        let args = [
            "simulate", "a.vtkhdf", "--scene", "s.toml", "--frames", "1-2", "-o", "o.vtkhdf",
        ];
        let (o, _) = knitvox_in(&dir, &args, Duration::from_secs(30));
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(65), "{key}: {e}");
        assert!(e.contains(&format!("character.{key}")), "{key}: {e}");
        assert!(!e.contains(&"q".repeat(100)), "{key}: {e}");
        assert!(!dir.join("o.vtkhdf").exists());
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
