//! Asset stages: embed yarns into a homogenized asset, shape-fit yarn frames
//! into its time series (Y2V), export stored steps as yarn curves (V2Y).

use std::path::{Path, PathBuf};
use std::time::Instant;

use sha2::{Digest, Sha256};

use crate::embed::{self, EmbedError, EmbedParams, EmbedStats, Embedded};
use crate::fit::{FitError, FitStats, ShapeFitParams, ShapeFitter};
use crate::geom::{
    Asset, InputFile, NodeSteps, Provenance, Vec3, YarnFrames, DEFAULT_GAMMA_S, DEFAULT_GAMMA_V,
};
use crate::io::{self, IoError, ReadOptions, WriteOptions};

/// Errors of the asset stages.
#[derive(Debug, thiserror::Error)]
pub enum StageError {
    #[error(transparent)]
    Io(#[from] IoError),
    #[error("{path}: embedding: {source}", path = path.display())]
    Embed {
        path: PathBuf,
        #[source]
        source: EmbedError,
    },
    #[error("{path}: shape fit: {source}", path = path.display())]
    Fit {
        path: PathBuf,
        #[source]
        source: FitError,
    },
    #[error("{path}: {message}", path = path.display())]
    Invalid { path: PathBuf, message: String },
}

impl StageError {
    /// Whether the inputs are at fault (as opposed to output or transient trouble).
    pub fn class(&self) -> io::ErrorClass {
        match self {
            StageError::Io(e) => e.class(),
            _ => io::ErrorClass::BadInput,
        }
    }
}

/// SHA-256 of a file, hex.
pub fn sha256_file(path: &Path) -> Result<String, IoError> {
    let bytes = std::fs::read(path).map_err(|source| IoError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    Ok(Sha256::digest(&bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect())
}

fn input_record(path: &Path) -> Result<InputFile, IoError> {
    let sha256 = if path.is_file() {
        sha256_file(path)?
    } else {
        String::new()
    };
    Ok(InputFile {
        path: path.display().to_string(),
        sha256,
    })
}

/// Reads yarns and embeds them into a new asset (default materials, domain 0).
pub fn build_asset(
    input: &Path,
    read: &ReadOptions,
    params: &EmbedParams,
    command: &str,
) -> Result<(Asset, EmbedStats), StageError> {
    let data = io::read_path(input, read)?;
    let e = embed::embed(&data.yarns, params).map_err(|source| StageError::Embed {
        path: input.to_path_buf(),
        source,
    })?;
    let mut rest_yarns = data.yarns.clone();
    rest_yarns.linear_density = Some(e.linear_density.clone());
    let used = EmbedParams {
        voxel_size: Some(e.stats.voxel_size),
        ..params.clone()
    };
    let parameters = serde_json::json!({
        "embed": used,
        "embed_requested": params,
        "voxel_size_rule": e.stats.voxel_size_rule,
        "read": {
            "units": data.units.0.metres_per_unit,
            "units_source": data.units.1,
            "up_axis": data.up_axis.0,
            "up_axis_source": data.up_axis.1,
            "radius_source": data.radius,
        },
        "materials": { "gamma_s_default": DEFAULT_GAMMA_S, "gamma_v_default": DEFAULT_GAMMA_V },
    });
    let nt = e.mesh.num_tets();
    let stats = e.stats.clone();
    let asset = Asset {
        grid: e.grid,
        mesh: e.mesh,
        tet_voxel: e.tet_voxel,
        node_mass: e.node_mass,
        gamma_s: vec![DEFAULT_GAMMA_S; nt],
        gamma_v: vec![DEFAULT_GAMMA_V; nt],
        domain: vec![0; nt],
        embedding: e.embedding,
        rest_yarns,
        parameters,
        provenance: Provenance {
            knitvox_version: env!("CARGO_PKG_VERSION").to_string(),
            command: command.to_string(),
            inputs: vec![input_record(input)?],
        },
        steps: NodeSteps::default(),
    };
    Ok((asset, stats))
}

/// Rebuilds the embedding (pieces, densities) of an asset from its rest yarns
/// and voxel size, and checks it reproduces the stored mesh.
pub fn re_embed(asset: &Asset, path: &Path) -> Result<Embedded, StageError> {
    let params = EmbedParams {
        voxel_size: Some(asset.grid.h),
        max_voxels: u64::MAX,
        ..EmbedParams::default()
    };
    let e = embed::embed(&asset.rest_yarns, &params).map_err(|source| StageError::Embed {
        path: path.to_path_buf(),
        source,
    })?;
    if e.mesh != asset.mesh || e.embedding != asset.embedding {
        return Err(StageError::Invalid {
            path: path.to_path_buf(),
            message: "the stored mesh does not match its rest yarns re-embedded at its voxel size (edited file, or written by an incompatible knitvox)".into(),
        });
    }
    Ok(e)
}

/// Result of shape-fitting frames into an asset.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ShapefitReport {
    pub frames: usize,
    pub prepare_ms: f64,
    pub fit_ms_total: f64,
    pub fit_ms_per_frame_median: f64,
    pub rms_error_max: f64,
    pub per_frame: Vec<FitStats>,
}

/// Y2V of the selected frames into the asset's time series (replacing it).
pub fn shapefit(
    asset: &mut Asset,
    asset_path: &Path,
    frames: &YarnFrames,
    selection: &[usize],
    params: &ShapeFitParams,
) -> Result<ShapefitReport, StageError> {
    if frames.num_vertices != asset.rest_yarns.num_points() {
        return Err(StageError::Invalid {
            path: asset_path.to_path_buf(),
            message: format!(
                "the frames have {} yarn vertices but the asset's yarns have {}",
                frames.num_vertices,
                asset.rest_yarns.num_points()
            ),
        });
    }
    let start = Instant::now();
    let e = re_embed(asset, asset_path)?;
    // re_embed checked that e.mesh and e.embedding equal the asset's.
    let fitter = ShapeFitter::from_embedded(&asset.rest_yarns, &e, params).map_err(|source| {
        StageError::Fit {
            path: asset_path.to_path_buf(),
            source,
        }
    })?;
    let prepare_ms = start.elapsed().as_secs_f64() * 1e3;
    let mut chosen = YarnFrames::new(frames.num_vertices);
    for &f in selection {
        chosen
            .push_frame(frames.times[f], frames.frame(f))
            .map_err(|e| StageError::Invalid {
                path: asset_path.to_path_buf(),
                message: e.to_string(),
            })?;
    }
    let t_fit = Instant::now();
    let results = fitter
        .fit_frames(&chosen)
        .map_err(|source| StageError::Fit {
            path: asset_path.to_path_buf(),
            source,
        })?;
    let fit_ms_total = t_fit.elapsed().as_secs_f64() * 1e3;
    let mut steps = NodeSteps::default();
    let mut per_frame = Vec::with_capacity(results.len());
    for (i, (nodes, st)) in results.into_iter().enumerate() {
        steps.times.push(chosen.times[i]);
        steps.positions.extend_from_slice(&nodes);
        steps.fit_error.push(st.rms_error);
        per_frame.push(st);
    }
    asset.steps = steps;
    let mut ms: Vec<f64> = per_frame.iter().map(|s| s.ms).collect();
    ms.sort_by(f64::total_cmp);
    Ok(ShapefitReport {
        frames: per_frame.len(),
        prepare_ms,
        fit_ms_total,
        fit_ms_per_frame_median: ms.get(ms.len() / 2).copied().unwrap_or(0.0),
        rms_error_max: per_frame.iter().map(|s| s.rms_error).fold(0.0, f64::max),
        per_frame,
    })
}

/// V2Y of the asset's stored steps: per-step yarn positions (m).
pub fn v2y_steps(asset: &Asset, steps: &[usize]) -> YarnFrames {
    let n = asset.mesh.num_nodes();
    let mut frames = YarnFrames::new(asset.rest_yarns.num_points());
    for &s in steps {
        let pts: Vec<Vec3> = asset.embedding.v2y(&asset.mesh, asset.steps.step(s, n));
        frames
            .push_frame(asset.steps.times[s], &pts)
            .expect("V2Y keeps the vertex count");
    }
    frames
}

/// Writes V2Y yarn curves of the selected steps into `out_dir` as
/// `name.####.ext` (step number = index in the asset's time series), or one
/// `name.h5` holding every selected step.
pub fn export(
    asset: &Asset,
    steps: &[usize],
    format: io::Format,
    out_dir: &Path,
    name: &str,
    opts: &WriteOptions,
) -> Result<Vec<PathBuf>, StageError> {
    std::fs::create_dir_all(out_dir).map_err(|source| IoError::Write {
        path: out_dir.to_path_buf(),
        source,
    })?;
    let frames = v2y_steps(asset, steps);
    let ext = format.extensions()[0];
    if format.holds_frames() {
        let path = out_dir.join(format!("{name}.{ext}"));
        return Ok(io::write_path(
            &path,
            &asset.rest_yarns,
            Some(&frames),
            opts,
        )?);
    }
    // Every step or none under its final name (issue 13 item 4).
    io::atomic::all_or_nothing(|| {
        let mut written = Vec::with_capacity(steps.len());
        for (i, &s) in steps.iter().enumerate() {
            let y =
                asset
                    .rest_yarns
                    .with_points(frames.frame(i))
                    .map_err(|e| StageError::Invalid {
                        path: out_dir.to_path_buf(),
                        message: e.to_string(),
                    })?;
            let path = out_dir.join(format!("{name}.{s:04}.{ext}"));
            written.extend(io::write_path(&path, &y, None, opts)?);
        }
        Ok(written)
    })
}

/// The size warning of an asset (see [`crate::geom::garment_size_warning`]):
/// its rest yarns against what the embedding's read assumed, as recorded in
/// `parameters.read` by [`build_asset`]. None for assets without that record.
pub fn size_warning(asset: &Asset) -> Option<String> {
    let read = asset.parameters.get("read")?;
    let is_assumed = |key: &str| read.get(key).and_then(|v| v.as_str()) == Some("assumed");
    let mut assumed = Vec::new();
    let units = read
        .get("units")
        .and_then(|v| v.as_f64())
        .and_then(crate::geom::Units::from_scale)?;
    if is_assumed("units_source") {
        assumed.push(format!("unit {units}"));
    }
    if is_assumed("up_axis_source") {
        let axis = read
            .get("up_axis")
            .and_then(|v| serde_json::from_value::<crate::geom::UpAxis>(v.clone()).ok());
        assumed.push(axis.map_or("up axis".into(), |a| format!("up axis {a}")));
    }
    let b = asset.rest_yarns.bounds()?;
    crate::geom::garment_size_warning(&b, units, &assumed)
}
