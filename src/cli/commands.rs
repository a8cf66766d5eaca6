//! `inspect`, `convert` and `demo`.

use anyhow::Context;

use super::{error_message, exit_code_for, ConvertArgs, DemoArgs, ExitCode, InspectArgs};
use crate::io;
use crate::pipeline::{demo, inspect::summarize};

pub fn inspect(a: &InspectArgs) -> anyhow::Result<ExitCode> {
    let opts = a.read.options();
    let mut code = ExitCode::Success;
    let mut json = Vec::new();
    for path in &a.files {
        match inspect_one(path, &opts) {
            Ok((value, text)) => {
                if a.json {
                    json.push(value);
                } else {
                    print!("{text}");
                }
            }
            Err(e) => {
                let e = anyhow::Error::new(e);
                if code == ExitCode::Success {
                    code = exit_code_for(&e);
                }
                eprintln!("error: {}", error_message(&e));
                if a.json {
                    json.push(serde_json::json!({ "path": path.display().to_string(), "error": error_message(&e) }));
                }
            }
        }
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(&json)?);
    }
    Ok(code)
}

/// The JSON and text report of one file: an asset, a foreign HDF5 file, or yarns.
fn inspect_one(
    path: &std::path::Path,
    opts: &io::ReadOptions,
) -> Result<(serde_json::Value, String), io::IoError> {
    use std::fmt::Write;
    let mut text = String::new();
    if is_asset(path) {
        let mut v = serde_json::to_value(io::vtkhdf::summary(path)?).unwrap_or_default();
        if let Some(obj) = v.as_object_mut() {
            let _ = writeln!(
                text,
                "{}\n  format                vtkhdf (knitvox homogenized asset)",
                path.display()
            );
            for (k, val) in obj.iter() {
                let _ = writeln!(text, "  {k:<22}{val}");
            }
            obj.insert("path".into(), path.display().to_string().into());
            obj.insert("format".into(), "vtkhdf".into());
        }
        return Ok((v, text));
    }
    if let Some(datasets) = foreign_hdf5(path) {
        let _ = writeln!(
            text,
            "{}\n  format        hdf5 (not a knitvox yarns file: no /yarns/points)",
            path.display()
        );
        for d in &datasets {
            let chunks = d
                .chunks
                .as_ref()
                .map_or(String::new(), |c| format!(" chunks {c:?}"));
            let _ = writeln!(
                text,
                "  dataset       {} {} {:?}{} {}",
                d.path,
                d.dtype,
                d.shape,
                chunks,
                d.filters.join(",")
            );
        }
        let v = serde_json::json!({
            "path": path.display().to_string(),
            "format": "hdf5",
            "knitvox_yarns": false,
            "datasets": datasets,
        });
        return Ok((v, text));
    }
    let r = summarize(&path.display().to_string(), &io::read_path(path, opts)?);
    Ok((serde_json::to_value(&r).unwrap_or_default(), r.to_text()))
}

fn is_asset(path: &std::path::Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("vtkhdf"))
}

/// The datasets of an HDF5 file that is not a knitvox yarns file (None otherwise,
/// and for anything list_datasets cannot open: read_path reports that properly).
fn foreign_hdf5(path: &std::path::Path) -> Option<Vec<io::h5::DatasetInfo>> {
    if io::sequence::is_pattern(path) || io::Format::from_path(path) != Some(io::Format::Hdf5) {
        return None;
    }
    let datasets = io::h5::list_datasets(path).ok()?;
    (!datasets.iter().any(|d| d.path == "/yarns/points")).then_some(datasets)
}

pub fn convert(a: &ConvertArgs) -> anyhow::Result<ExitCode> {
    let d = io::read_path(&a.input, &a.read.options())?;
    let out_format = io::format_of(&a.output)?;
    let frames = d.frames.as_ref();
    if let Some(f) = frames {
        if !out_format.holds_frames() && !io::sequence::is_pattern(&a.output) {
            eprintln!(
                "warning: {} holds {} frames but {} keeps only the first frame's curves; \
                 write name.####.{} or .h5 to keep every frame",
                a.input.display(),
                f.num_frames(),
                a.output.display(),
                out_format.extensions()[0]
            );
        }
    }
    if d.yarns.rest.is_some() && out_format != io::Format::Hdf5 {
        eprintln!(
            "note: {} carries a rest shape (rest lengths, curvatures, material frames) that {} \
             cannot hold: it is dropped (only .h5 keeps it; simulations from the output start \
             from its positions)",
            a.input.display(),
            a.output.display()
        );
    }
    let written = io::write_path(&a.output, &d.yarns, frames, &a.write_options())
        .with_context(|| format!("converting {} to {}", a.input.display(), a.output.display()))?;
    if a.json {
        let files: Vec<String> = written.iter().map(|p| p.display().to_string()).collect();
        println!(
            "{}",
            serde_json::json!({
                "input": a.input.display().to_string(),
                "curves": d.yarns.num_curves(),
                "points": d.yarns.num_points(),
                "frames": frames.map_or(0, |f| f.num_frames()),
                "written": files,
            })
        );
    } else {
        eprintln!(
            "wrote {} file(s): {} curves, {} points{}",
            written.len(),
            d.yarns.num_curves(),
            d.yarns.num_points(),
            frames.map_or(String::new(), |f| format!(", {} frames", f.num_frames()))
        );
        for p in &written {
            println!("{}", p.display());
        }
    }
    Ok(ExitCode::Success)
}

pub fn demo(a: &DemoArgs) -> anyhow::Result<ExitCode> {
    let r = demo::run(&a.out, &super::asset::command_line()).map_err(|e| match e {
        demo::DemoError::Stage(s) => anyhow::Error::new(s),
        demo::DemoError::Shot(s) => anyhow::Error::new(s),
        demo::DemoError::YarnLevel(s) => anyhow::Error::new(s),
    })?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&r)?);
    } else {
        println!(
            "knitvox demo: generated example input {}",
            r.input.display()
        );
        print!("{}", r.input_report.to_text());
        println!(
            "converted to every output format ({} frames for the sequences):",
            r.frames
        );
        for p in &r.outputs {
            println!("  {}", p.display());
        }
        let e = &r.embed;
        println!(
            "embedded into {}: {} voxels (h = {:.3e} m), {} nodes, {} tets in {:.1} ms",
            r.asset.display(),
            e.voxels,
            e.voxel_size,
            e.nodes,
            e.tets,
            e.voxelize_ms + e.tetrahedralize_ms + e.mass_ms + e.embedding_ms
        );
        println!(
            "shape-fitted {} frames into its time series: {:.2} ms per frame, worst RMS yarn error {:.3e} m",
            r.shapefit.frames, r.shapefit.fit_ms_per_frame_median, r.shapefit.rms_error_max
        );
        println!("exported the fitted frames as yarn curves:");
        for p in &r.exported {
            println!("  {}", p.display());
        }
        for (what, sh) in [
            ("dropped onto a sphere", &r.drape),
            ("on the walking fox", &r.fox),
        ] {
            println!(
                "simulated the swatch {what}: {} frames -> {} and {} yarn files; {} steps, {:.2} ms per step, max penetration {:.2e} m",
                sh.frames,
                sh.output.display(),
                sh.yarn_files.len(),
                sh.steps,
                sh.ms_per_step_median,
                sh.max_penetration_body_m.unwrap_or(sh.max_penetration_m)
            );
        }
        let y = &r.yls;
        println!(
            "yarn level: generated a 1x1 rib swatch ({} vertices) and stretched it 30%: {} frames -> {}; {} steps, {:.1} ms per frame, min distance / 2r {:.3}",
            y.vertices,
            y.frames,
            y.output.display(),
            y.steps,
            y.ms_per_frame_median,
            y.min_distance_ratio
        );
    }
    Ok(ExitCode::Success)
}
