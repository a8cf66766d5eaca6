//! The local step of projective dynamics (VH §7.1): per tet, the closest
//! rotation `R(F)` and the closest volume-preserving matrix `V(F)` to the
//! deformation gradient (VH Eq. 8, Eq. 26), computed by
//! [`super::projection`].

use nalgebra::Matrix3;
use rayon::prelude::*;

use super::energy::ElasticModel;
use super::projection::*;
use super::SimError;
use crate::geom::Vec3;

/// Targets of the local step for one tet.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TetTargets {
    /// `P_s = R(F)`, the closest rotation.
    pub rotation: Matrix3<f64>,
    /// `P_v = V(F)`, the closest volume-preserving matrix.
    pub volume: Matrix3<f64>,
}

/// Statistics of one local step.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LocalStats {
    /// Most Newton/bisection iterations any tet's Eq. 26 solve took.
    pub max_iterations: u32,
    /// Tets whose singular values or solution hit the 0.01 floor
    /// (inverted, degenerate or extremely compressed).
    pub clamped: usize,
}

/// The PD local step (VH §7.1): for every tet, `R(F_e)` and `V(F_e)` for the
/// node positions `x` (m). Parallel over tets; the result does not depend on
/// the number of threads (each tet is computed independently and collected
/// in order).
pub fn local_step(
    model: &ElasticModel,
    x: &[Vec3],
) -> Result<(Vec<TetTargets>, LocalStats), SimError> {
    let fs = model.deformation_gradients(x)?;
    let out: Vec<(TetTargets, u32, bool)> = fs
        .par_iter()
        .map(|f| {
            let rotation = project_rotation(f);
            let (volume, p) = project_volume_detailed(f);
            (TetTargets { rotation, volume }, p.iterations, p.clamped)
        })
        .collect();
    let mut stats = LocalStats::default();
    let targets = out
        .into_iter()
        .map(|(t, it, cl)| {
            stats.max_iterations = stats.max_iterations.max(it);
            stats.clamped += cl as usize;
            t
        })
        .collect();
    Ok((targets, stats))
}
