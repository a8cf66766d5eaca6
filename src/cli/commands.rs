//! `inspect`, `convert` and `demo`.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;

use super::args::ReadArgs;

use super::exit::{error_message, exit_code_for, ExitCode};
use crate::geom::{Units, UpAxis};
use crate::io::{self, WriteOptions};
use crate::pipeline::{demo, inspect::summarize};

#[derive(Debug, Args)]
pub struct InspectArgs {
    /// Yarn files (a `name.####.ext` pattern reads a frame sequence).
    #[arg(required = true)]
    pub files: Vec<PathBuf>,
    /// Print one JSON array instead of text.
    #[arg(long)]
    pub json: bool,
    /// glTF characters: give the joints' places in this animation
    /// [default: the bind pose].
    #[arg(long, value_name = "NAME")]
    pub animation: Option<String>,
    /// glTF characters: time into `--animation` (s) of the joints' places.
    #[arg(long, value_name = "SECONDS", default_value_t = 0.0, value_parser = super::parse::parse_non_negative)]
    pub time: f64,
    #[command(flatten)]
    pub read: ReadArgs,
}

#[derive(Debug, Args)]
pub struct ConvertArgs {
    /// Input yarn file or `name.####.ext` frame sequence.
    pub input: PathBuf,
    /// Output file; `name.####.ext` writes one file per frame; .h5 holds all frames.
    pub output: PathBuf,
    #[command(flatten)]
    pub read: ReadArgs,
    /// Unit of the written coordinates for bcc, obj, ply (glTF and HDF5 are always metres).
    #[arg(long, value_name = "mm|cm|m|SCALE", default_value = "m")]
    pub out_units: Units,
    /// Up axis of the written coordinates for bcc, obj, ply (glTF and HDF5 are always +Y up).
    #[arg(long, value_name = "y|z", default_value = "y")]
    pub out_up_axis: UpAxis,
    /// First frame number of a written sequence (-1e9 to 1e9).
    #[arg(long, default_value_t = WriteOptions::default().first_frame, allow_negative_numbers = true,
          value_parser = clap::value_parser!(i64).range(-crate::geom::MAX_FRAME_NUMBER..=crate::geom::MAX_FRAME_NUMBER))]
    pub first_frame: i64,
    /// Print what was written as JSON.
    #[arg(long)]
    pub json: bool,
}

impl ConvertArgs {
    pub fn write_options(&self) -> WriteOptions {
        WriteOptions {
            units: self.out_units,
            up_axis: self.out_up_axis,
            first_frame: self.first_frame,
        }
    }
}

#[derive(Debug, Args)]
pub struct DemoArgs {
    /// Output folder.
    #[arg(long, short, default_value = "demo-out")]
    pub out: PathBuf,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

pub fn inspect(a: &InspectArgs) -> anyhow::Result<ExitCode> {
    let opts = a.read.options();
    let mut code = ExitCode::Success;
    let mut json = Vec::new();
    for path in &a.files {
        match inspect_one(path, &opts, (a.animation.as_deref(), a.time)) {
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
    pose: (Option<&str>, f64),
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
    if let Some(c) = character(path, pose)? {
        return Ok(character_report(path, &c));
    }
    if io::Format::from_path(path) == Some(io::Format::Hdf5)
        && io::character_h5::is_character_cache(path)
    {
        return character_cache_report(path);
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

/// The summary of a glTF that is a character (triangle meshes with a skin
/// or animations); None for anything else, yarn glTFs included.
/// `pose`: the animation (by name) and time the joints are placed at; an
/// unknown animation is an error naming the file and the ones it has.
fn character(
    path: &std::path::Path,
    pose: (Option<&str>, f64),
) -> Result<Option<crate::anim::summary::CharacterSummary>, io::IoError> {
    let glb_or_gltf = matches!(
        io::Format::from_path(path),
        Some(io::Format::Gltf | io::Format::Glb)
    );
    if !glb_or_gltf || io::sequence::is_pattern(path) {
        return Ok(None);
    }
    let Ok(ch) = io::gltf_skin::read_character(path) else {
        return Ok(None);
    };
    let animated = !ch.skins.is_empty() || !ch.animations.is_empty();
    if ch.meshes.is_empty() || !animated {
        return Ok(None);
    }
    let anim = match pose.0 {
        None => None,
        Some(name) => Some(
            ch.animation_index(name)
                .ok_or_else(|| io::IoError::Unsupported {
                    path: path.to_path_buf(),
                    message: format!(
                        "--animation {:?}: no such animation; the file has {}",
                        crate::geom::excerpt(name),
                        ch.animation_names()
                            .iter()
                            .map(|n| crate::geom::excerpt(n))
                            .collect::<Vec<_>>()
                            .join(", ")
                    ),
                })?,
        ),
    };
    Ok(Some(crate::anim::summary::summarize_at(&ch, anim, pose.1)))
}

/// JSON and text of a character (names cut like any quoted input).
fn character_report(
    path: &std::path::Path,
    c: &crate::anim::summary::CharacterSummary,
) -> (serde_json::Value, String) {
    use crate::geom::excerpt;
    let mut v = serde_json::to_value(c).unwrap_or_default();
    if let Some(o) = v.as_object_mut() {
        o.insert("path".into(), path.display().to_string().into());
        o.insert("format".into(), "gltf character".into());
    }
    let names = |n: &[String]| n.iter().map(|s| excerpt(s)).collect::<Vec<_>>().join(", ");
    let anims: Vec<String> = c
        .animations
        .iter()
        .map(|a| format!("{} ({:.3} s)", excerpt(&a.name), a.duration_s))
        .collect();
    let fmt3 = |p: Option<[f64; 3]>| {
        p.map_or("-".into(), |p| {
            format!("[{:.4}, {:.4}, {:.4}]", p[0], p[1], p[2])
        })
    };
    let skins: Vec<String> = c.skins.iter().map(|s| s.joints.len().to_string()).collect();
    let text = format!(
        "{}\n  format        glTF character (skinned/animated triangle meshes)\n  \
         nodes         {}; {} meshes, {} vertices, {} triangles\n  \
         skins         {} (joints per skin: {})\n  joints        {}\n  \
         animations    {}\n  bind bbox     {} .. {} (file units; glTF: m, +Y up)\n  \
         height        {:.4} (bind pose, along +Y)\n  \
         suggested     --character-scale {} (a body {} m tall; 1 when already {}-{} m)\n",
        path.display(),
        c.nodes,
        c.meshes,
        c.vertices,
        c.triangles,
        c.skins.len(),
        skins.join(", "),
        names(&c.joints),
        if anims.is_empty() {
            "none".into()
        } else {
            anims.join(", ")
        },
        fmt3(c.bind_bbox_min),
        fmt3(c.bind_bbox_max),
        c.height,
        c.suggested_character_scale
            .map_or("-".into(), |s| s.to_string()),
        crate::anim::summary::TARGET_HEIGHT_M,
        crate::anim::summary::PLAUSIBLE_HEIGHT_M.0,
        crate::anim::summary::PLAUSIBLE_HEIGHT_M.1,
    );
    let mut text = text;
    {
        use std::fmt::Write;
        let _ = writeln!(
            text,
            "  joint places  {} (file units; for --fit-joint and dressing)",
            match &c.pose.animation {
                None => "bind pose".to_string(),
                Some(a) => format!("{} at {} s", excerpt(a), c.pose.time_s),
            }
        );
        for j in &c.joint_places {
            let _ = writeln!(
                text,
                "    {:<24} [{:.4}, {:.4}, {:.4}]  bone {} from {}",
                excerpt(&j.name),
                j.position[0],
                j.position[1],
                j.position[2],
                j.bone_length.map_or("-".into(), |l| format!("{l:.4}")),
                j.parent.as_deref().map_or("-".into(), excerpt)
            );
        }
    }
    (v, text)
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
    let mut warnings = Vec::new();
    if let Some(f) = frames {
        if !out_format.holds_frames() && !io::sequence::is_pattern(&a.output) {
            warnings.push(format!(
                "{} holds {} frames but {} keeps only the first frame's curves; \
                 write name.####.{} or .h5 to keep every frame",
                a.input.display(),
                f.num_frames(),
                a.output.display(),
                out_format.extensions()[0]
            ));
        }
    }
    for w in d.warnings() {
        warnings.push(format!("{}: {w}", a.input.display()));
    }
    let warnings = super::console::warn_all(warnings);
    if d.yarns.rest.is_some() && out_format != io::Format::Hdf5 {
        eprintln!(
            "note: {} carries a rest shape (rest lengths, curvatures, material frames, the yarn \
             material it was relaxed under) that {} cannot hold: it is dropped (only .h5 keeps \
             it; simulations from the output start from its positions under the default yarn)",
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
                "warnings": warnings,
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

fn print_demo_fabric(f: &crate::pipeline::fabric_test::FabricTestReport) {
    use crate::pipeline::fabric_test::TestFigures;
    let TestFigures::Stretch(s) = &f.figures else {
        return;
    };
    if let Some(x) = &f.relaxation {
        println!(
            "fabric: relaxed a {} ({} vertices) into contact: {:.0}% of vertices touching, {:.2} contacts per vertex",
            f.swatch,
            f.vertices,
            100.0 * x.contact.near_fraction,
            x.contact.contacts_per_vertex
        );
    }
    println!(
        "stretch test along the courses ({:.1} mm wide, clamps {:.1} mm apart):",
        1e3 * s.width_m,
        1e3 * s.gauge_m
    );
    for p in s.points.iter().filter(|p| p.stretch > 0.0) {
        println!(
            "  {:>3.0}%: {:.3} N, compression {:.3}",
            100.0 * p.stretch,
            p.force_n,
            p.compression
        );
    }
    for p in &f.written {
        println!("  {}", p.display());
    }
}

fn print_demo_fit(f: &demo::FitDemo) {
    let r = &f.fit;
    println!(
        "homogenization: fitted {} ({} tets) to {} yarn-level training poses ({}): loss {:.3e} -> {:.3e} (uniform {:.3e}), gamma_s {:.3e}-{:.3e} Pa, gamma_v {:.3e}-{:.3e} Pa",
        f.fitted.display(),
        r.tets,
        r.poses.len(),
        f.job.display(),
        r.loss_before,
        r.loss_fitted,
        r.loss_uniform,
        r.gamma_s_range[0],
        r.gamma_s_range[1],
        r.gamma_v_range[0],
        r.gamma_v_range[1]
    );
    let v = &f.validate;
    println!(
        "held-out fidelity ({}): {}",
        f.held_out.display(),
        v.summary()
    );
    println!("  {}", v.verdict);
    println!("  fit and validation took {:.1} s", f.wall_s);
}

pub fn demo(a: &DemoArgs) -> anyhow::Result<ExitCode> {
    let r = demo::run(&a.out, &super::asset::command_line()).map_err(|e| match e {
        demo::DemoError::Stage(s) => anyhow::Error::new(s),
        demo::DemoError::Shot(s) => anyhow::Error::new(s),
        demo::DemoError::YarnLevel(s) => anyhow::Error::new(s),
        demo::DemoError::Fabric(s) => anyhow::Error::new(s),
        demo::DemoError::Pipeline(s) => anyhow::Error::new(s),
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
        print_demo_fabric(&r.fabric);
        print_demo_fit(&r.fit);
    }
    Ok(ExitCode::Success)
}

/// The summary of an HDF5 character cache (schemas/character-hdf5.md).
fn character_cache_report(
    path: &std::path::Path,
) -> Result<(serde_json::Value, String), io::IoError> {
    let read = io::character_h5::read_character_cache(path, io::max_memory())?;
    let c = &read.cache;
    let rest = c.rest_positions();
    let (lo, hi) = rest.iter().fold(
        ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]),
        |(lo, hi), p| {
            (
                std::array::from_fn(|k| lo[k].min(p[k])),
                std::array::from_fn(|k| hi[k].max(p[k])),
            )
        },
    );
    let v = serde_json::json!({
        "path": path.display().to_string(),
        "format": "character-hdf5",
        "frames": c.num_frames(),
        "first_time_s": c.times[0],
        "duration_s": c.duration(),
        "vertices": c.num_vertices,
        "triangles": c.triangles.len(),
        "rest_pose": if c.rest.is_some() { "rest_points" } else { "frame 0" },
        "rest_bbox_m": [lo, hi],
        "height_m": hi[1] - lo[1],
        "notes": read.notes,
    });
    let text = format!(
        "{}\n  format        character cache (HDF5)\n  frames        {} from {} s over {:.4} s\n  vertices      {}\n  triangles     {}\n  rest pose     {}\n  height        {:.4} m (+Y, metres)\n{}",
        path.display(),
        c.num_frames(),
        c.times[0],
        c.duration(),
        c.num_vertices,
        c.triangles.len(),
        if c.rest.is_some() { "rest_points" } else { "frame 0" },
        hi[1] - lo[1],
        read.notes.iter().map(|n| format!("  note          {n}\n")).collect::<String>()
    );
    Ok((v, text))
}
