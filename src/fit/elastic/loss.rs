//! The loss of VH Eq. 10 for one frame:
//!
//! `ε(x) = Σ_e V_e |F_e(x) - F̂_e|²_F + α Σ_k w_k |Σ_a c_ka x_{n_ka} - y_k|²`
//!
//! `F̂_e` is the target deformation gradient of tet `e` (Eq. 5, from Y2V),
//! and each position term `k` compares an interpolated point of the mesh
//! (a yarn vertex: `N x` of Eq. 4, or simply a node) with its target `y_k`.
//! The printed mass term `|N M^V x - M^Y x^Y|²` mixes units; as in
//! [`crate::fit::shapefit`] the weights `w_k` are masses made dimensionless,
//! `w_k = (m_k / M) (V / h²)` (`M` total mass, `V` mesh volume, `h` voxel
//! size), so a position misfit `d` weighs like a deformation-gradient misfit
//! `d / h`. `ε` is quadratic in `x`: its Hessian `G` (Eq. 19) is constant.

use nalgebra::{Matrix3, Vector3};

use crate::geom::Vec3;
use crate::sim::element::{node_gradients, TetRest};
use crate::sim::energy::ElasticModel;

/// Why a frame's targets cannot be made or do not fit the model.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TargetError {
    /// The target positions or the masses do not match the model's nodes.
    #[error("{positions} target positions and {masses} masses for {nodes} nodes")]
    Lengths {
        positions: usize,
        masses: usize,
        nodes: usize,
    },
    /// The voxel size is not positive and finite, or `alpha` is negative
    /// or not finite.
    #[error("voxel size {h} and alpha {alpha} must be > 0, >= 0")]
    Scale { h: f64, alpha: f64 },
    /// The node masses do not sum to a positive finite mass (kg).
    #[error("total node mass {mass} kg must be > 0")]
    TotalMass { mass: f64 },
    /// There is not one target deformation gradient per tet.
    #[error("{targets} target F for {tets} tets")]
    TargetCount { targets: usize, tets: usize },
    /// The weight of the position term is negative or not finite.
    #[error("alpha {alpha} must be finite and >= 0")]
    Alpha { alpha: f64 },
    /// A target deformation gradient has a non-finite entry.
    #[error("target F of tet {tet} is not finite")]
    NonFiniteTarget { tet: usize },
    /// A target tet is inverted or flat (`det F̂ <= 0`).
    #[error("target F of tet {tet} is inverted (det {det:e})")]
    InvertedTarget { tet: usize, det: f64 },
    /// A position term names a node outside the model, or has a non-finite
    /// value or a negative weight.
    #[error("position term {term}: nodes within {nodes}, finite values and weight >= 0 required")]
    PositionTerm { term: usize, nodes: usize },
}

/// One position term of Eq. 10: the point `Σ_a coeffs[a] x[nodes[a]]`
/// should be at `target` (m), with weight `weight` (dimensionless, >= 0).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PositionTerm {
    pub nodes: [usize; 4],
    pub coeffs: [f64; 4],
    pub target: Vec3,
    pub weight: f64,
}

/// The targets of one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameTarget {
    /// `F̂_e` per tet (dimensionless), det > 0.
    pub f_target: Vec<Matrix3<f64>>,
    /// Weight α of the position term (dimensionless). VH: 0.1.
    pub alpha: f64,
    /// The position terms.
    pub positions: Vec<PositionTerm>,
}

fn v3(p: Vec3) -> Vector3<f64> {
    Vector3::new(p[0], p[1], p[2])
}

/// Shape-function gradients `∇N_a` (1/m) of a tet: `F = Σ_a x_a ∇N_aᵀ`.
pub(crate) fn shape_gradients(r: &TetRest) -> [Vector3<f64>; 4] {
    let g: [Vector3<f64>; 3] = std::array::from_fn(|j| r.dm_inv.row(j).transpose());
    [-(g[0] + g[1] + g[2]), g[0], g[1], g[2]]
}

fn deformation_gradient(x: &[Vec3], r: &TetRest) -> Matrix3<f64> {
    let g = shape_gradients(r);
    let mut f = Matrix3::zeros();
    for a in 0..4 {
        f += v3(x[r.nodes[a]]) * g[a].transpose();
    }
    f
}

impl FrameTarget {
    /// Targets from target node positions `x_hat` (m; e.g. the Y2V fit of
    /// a yarn pose): `F̂_e = F_e(x̂)` and one position term per node with
    /// mass, weight `(m_i / M)(V / h²)` for node masses `mass` (kg) and voxel
    /// size `h` (m).
    pub fn from_nodes(
        model: &ElasticModel,
        x_hat: &[Vec3],
        mass: &[f64],
        alpha: f64,
        h: f64,
    ) -> Result<FrameTarget, TargetError> {
        let n = model.num_nodes();
        if x_hat.len() != n || mass.len() != n {
            return Err(TargetError::Lengths {
                positions: x_hat.len(),
                masses: mass.len(),
                nodes: n,
            });
        }
        if !(h > 0.0 && h.is_finite() && alpha >= 0.0 && alpha.is_finite()) {
            return Err(TargetError::Scale { h, alpha });
        }
        let total_mass: f64 = mass.iter().sum();
        let volume: f64 = model.rest().iter().map(|r| r.volume).sum();
        if !(total_mass > 0.0 && total_mass.is_finite()) {
            return Err(TargetError::TotalMass { mass: total_mass });
        }
        let f_target = model
            .rest()
            .iter()
            .map(|r| deformation_gradient(x_hat, r))
            .collect();
        let positions = (0..n)
            .filter(|&i| mass[i] > 0.0)
            .map(|i| PositionTerm {
                nodes: [i; 4],
                coeffs: [1.0, 0.0, 0.0, 0.0],
                target: x_hat[i],
                weight: mass[i] / total_mass * volume / (h * h),
            })
            .collect();
        Ok(FrameTarget {
            f_target,
            alpha,
            positions,
        })
    }

    /// Checks the targets against `model`; the message names the problem.
    /// An inverted or flat target tet (det F̂ <= 0) is refused: no
    /// simulation of the Eq. 7 energy can be asked to reach it.
    pub fn validate(&self, model: &ElasticModel) -> Result<(), TargetError> {
        let (nt, n) = (model.rest().len(), model.num_nodes());
        if self.f_target.len() != nt {
            return Err(TargetError::TargetCount {
                targets: self.f_target.len(),
                tets: nt,
            });
        }
        if !(self.alpha >= 0.0 && self.alpha.is_finite()) {
            return Err(TargetError::Alpha { alpha: self.alpha });
        }
        for (e, f) in self.f_target.iter().enumerate() {
            if !f.iter().all(|v| v.is_finite()) {
                return Err(TargetError::NonFiniteTarget { tet: e });
            }
            let d = f.determinant();
            if !(d > 0.0) {
                return Err(TargetError::InvertedTarget { tet: e, det: d });
            }
        }
        for (k, p) in self.positions.iter().enumerate() {
            if p.nodes.iter().any(|&i| i >= n)
                || !(p.weight >= 0.0 && p.weight.is_finite())
                || !p.target.iter().chain(&p.coeffs).all(|v| v.is_finite())
            {
                return Err(TargetError::PositionTerm { term: k, nodes: n });
            }
        }
        Ok(())
    }

    /// `ε(x)` (m³ in the F term; see the module doc).
    pub fn loss(&self, model: &ElasticModel, x: &[Vec3]) -> f64 {
        let mut e = 0.0;
        for (r, ft) in model.rest().iter().zip(&self.f_target) {
            e += r.volume * (deformation_gradient(x, r) - ft).norm_squared();
        }
        for p in &self.positions {
            e += self.alpha * p.weight * (self.point(p, x) - v3(p.target)).norm_squared();
        }
        e
    }

    fn point(&self, p: &PositionTerm, x: &[Vec3]) -> Vector3<f64> {
        (0..4).map(|a| p.coeffs[a] * v3(x[p.nodes[a]])).sum()
    }

    /// `∂ε/∂x` (m² per m of node motion) at every node.
    pub fn gradient(&self, model: &ElasticModel, x: &[Vec3]) -> Vec<Vec3> {
        let mut g = vec![[0.0; 3]; x.len()];
        for (r, ft) in model.rest().iter().zip(&self.f_target) {
            let d = 2.0 * r.volume * (deformation_gradient(x, r) - ft);
            for (a, ga) in node_gradients(&d, &r.dm_inv).iter().enumerate() {
                for c in 0..3 {
                    g[r.nodes[a]][c] += ga[c];
                }
            }
        }
        for p in &self.positions {
            let d = 2.0 * self.alpha * p.weight * (self.point(p, x) - v3(p.target));
            for a in 0..4 {
                for c in 0..3 {
                    g[p.nodes[a]][c] += p.coeffs[a] * d[c];
                }
            }
        }
        g
    }

    /// The Hessian `G = ∂²ε/∂x²` per coordinate: scalar entries `(i, j, v)`
    /// over nodes (the 3n x 3n Hessian is this times the 3x3 identity).
    /// Duplicates are to be summed.
    pub fn hessian_entries(&self, model: &ElasticModel) -> Vec<(usize, usize, f64)> {
        let mut t = Vec::with_capacity(model.rest().len() * 16 + self.positions.len() * 16);
        for r in model.rest() {
            let g = shape_gradients(r);
            for a in 0..4 {
                for b in 0..4 {
                    t.push((r.nodes[a], r.nodes[b], 2.0 * r.volume * g[a].dot(&g[b])));
                }
            }
        }
        for p in &self.positions {
            let w = 2.0 * self.alpha * p.weight;
            for a in 0..4 {
                for b in 0..4 {
                    let v = w * p.coeffs[a] * p.coeffs[b];
                    if v != 0.0 {
                        t.push((p.nodes[a], p.nodes[b], v));
                    }
                }
            }
        }
        t
    }
}
