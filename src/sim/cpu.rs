//! CPU (f64) implementations of the PD backend traits of [`super::backend`]:
//! the reference the GPU backend is checked against.
//!
//! * [`CpuElasticRhs`]: the local step of [`super::local`] fused with the
//!   elastic right-hand side of the global step (VH Eq. 26, 28).
//! * The Chebyshev-Jacobi solver lives in [`super::jacobi`] (`CpuJacobi`).

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

use super::backend::{ElasticRhs, LocalEval};
use super::element::node_gradients;
use super::energy::ElasticModel;
use super::projection::{
    project_diag_sl3, project_volume_detailed, signed_svd_warm, signed_svd_warm_x4, SignedSvd,
    SVD_LANES,
};
use super::SimError;
use crate::geom::Vec3;

/// Tets per rayon task in the per-tet pass (large enough that scheduling
/// costs nothing next to two 3x3 projections per tet).
const TET_CHUNK: usize = 512;

/// The local step and elastic right-hand side on the CPU.
///
/// Per tet (in parallel): `F_e`, `R_e = R(F_e)`, `V_e = V(F_e)` (VH Eq. 26),
/// the energy `V_e (γs |F - R|² + γv |F - V|²)` and the four node
/// contributions of `2 V_e (γs R_e + γv V_e)` (module doc of `sim::pd`).
/// Per node (in parallel) the contributions are summed over the node's tets
/// in tet order, and the energies are summed in tet order, so the result does
/// not depend on the thread count.
#[derive(Debug, Clone)]
pub struct CpuElasticRhs {
    model: ElasticModel,
    /// Node -> (tet, corner) incidences, CSR: `node_ptr[a]..node_ptr[a + 1]`
    /// index `incidence`, in increasing tet order.
    node_ptr: Vec<usize>,
    incidence: Vec<u32>,
    /// Per-tet scratch: four node contributions.
    per_tet: Vec<[Vector3<f64>; 4]>,
    /// Per-tet scratch: energy and clamped flag.
    per_tet_energy: Vec<(f64, bool)>,
    /// Per tet, the right singular vectors `V` of its last `F`: the warm
    /// start of the next SVD ([`signed_svd_warm`]; PD iterations and time
    /// steps move `F` little).
    warm_v: Vec<Matrix3<f64>>,
}

impl CpuElasticRhs {
    /// Prepares the evaluation for `model` (keeps a copy: rebuild it when the
    /// materials change).
    pub fn new(model: &ElasticModel) -> CpuElasticRhs {
        let n = model.num_nodes();
        let rest = model.rest();
        let mut count = vec![0usize; n + 1];
        for r in rest {
            for &a in &r.nodes {
                count[a + 1] += 1;
            }
        }
        for a in 0..n {
            count[a + 1] += count[a];
        }
        let mut fill = count.clone();
        let mut incidence = vec![0u32; count[n]];
        for (e, r) in rest.iter().enumerate() {
            for (c, &a) in r.nodes.iter().enumerate() {
                // 4 corners: the incidence packs tet and corner in one u32
                // as long as the mesh has fewer than 2^30 tets.
                incidence[fill[a]] = ((e as u32) << 2) | c as u32;
                fill[a] += 1;
            }
        }
        CpuElasticRhs {
            model: model.clone(),
            node_ptr: count,
            incidence,
            per_tet: vec![[Vector3::zeros(); 4]; rest.len()],
            per_tet_energy: vec![(0.0, false); rest.len()],
            warm_v: vec![Matrix3::identity(); rest.len()],
        }
    }

    /// The model this evaluator uses.
    pub fn model(&self) -> &ElasticModel {
        &self.model
    }
}

fn v3(p: Vec3) -> Vector3<f64> {
    Vector3::new(p[0], p[1], p[2])
}

/// `R(F)` and `V(F)` of [`super::local`] from one signed SVD (the two
/// public projections compute it twice): bitwise the same results as
/// `project_rotation` and `project_volume_detailed`, which both start from
/// `signed_svd(f)` and fall back to the identity when it fails.
#[cfg(test)]
fn project_both(f: &Matrix3<f64>) -> (Matrix3<f64>, Matrix3<f64>, bool) {
    project_from_svd(f, super::projection::signed_svd(f))
}

/// [`project_both`] from an SVD of `f` (`None`: `f` not finite).
fn project_from_svd(
    f: &Matrix3<f64>,
    svd: Option<SignedSvd>,
) -> (Matrix3<f64>, Matrix3<f64>, bool) {
    match svd {
        Some(svd) => {
            let rot = svd.u * svd.v.transpose();
            let p = project_diag_sl3([svd.s[0], svd.s[1], svd.s[2]]);
            let d = Vector3::new(p.d[0], p.d[1], p.d[2]);
            let vol = svd.u * Matrix3::from_diagonal(&d) * svd.v.transpose();
            (rot, vol, p.clamped)
        }
        None => {
            let (vol, p) = project_volume_detailed(f);
            (Matrix3::identity(), vol, p.clamped)
        }
    }
}

/// One tet's energy `V (γs |F - R|² + γv |F - V(F)|²)` (J, VH Eq. 7) and
/// the PD target `2 V (γs R + γv V(F))` from the signed SVD of `F`, and
/// whether the SL(3) projection clamped. With `F = U S Vᵀ`, `R = U Vᵀ` and
/// `V(F) = U D Vᵀ` (U, V rotations) both come from the singular values:
/// `|F - R|² = Σ (s_i - 1)²`, `|F - V(F)|² = Σ (s_i - d_i)²` and the target
/// is `U diag(2 V (γs + γv d_i)) Vᵀ`, one matrix product instead of five.
fn targets_from_svd(
    svd: &SignedSvd,
    volume: f64,
    gamma_s: f64,
    gamma_v: f64,
) -> (f64, Matrix3<f64>, bool) {
    let p = project_diag_sl3([svd.s[0], svd.s[1], svd.s[2]]);
    let (mut e_s, mut e_v) = (0.0, 0.0);
    let mut u = svd.u;
    for k in 0..3 {
        e_s += (svd.s[k] - 1.0).powi(2);
        e_v += (svd.s[k] - p.d[k]).powi(2);
        let w = 2.0 * volume * (gamma_s + gamma_v * p.d[k]);
        u.column_mut(k).scale_mut(w);
    }
    (
        volume * (gamma_s * e_s + gamma_v * e_v),
        u * svd.v.transpose(),
        p.clamped,
    )
}

impl ElasticRhs for CpuElasticRhs {
    fn evaluate(&mut self, x: &[Vec3], out: &mut [Vec3]) -> Result<LocalEval, SimError> {
        let n = self.model.num_nodes();
        if x.len() != n || out.len() != n {
            return Err(SimError::Inconsistent(format!(
                "elastic rhs got {} positions and {} outputs for {n} nodes",
                x.len(),
                out.len()
            )));
        }
        if self.model.rest().len() >= (1usize << 30) {
            return Err(SimError::Inconsistent(
                "meshes of 2^30 tets or more are not supported".into(),
            ));
        }
        let model = &self.model;
        let rest = model.rest();
        let (gs, gv) = (model.gamma_s(), model.gamma_v());
        let fibres = model.fibres();
        self.per_tet
            .par_chunks_mut(TET_CHUNK)
            .zip(self.per_tet_energy.par_chunks_mut(TET_CHUNK))
            .zip(self.warm_v.par_chunks_mut(TET_CHUNK))
            .enumerate()
            .for_each(|(c, ((g_chunk, e_chunk), w_chunk))| {
                let base = c * TET_CHUNK;
                let def_grad = |e: usize| {
                    let r = &rest[e];
                    let x0 = v3(x[r.nodes[0]]);
                    let ds = Matrix3::from_columns(&[
                        v3(x[r.nodes[1]]) - x0,
                        v3(x[r.nodes[2]]) - x0,
                        v3(x[r.nodes[3]]) - x0,
                    ]);
                    ds * r.dm_inv
                };
                let finish = |e: usize, f: &Matrix3<f64>, svd: Option<&SignedSvd>| {
                    let r = &rest[e];
                    let (mut energy, mut target, clamped) = match svd {
                        Some(svd) => targets_from_svd(svd, r.volume, gs[e], gv[e]),
                        None => {
                            let (rot, vol, clamped) = project_from_svd(f, None);
                            let energy = r.volume
                                * (gs[e] * (f - rot).norm_squared()
                                    + gv[e] * (f - vol).norm_squared());
                            let target = 2.0 * r.volume * (gs[e] * rot + gv[e] * vol);
                            (energy, target, clamped)
                        }
                    };
                    for fam in fibres {
                        let (t, en) = fam.target(e, f, r.volume);
                        target += t;
                        energy += en;
                    }
                    ((energy, clamped), node_gradients(&target, &r.dm_inv))
                };
                // Four tets per SVD call (latency: see the x4 doc), the
                // chunk's remainder one by one; same results either way.
                let n = g_chunk.len();
                let mut svds = [None; SVD_LANES];
                let mut j = 0;
                while j + SVD_LANES <= n {
                    let fs: [Matrix3<f64>; SVD_LANES] =
                        std::array::from_fn(|l| def_grad(base + j + l));
                    let w0: [Matrix3<f64>; SVD_LANES] = std::array::from_fn(|l| w_chunk[j + l]);
                    signed_svd_warm_x4(&fs, &w0, &mut svds);
                    for l in 0..SVD_LANES {
                        if let Some(svd) = &svds[l] {
                            w_chunk[j + l] = svd.v;
                        }
                        (e_chunk[j + l], g_chunk[j + l]) =
                            finish(base + j + l, &fs[l], svds[l].as_ref());
                    }
                    j += SVD_LANES;
                }
                for j in j..n {
                    let f = def_grad(base + j);
                    let svd = signed_svd_warm(&f, &w_chunk[j]);
                    if let Some(svd) = &svd {
                        w_chunk[j] = svd.v;
                    }
                    (e_chunk[j], g_chunk[j]) = finish(base + j, &f, svd.as_ref());
                }
            });
        let per_tet = &self.per_tet;
        let (ptr, inc) = (&self.node_ptr, &self.incidence);
        out.par_iter_mut()
            .enumerate()
            .with_min_len(1024)
            .for_each(|(a, o)| {
                let mut s = [0.0; 3];
                for &code in &inc[ptr[a]..ptr[a + 1]] {
                    let g = &per_tet[(code >> 2) as usize][(code & 3) as usize];
                    for k in 0..3 {
                        s[k] += g[k];
                    }
                }
                *o = s;
            });
        let mut eval = LocalEval::default();
        for &(en, clamped) in &self.per_tet_energy {
            eval.elastic_energy += en;
            eval.clamped_tets += clamped as usize;
        }
        if !eval.elastic_energy.is_finite() {
            let node = (0..n)
                .find(|&a| !out[a].iter().all(|c| c.is_finite()))
                .unwrap_or(0);
            return Err(SimError::Diverged {
                step: 0,
                node,
                reason: "elastic energy not finite in the local step".into(),
            });
        }
        Ok(eval)
    }

    fn name(&self) -> &'static str {
        "cpu"
    }

    fn warm_start(&self) -> Vec<f64> {
        self.warm_v.iter().flat_map(|m| m.iter().copied()).collect()
    }

    fn set_warm_start(&mut self, state: &[f64]) -> Result<(), SimError> {
        if state.len() != 9 * self.warm_v.len() || state.iter().any(|v| !v.is_finite()) {
            return Err(SimError::Inconsistent(format!(
                "SVD warm start of {} values for {} tets (9 finite values per tet)",
                state.len(),
                self.warm_v.len()
            )));
        }
        for (m, c) in self.warm_v.iter_mut().zip(state.chunks_exact(9)) {
            *m = Matrix3::from_column_slice(c);
        }
        Ok(())
    }

    fn update_materials(&mut self, model: &ElasticModel) -> Result<bool, SimError> {
        if model.rest().len() != self.model.rest().len()
            || model.num_nodes() != self.model.num_nodes()
        {
            return Ok(false);
        }
        *self = CpuElasticRhs::new(model);
        Ok(true)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::TetMesh;
    use crate::sim::local::local_step;

    #[test]
    fn matches_local_step_and_energy() {
        // Two tets sharing a face, deformed.
        let mesh = TetMesh {
            nodes: vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.0, 0.0, 1.0],
                [1.0, 1.0, 1.0],
            ],
            tets: vec![[0, 1, 2, 3], [1, 2, 3, 4]],
        };
        // Orientation: make both positive.
        let mut mesh = mesh;
        if mesh.volume(1) < 0.0 {
            mesh.tets[1] = [2, 1, 3, 4];
        }
        let model = ElasticModel::new(&mesh, &[2.0, 3.0], &[5.0, 7.0]).unwrap();
        let x: Vec<Vec3> = mesh
            .nodes
            .iter()
            .map(|p| [1.2 * p[0] + 0.1 * p[1], 0.9 * p[1], p[2] + 0.3 * p[0]])
            .collect();
        let mut rhs = CpuElasticRhs::new(&model);
        let mut out = vec![[0.0; 3]; 5];
        let eval = rhs.evaluate(&x, &mut out).unwrap();
        assert!((eval.elastic_energy - model.energy(&x).unwrap()).abs() < 1e-12);
        let (targets, _) = local_step(&model, &x).unwrap();
        let mut expect = vec![[0.0; 3]; 5];
        for (e, (r, t)) in model.rest().iter().zip(&targets).enumerate() {
            let target =
                2.0 * r.volume * (model.gamma_s()[e] * t.rotation + model.gamma_v()[e] * t.volume);
            for (&a, g) in r.nodes.iter().zip(&node_gradients(&target, &r.dm_inv)) {
                for k in 0..3 {
                    expect[a][k] += g[k];
                }
            }
        }
        for (o, e) in out.iter().zip(&expect) {
            for k in 0..3 {
                assert!((o[k] - e[k]).abs() < 1e-12, "{o:?} vs {e:?}");
            }
        }
        assert!(rhs.evaluate(&x[..4], &mut out).is_err());

        // A second evaluation starts its SVDs from the first one's V (warm
        // start): it must still match the cold local step at the new
        // positions, here strongly deformed and with an inverted tet.
        let x2: Vec<Vec3> = mesh
            .nodes
            .iter()
            .map(|p| {
                [
                    0.7 * p[0] - 0.4 * p[2],
                    1.3 * p[1] + 0.2 * p[0],
                    -0.8 * p[2],
                ]
            })
            .collect();
        let mut out2 = vec![[0.0; 3]; 5];
        let eval2 = rhs.evaluate(&x2, &mut out2).unwrap();
        assert!((eval2.elastic_energy - model.energy(&x2).unwrap()).abs() < 1e-10);
        let mut cold = CpuElasticRhs::new(&model);
        let mut out_cold = vec![[0.0; 3]; 5];
        cold.evaluate(&x2, &mut out_cold).unwrap();
        for (o, e) in out2.iter().zip(&out_cold) {
            for k in 0..3 {
                assert!((o[k] - e[k]).abs() < 1e-10, "{o:?} vs {e:?}");
            }
        }
    }

    #[test]
    fn targets_from_singular_values_match_the_matrices() {
        // Stretched, compressed, near-degenerate and inverted F.
        for (i, f) in [
            Matrix3::new(1.1, 0.2, -0.1, 0.0, 0.8, 0.3, 0.1, 0.0, 1.3),
            Matrix3::new(0.3, 0.05, 0.0, -0.02, 2.5, 0.4, 0.1, 0.0, 0.9),
            Matrix3::new(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1e-4),
            Matrix3::new(-1.0, 0.1, 0.0, 0.0, 1.0, 0.2, 0.3, 0.0, 1.2),
            Matrix3::identity(),
        ]
        .iter()
        .enumerate()
        {
            let (vol, gs, gv) = (0.37, 2.0, 5.0);
            let (rot, proj, clamped) = project_both(f);
            let energy = vol * (gs * (f - rot).norm_squared() + gv * (f - proj).norm_squared());
            let target = 2.0 * vol * (gs * rot + gv * proj);
            let svd = crate::sim::projection::signed_svd(f).unwrap();
            let (e2, t2, c2) = targets_from_svd(&svd, vol, gs, gv);
            assert!(
                (e2 - energy).abs() <= 1e-12 * energy.max(1.0),
                "case {i}: {e2} vs {energy}"
            );
            assert!((t2 - target).norm() <= 1e-12 * target.norm(), "case {i}");
            assert_eq!(c2, clamped, "case {i}");
        }
    }

    #[test]
    fn fused_projection_is_bitwise_the_public_one() {
        use crate::sim::projection::project_rotation;
        for (i, f) in [
            Matrix3::new(1.1, 0.2, -0.1, 0.0, 0.8, 0.3, 0.1, 0.0, 1.3),
            Matrix3::new(-1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
            Matrix3::identity(),
            Matrix3::zeros(),
            Matrix3::new(f64::NAN, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
        ]
        .iter()
        .enumerate()
        {
            let (r, v, c) = project_both(f);
            let (v2, p) = project_volume_detailed(f);
            assert_eq!(r, project_rotation(f), "case {i}");
            assert_eq!(v, v2, "case {i}");
            assert_eq!(c, p.clamped, "case {i}");
        }
    }
}
