//! The homogenized asset: tet mesh, materials, embedding, rest yarns,
//! parameters, provenance and a time series of node positions. Stored as
//! VTKHDF by `io::vtkhdf` (layout in schemas/asset-vtkhdf.md).

use super::{Embedding, TetMesh, Vec3, VoxelGrid, Yarns};

/// Default per-tet shape stiffness gamma_s (VH Eq. 7) before fitting (Pa).
pub const DEFAULT_GAMMA_S: f64 = 1.0e4;
/// Default per-tet volume stiffness gamma_v (VH Eq. 7) before fitting (Pa).
pub const DEFAULT_GAMMA_V: f64 = 1.0e4;

/// Where an asset came from.
#[derive(Debug, Clone, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct Provenance {
    /// knitvox version that wrote it.
    pub knitvox_version: String,
    /// The command line that made it.
    pub command: String,
    /// Input files and their SHA-256 (hex).
    pub inputs: Vec<InputFile>,
}

#[derive(Debug, Clone, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct InputFile {
    pub path: String,
    pub sha256: String,
}

/// A time series of node positions (fixed topology).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct NodeSteps {
    /// Time of each step (s).
    pub times: Vec<f64>,
    /// Node positions (m), step-major: step `s` owns `positions[s * n .. (s + 1) * n]`.
    pub positions: Vec<Vec3>,
    /// Optional per-step fit error (e.g. Y2V RMS yarn error, m); empty when unknown.
    pub fit_error: Vec<f64>,
}

impl NodeSteps {
    pub fn num_steps(&self) -> usize {
        self.times.len()
    }
    pub fn step(&self, s: usize, num_nodes: usize) -> &[Vec3] {
        &self.positions[s * num_nodes..(s + 1) * num_nodes]
    }
}

/// A homogenized asset.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Asset {
    /// Voxels the mesh was built from.
    pub grid: VoxelGrid,
    /// Rest tet mesh (m).
    pub mesh: TetMesh,
    /// Voxel (index into `grid.voxels`) of each tet.
    pub tet_voxel: Vec<u32>,
    /// Lumped node masses (kg), VH Eq. 1-3.
    pub node_mass: Vec<f64>,
    /// Per-tet shape stiffness gamma_s (Pa).
    pub gamma_s: Vec<f64>,
    /// Per-tet volume stiffness gamma_v (Pa).
    pub gamma_v: Vec<f64>,
    /// Per-tet domain id (for domain-decomposed solvers); 0 by default.
    pub domain: Vec<i32>,
    /// Tension-only fibres along the courses and wales (`knitvox fit
    /// --fibres`); `None`: VH Eq. 7 alone.
    pub fibres: Option<AssetFibres>,
    /// Yarn vertices in the mesh (V2Y).
    pub embedding: Embedding,
    /// Rest yarns (m, +Y up).
    pub rest_yarns: Yarns,
    /// Every parameter used to build and fit the asset, as a JSON object.
    pub parameters: serde_json::Value,
    pub provenance: Provenance,
    /// Node positions over time.
    pub steps: NodeSteps,
}

/// Fibre families of an asset ([`crate::sim::fibre`]): per tet the unit
/// rest directions of the course and the wale and their stiffnesses (Pa,
/// finite, `>= 0`), and for the knit material their stiffenings.
#[derive(Debug, Clone, PartialEq)]
pub struct AssetFibres {
    pub course: Vec<Vec3>,
    pub wale: Vec<Vec3>,
    pub gamma_course: Vec<f64>,
    pub gamma_wale: Vec<f64>,
    /// Stiffening `β` per tet along the course and the wale
    /// (dimensionless, finite, `>= 0`; [`crate::sim::knit`]); both empty
    /// for quadratic fibres.
    pub beta_course: Vec<f64>,
    pub beta_wale: Vec<f64>,
}

/// The elasticity fit an asset records (`knitvox fit`, VH §6): stored as
/// the key [`FIT_RECORD_KEY`] of the asset's parameters (`/knitvox/parameters`,
/// schemas/asset-vtkhdf.md).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FitRecord {
    /// knitvox version that fitted.
    pub knitvox_version: String,
    /// The training poses, in fitting order.
    pub poses: Vec<FitPose>,
    /// Frames fitted per pose (`--samples`).
    pub samples_per_pose: usize,
    /// Harmonic ranks of the initialization (VH §6.5).
    pub harmonic_ranks: Vec<usize>,
    /// Whether the poses were fitted together (VH Eq. 9) rather than one
    /// by one with the Eq. 22 fold.
    #[serde(default)]
    pub joint: bool,
    /// The best uniform material: the r = 1 harmonic stage, fitted on the
    /// same poses from the asset's earlier material (Pa).
    pub uniform: UniformMaterial,
    /// Loss (m³, VH Eq. 10, summed over each pose's frames) per pose at the
    /// earlier material, at the uniform one and at the fitted field.
    pub losses: Vec<PoseLosses>,
    /// Every fitting parameter (`fit::elastic::ElasticFitParams`), as JSON.
    pub params: serde_json::Value,
}

/// One training pose of a [`FitRecord`].
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FitPose {
    pub path: String,
    pub sha256: String,
    /// 0-based frames of the file that were fitted.
    pub frames: Vec<usize>,
    /// Its Eq. 22 weight (J).
    pub energy: f64,
}

/// A uniform material (Pa).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct UniformMaterial {
    pub gamma_s: f64,
    pub gamma_v: f64,
    /// Fibre stiffnesses along the course and the wale (Pa) of a fit with
    /// fibres (`knitvox fit --fibres`); absent otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gamma_course: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gamma_wale: Option<f64>,
    /// Their stiffenings (dimensionless) of a knit-material fit; absent
    /// otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub beta_course: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub beta_wale: Option<f64>,
}

/// In-sample fidelity: the RMS distance (yarn diameters, over every yarn
/// vertex of the fitted frames) between the pose's yarns and V2Y of the
/// mesh's equilibrium under each material, as `validate` measures held-out
/// motion. The field can do no better on held-out motion than its margin
/// over the uniform material here suggests: what no material of Eq. 7 on
/// this mesh reaches on a pose stays out of reach elsewhere.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TrainingFidelity {
    /// V2Y of the shape fit (VH Eq. 5-6) of each frame: the Y2V floor.
    pub y2v_floor_rms_yarn_diameters: f64,
    /// The asset's material as read.
    pub before_rms_yarn_diameters: f64,
    pub uniform_rms_yarn_diameters: f64,
    pub fitted_rms_yarn_diameters: f64,
}

/// Losses of one pose (m³).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PoseLosses {
    pub pose: String,
    /// At the asset's material before the fit.
    pub before: f64,
    /// At the uniform material.
    pub uniform: f64,
    /// At the fitted (folded) field.
    pub fitted: f64,
    /// Last loss of each stage of this pose's own fit (`harmonic r=N`,
    /// `full`; with a joint fit, of the joint one).
    pub stages: Vec<(String, f64)>,
    /// The fit's fidelity on this pose (absent in records written before
    /// it was measured).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub training: Option<TrainingFidelity>,
}

/// Key of the fit record in [`Asset::parameters`].
pub const FIT_RECORD_KEY: &str = "fit";

/// A fit record in an asset's parameters that does not parse.
#[derive(Debug, thiserror::Error)]
#[error("parameters.{}: {}", FIT_RECORD_KEY, .0)]
pub struct FitRecordError(#[source] pub serde_json::Error);

/// Key of the damping record in [`Asset::parameters`].
pub const DAMPING_RECORD_KEY: &str = "damping";

/// The homogenized damping an asset records (`knitvox fit-damping`): the
/// stiffness-proportional damping found on a dynamic scene, stored as the
/// key [`DAMPING_RECORD_KEY`] of the asset's parameters.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DampingRecord {
    /// knitvox version that fitted.
    pub knitvox_version: String,
    /// Stiffness-proportional damping `β` (s, finite, >= 0;
    /// `crate::sim::pd::PdParams::stiffness_damping`).
    pub stiffness_damping_s: f64,
    /// The scene it was fitted on (its file as given, and the SHA-256 of
    /// its text) and its yarn-level run's name.
    pub scene: String,
    pub scene_sha256: String,
    /// RMS distance (yarn diameters) of the homogenized run from the yarn
    /// level on that scene, with `β` and without damping.
    pub rms_yarn_diameters: f64,
    pub undamped_rms_yarn_diameters: f64,
    /// Every damping tried and its RMS (yarn diameters), in order.
    pub evaluations: Vec<[f64; 2]>,
    /// The largest PD step (s) of the runs it was fitted with (absent in
    /// records made before it was kept). Implicit Euler dissipates by
    /// itself, the more the longer the step, so `β` holds at that step.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dt_s: Option<f64>,
    /// Whether `β` was fitted with the co-rotated damping, which leaves
    /// rigid rotation free (false in records made before it: that linear
    /// form damped rotations too, so its `β` does not carry).
    #[serde(default)]
    pub corotated: bool,
}

impl DampingRecord {
    /// A warning for a damping fitted with the earlier linear form, which
    /// the PD step no longer has.
    pub fn superseded(&self) -> Option<String> {
        (!self.corotated && self.stiffness_damping_s > 0.0).then(|| {
            format!(
                "the asset's damping ({:.3e} s) was fitted with the linear stiffness damping of an earlier \
                 knitvox, which also damped rigid rotation; the PD step now damps only deformation, so \
                 that value does not carry (run `knitvox fit-damping` again)",
                self.stiffness_damping_s
            )
        })
    }
}

/// A damping record in an asset's parameters that does not parse or holds
/// a damping that is not finite and >= 0.
#[derive(Debug, thiserror::Error)]
#[error("parameters.{}: {}", DAMPING_RECORD_KEY, .0)]
pub struct DampingRecordError(pub String);

impl Asset {
    /// The recorded damping, `Ok(None)` when none was fitted.
    pub fn damping_record(&self) -> Result<Option<DampingRecord>, DampingRecordError> {
        let Some(v) = self.parameters.get(DAMPING_RECORD_KEY) else {
            return Ok(None);
        };
        let r: DampingRecord =
            serde_json::from_value(v.clone()).map_err(|e| DampingRecordError(e.to_string()))?;
        let b = r.stiffness_damping_s;
        if !(b.is_finite() && b >= 0.0) {
            return Err(DampingRecordError(format!(
                "stiffness_damping_s {b} must be finite and >= 0"
            )));
        }
        Ok(Some(r))
    }

    /// Records `record` (replacing an earlier one).
    pub fn set_damping_record(&mut self, record: &DampingRecord) {
        if !self.parameters.is_object() {
            let old = std::mem::take(&mut self.parameters);
            self.parameters = serde_json::json!({ "parameters": old });
        }
        let v = serde_json::to_value(record).expect("a damping record is plain data");
        if let Some(o) = self.parameters.as_object_mut() {
            o.insert(DAMPING_RECORD_KEY.to_string(), v);
        }
    }

    /// The recorded fit, `Ok(None)` when the asset was never fitted; an
    /// error names what is wrong with a malformed record.
    pub fn fit_record(&self) -> Result<Option<FitRecord>, FitRecordError> {
        match self.parameters.get(FIT_RECORD_KEY) {
            None => Ok(None),
            Some(v) => serde_json::from_value(v.clone())
                .map(Some)
                .map_err(FitRecordError),
        }
    }

    /// Records `record` (replacing an earlier one). Parameters that are not
    /// a JSON object are kept under the key `parameters`.
    pub fn set_fit_record(&mut self, record: &FitRecord) {
        if !self.parameters.is_object() {
            let old = std::mem::take(&mut self.parameters);
            self.parameters = serde_json::json!({ "parameters": old });
        }
        let v = serde_json::to_value(record).expect("a fit record is plain data");
        if let Some(o) = self.parameters.as_object_mut() {
            o.insert(FIT_RECORD_KEY.to_string(), v);
        }
    }
}
