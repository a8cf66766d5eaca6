//! Sample-by-sample fitting (VH §6.4, Eq. 22) and the driver
//! [`fit_materials`].
//!
//! Every sample is fitted from the same initial material (so samples are
//! independent and a farm may fit them in parallel), then the fields are
//! folded in order: `γ ← w/(w + w_k) γ + w_k/(w + w_k) γ_k`, where `w_k` is
//! the sample's yarn-level elastic energy and `w` the largest energy seen so
//! far (0 before the first sample, VH §6.4). A convex combination of fields
//! that are `>=` the floor stays `>=` the floor.

use std::time::Instant;

use super::adjoint::Anchor;
use super::gauss_newton::StageReport;
use super::harmonic::harmonic_basis;
use super::types::{ElasticFitError, ElasticFitParams, FitProgress, MaterialFields, Sample};
use crate::geom::TetMesh;

/// Inputs of [`fit_materials`].
#[derive(Clone, Copy)]
pub struct FitInputs<'a> {
    /// The tet mesh (rest positions in m).
    pub mesh: &'a TetMesh,
    /// Lumped node masses (kg), as given to the simulator.
    pub mass: &'a [f64],
    /// Training samples, folded in this order.
    pub samples: &'a [Sample],
    /// Initial material (Pa per tet), e.g. the uniform placeholder 1e4 Pa.
    pub init: &'a MaterialFields,
    /// Called after every iteration of every stage (progress lines).
    pub progress: Option<&'a dyn Fn(&FitProgress)>,
}

impl std::fmt::Debug for FitInputs<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FitInputs")
            .field("tets", &self.mesh.num_tets())
            .field("samples", &self.samples.len())
            .field("progress", &self.progress.is_some())
            .finish()
    }
}

/// What the fit of one sample did.
#[derive(Debug, Clone, PartialEq, Default, serde::Serialize)]
pub struct SampleReport {
    pub name: String,
    /// Its Eq. 22 weight `w_k` (J).
    pub energy: f64,
    /// Its weight in the fold, `w_k / (w + w_k)`.
    pub fold_weight: f64,
    /// Loss (m³) at the initial material and after the last stage.
    pub initial_loss: f64,
    pub final_loss: f64,
    /// Stages in order (losses per iteration inside).
    pub stages: Vec<StageReport>,
    /// Wall time (ms).
    pub ms: f64,
    /// Every frame's equilibrium under this sample's own fitted field (not
    /// the folded one), to warm-start later solves
    /// ([`super::adjoint::equilibrium_continued`]); not serialized.
    #[serde(skip)]
    pub anchors: Vec<Anchor>,
}

/// What [`fit_materials`] did.
#[derive(Debug, Clone, PartialEq, Default, serde::Serialize)]
pub struct FitReport {
    pub samples: Vec<SampleReport>,
    /// Time to compute the harmonic basis (ms).
    pub harmonic_ms: f64,
    /// Total wall time (ms).
    pub total_ms: f64,
    /// Smallest and largest fitted `γs` and `γv` (Pa).
    pub gamma_s_range: [f64; 2],
    pub gamma_v_range: [f64; 2],
}

/// Folds `gamma_k` with weight `w_k` into `gamma` with weight `w` (Eq. 22);
/// returns the fold weight `w_k / (w + w_k)`. `w = 0` takes `gamma_k`.
pub fn fold(gamma: &mut MaterialFields, w: f64, gamma_k: &MaterialFields, w_k: f64) -> f64 {
    let a = if w + w_k > 0.0 { w_k / (w + w_k) } else { 1.0 };
    let folded: Vec<f64> = gamma
        .stacked()
        .iter()
        .zip(gamma_k.stacked())
        .map(|(g, gk)| (1.0 - a) * g + a * gk)
        .collect();
    *gamma = gamma.with_stacked(&folded);
    a
}

fn range(v: &[f64]) -> [f64; 2] {
    v.iter().fold([f64::INFINITY, f64::NEG_INFINITY], |r, &x| {
        [r[0].min(x), r[1].max(x)]
    })
}

/// Fits per-element materials to the training samples (VH §6): each sample
/// by [`fit_sample`] (harmonic stages, then the full field; GD then GN in
/// each), folded by Eq. 22. Errors name the sample that cannot be fitted.
pub fn fit_materials(
    inputs: &FitInputs<'_>,
    params: &ElasticFitParams,
) -> Result<(MaterialFields, FitReport), ElasticFitError> {
    let start = Instant::now();
    params.check()?;
    let ne = inputs.mesh.num_tets();
    if inputs.samples.is_empty() {
        return Err(ElasticFitError::Inconsistent("no training samples".into()));
    }
    if inputs.init.gamma_s.len() != ne || inputs.init.gamma_v.len() != ne {
        return Err(ElasticFitError::Inconsistent(format!(
            "initial material has {} gamma_s and {} gamma_v for {ne} tets",
            inputs.init.gamma_s.len(),
            inputs.init.gamma_v.len()
        )));
    }
    for (k, f) in inputs.init.fibres.iter().enumerate() {
        f.check(ne, k)
            .map_err(|e| ElasticFitError::Inconsistent(format!("initial material: {e}")))?;
    }
    let t = Instant::now();
    let rmax = params
        .harmonic_ranks
        .iter()
        .copied()
        .filter(|&r| r < ne)
        .max()
        .unwrap_or(0);
    let basis =
        harmonic_basis(inputs.mesh, rmax).map_err(|e| ElasticFitError::Harmonic(e.to_string()))?;
    let mut report = FitReport {
        harmonic_ms: t.elapsed().as_secs_f64() * 1e3,
        ..Default::default()
    };
    let mut gamma = inputs.init.clone();
    let mut w = 0.0f64;
    for sample in inputs.samples {
        let ts = Instant::now();
        let (gk, stages, loss0, xs) = super::gauss_newton::fit_sample_observed(
            inputs.mesh,
            inputs.mass,
            sample,
            inputs.init,
            &basis,
            params,
            inputs.progress,
        )?;
        let final_loss = stages
            .last()
            .and_then(|s| s.losses.last().copied())
            .unwrap_or(loss0);
        let a = fold(&mut gamma, w, &gk, sample.energy);
        w = w.max(sample.energy);
        report.samples.push(SampleReport {
            name: sample.name.clone(),
            energy: sample.energy,
            fold_weight: a,
            initial_loss: loss0,
            final_loss,
            stages,
            ms: ts.elapsed().as_secs_f64() * 1e3,
            anchors: {
                let g = std::sync::Arc::new(gk.stacked());
                xs.into_iter()
                    .map(|x| Anchor {
                        gamma: g.clone(),
                        x,
                    })
                    .collect()
            },
        });
    }
    if let Some(g) = gamma
        .stacked()
        .iter()
        .find(|g| !(g.is_finite() && **g >= params.gamma_floor))
    {
        return Err(ElasticFitError::Inconsistent(format!(
            "the folded material has gamma {g}"
        )));
    }
    report.gamma_s_range = range(&gamma.gamma_s);
    report.gamma_v_range = range(&gamma.gamma_v);
    report.total_ms = start.elapsed().as_secs_f64() * 1e3;
    Ok((gamma, report))
}
