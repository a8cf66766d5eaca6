//! `knitvox bench NAME --json`: benchmarks that print the README's figures.

use std::collections::BTreeMap;
use std::time::Instant;

use serde::Serialize;

use super::{BenchIoArgs, ExitCode};
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

#[cfg(test)]
mod tests {
    #[test]
    fn median_odd_even() {
        assert_eq!(super::median(vec![3.0, 1.0, 2.0]), 2.0);
        assert_eq!(super::median(vec![4.0, 1.0, 2.0, 3.0]), 2.5);
    }
}
