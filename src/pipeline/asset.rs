//! Asset stages: embed yarns into a homogenized asset, shape-fit yarn frames
//! into its time series (Y2V), export stored steps as yarn curves (V2Y).

use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::embed::{self, EmbedError, EmbedParams, EmbedStats, Embedded};
use crate::fit::{FitError, FitStats, ShapeFitParams, ShapeFitter};
use crate::geom::{
    Asset, FrameSpec, InputFile, NodeSteps, Provenance, Vec3, YarnFrames, DEFAULT_GAMMA_S,
    DEFAULT_GAMMA_V,
};
use crate::io::{self, IoError, ReadOptions, WriteOptions};
use crate::pipeline::frames::{FrameSink, YarnFrameWriter};
use crate::pipeline::util::sha256_file;
use crate::pipeline::{Error, ErrorClass, Observer, Stage};

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
    pub fn class(&self) -> ErrorClass {
        match self {
            StageError::Io(e) => e.class().into(),
            _ => ErrorClass::BadInput,
        }
    }
}

pub(crate) fn input_record(path: &Path) -> Result<InputFile, IoError> {
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
    // The embedding's memory is bounded by the process's budget too.
    let bounded = EmbedParams {
        max_memory: io::max_memory(),
        ..params.clone()
    };
    let e = embed::embed(&data.yarns, &bounded).map_err(|source| StageError::Embed {
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
            "welded_points": data.weld.welded_points,
            "dropped_curves": data.weld.dropped_curves.len(),
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
        fibres: None,
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
    // The stored mesh has exactly as many voxels as the re-embedding must
    // make, so a file's voxel size cannot ask for more work than that.
    let params = EmbedParams {
        voxel_size: Some(asset.grid.h),
        max_voxels: asset.grid.voxels.len() as u64,
        max_memory: io::max_memory(),
        ..EmbedParams::default()
    };
    let mismatch = || {
        StageError::Invalid {
        path: path.to_path_buf(),
        message: "the stored mesh does not match its rest yarns re-embedded at its voxel size (edited file, or written by an incompatible knitvox)".into(),
    }
    };
    let e = embed::embed(&asset.rest_yarns, &params).map_err(|source| match source {
        EmbedError::TooManyVoxels { .. } => mismatch(),
        source => StageError::Embed {
            path: path.to_path_buf(),
            source,
        },
    })?;
    if e.mesh != asset.mesh || e.embedding != asset.embedding {
        return Err(mismatch());
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

/// Per-vertex distances in yarn diameters, `|V2Y(nodes) - yarn| / 2 r`,
/// between the yarns the asset's mesh carries at node positions `nodes`
/// and the yarn positions `yarn` (the measure of `validate` and of `fit`'s
/// training fidelity).
pub fn yarn_distances(asset: &Asset, nodes: &[Vec3], yarn: &[Vec3]) -> Vec<f64> {
    let y = asset.embedding.v2y(&asset.mesh, nodes);
    y.iter()
        .zip(yarn)
        .enumerate()
        .map(|(v, (a, b))| crate::geom::dist(*a, *b) / (2.0 * asset.rest_yarns.radius_at(v)))
        .collect()
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

/// The frame number of each stored step: a shot's output asset (it records
/// `parameters.simulate.scene.simulation.fps`) stores farm frame `f` at
/// time `f / fps`, so its steps carry their farm frame numbers, the same
/// numbers `simulate --yarns-out` writes; other assets (`shapefit` poses)
/// number their steps from 0.
pub fn step_frame_numbers(asset: &Asset) -> Vec<i64> {
    let fps = asset
        .parameters
        .pointer("/simulate/scene/simulation/fps")
        .and_then(|v| v.as_f64())
        .filter(|f| f.is_finite() && *f > 0.0);
    match fps {
        Some(fps) => asset
            .steps
            .times
            .iter()
            .map(|t| (t * fps).round() as i64)
            .collect(),
        None => (0..asset.steps.num_steps() as i64).collect(),
    }
}

/// Writes V2Y yarn curves of the selected steps into `out_dir` as
/// `name.####.ext` (numbered by [`step_frame_numbers`]), or one `name.h5`
/// holding every selected step. Each step goes through the frame
/// writer as it is computed; every file or none gets its final name.
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
    let ext = format.extensions()[0];
    let n = asset.mesh.num_nodes();
    let numbers = step_frame_numbers(asset);
    // Every step or none under its final name.
    io::atomic::all_or_nothing(|| {
        let mut writer = if format.holds_frames() {
            YarnFrameWriter::create(
                &out_dir.join(format!("{name}.{ext}")),
                &asset.rest_yarns,
                opts,
            )?
        } else {
            // Built, not parsed: `name` may hold any character.
            let pattern = io::sequence::Pattern {
                dir: out_dir.to_path_buf(),
                prefix: format!("{name}."),
                width: 4,
                suffix: format!(".{ext}"),
            };
            YarnFrameWriter::per_frame(pattern, &asset.rest_yarns, opts)
        };
        for &s in steps {
            let pts = asset.embedding.v2y(&asset.mesh, asset.steps.step(s, n));
            writer.push(numbers[s], asset.steps.times[s], &pts)?;
        }
        Ok(writer.finish()?)
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

/// The radius warning of an asset (see [`crate::geom::yarn_radius_warning`]):
/// its rest yarns' radii, from the file or not as `parameters.read`
/// records. None for assets without that record.
pub fn radius_warning(asset: &Asset) -> Option<String> {
    let read = asset.parameters.get("read")?;
    let units = read
        .get("units")
        .and_then(|v| v.as_f64())
        .and_then(crate::geom::Units::from_scale)?;
    let from_file = read.get("radius_source").and_then(|v| v.as_str()) == Some("file");
    let y = &asset.rest_yarns;
    let radii = y.vertex_radius.as_ref().unwrap_or(&y.radius);
    if radii.is_empty() {
        return None;
    }
    let min = radii.iter().copied().fold(f64::INFINITY, f64::min);
    let max = radii.iter().copied().fold(0.0, f64::max);
    crate::geom::yarn_radius_warning(min, max, units, from_file)
}

/// Refuses an asset path without the `.vtkhdf` extension.
pub fn check_asset_ext(path: &Path) -> Result<(), IoError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    if ext.as_deref() != Some("vtkhdf") {
        return Err(IoError::Unsupported {
            path: path.to_path_buf(),
            message: "an asset file must have the .vtkhdf extension".into(),
        });
    }
    Ok(())
}

/// Resolves a frame selection against `n` available frames: 0-based
/// indices, all in range [default: all]. One out of range is a usage error
/// naming the `--frames` option: the file is fine, the request asks for
/// what it does not hold.
pub fn select(
    spec: &Option<FrameSpec>,
    n: usize,
    what: &str,
    path: &Path,
) -> Result<Vec<usize>, Error> {
    let frames = spec.clone().unwrap_or_else(|| FrameSpec::all(n)).frames();
    frames
        .into_iter()
        .map(|f| {
            usize::try_from(f).ok().filter(|&i| i < n).ok_or_else(|| {
                Error::Usage(format!(
                    "--frames {}: {what} {f} does not exist: {} has {n} {what}s (0..{})",
                    spec.as_ref().map_or(String::new(), |s| s.to_string()),
                    path.display(),
                    n.saturating_sub(1)
                ))
            })
        })
        .collect()
}

/// The steps whose numbers (`numbers[s]`, e.g. [`step_frame_numbers`])
/// `spec` selects [default: all]; a number no step has is a usage error.
pub fn select_numbered(
    spec: &Option<FrameSpec>,
    numbers: &[i64],
    path: &Path,
) -> Result<Vec<usize>, Error> {
    let Some(spec) = spec else {
        return Ok((0..numbers.len()).collect());
    };
    spec.frames()
        .into_iter()
        .map(|f| {
            numbers.iter().position(|&k| k == f).ok_or_else(|| {
                let have = match (numbers.first(), numbers.last()) {
                    (Some(a), Some(b)) => format!("{a}..{b}"),
                    _ => "none".into(),
                };
                Error::Usage(format!(
                    "--frames {spec}: step {f} does not exist: {} has {} steps, numbered {have}",
                    path.display(),
                    numbers.len()
                ))
            })
        })
        .collect()
}

/// The `embed` stage: yarns -> homogenized asset (.vtkhdf).
#[derive(Debug, Clone)]
pub struct EmbedJob {
    /// Yarn file (any readable format).
    pub yarns: PathBuf,
    /// How to read it.
    pub read: ReadOptions,
    /// Embedding parameters.
    pub params: EmbedParams,
    /// Output asset (.vtkhdf).
    pub output: PathBuf,
    /// The command line, for provenance.
    pub command: String,
    /// Material cards carried onto the garment (`--card`,
    /// [`crate::pipeline::card_transfer::apply_cards`]); empty: the placeholder
    /// material.
    pub cards: Vec<crate::pipeline::card_transfer::CardSpec>,
}

/// What `embed` did.
#[derive(Debug, Clone, serde::Serialize)]
pub struct EmbedReport {
    pub asset: PathBuf,
    pub stats: EmbedStats,
    /// The cards' transfer (null without `--card`).
    pub cards: Option<crate::pipeline::card_transfer::CardTransfer>,
    /// Repeated points of the yarn file welded on read, and curves
    /// dropped for it ([`crate::geom::Yarns::weld`]).
    pub welded_points: usize,
    pub dropped_curves: usize,
}

/// The welding an asset's read recorded (`parameters.read`): points
/// welded and curves dropped (0 for assets from before it was recorded).
pub fn recorded_weld(asset: &Asset) -> (usize, usize) {
    let read = asset.parameters.get("read");
    let count = |k: &str| {
        read.and_then(|r| r.get(k))
            .and_then(|v| v.as_u64())
            .map_or(0, |n| n as usize)
    };
    (count("welded_points"), count("dropped_curves"))
}

impl Stage for EmbedJob {
    type Report = EmbedReport;
    const NAME: &'static str = "embed";
    fn run(&self, observer: &mut dyn Observer) -> Result<EmbedReport, Error> {
        check_asset_ext(&self.output)?;
        // Cards are read (and refused) before the embedding's work.
        let cards = self
            .cards
            .iter()
            .map(|c| {
                let (card, sha) = crate::pipeline::card_transfer::read_card(&c.path)?;
                Ok((c.clone(), card, sha))
            })
            .collect::<Result<Vec<_>, Error>>()?;
        let (mut asset, stats) = build_asset(&self.yarns, &self.read, &self.params, &self.command)?;
        for w in size_warning(&asset)
            .into_iter()
            .chain(radius_warning(&asset))
        {
            observer.warning(&format!("{}: {w}", self.yarns.display()));
        }
        let (welded_points, dropped_curves) = recorded_weld(&asset);
        if welded_points > 0 || dropped_curves > 0 {
            // A repair of the file, said where the operator looks.
            observer.warning(&format!(
                "{}: welded {welded_points} repeated point(s) (zero-length segments){}",
                self.yarns.display(),
                if dropped_curves > 0 {
                    format!(" and dropped {dropped_curves} curve(s) left with too few points")
                } else {
                    String::new()
                }
            ));
        }
        let transfer = if cards.is_empty() {
            None
        } else {
            let specs: Vec<_> = cards
                .iter()
                .map(|(s, c, _)| (s.clone(), c.clone()))
                .collect();
            let mut t = crate::pipeline::card_transfer::apply_cards(&mut asset, &specs).map_err(
                |source| StageError::Embed {
                    path: self.yarns.clone(),
                    source,
                },
            )?;
            for (applied, (_, _, sha)) in t.cards.iter_mut().zip(&cards) {
                applied.sha256 = sha.clone();
            }
            for w in &t.warnings {
                observer.warning(&format!("{}: {w}", self.yarns.display()));
            }
            if let Some(o) = asset.parameters.as_object_mut() {
                o.insert(
                    "cards".into(),
                    serde_json::to_value(&t.cards).unwrap_or_default(),
                );
            }
            for (spec, _, sha) in &cards {
                asset.provenance.inputs.push(crate::geom::InputFile {
                    path: spec.path.display().to_string(),
                    sha256: sha.clone(),
                });
            }
            Some(t)
        };
        io::vtkhdf::write_asset(&self.output, &asset)?;
        Ok(EmbedReport {
            asset: self.output.clone(),
            stats,
            cards: transfer,
            welded_points,
            dropped_curves,
        })
    }
}

/// The `shapefit` stage: yarn frames -> the asset's time series (Y2V).
#[derive(Debug, Clone)]
pub struct ShapefitJob {
    /// The asset (.vtkhdf).
    pub asset: PathBuf,
    /// Yarn frames: knitvox HDF5 or a `name.####.ext` sequence.
    pub frames: PathBuf,
    /// How to read the frames.
    pub read: ReadOptions,
    /// Frames to fit, 0-based [default: all].
    pub selection: Option<FrameSpec>,
    /// Where the fitted asset goes [default: the asset, updated in place].
    pub output: Option<PathBuf>,
    /// Shape-fit parameters.
    pub params: ShapeFitParams,
    /// The command line, for provenance.
    pub command: String,
}

impl ShapefitJob {
    /// The asset written.
    pub fn output_path(&self) -> &Path {
        self.output.as_deref().unwrap_or(&self.asset)
    }
}

impl Stage for ShapefitJob {
    type Report = ShapefitReport;
    const NAME: &'static str = "shapefit";
    fn run(&self, _observer: &mut dyn Observer) -> Result<ShapefitReport, Error> {
        check_asset_ext(&self.asset)?;
        let mut asset = io::vtkhdf::read_asset(&self.asset)?;
        let data = io::read_path(&self.frames, &self.read)?;
        let Some(frames) = data.frames else {
            return Err(IoError::Unsupported {
                path: self.frames.clone(),
                message: "holds no frames: give a knitvox HDF5 file with /frames or a name.####.ext sequence".into(),
            }
            .into());
        };
        let selection = select(&self.selection, frames.num_frames(), "frame", &self.frames)?;
        let report = shapefit(&mut asset, &self.asset, &frames, &selection, &self.params)?;
        asset.provenance.inputs.push(input_record(&self.frames)?);
        asset.provenance.command = format!("{} && {}", asset.provenance.command, self.command);
        io::vtkhdf::write_asset(self.output_path(), &asset)?;
        Ok(report)
    }
}

/// The `export` stage: an asset's stored steps -> yarn curves (V2Y).
#[derive(Debug, Clone)]
pub struct ExportJob {
    /// The asset (.vtkhdf).
    pub asset: PathBuf,
    /// Steps to export [default: all]: farm frame numbers for a shot's
    /// output asset, 0-based step indices otherwise ([`step_frame_numbers`]).
    pub selection: Option<FrameSpec>,
    /// Output format.
    pub format: io::Format,
    /// Output folder.
    pub output: PathBuf,
    /// Base name of the files [default: the asset's file stem].
    pub name: Option<String>,
    /// Units and up axis of bcc, obj and ply files.
    pub write: WriteOptions,
    /// An asset without steps (only embedded) exports its rest shape as
    /// step 0 instead of being refused [default false; a job's export
    /// without a shot sets it].
    pub rest_if_static: bool,
}

/// What `export` did.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ExportReport {
    pub steps: usize,
    pub written: Vec<PathBuf>,
}

impl Stage for ExportJob {
    type Report = ExportReport;
    const NAME: &'static str = "export";
    fn run(&self, _observer: &mut dyn Observer) -> Result<ExportReport, Error> {
        check_asset_ext(&self.asset)?;
        let mut asset = io::vtkhdf::read_asset(&self.asset)?;
        if asset.steps.num_steps() == 0 && self.rest_if_static {
            asset.steps.times.push(0.0);
            asset.steps.positions = asset.mesh.nodes.clone();
        }
        if asset.steps.num_steps() == 0 {
            return Err(IoError::Unsupported {
                path: self.asset.clone(),
                message: "the asset has no steps to export: fill it with `knitvox shapefit` or `knitvox simulate` first".into(),
            }
            .into());
        }
        let steps = select_numbered(&self.selection, &step_frame_numbers(&asset), &self.asset)?;
        let name = self.name.clone().unwrap_or_else(|| {
            self.asset
                .file_stem()
                .map_or("asset".into(), |s| s.to_string_lossy().into_owned())
        });
        let written = export(
            &asset,
            &steps,
            self.format,
            &self.output,
            &name,
            &self.write,
        )?;
        Ok(ExportReport {
            steps: steps.len(),
            written,
        })
    }
}

/// The uniform material of a fit record on `asset`'s tets: with fibres along
/// the asset's course and wale directions where the record has their
/// stiffnesses and the asset their directions.
pub fn uniform_material(
    asset: &Asset,
    u: &crate::geom::UniformMaterial,
) -> crate::fit::elastic::MaterialFields {
    let ne = asset.mesh.num_tets();
    let mut m = crate::fit::elastic::MaterialFields::uniform(ne, u.gamma_s, u.gamma_v);
    if let (Some(f), Some(gc), Some(gw)) = (&asset.fibres, u.gamma_course, u.gamma_wale) {
        let beta = match (u.beta_course, u.beta_wale) {
            (Some(bc), Some(bw)) => (vec![bc; ne], vec![bw; ne]),
            _ => (Vec::new(), Vec::new()),
        };
        m.fibres = fibre_families(f, vec![gc; ne], vec![gw; ne], beta);
    }
    m
}

/// The course and wale families of `f` with the stiffnesses given.
fn fibre_families(
    f: &crate::geom::AssetFibres,
    gamma_course: Vec<f64>,
    gamma_wale: Vec<f64>,
    (beta_course, beta_wale): (Vec<f64>, Vec<f64>),
) -> Vec<crate::sim::fibre::FibreFamily> {
    use crate::sim::fibre::FibreFamily;
    vec![
        FibreFamily {
            directions: f.course.clone(),
            beta: beta_course,
            gamma: gamma_course,
        },
        FibreFamily {
            directions: f.wale.clone(),
            beta: beta_wale,
            gamma: gamma_wale,
        },
    ]
}

/// The asset's materials as fitted fields: `γs`, `γv` and, where it has
/// them, its fibre families (course first, then wale).
pub fn asset_materials(asset: &Asset) -> crate::fit::elastic::MaterialFields {
    crate::fit::elastic::MaterialFields {
        gamma_s: asset.gamma_s.clone(),
        gamma_v: asset.gamma_v.clone(),
        fibres: asset
            .fibres
            .as_ref()
            .map(|f| {
                fibre_families(
                    f,
                    f.gamma_course.clone(),
                    f.gamma_wale.clone(),
                    (f.beta_course.clone(), f.beta_wale.clone()),
                )
            })
            .unwrap_or_default(),
    }
}

/// Material fields with another number of fibre families than an asset
/// keeps (none, or a course and a wale).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("{families} fibre families; an asset keeps a course and a wale")]
pub struct FibreFamilyCount {
    /// The number of families given.
    pub families: usize,
}

/// Writes `m` into the asset's materials (the inverse of
/// [`asset_materials`]); `m` has no fibre families or two (course, wale).
pub fn set_asset_materials(
    asset: &mut Asset,
    m: &crate::fit::elastic::MaterialFields,
) -> Result<(), FibreFamilyCount> {
    asset.gamma_s = m.gamma_s.clone();
    asset.gamma_v = m.gamma_v.clone();
    asset.fibres = match m.fibres.as_slice() {
        [] => None,
        [c, w] => Some(crate::geom::AssetFibres {
            course: c.directions.clone(),
            wale: w.directions.clone(),
            gamma_course: c.gamma.clone(),
            gamma_wale: w.gamma.clone(),
            beta_course: c.beta.clone(),
            beta_wale: w.beta.clone(),
        }),
        f => return Err(FibreFamilyCount { families: f.len() }),
    };
    Ok(())
}

impl crate::pipeline::error::StageFailure for StageError {
    fn class(&self) -> crate::pipeline::ErrorClass {
        StageError::class(self)
    }
    fn file(&self) -> Option<std::path::PathBuf> {
        match self {
            StageError::Io(e) => Some(e.path().to_path_buf()),
            StageError::Embed { path, .. }
            | StageError::Fit { path, .. }
            | StageError::Invalid { path, .. } => Some(path.clone()),
        }
    }
    fn as_error(&self) -> &(dyn std::error::Error + 'static) {
        self
    }
}

impl From<StageError> for crate::pipeline::Error {
    fn from(e: StageError) -> Self {
        crate::pipeline::Error::stage(e)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::{ErrorClass, Quiet};
    use crate::yarn::analytic::{knit_swatch, SwatchParams};

    fn embed_job(dir: &Path, yarns: &str) -> EmbedJob {
        EmbedJob {
            yarns: dir.join(yarns),
            read: ReadOptions::default(),
            params: EmbedParams {
                voxel_size: Some(2.5e-3),
                ..EmbedParams::default()
            },
            output: dir.join("a.vtkhdf"),
            command: "test".into(),
            cards: Vec::new(),
        }
    }

    /// The stages read and write their own files, record provenance, and
    /// fail with a classified error naming the file.
    #[test]
    fn stages_own_their_files_and_classify_failures() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let e = embed_job(d, "missing.ply").run(&mut Quiet).unwrap_err();
        assert_eq!(e.class(), ErrorClass::Missing, "{e}");
        assert_eq!(e.file(), Some(d.join("missing.ply")));
        assert!(!d.join("a.vtkhdf").exists());

        let y = knit_swatch(&SwatchParams {
            courses: 3,
            wales: 3,
            ..SwatchParams::default()
        });
        io::write_path(&d.join("sw.ply"), &y, None, &WriteOptions::default()).unwrap();
        let r = embed_job(d, "sw.ply").run(&mut Quiet).unwrap();
        assert_eq!(r.asset, d.join("a.vtkhdf"));
        let asset = io::vtkhdf::read_asset(&r.asset).unwrap();
        assert_eq!(
            asset.provenance.inputs[0].sha256,
            sha256_file(&d.join("sw.ply")).unwrap()
        );
        assert_eq!(asset.mesh.num_tets(), r.stats.tets);

        let mut export = ExportJob {
            asset: r.asset.clone(),
            selection: None,
            format: io::Format::Ply,
            output: d.join("out"),
            name: None,
            write: WriteOptions::default(),
            rest_if_static: false,
        };
        // A fresh asset has no steps: the input cannot be exported.
        let e = export.run(&mut Quiet).unwrap_err();
        assert_eq!(e.class(), ErrorClass::BadInput, "{e}");

        // Fill two steps, then ask for one it does not hold: usage (exit 2).
        let mut filled = asset.clone();
        for t in [0.0, 0.5] {
            filled.steps.times.push(t);
            filled.steps.positions.extend_from_slice(&asset.mesh.nodes);
        }
        io::vtkhdf::write_asset(&r.asset, &filled).unwrap();
        export.selection = Some("0-2".parse().unwrap());
        let e = export.run(&mut Quiet).unwrap_err();
        assert_eq!(e.class(), ErrorClass::Usage, "{e}");
        assert!(e.to_string().contains("step 2 does not exist"), "{e}");
        assert!(!d.join("out/a.0000.ply").exists());
        export.selection = None;
        let r = export.run(&mut Quiet).unwrap();
        assert_eq!(r.steps, 2);
        assert_eq!(
            r.written,
            [d.join("out/a.0000.ply"), d.join("out/a.0001.ply")]
        );
        let back = io::read_path(&r.written[1], &ReadOptions::default()).unwrap();
        assert_eq!(back.yarns.num_points(), y.num_points());
    }
}

/// The asset's yarn vertices as contact points: their tets' nodes and
/// weights, and per vertex half the yarn of each segment at it (linear
/// density of the curve when the yarns carry one, else proportional to
/// `r²`), scaled so the vertices carry the nodes' total mass.
pub fn yarn_contact_points(asset: &Asset) -> crate::sim::contact::EmbeddedPoints {
    let yarns = &asset.rest_yarns;
    let nv = asset.embedding.num_vertices();
    let mut share = vec![0.0f64; nv];
    for c in 0..yarns.num_curves() {
        for [a, b] in yarns.segments_of(c) {
            let ld = yarns
                .linear_density
                .as_ref()
                .map_or_else(|| yarns.radius_at(a).powi(2), |d| d[c]);
            let m = 0.5 * ld * crate::geom::dist(yarns.points[a], yarns.points[b]);
            for v in [a, b] {
                if let Some(s) = share.get_mut(v) {
                    *s += m;
                }
            }
        }
    }
    let total: f64 = share.iter().sum();
    let node_total: f64 = asset.node_mass.iter().sum();
    let scale = if total > 0.0 { node_total / total } else { 0.0 };
    // A vertex on no segment (or a zero-length one) still gets a small
    // weight: every contact point needs one.
    let floor = if nv > 0 {
        1e-6 * node_total / nv as f64
    } else {
        0.0
    };
    crate::sim::contact::EmbeddedPoints {
        nodes: asset
            .embedding
            .tet
            .iter()
            .map(|&t| asset.mesh.tets[t as usize])
            .collect(),
        weights: asset.embedding.weights.clone(),
        mass: share
            .iter()
            .map(|s| (s * scale).max(floor).max(f64::MIN_POSITIVE))
            .collect(),
    }
}
