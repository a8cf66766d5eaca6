//! Hostile sizes and numbers: work is bounded before it starts (voxel
//! counts, yarn pieces, fit counts), bad frame times are refused, and error
//! messages stay short whatever they quote. Every input is generated here;
//! every run has a deadline.
mod common;

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// What a finished run left: exit code, output, and its peak memory (KiB).
struct Run {
    code: i32,
    stdout: String,
    stderr: String,
    max_rss_kib: i64,
}

/// Runs knitvox in `dir` with a deadline, reaping it with `wait4` so its own
/// peak resident memory is known (other tests' children do not count).
fn knitvox_in(dir: &Path, args: &[&str], deadline: Duration) -> Run {
    let t0 = Instant::now();
    let mut child = Command::new(common::knitvox_bin())
        .args(args)
        .current_dir(dir)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run knitvox");
    let drain = |mut r: Box<dyn Read + Send>| {
        std::thread::spawn(move || {
            let mut v = Vec::new();
            let _ = r.read_to_end(&mut v);
            v
        })
    };
    let out = drain(Box::new(child.stdout.take().unwrap()));
    let err = drain(Box::new(child.stderr.take().unwrap()));
    let pid = child.id() as libc::pid_t;
    let mut status = 0;
    // SAFETY: rusage is plain data, filled by wait4.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    loop {
        // SAFETY: waits for our own child; WNOHANG so the deadline holds.
        let r = unsafe { libc::wait4(pid, &mut status, libc::WNOHANG, &mut usage) };
        if r == pid {
            break;
        }
        assert!(r == 0, "wait4 failed");
        if t0.elapsed() > deadline {
            let _ = child.kill();
            let e = err.join().unwrap();
            panic!(
                "knitvox {:?} still running after {deadline:?}: {}",
                &args[..args.len().min(4)],
                String::from_utf8_lossy(&e[..e.len().min(2000)])
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let code = if libc::WIFEXITED(status) {
        libc::WEXITSTATUS(status)
    } else {
        -1
    };
    Run {
        code,
        stdout: String::from_utf8_lossy(&out.join().unwrap()).into_owned(),
        stderr: String::from_utf8_lossy(&err.join().unwrap()).into_owned(),
        max_rss_kib: usage.ru_maxrss,
    }
}

fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("knitvox-bounds-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// An OBJ of one open polyline along x, `n` points `step` metres apart.
fn write_line_obj(path: &Path, n: usize, step: f64) {
    let mut s = String::new();
    for i in 0..n {
        s.push_str(&format!("v {} 0.01 0.02\n", i as f64 * step));
    }
    s.push('l');
    for i in 1..=n {
        s.push_str(&format!(" {i}"));
    }
    s.push('\n');
    std::fs::write(path, s).unwrap();
}

/// A BCC file of `n` two-point curves, all the same 1 mm segment.
fn write_stacked_bcc(path: &Path, n: usize) {
    let mut b = Vec::new();
    b.extend_from_slice(b"BCC\x44PL\x03\x01");
    b.extend_from_slice(&(n as u64).to_le_bytes());
    b.extend_from_slice(&(2 * n as u64).to_le_bytes());
    b.extend_from_slice(&[0u8; 40]);
    for _ in 0..n {
        b.extend_from_slice(&2i32.to_le_bytes());
        for x in [0.0f32, 0.0, 0.0, 0.001, 0.0, 0.0] {
            b.extend_from_slice(&x.to_le_bytes());
        }
    }
    std::fs::write(path, b).unwrap();
}

/// The longest run of decimal digits in `s`.
fn longest_digit_run(s: &str) -> usize {
    s.split(|c: char| !c.is_ascii_digit())
        .map(str::len)
        .max()
        .unwrap_or(0)
}

#[test]
fn a_voxel_size_needing_too_many_voxels_is_refused_before_the_walk() {
    let d = scratch("fine");
    write_line_obj(&d.join("line.obj"), 100, 1e-3);
    let r = knitvox_in(
        &d,
        &[
            "embed",
            "line.obj",
            "-o",
            "a.vtkhdf",
            "--voxel-size",
            "1e-9",
        ],
        Duration::from_secs(20),
    );
    assert_eq!(r.code, 2, "{}", r.stderr);
    for part in ["--voxel-size 1e-9", "at least", "20000000", "--max-voxels"] {
        assert!(r.stderr.contains(part), "{part}: {}", r.stderr);
    }
    assert!(r.max_rss_kib < 200 * 1024, "{} KiB", r.max_rss_kib);
    assert!(!d.join("a.vtkhdf").exists());
    // Ten metres at 1 nm: beyond the grid's index range, named the same way.
    std::fs::write(d.join("long.obj"), "v 0 0 0\nv 10 0 0\nl 1 2\n").unwrap();
    let r = knitvox_in(
        &d,
        &[
            "embed",
            "long.obj",
            "-o",
            "a.vtkhdf",
            "--voxel-size",
            "1e-9",
        ],
        Duration::from_secs(20),
    );
    assert_eq!(r.code, 2, "{}", r.stderr);
    assert!(r.stderr.contains("--voxel-size 1e-9"), "{}", r.stderr);
    assert!(longest_digit_run(&r.stderr) <= 20, "{}", r.stderr);
}

#[test]
fn a_voxel_size_splitting_stacked_curves_beyond_the_memory_budget_is_refused() {
    let d = scratch("pieces");
    write_stacked_bcc(&d.join("s.bcc"), 20_000);
    // Few voxels (the curves coincide) but 20,000 x 6,000 yarn pieces.
    let r = knitvox_in(
        &d,
        &[
            "embed",
            "s.bcc",
            "-o",
            "a.vtkhdf",
            "--voxel-size",
            "5e-7",
            "--max-memory",
            "256M",
        ],
        Duration::from_secs(20),
    );
    assert_eq!(r.code, 2, "{}", r.stderr);
    for part in ["--voxel-size 5e-7", "pieces", "--max-memory"] {
        assert!(r.stderr.contains(part), "{part}: {}", r.stderr);
    }
    assert!(r.max_rss_kib < 300 * 1024, "{} KiB", r.max_rss_kib);
}

#[test]
fn many_curves_over_the_same_voxels_embed_within_the_memory_budget() {
    let d = scratch("stacked");
    write_stacked_bcc(&d.join("s.bcc"), 20_000);
    let r = knitvox_in(
        &d,
        &[
            "embed",
            "s.bcc",
            "-o",
            "a.vtkhdf",
            "--max-memory",
            "128M",
            "--json",
        ],
        Duration::from_secs(120),
    );
    assert_eq!(r.code, 0, "{}", r.stderr);
    assert!(d.join("a.vtkhdf").is_file());
    // The default voxel size stays coarse enough for the budget (without
    // it, the node-count target drives it down to 5 µm: ~570 MB).
    assert!(r.max_rss_kib < 400 * 1024, "{} KiB", r.max_rss_kib);
    let v: serde_json::Value = serde_json::from_str(&r.stdout).unwrap();
    assert!(v["stats"]["pieces"].as_u64().unwrap() < 2_000_000, "{v}");
}

#[test]
fn fit_sample_and_iteration_counts_have_a_maximum() {
    let d = scratch("fitcounts");
    for args in [
        ["--samples", "1000000000"],
        ["--gd-iterations", "4000000000"],
        ["--gn-iterations", "100000"],
    ] {
        let mut all = vec!["fit", "missing.vtkhdf", "--train", "p.h5"];
        all.extend(args);
        let r = knitvox_in(&d, &all, Duration::from_secs(20));
        assert_eq!(r.code, 2, "{args:?}: {}", r.stderr);
        assert!(r.stderr.contains(args[0]), "{}", r.stderr);
        assert!(r.stderr.contains("10000"), "{}", r.stderr);
    }
}

/// An asset of a small swatch, and a pose of its rest yarns at `times`.
fn asset_and_pose(d: &Path, times: &[f64]) {
    let yarns = common::flat_swatch("jersey", 2, 2);
    knitvox::io::h5::write_file(&d.join("y.h5"), &yarns, None).unwrap();
    let r = knitvox_in(
        d,
        &["embed", "y.h5", "-o", "a.vtkhdf"],
        Duration::from_secs(120),
    );
    assert_eq!(r.code, 0, "{}", r.stderr);
    let asset = knitvox::io::vtkhdf::read_asset(&d.join("a.vtkhdf")).unwrap();
    let rest = &asset.rest_yarns;
    let mut w = knitvox::io::h5::FrameWriter::create(&d.join("pose.h5"), rest).unwrap();
    for &t in times {
        w.push(t, &rest.points).unwrap();
    }
    w.finish().unwrap();
}

#[test]
fn a_pose_whose_frame_times_decrease_is_refused_naming_the_frame() {
    let d = scratch("times");
    asset_and_pose(&d, &[0.0, 0.5, 0.25]);
    let r = knitvox_in(
        &d,
        &["fit", "a.vtkhdf", "--train", "pose.h5", "-o", "f.vtkhdf"],
        Duration::from_secs(120),
    );
    assert_eq!(r.code, 65, "{}", r.stderr);
    for part in ["pose.h5", "/frames/times", "frame 2", "0.25"] {
        assert!(r.stderr.contains(part), "{part}: {}", r.stderr);
    }
    assert!(!d.join("f.vtkhdf").exists());
}

#[test]
fn a_huge_path_gives_a_short_error_on_stderr_and_in_json() {
    let d = scratch("path");
    // Too long for one argument (the kernel takes 128 KiB), so it comes in
    // a manifest.
    let huge = format!("{}.bcc", "p".repeat(10 << 20));
    std::fs::write(
        d.join("job.toml"),
        format!("frames = \"1-2\"\n[garment]\nyarns = \"{huge}\"\n"),
    )
    .unwrap();
    let r = knitvox_in(&d, &["run", "job.toml", "--json"], Duration::from_secs(60));
    assert_ne!(r.code, 0);
    // The path is quoted as an excerpt (the job refuses it before reading).
    assert!(r.stderr.len() < 8192, "{} bytes on stderr", r.stderr.len());
    let line = r.stdout.lines().last().unwrap_or("");
    assert!(line.len() < 16384, "{} bytes of JSON", line.len());
    let v: serde_json::Value = serde_json::from_str(line).unwrap();
    assert_eq!(v["event"], "error");
    // A flag's value quoted back by the parser is cut the same way.
    let long = "p".repeat(100_000);
    let r = knitvox_in(
        &d,
        &[
            "embed",
            "x.obj",
            "-o",
            "a.vtkhdf",
            "--voxel-size",
            &long,
            "--json",
        ],
        Duration::from_secs(60),
    );
    assert_eq!(r.code, 2);
    assert!(r.stderr.len() < 8192, "{} bytes on stderr", r.stderr.len());
    let line = r.stdout.lines().last().unwrap_or("");
    assert!(line.len() < 8192, "{} bytes of JSON", line.len());
}

#[test]
fn a_tiny_time_step_is_printed_short() {
    let d = scratch("dt");
    std::fs::write(d.join("s.toml"), "[simulation]\nfps = 24\ndt = 0.001\n").unwrap();
    std::fs::write(d.join("tiny.toml"), "[simulation]\nfps = 24\ndt = 1e-300\n").unwrap();
    let base = [
        "simulate",
        "missing.vtkhdf",
        "--frames",
        "1-10",
        "-o",
        "out.vtkhdf",
    ];
    for extra in [
        &["--scene", "s.toml", "--dt", "1e-300"][..],
        &["--scene", "tiny.toml"][..],
    ] {
        let mut args = base.to_vec();
        args.extend(extra);
        let r = knitvox_in(&d, &args, Duration::from_secs(60));
        assert_ne!(r.code, 0, "{}", r.stderr);
        assert!(r.stderr.contains("1e-300"), "{}", r.stderr);
        assert!(longest_digit_run(&r.stderr) <= 20, "{}", r.stderr);
    }
}
