//! `knitvox bench NAME --json`: benchmarks that print the README's figures.

use std::collections::BTreeMap;
use std::time::Instant;

use serde::Serialize;

use super::{BenchEmbedArgs, BenchIoArgs, ExitCode};
use crate::io::{self, Format, ReadOptions, WriteOptions};
use crate::yarn::analytic::knit_swatch_with_points;

/// Median of a set of timings (ms).
pub fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        return f64::NAN;
    }
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

fn time_ms<T>(runs: usize, mut f: impl FnMut() -> anyhow::Result<T>) -> anyhow::Result<f64> {
    let mut t = Vec::with_capacity(runs);
    for _ in 0..runs.max(1) {
        let s = Instant::now();
        std::hint::black_box(f()?);
        t.push(s.elapsed().as_secs_f64() * 1e3);
    }
    Ok(median(t))
}

#[derive(Serialize)]
struct FormatTimes {
    write_ms: f64,
    read_ms: f64,
    bytes: u64,
}

#[derive(Serialize)]
struct IoBench {
    bench: &'static str,
    input: String,
    curves: usize,
    points: usize,
    runs: usize,
    threads: usize,
    input_read_ms: Option<f64>,
    formats: BTreeMap<&'static str, FormatTimes>,
}

pub fn io(a: &BenchIoArgs) -> anyhow::Result<ExitCode> {
    let opts = a.read.options();
    let (yarns, input, input_read_ms) = match &a.input {
        Some(p) => {
            let d = io::read_path(p, &opts)?;
            let ms = time_ms(a.runs, || Ok(io::read_path(p, &opts)?))?;
            (d.yarns, p.display().to_string(), Some(ms))
        }
        None => (
            knit_swatch_with_points(a.points),
            format!("built-in analytic swatch ({} points)", a.points),
            None,
        ),
    };
    let dir = tempfile::tempdir()?;
    let mut formats = BTreeMap::new();
    let read_back = ReadOptions {
        radius: opts.radius,
        ..ReadOptions::default()
    };
    for format in Format::ALL.into_iter().filter(|f| f.is_writable()) {
        let path = dir.path().join(format!("bench.{}", format.extensions()[0]));
        let write_ms = time_ms(a.runs, || {
            Ok(io::write_path(
                &path,
                &yarns,
                None,
                &WriteOptions::default(),
            )?)
        })?;
        let read_ms = time_ms(a.runs, || Ok(io::read_path(&path, &read_back)?))?;
        let bytes = std::fs::metadata(&path)?.len();
        formats.insert(
            format.name(),
            FormatTimes {
                write_ms,
                read_ms,
                bytes,
            },
        );
    }
    let r = IoBench {
        bench: "io",
        input,
        curves: yarns.num_curves(),
        points: yarns.num_points(),
        runs: a.runs,
        threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
        input_read_ms,
        formats,
    };
    if a.json {
        println!("{}", serde_json::to_string_pretty(&r)?);
    } else {
        println!(
            "{}: {} curves, {} points, median of {} runs",
            r.input, r.curves, r.points, r.runs
        );
        if let Some(ms) = r.input_read_ms {
            println!("  read input      {ms:9.2} ms");
        }
        for (name, t) in &r.formats {
            println!(
                "  {name:<6} write {:9.2} ms   read {:9.2} ms   {:>12} bytes",
                t.write_ms, t.read_ms, t.bytes
            );
        }
    }
    Ok(ExitCode::Success)
}

/// Peak resident memory of this process (MB), from /proc (Linux); None elsewhere.
pub fn peak_rss_mb() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

#[derive(Serialize)]
struct EmbedBench {
    bench: &'static str,
    input: String,
    yarn_points: usize,
    voxel_size: f64,
    voxels: usize,
    nodes: usize,
    tets: usize,
    nodes_per_yarn_point: f64,
    runs: usize,
    threads: usize,
    embed_ms: f64,
    shapefit_prepare_ms: f64,
    shapefit_frames: usize,
    shapefit_ms_per_frame: f64,
    shapefit_rms_error_max_m: f64,
    peak_rss_mb: Option<f64>,
}

pub fn embed(a: &BenchEmbedArgs) -> anyhow::Result<ExitCode> {
    use crate::embed::{embed as run_embed, EmbedParams};
    use crate::fit::{ShapeFitParams, ShapeFitter};
    let (yarns, input) = match &a.input {
        Some(p) => (
            io::read_path(p, &a.read.options())?.yarns,
            p.display().to_string(),
        ),
        None => (
            knit_swatch_with_points(a.points),
            format!("built-in analytic swatch ({} points)", a.points),
        ),
    };
    let params = EmbedParams {
        voxel_size: a.voxel_size,
        ..EmbedParams::default()
    };
    let e = run_embed(&yarns, &params)?;
    let embed_ms = time_ms(a.runs, || Ok(run_embed(&yarns, &params)?))?;
    let t = Instant::now();
    let fitter = ShapeFitter::from_embedded(&yarns, &e, &ShapeFitParams::default())?;
    let prepare_ms = t.elapsed().as_secs_f64() * 1e3;
    let frames = crate::pipeline::demo::demo_frames(&yarns, a.frames.max(1));
    let mut per_frame = Vec::new();
    let mut worst: f64 = 0.0;
    for f in 0..frames.num_frames() {
        let t = Instant::now();
        let (_, st) = fitter.fit(frames.frame(f))?;
        per_frame.push(t.elapsed().as_secs_f64() * 1e3);
        worst = worst.max(st.rms_error);
    }
    let r = EmbedBench {
        bench: "embed",
        input,
        yarn_points: yarns.num_points(),
        voxel_size: e.stats.voxel_size,
        voxels: e.stats.voxels,
        nodes: e.mesh.num_nodes(),
        tets: e.mesh.num_tets(),
        nodes_per_yarn_point: e.mesh.num_nodes() as f64 / yarns.num_points().max(1) as f64,
        runs: a.runs,
        threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
        embed_ms,
        shapefit_prepare_ms: prepare_ms,
        shapefit_frames: per_frame.len(),
        shapefit_ms_per_frame: median(per_frame),
        shapefit_rms_error_max_m: worst,
        peak_rss_mb: peak_rss_mb(),
    };
    if a.json {
        println!("{}", serde_json::to_string_pretty(&r)?);
    } else {
        println!(
            "{}: {} yarn points -> {} nodes, {} tets (h = {:.3e} m); embed {:.1} ms; shape fit: prepare {:.1} ms, {:.2} ms per frame; peak RSS {:.0} MB",
            r.input, r.yarn_points, r.nodes, r.tets, r.voxel_size, r.embed_ms, r.shapefit_prepare_ms, r.shapefit_ms_per_frame,
            r.peak_rss_mb.unwrap_or(f64::NAN)
        );
    }
    Ok(ExitCode::Success)
}

#[cfg(test)]
mod tests {
    #[test]
    fn median_odd_even() {
        assert_eq!(super::median(vec![3.0, 1.0, 2.0]), 2.0);
        assert_eq!(super::median(vec![4.0, 1.0, 2.0, 3.0]), 2.5);
    }
}
