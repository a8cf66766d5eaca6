//! The element energy of VH Eq. 7-8 and its gradient.
//!
//! Per tet `e` with rest shape matrix `Dm = [X1-X0, X2-X0, X3-X0]` (m), rest
//! volume `V_e = det(Dm) / 6` (m³), deformed shape matrix `Ds` (same columns
//! for the current positions) and `F = Ds Dm⁻¹`:
//!
//! `E_e = γs V_e |F - R(F)|²_F + γv V_e |F - V(F)|²_F`  (VH Eq. 7)
//!
//! with `R(F)` the closest rotation and `V(F)` the closest matrix of SL(3)
//! (VH Eq. 8, computed in [`super::local`]). Units: positions m, γ Pa, so
//! `E` is in J (Pa · m³) and the gradient in N.
//!
//! Gradient: each term is `γ V_e min_{A in C} |F - A|²` over a fixed set `C`
//! (SO(3) or SL(3)). By the envelope theorem (Danskin), the derivative of a
//! minimum over `A` is the partial derivative at the minimizer, the
//! minimizer's own change contributing nothing to first order: `∂E/∂F =
//! 2 γ V_e (F - P(F))`. This is the projective-dynamics force, and it is exact
//! wherever the projection is unique and the 0.01 floor of the local step is
//! not active. With `F = Ds Dm⁻¹`, `∂E/∂Ds = (∂E/∂F) Dm⁻ᵀ =: H`; nodes 1-3
//! receive the columns of `H` and node 0 receives minus their sum.

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

use super::element::{node_gradients, TetRest};
use super::fibre::{FibreFamily, MAX_FIBRE_FAMILIES};
use super::projection::{project_rotation, project_volume};
use super::SimError;
use crate::geom::{TetMesh, Vec3};

/// The elastic model of a mesh: rest shapes, per-tet stiffnesses `γs`, `γv`
/// (Pa) and up to [`MAX_FIBRE_FAMILIES`] tension-only fibre families
/// ([`super::fibre`]; none by default). Validated once on construction.
#[derive(Debug, Clone, PartialEq)]
pub struct ElasticModel {
    rest: Vec<TetRest>,
    gamma_s: Vec<f64>,
    gamma_v: Vec<f64>,
    fibres: Vec<FibreFamily>,
    num_nodes: usize,
}

fn v3(p: Vec3) -> Vector3<f64> {
    Vector3::new(p[0], p[1], p[2])
}

/// `[x1-x0, x2-x0, x3-x0]` of the tet `ids` at positions `x` (indices checked
/// by the caller).
fn shape_matrix(x: &[Vec3], ids: &[usize; 4]) -> Matrix3<f64> {
    let x0 = v3(x[ids[0]]);
    Matrix3::from_columns(&[v3(x[ids[1]]) - x0, v3(x[ids[2]]) - x0, v3(x[ids[3]]) - x0])
}

impl ElasticModel {
    /// Builds the model of `mesh` with per-tet `gamma_s`, `gamma_v` (Pa, one
    /// per tet, finite and `>= 0`). Every tet must have in-range node indices
    /// and a positive, finite rest volume.
    pub fn new(mesh: &TetMesh, gamma_s: &[f64], gamma_v: &[f64]) -> Result<Self, SimError> {
        let nt = mesh.num_tets();
        if gamma_s.len() != nt || gamma_v.len() != nt {
            return Err(SimError::Inconsistent(format!(
                "{nt} tets but {} gamma_s and {} gamma_v values",
                gamma_s.len(),
                gamma_v.len()
            )));
        }
        if let Some((e, g)) = gamma_s
            .iter()
            .chain(gamma_v)
            .enumerate()
            .find(|(_, g)| !(g.is_finite() && **g >= 0.0))
        {
            let (which, t) = if e < nt {
                ("gamma_s", e)
            } else {
                ("gamma_v", e - nt)
            };
            return Err(SimError::Inconsistent(format!(
                "{which} of tet {t} is {g}; stiffnesses must be finite and >= 0"
            )));
        }
        let n = mesh.num_nodes();
        if let Some(i) = mesh
            .nodes
            .iter()
            .position(|p| !p.iter().all(|c| c.is_finite()))
        {
            return Err(SimError::Inconsistent(format!(
                "rest position of node {i} is not finite"
            )));
        }
        let mut rest = Vec::with_capacity(nt);
        for (t, tet) in mesh.tets.iter().enumerate() {
            let nodes = tet.map(|i| i as usize);
            if let Some(&bad) = nodes.iter().find(|&&i| i >= n) {
                return Err(SimError::Inconsistent(format!(
                    "tet {t} uses node {bad} but the mesh has {n} nodes"
                )));
            }
            let dm = shape_matrix(&mesh.nodes, &nodes);
            let volume = dm.determinant() / 6.0;
            let dm_inv = match dm.try_inverse() {
                Some(m) if volume > 0.0 && m.iter().all(|x| x.is_finite()) => m,
                _ => {
                    return Err(SimError::Inconsistent(format!(
                        "tet {t} has rest volume {volume} m^3; it must be positive"
                    )))
                }
            };
            rest.push(TetRest {
                nodes,
                dm_inv,
                volume,
            });
        }
        Ok(ElasticModel {
            rest,
            gamma_s: gamma_s.to_vec(),
            gamma_v: gamma_v.to_vec(),
            fibres: Vec::new(),
            num_nodes: n,
        })
    }

    /// The same model with the fibre families `fibres` (at most
    /// [`MAX_FIBRE_FAMILIES`], each checked: one unit direction and one
    /// finite stiffness `>= 0` per tet) in place of its own.
    pub fn with_fibres(mut self, fibres: Vec<FibreFamily>) -> Result<Self, SimError> {
        if fibres.len() > MAX_FIBRE_FAMILIES {
            return Err(SimError::Inconsistent(format!(
                "{} fibre families; at most {MAX_FIBRE_FAMILIES} are supported",
                fibres.len()
            )));
        }
        for (k, fam) in fibres.iter().enumerate() {
            fam.check(self.rest.len(), k)?;
        }
        self.fibres = fibres;
        Ok(self)
    }

    /// The fibre families (empty: Eq. 7 alone).
    pub fn fibres(&self) -> &[FibreFamily] {
        &self.fibres
    }

    /// Energy (J) of tet `e` at deformation gradient `f`: Eq. 7 plus its fibres.
    pub fn tet_energy(&self, e: usize, f: &Matrix3<f64>) -> f64 {
        let v = self.rest[e].volume;
        let mut en = element_energy(f, v, self.gamma_s[e], self.gamma_v[e]);
        for fam in &self.fibres {
            en += fam.energy(e, f, v);
        }
        en
    }

    /// `∂E_e/∂F` (J) of tet `e` at `f`: Eq. 7 plus its fibres.
    pub fn tet_stress(&self, e: usize, f: &Matrix3<f64>) -> Matrix3<f64> {
        let v = self.rest[e].volume;
        let mut p = element_stress(f, v, self.gamma_s[e], self.gamma_v[e]);
        for fam in &self.fibres {
            p += fam.stress(e, f, v);
        }
        p
    }

    /// Rest data of every tet.
    pub fn rest(&self) -> &[TetRest] {
        &self.rest
    }
    /// Per-tet `γs` (Pa).
    pub fn gamma_s(&self) -> &[f64] {
        &self.gamma_s
    }
    /// Per-tet `γv` (Pa).
    pub fn gamma_v(&self) -> &[f64] {
        &self.gamma_v
    }
    /// Number of mesh nodes the model expects in `x`.
    pub fn num_nodes(&self) -> usize {
        self.num_nodes
    }

    fn check(&self, x: &[Vec3]) -> Result<(), SimError> {
        if x.len() != self.num_nodes {
            return Err(SimError::Inconsistent(format!(
                "{} positions for a mesh of {} nodes",
                x.len(),
                self.num_nodes
            )));
        }
        Ok(())
    }

    /// Deformation gradient `F_e = Ds Dm⁻¹` (dimensionless) of every tet for
    /// node positions `x` (m).
    pub fn deformation_gradients(&self, x: &[Vec3]) -> Result<Vec<Matrix3<f64>>, SimError> {
        self.check(x)?;
        Ok(self
            .rest
            .par_iter()
            .map(|r| shape_matrix(x, &r.nodes) * r.dm_inv)
            .collect())
    }

    /// Total energy `Σ_e E_e` (J) of VH Eq. 7 and the fibres for node positions `x` (m).
    /// Deterministic: per-tet values are summed in tet order.
    pub fn energy(&self, x: &[Vec3]) -> Result<f64, SimError> {
        self.check(x)?;
        let per_tet: Vec<f64> = (0..self.rest.len())
            .into_par_iter()
            .map(|e| {
                let r = &self.rest[e];
                self.tet_energy(e, &(shape_matrix(x, &r.nodes) * r.dm_inv))
            })
            .collect();
        Ok(per_tet.iter().sum())
    }

    /// Gradient `∂E/∂x` (N) of the total energy with respect to every node
    /// position (see the module doc: envelope theorem). The force is its
    /// negative. Deterministic: per-tet contributions are accumulated in tet
    /// order.
    pub fn gradient(&self, x: &[Vec3]) -> Result<Vec<Vec3>, SimError> {
        self.check(x)?;
        let per_tet: Vec<[Vector3<f64>; 4]> = (0..self.rest.len())
            .into_par_iter()
            .map(|e| {
                let r = &self.rest[e];
                let f = shape_matrix(x, &r.nodes) * r.dm_inv;
                node_gradients(&self.tet_stress(e, &f), &r.dm_inv)
            })
            .collect();
        let mut g = vec![[0.0; 3]; self.num_nodes];
        for (r, gs) in self.rest.iter().zip(&per_tet) {
            for (a, ga) in gs.iter().enumerate() {
                let gi = &mut g[r.nodes[a]];
                for k in 0..3 {
                    gi[k] += ga[k];
                }
            }
        }
        Ok(g)
    }
}

/// Energy `E_e` (J) of one tet with deformation gradient `f`, rest volume
/// `volume` (m³) and stiffnesses `gamma_s`, `gamma_v` (Pa): VH Eq. 7.
pub fn element_energy(f: &Matrix3<f64>, volume: f64, gamma_s: f64, gamma_v: f64) -> f64 {
    let r = project_rotation(f);
    let v = project_volume(f);
    volume * (gamma_s * (f - r).norm_squared() + gamma_v * (f - v).norm_squared())
}

/// `∂E_e/∂F = 2 V_e (γs (F - R(F)) + γv (F - V(F)))` (J, i.e. Pa · m³):
/// the derivative of VH Eq. 7 by the envelope theorem (module doc).
pub fn element_stress(f: &Matrix3<f64>, volume: f64, gamma_s: f64, gamma_v: f64) -> Matrix3<f64> {
    let r = project_rotation(f);
    let v = project_volume(f);
    2.0 * volume * (gamma_s * (f - r) + gamma_v * (f - v))
}

/// Total energy (J) of VH Eq. 7 over `mesh` at node positions `x` (m) with
/// per-tet stiffnesses (Pa). Builds an [`ElasticModel`]; keep one instead when
/// evaluating many poses.
pub fn total_energy(
    mesh: &TetMesh,
    x: &[Vec3],
    gamma_s: &[f64],
    gamma_v: &[f64],
) -> Result<f64, SimError> {
    ElasticModel::new(mesh, gamma_s, gamma_v)?.energy(x)
}

/// Gradient (N) of [`total_energy`] with respect to every node position.
pub fn gradient(
    mesh: &TetMesh,
    x: &[Vec3],
    gamma_s: &[f64],
    gamma_v: &[f64],
) -> Result<Vec<Vec3>, SimError> {
    ElasticModel::new(mesh, gamma_s, gamma_v)?.gradient(x)
}
