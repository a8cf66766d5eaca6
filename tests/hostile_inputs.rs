//! Inputs that are not what they claim: FIFOs, devices, directories, sparse
//! giants, compression bombs and deep node chains. Every one is refused (or
//! read) promptly and within the memory budget; every run has a deadline, so
//! a regression fails instead of hanging.
mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// Runs knitvox in `dir` (through `wrapper`, e.g. `/usr/bin/time -v`, when
/// given); a run still going after `deadline` is killed and fails the test.
fn run_in(dir: &Path, wrapper: &[&str], args: &[&str], deadline: Duration) -> (Output, Duration) {
    let t0 = Instant::now();
    let bin = common::knitvox_bin();
    let mut cmd = match wrapper.split_first() {
        Some((w, rest)) => {
            let mut c = Command::new(w);
            c.args(rest).arg(&bin);
            c
        }
        None => Command::new(&bin),
    };
    let mut child = cmd
        .args(args)
        .current_dir(dir)
        .stdin(Stdio::null())
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
                "knitvox {args:?} did not exit by itself within {deadline:?} (killed): {}",
                String::from_utf8_lossy(&o.stderr)
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let elapsed = t0.elapsed();
    (child.wait_with_output().unwrap(), elapsed)
}

fn knitvox_in(dir: &Path, args: &[&str], deadline: Duration) -> (Output, Duration) {
    run_in(dir, &[], args, deadline)
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!(
        "knitvox-hostile-inputs-{name}-{}",
        std::process::id()
    ));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn mkfifo(path: &Path) {
    use std::os::unix::ffi::OsStrExt;
    let c = std::ffi::CString::new(path.as_os_str().as_bytes()).unwrap();
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0, "mkfifo");
}

const DEADLINE: Duration = Duration::from_secs(20);

#[test]
fn a_fifo_as_yarn_file_scene_manifest_or_character_is_refused_without_blocking() {
    let dir = scratch("fifo");
    for name in ["f.bcc", "f.h5", "scene.toml", "job.toml", "c.glb"] {
        mkfifo(&dir.join(name));
    }
    for args in [
        &["inspect", "f.bcc"][..],
        &["convert", "f.bcc", "out.ply"],
        &["inspect", "f.h5"],
        &["yls", "scene.toml", "-o", "out.h5"],
        &["run", "job.toml"],
        &["bake", "c.glb", "-o", "cache.h5"],
    ] {
        let (o, t) = knitvox_in(&dir, args, DEADLINE);
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(65), "{args:?}: {e}");
        assert!(e.contains("a FIFO") && e.contains(args[1]), "{args:?}: {e}");
        assert!(t < Duration::from_secs(10), "{args:?} took {t:?}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn dev_zero_behind_a_yarn_name_is_refused_at_once() {
    let dir = scratch("zero");
    for name in ["z.ply", "z.bcc", "z.obj", "z.glb", "z.h5"] {
        std::os::unix::fs::symlink("/dev/zero", dir.join(name)).unwrap();
        let (o, t) = knitvox_in(&dir, &["inspect", name], DEADLINE);
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(65), "{name}: {e}");
        assert!(e.contains("a device") && e.contains(name), "{name}: {e}");
        assert!(t < Duration::from_secs(5), "{name} took {t:?}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_directory_named_like_a_yarn_file_is_refused_clearly() {
    let dir = scratch("dir");
    for name in ["x.bcc", "x.h5", "x.gltf"] {
        std::fs::create_dir(dir.join(name)).unwrap();
        let (o, _) = knitvox_in(&dir, &["inspect", name], DEADLINE);
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(65), "{name}: {e}");
        assert!(e.contains("a directory") && e.contains(name), "{name}: {e}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_sparse_file_over_the_budget_is_refused_before_it_is_read() {
    let dir = scratch("sparse");
    let size: u64 = 3 << 30;
    for name in ["big.ply", "big.bcc", "big.h5"] {
        std::fs::File::create(dir.join(name))
            .unwrap()
            .set_len(size)
            .unwrap();
        let (o, t) = knitvox_in(&dir, &["inspect", name, "--max-memory", "100M"], DEADLINE);
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(65), "{name}: {e}");
        assert!(
            e.contains(name)
                && e.contains(&format!("{size} bytes"))
                && e.contains("memory budget of 104857600 bytes")
                && e.contains("--max-memory"),
            "{name}: {e}"
        );
        // Reading 3 GB (even of holes) takes seconds; a refusal takes none.
        assert!(t < Duration::from_secs(3), "{name} took {t:?}");
    }
    // A scene over the budget is refused the same way.
    std::fs::File::create(dir.join("scene.toml"))
        .unwrap()
        .set_len(size)
        .unwrap();
    let (o, t) = knitvox_in(
        &dir,
        &["yls", "scene.toml", "-o", "o.h5", "--max-memory", "100M"],
        DEADLINE,
    );
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(65), "{e}");
    assert!(e.contains("scene.toml") && e.contains("104857600"), "{e}");
    assert!(t < Duration::from_secs(3), "took {t:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A file within the budget but without its format's signature is refused
/// from its first bytes, not read whole first.
#[test]
fn a_binary_file_without_its_signature_is_refused_before_it_is_read() {
    let dir = scratch("signature");
    let size: u64 = 600 << 20;
    let time_v = Path::new("/usr/bin/time").exists();
    let wrapper: &[&str] = if time_v {
        &["/usr/bin/time", "-v"]
    } else {
        &[]
    };
    for (name, words) in [
        ("zeros.bcc", "not a BCC file"),
        ("zeros.ply", "not a PLY file"),
        ("zeros.glb", "glb"),
    ] {
        std::fs::File::create(dir.join(name))
            .unwrap()
            .set_len(size)
            .unwrap();
        let (o, t) = run_in(
            &dir,
            wrapper,
            &["inspect", name, "--max-memory", "1G"],
            DEADLINE,
        );
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(65), "{name}: {e}");
        assert!(e.contains(name) && e.contains(words), "{name}: {e}");
        if let Some(rss) = max_rss(&e) {
            eprintln!("{name} ({size} bytes of zeros): refused in {t:?}, peak RSS {rss} bytes");
            assert!(rss < 128 << 20, "{name}: read whole (peak RSS {rss} bytes)");
        }
        std::fs::remove_file(dir.join(name)).unwrap();
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A small knitvox yarns file `base.h5` in `dir` (one yarn of two points).
fn yarns_h5(dir: &Path) -> PathBuf {
    std::fs::write(dir.join("a.obj"), "v 0 0 0\nv 0.01 0 0\nl 1 2\n").unwrap();
    let (o, _) = knitvox_in(dir, &["convert", "a.obj", "base.h5"], DEADLINE);
    assert!(o.status.success(), "{}", stderr(&o));
    dir.join("base.h5")
}

const BOMB_POINTS: usize = 40 << 20;

/// Copies `base` to `name` with `/yarns/points` replaced by `BOMB_POINTS`
/// gzip-compressed points (960 MiB declared, within the default budget) in
/// chunks of `chunk_rows`. `None`: every chunk is written with zeros (a true
/// gzip bomb of about 1 MB). `Some(k)`: only the first k chunks are stored,
/// with incompressible values, and libhdf5 makes up the rest from the fill
/// value (a ratio the gzip rules let through).
fn h5_bomb(
    dir: &Path,
    base: &Path,
    name: &str,
    chunk_rows: usize,
    written_chunks: Option<usize>,
) -> PathBuf {
    let path = dir.join(name);
    std::fs::copy(base, &path).unwrap();
    let f = common::h5_edit(&path);
    let g = f.group("yarns").unwrap();
    for k in ["points", "offsets"] {
        g.unlink(k).unwrap();
    }
    let ds = g
        .new_dataset::<f64>()
        .shape((BOMB_POINTS, 3))
        .chunk((chunk_rows, 3))
        .deflate(9)
        .create("points")
        .unwrap();
    let mut chunk = ndarray::Array2::<f64>::zeros((chunk_rows, 3));
    if written_chunks.is_some() {
        let mut x: u64 = 0x9e37_79b9_7f4a_7c15;
        chunk.iter_mut().for_each(|v| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            *v = (x >> 11) as f64 / (1u64 << 53) as f64;
        });
    }
    let chunks = written_chunks.unwrap_or(BOMB_POINTS / chunk_rows);
    for c in 0..chunks {
        ds.write_slice(
            &chunk,
            ndarray::s![c * chunk_rows..(c + 1) * chunk_rows, ..],
        )
        .unwrap();
    }
    g.new_dataset_builder()
        .with_data(&[0i64, BOMB_POINTS as i64])
        .create("offsets")
        .unwrap();
    drop(ds);
    drop(g);
    f.close().unwrap();
    path
}

/// The largest resident size (bytes) `/usr/bin/time -v` reports, if any.
fn max_rss(stderr: &str) -> Option<u64> {
    stderr
        .lines()
        .find_map(|l| l.trim().strip_prefix("Maximum resident set size (kbytes):"))
        .and_then(|v| v.trim().parse::<u64>().ok())
        .map(|kib| kib * 1024)
}

#[test]
fn hdf5_compression_bombs_are_refused_under_the_default_budget() {
    let dir = scratch("h5bomb");
    let base = yarns_h5(&dir);
    let time_v = Path::new("/usr/bin/time").exists();
    for (name, chunk_rows, chunks, why) in [
        ("gzip.h5", 1 << 20, None, "more than 1000 to one"),
        (
            "sparse.h5",
            1 << 16,
            Some(1),
            "640 chunks of which the file stores only 1",
        ),
    ] {
        let path = h5_bomb(&dir, &base, name, chunk_rows, chunks);
        let size = std::fs::metadata(&path).unwrap().len();
        assert!(size < 4 << 20, "{name} is {size} bytes");
        // No --max-memory: the default budget (at most 2 GiB) would let
        // the 960 MiB through; the bomb rule refuses it.
        let wrapper: &[&str] = if time_v {
            &["/usr/bin/time", "-v"]
        } else {
            &[]
        };
        let (o, t) = run_in(&dir, wrapper, &["inspect", name], DEADLINE);
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(65), "{name}: {e}");
        assert!(
            e.contains(name)
                && e.contains("/yarns/points")
                && e.contains(&format!("declares {} bytes", BOMB_POINTS * 24))
                && e.contains("compression bomb")
                && e.contains(why),
            "{name}: {e}"
        );
        assert!(t < Duration::from_secs(5), "{name} took {t:?}");
        if let Some(rss) = max_rss(&e) {
            eprintln!(
                "{name} ({size} bytes, declares 960 MiB): refused in {t:?}, peak RSS {rss} bytes"
            );
            assert!(rss < 256 << 20, "{name}: peak RSS {rss} bytes");
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A glTF whose nodes form one chain `0 -> 1 -> ... -> n-1`, each moved by
/// 1 mm along +x, the last holding a two-point LINE_STRIP at its origin.
fn node_chain(n: usize) -> String {
    let mut nodes: Vec<serde_json::Value> = (0..n)
        .map(|i| {
            if i + 1 < n {
                serde_json::json!({"children": [i + 1], "translation": [0.001, 0.0, 0.0]})
            } else {
                serde_json::json!({"mesh": 0, "translation": [0.001, 0.0, 0.0]})
            }
        })
        .collect();
    nodes.shrink_to_fit();
    let pts: Vec<u8> = [0f32, 0.0, 0.0, 0.0, 0.01, 0.0]
        .iter()
        .flat_map(|f| f.to_le_bytes())
        .collect();
    use base64::Engine;
    let uri = format!(
        "data:application/octet-stream;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(&pts)
    );
    serde_json::json!({
        "asset": {"version": "2.0"},
        "scenes": [{"nodes": [0]}], "scene": 0,
        "nodes": nodes,
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "mode": 3}]}],
        "buffers": [{"byteLength": 24, "uri": uri}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 24}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 2, "type": "VEC3",
                       "min": [0.0, 0.0, 0.0], "max": [0.0, 0.01, 0.0]}]
    })
    .to_string()
}

#[test]
fn inspecting_a_chain_of_100k_nodes_is_linear() {
    let dir = scratch("chain");
    let n = 100_000;
    std::fs::write(dir.join("chain.gltf"), node_chain(n)).unwrap();
    let (o, t) = knitvox_in(
        &dir,
        &["inspect", "--json", "chain.gltf"],
        Duration::from_secs(60),
    );
    assert!(o.status.success(), "{}", stderr(&o));
    eprintln!("{n}-node chain inspected in {t:?}");
    assert!(t < Duration::from_secs(20), "took {t:?}");
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let r = &v[0];
    assert_eq!(r["points"], 2, "{r}");
    // Every node's 1 mm adds up: the curve sits 100 m along +x.
    let x = r["bbox_m"]["min"][0].as_f64().unwrap();
    assert!((x - 0.001 * n as f64).abs() < 1e-3, "{r}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_gltf_with_more_nodes_than_the_limit_is_refused() {
    let dir = scratch("nodes");
    let n = knitvox::io::gltf::MAX_NODES + 1;
    let text = format!(
        "{{\"asset\":{{\"version\":\"2.0\"}},\"nodes\":[{}{{}}]}}",
        "{},".repeat(n - 1)
    );
    std::fs::write(dir.join("many.gltf"), text).unwrap();
    let (o, t) = knitvox_in(&dir, &["inspect", "many.gltf"], Duration::from_secs(60));
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(65), "{e}");
    assert!(
        e.contains("many.gltf") && e.contains("1000001 nodes"),
        "{e}"
    );
    eprintln!("{n} nodes refused in {t:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_yarn_file_whose_datasets_together_pass_the_budget_is_refused() {
    let dir = scratch("h5ledger");
    let base = yarns_h5(&dir);
    let path = dir.join("two.h5");
    std::fs::copy(&base, &path).unwrap();
    // 400,000 points (9.6 MB) and as many vertex radii (3.2 MB): each under
    // a 10 MiB budget, together over it.
    const N: usize = 400_000;
    {
        let f = common::h5_edit(&path);
        let g = f.group("yarns").unwrap();
        for k in ["points", "offsets"] {
            g.unlink(k).unwrap();
        }
        let pts = ndarray::Array2::<f64>::from_shape_fn((N, 3), |(i, c)| {
            if c == 0 {
                i as f64 * 1e-4
            } else {
                0.0
            }
        });
        // Compressed, so that the file itself is far under the budget.
        g.new_dataset_builder()
            .with_data(&pts)
            .chunk((N / 8, 3))
            .deflate(6)
            .create("points")
            .unwrap();
        g.new_dataset_builder()
            .with_data(&[0i64, N as i64])
            .create("offsets")
            .unwrap();
        g.new_dataset_builder()
            .with_data(&vec![1e-3f64; N])
            .chunk(N / 8)
            .deflate(6)
            .create("vertex_radius")
            .unwrap();
        f.close().unwrap();
    }
    let size = std::fs::metadata(&path).unwrap().len();
    assert!(size < 4 << 20, "two.h5 is {size} bytes");
    let (o, _) = knitvox_in(
        &dir,
        &["inspect", "two.h5", "--max-memory", "10M"],
        DEADLINE,
    );
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(65), "{e}");
    assert!(
        e.contains("two.h5")
            && e.contains("/yarns/vertex_radius")
            && e.contains("with the datasets read before it")
            && e.contains("--max-memory"),
        "{e}"
    );
    // Under a budget that holds both it reads.
    let (o, _) = knitvox_in(
        &dir,
        &["inspect", "two.h5", "--max-memory", "20M"],
        DEADLINE,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    std::fs::remove_dir_all(&dir).unwrap();
}
