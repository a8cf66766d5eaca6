//! Discrete elastic rods with material frames and twist (Bergou et al. 2008
//! "Discrete Elastic Rods", 2010 "Discrete Viscous Threads"; the yarn model
//! of HYLC 2020 §5.1, Eq. 23) as an [`EnergyTerm`] of the quasi-static solver.
//!
//! Coordinates follow `yarn::statics`: `3 * n_vertices` positions (m), then
//! one twist angle (rad) per edge ([`RodTopology::twist_dof`]).
//!
//! * [`RodTopology`]: edges and hinges of one rod per yarn curve.
//! * [`RodRest`]: rest lengths, rest reference directors (twist-free
//!   material frames), signed rest curvatures and rest twists; plain arrays.
//! * [`RodParams`]: `E`, `G` and HYLC's bend/twist scale.
//! * [`RodState`]: reference directors carried by time-parallel transport
//!   and the continuous reference twist.
//! * [`RodEnergy`]: stretch + bend + twist as one term named `"rods"`
//!   ([`RodEnergy::energies`] splits the value for statistics).
//!
//! Derivatives: stretch is hand-derived; bend/twist per hinge are written
//! once over a generic scalar and differentiated by forward-mode dual numbers
//! over the hinge's 8 intrinsic variables (two edge vectors, two twists), so
//! gradient and Hessian are exact for the evaluated function, reference-frame
//! transport included. Hessians are PSD per element (stretch: negative
//! transverse part dropped; hinge, [`HingeHessian`]: by default Gauss-Newton
//! over the hinge's five strains from first-order duals, or the exact 8x8
//! block in edge-vector coordinates with its eigenvalues clamped at 0,
//! which keeps `J^T H J` PSD).
//!
//! State: the reference frames start as the rest directors made
//! perpendicular to the tangents of the initial `q` (exactly the rest frames
//! when `q` has the rest positions; twists in `q` are then measured from
//! them), and move with `begin_iteration` / `accept` by time-parallel
//! transport. `max_step` keeps every edge in the half-space of its stored
//! tangent, where that transport is regular.
//!
//! Pure: no files, no printing, no environment.

mod dual;
mod frame;
mod rest;
mod shape;
mod topology;

#[cfg(test)]
mod tests;

pub use rest::{RodParams, RodRest};
pub use shape::{check_rest_state, REST_LENGTH_RATIO};
pub use topology::{Hinge, RodTopology};

use crate::geom::vec3::{dot, norm, scale, sub};
use crate::geom::{GeomError, Vec3};
use crate::yarn::statics::term::BlockSink;
use crate::yarn::statics::{EnergyTerm, Triplets};
use dual::{Real, D1, D2};
use frame::{
    edge_frame, hinge_energy_frames, hinge_strains, hinge_terms, perpendicular, strain_energies,
    transport, unwrap_near, EdgeFrame, HingeConst,
};
use rayon::prelude::*;

/// Why rods could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RodError {
    #[error("yarns: {0}")]
    Geom(#[from] GeomError),
    #[error("{what}: expected {expected} entries, got {got}")]
    Length {
        what: &'static str,
        expected: usize,
        got: usize,
    },
    #[error("edge {edge} has length {length}; rods need edges of positive finite length")]
    DegenerateEdge { edge: usize, length: f64 },
    #[error("{what} [{index}] = {value} is out of range")]
    BadParameter {
        what: &'static str,
        index: usize,
        value: f64,
    },
    #[error(
        "segment {edge} (vertices {} and {}) is {length:.4e} m long at the yarns' positions \
         but {rest:.4e} m at rest: the positions are not a state of the stored rest shape \
         (a point moved or a rest length changed)",
        vertices[0], vertices[1]
    )]
    RestMismatch {
        edge: usize,
        vertices: [usize; 2],
        length: f64,
        rest: f64,
    },
}

/// Elements per parallel work item; fixed so that sums are taken in the same
/// order for any thread count.
const CHUNK: usize = 256;

/// Reference frames of the current Newton iterate (Bergou 2008 §4.2.2).
#[derive(Debug, Clone, PartialEq)]
pub struct RodState {
    /// Per edge: unit tangent at the last update.
    pub t: Vec<Vec3>,
    /// Per edge: reference director (unit, perpendicular to `t`).
    pub u: Vec<Vec3>,
    /// Per hinge: reference twist (rad), continuous over updates (no 2 pi
    /// jumps).
    pub ref_twist: Vec<f64>,
}

fn edge_vec(q: &[f64], [a, b]: [usize; 2]) -> Vec3 {
    [
        q[3 * b] - q[3 * a],
        q[3 * b + 1] - q[3 * a + 1],
        q[3 * b + 2] - q[3 * a + 2],
    ]
}

/// Unit vector of `u` with its component along unit `t` removed, or any
/// perpendicular when `u` is (nearly) parallel to `t`.
fn orthonormalize(u: Vec3, t: Vec3) -> Vec3 {
    let p = sub(u, scale(t, dot(u, t)));
    let n = norm(p);
    if n > 1e-8 {
        scale(p, 1.0 / n)
    } else {
        perpendicular(t)
    }
}

impl RodState {
    /// Reference frames at `q`: the rest directors `d1` made perpendicular to
    /// the current tangents (exactly `d1` when `q` has the rest positions),
    /// reference twists on the branch of the rest twists. With zero twist
    /// angles in `q` the material frames start as these reference frames.
    pub fn new(topo: &RodTopology, rest: &RodRest, q: &[f64]) -> Result<RodState, RodError> {
        if q.len() != topo.num_dofs() {
            return Err(RodError::Length {
                what: "coordinates q",
                expected: topo.num_dofs(),
                got: q.len(),
            });
        }
        rest.check(topo)?;
        let mut t = Vec::with_capacity(topo.num_edges());
        let mut u = Vec::with_capacity(topo.num_edges());
        for (e, &ed) in topo.edges.iter().enumerate() {
            let d = edge_vec(q, ed);
            let l = norm(d);
            if !(l > 0.0 && l.is_finite()) {
                return Err(RodError::DegenerateEdge { edge: e, length: l });
            }
            let te = scale(d, 1.0 / l);
            t.push(te);
            u.push(orthonormalize(rest.d1[e], te));
        }
        let mut state = RodState {
            t,
            u,
            ref_twist: rest.m_bar.clone(),
        };
        state.ref_twist = state.reference_twists(topo, q);
        Ok(state)
    }

    /// Reference twists of the stored frames at `q` (which must be the
    /// configuration the frames belong to), on the branch nearest the stored
    /// values.
    fn reference_twists(&self, topo: &RodTopology, q: &[f64]) -> Vec<f64> {
        topo.hinges
            .iter()
            .zip(&self.ref_twist)
            .map(|(h, &prev)| {
                let [ea, eb] = h.edges;
                let e = [edge_vec(q, topo.edges[ea]), edge_vec(q, topo.edges[eb])];
                let f = |j: usize, ed: usize| {
                    EdgeFrame::new(e[j], norm(e[j]), self.t[ed], self.u[ed], 0.0)
                };
                unwrap_near(hinge_terms(&f(0, ea), &f(1, eb)).1, prev)
            })
            .collect()
    }

    /// Moves the frames to `q` by time-parallel transport of each reference
    /// director from its stored tangent to the new one (Bergou 2008 §4.2.2)
    /// and tracks the reference twist continuously. Edges of zero length keep
    /// their frames.
    pub fn update(&mut self, topo: &RodTopology, q: &[f64]) {
        for (e, &ed) in topo.edges.iter().enumerate() {
            let d = edge_vec(q, ed);
            let l = norm(d);
            if !(l > 0.0 && l.is_finite()) {
                continue;
            }
            let tn = scale(d, 1.0 / l);
            let u = if dot(self.t[e], tn) > -0.9 {
                transport(self.t[e], tn, self.u[e])
            } else {
                // Near-reversal: transport is ill-conditioned; keep the
                // director's component perpendicular to the new tangent.
                self.u[e]
            };
            // Re-orthonormalize against rounding drift over many updates.
            self.u[e] = orthonormalize(u, tn);
            self.t[e] = tn;
        }
        self.ref_twist = self.reference_twists(topo, q);
    }
}

/// The three parts of the rod energy (J).
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct RodEnergies {
    pub stretch: f64,
    pub bend: f64,
    pub twist: f64,
}

impl RodEnergies {
    pub fn total(&self) -> f64 {
        self.stretch + self.bend + self.twist
    }
}

/// Stretch, bending and twisting of discrete elastic rods: one
/// [`EnergyTerm`] named `"rods"`.
///
/// * stretch per edge `1/2 k_s l0 (|e| / l0 - 1)^2`, `k_s = E pi r^2`;
/// * bend per hinge `1/(2 lbar) sum_{j = i-1, i} 1/2 B |kappa^(j) -
///   kappa_bar^(j)|^2`, `B = gamma E pi r^4 / 4` (Bergou 2010);
/// * twist per hinge `beta (m - m_bar)^2 / (2 lbar)`, `beta = gamma G pi r^4
///   / 2`, `m = theta_i - theta_{i-1} + reference twist` (Bergou 2008).
///
/// `lbar` is the mean rest length of the hinge's edges; the hinge radius the
/// mean of its edges' radii.
///
/// Within one state (between [`EnergyTerm::begin_iteration`] /
/// [`EnergyTerm::accept`] calls) the energy is a smooth function of `q`: the
/// reference directors are the time-parallel transports of the stored ones to
/// the tangents at `q`, and that function is what gradient and Hessian
/// differentiate.
#[derive(Debug, Clone)]
pub struct RodEnergy {
    topo: RodTopology,
    rest: RodRest,
    /// Per edge: stretch stiffness (N).
    ks: Vec<f64>,
    /// Per hinge: `(B, beta, lbar)`.
    hinge_k: Vec<[f64; 3]>,
    state: RodState,
    params: RodParams,
    /// How the hinges' Hessians are formed (the stretch term's is projected
    /// unless [`HingeHessian::Exact`]).
    hessian: HingeHessian,
}

/// How the bend/twist Hessian of a hinge enters Newton's matrix.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum HingeHessian {
    /// `2 sum_k w_k grad d_k grad d_k^T` over the hinge's five strains (the
    /// `E = sum_k w_k d_k^2` of `frame::hinge_strains`): PSD by
    /// construction, from first derivatives only. The default: the 26x26
    /// rib's 30% stretch takes 106 Newton iterations and 45 s with it,
    /// against 144 and 77 s with the projected exact Hessian
    /// (docs/performance.md).
    #[default]
    GaussNewton,
    /// The exact Hessian with the eigenvalues of each 8x8 block clamped at 0.
    Projected,
    /// The exact Hessian, unprojected (tests of the derivatives).
    Exact,
}

/// Per-chunk results, combined in chunk order.
struct ChunkOut {
    energy: RodEnergies,
    grad: Vec<(u32, f64)>,
}

/// Runs `f` on fixed chunks of `0..n` in parallel; results in chunk order.
/// With a sink, each chunk gets its own `per` entries per element of it, in
/// element order.
fn chunks<F>(n: usize, per: usize, sink: Option<&mut BlockSink>, f: F) -> Vec<ChunkOut>
where
    F: Fn(std::ops::Range<usize>, Option<&mut BlockSink>) -> ChunkOut + Sync,
{
    let nc = n.div_ceil(CHUNK);
    let range = |c: usize| c * CHUNK..((c + 1) * CHUNK).min(n);
    match sink {
        Some(sink) => {
            let parts: Vec<BlockSink> = (0..nc)
                .map(|c| sink.split_off_front(per * range(c).len()))
                .collect();
            parts
                .into_par_iter()
                .enumerate()
                .map(|(c, mut part)| f(range(c), Some(&mut part)))
                .collect()
        }
        None => (0..nc).into_par_iter().map(|c| f(range(c), None)).collect(),
    }
}

/// Local dof -> (edge-variable, coefficient) map of a hinge (edge vectors
/// `e0 = x1 - x0`, `e1 = x2 - x1`, then the two twists).
const HINGE_J: [[(usize, f64); 2]; 11] = {
    let mut j = [[(0usize, 0.0f64); 2]; 11];
    let mut k = 0;
    while k < 3 {
        j[k] = [(k, -1.0), (k, 0.0)]; // x0
        j[3 + k] = [(k, 1.0), (3 + k, -1.0)]; // x1
        j[6 + k] = [(3 + k, 1.0), (3 + k, 0.0)]; // x2
        k += 1;
    }
    j[9] = [(6, 1.0), (6, 0.0)];
    j[10] = [(7, 1.0), (7, 0.0)];
    j
};

impl RodEnergy {
    /// Rods of `topo` with rest state `rest`, material `params`, frames
    /// initialised at `q` (see [`RodState::new`]).
    pub fn new(
        topo: RodTopology,
        rest: RodRest,
        params: &RodParams,
        q: &[f64],
    ) -> Result<RodEnergy, RodError> {
        params.check()?;
        let state = RodState::new(&topo, &rest, q)?;
        let (ks, hinge_k) = stiffnesses(&topo, &rest, params);
        Ok(RodEnergy {
            topo,
            rest,
            ks,
            hinge_k,
            state,
            params: *params,
            hessian: HingeHessian::default(),
        })
    }

    /// Selects how hinge Hessians are formed.
    pub fn set_hinge_hessian(&mut self, hessian: HingeHessian) {
        self.hessian = hessian;
    }

    /// Replaces the rest state (e.g. after rest-length scaling, Leaf 2018
    /// §6.1); the reference frames stay.
    pub fn set_rest(&mut self, rest: RodRest) -> Result<(), RodError> {
        rest.check(&self.topo)?;
        let (ks, hinge_k) = stiffnesses(&self.topo, &rest, &self.params);
        self.ks = ks;
        self.hinge_k = hinge_k;
        self.rest = rest;
        Ok(())
    }

    /// First material director of every edge at `q` (the frames must have
    /// been updated to `q`): the reference director turned by the edge's
    /// twist angle about its tangent. A rest state whose `d1` are these
    /// directors and whose curvatures and twists are kept describes the same
    /// energy at `q` with zero twist angles (how a relaxed state is stored).
    pub fn material_directors(&self, q: &[f64]) -> Vec<Vec3> {
        (0..self.topo.num_edges())
            .map(|e| {
                let (t, u) = (self.state.t[e], self.state.u[e]);
                let th = q[self.topo.twist_dof(e)];
                let v = crate::geom::vec3::cross(t, u);
                [0, 1, 2].map(|c| th.cos() * u[c] + th.sin() * v[c])
            })
            .collect()
    }

    pub fn params(&self) -> &RodParams {
        &self.params
    }

    pub fn topology(&self) -> &RodTopology {
        &self.topo
    }
    pub fn rest(&self) -> &RodRest {
        &self.rest
    }
    pub fn state(&self) -> &RodState {
        &self.state
    }

    /// The energy split into stretch, bend and twist (J).
    pub fn energies(&self, q: &[f64]) -> RodEnergies {
        let mut grad = vec![0.0; q.len()];
        self.eval_parts(q, &mut grad, None)
    }

    fn hinge_const(&self, k: usize) -> HingeConst {
        let h = &self.topo.hinges[k];
        let [ea, eb] = h.edges;
        let [bend, twist, lbar] = self.hinge_k[k];
        HingeConst {
            tp: [self.state.t[ea], self.state.t[eb]],
            up: [self.state.u[ea], self.state.u[eb]],
            kappa_bar: self.rest.kappa_bar[k],
            m_bar: self.rest.m_bar[k],
            ref_prev: self.state.ref_twist[k],
            lbar,
            bend,
            twist,
        }
    }

    fn hinge_dofs(&self, k: usize) -> [usize; 11] {
        let h = &self.topo.hinges[k];
        let [a, b, c] = h.vertices;
        [
            3 * a,
            3 * a + 1,
            3 * a + 2,
            3 * b,
            3 * b + 1,
            3 * b + 2,
            3 * c,
            3 * c + 1,
            3 * c + 2,
            self.topo.twist_dof(h.edges[0]),
            self.topo.twist_dof(h.edges[1]),
        ]
    }

    fn stretch_chunk(
        &self,
        q: &[f64],
        r: std::ops::Range<usize>,
        mut sink: Option<&mut BlockSink>,
    ) -> ChunkOut {
        let mut out = ChunkOut {
            energy: RodEnergies::default(),
            grad: Vec::with_capacity(6 * r.len()),
        };
        for e in r {
            let [a, b] = self.topo.edges[e];
            let d = edge_vec(q, [a, b]);
            let l = norm(d);
            let (k, l0) = (self.ks[e], self.rest.l0[e]);
            let strain = l / l0 - 1.0;
            out.energy.stretch += 0.5 * k * l0 * strain * strain;
            if !(l > 0.0) {
                if let Some(sink) = sink.as_deref_mut() {
                    // Keep every element's place in the sink: a zero block.
                    let dofs = [3 * a, 3 * a + 1, 3 * a + 2, 3 * b, 3 * b + 1, 3 * b + 2];
                    sink.block(&dofs, &[0.0; 36]);
                }
                continue;
            }
            let t = scale(d, 1.0 / l);
            let ge = scale(t, k * strain);
            for i in 0..3 {
                out.grad.push(((3 * a + i) as u32, -ge[i]));
                out.grad.push(((3 * b + i) as u32, ge[i]));
            }
            if let Some(sink) = sink.as_deref_mut() {
                // d2E/de2 = k/l0 t t^T + k (1/l0 - 1/l) (I - t t^T); the
                // transverse part is negative when compressed: dropped.
                let axial = k / l0;
                let mut trans = k * (1.0 / l0 - 1.0 / l);
                if self.hessian != HingeHessian::Exact {
                    trans = trans.max(0.0);
                }
                let mut he = [[0.0; 3]; 3];
                for i in 0..3 {
                    for j in 0..3 {
                        let id = if i == j { 1.0 } else { 0.0 };
                        he[i][j] = axial * t[i] * t[j] + trans * (id - t[i] * t[j]);
                    }
                }
                let dofs = [3 * a, 3 * a + 1, 3 * a + 2, 3 * b, 3 * b + 1, 3 * b + 2];
                let mut block = [0.0; 36];
                for i in 0..6 {
                    for j in 0..6 {
                        let s = if (i < 3) == (j < 3) { 1.0 } else { -1.0 };
                        block[i * 6 + j] = s * he[i % 3][j % 3];
                    }
                }
                sink.block(&dofs, &block);
            }
        }
        out
    }

    fn hinge_vars(&self, q: &[f64], k: usize) -> ([Vec3; 2], [f64; 2]) {
        let h = &self.topo.hinges[k];
        let [ea, eb] = h.edges;
        (
            [
                edge_vec(q, self.topo.edges[ea]),
                edge_vec(q, self.topo.edges[eb]),
            ],
            [q[self.topo.twist_dof(ea)], q[self.topo.twist_dof(eb)]],
        )
    }

    /// One hinge's bend and twist energies (J), gradient and, with
    /// `want_h`, Hessian (as [`HingeHessian`] says) over its 8 variables.
    fn hinge_local(
        &self,
        q: &[f64],
        k: usize,
        want_h: bool,
    ) -> (f64, f64, [f64; 8], Option<[[f64; 8]; 8]>) {
        let c = self.hinge_const(k);
        let (e, th) = self.hinge_vars(q, k);
        if want_h && self.hessian != HingeHessian::GaussNewton {
            return self.hinge_second_order(&c, e, th);
        }
        let ed: [[D1<8>; 3]; 2] =
            std::array::from_fn(|j| std::array::from_fn(|i| D1::var(e[j][i], 3 * j + i)));
        let td = [D1::var(th[0], 6), D1::var(th[1], 7)];
        let f0 = edge_frame(ed[0], td[0], c.tp[0], c.up[0]);
        let f1 = edge_frame(ed[1], td[1], c.tp[1], c.up[1]);
        let (d, _) = hinge_strains(&f0, &f1, &c);
        let (b, t) = strain_energies(&d, &c);
        let h = want_h.then(|| gauss_newton_block(&d, c.strain_weights()));
        (b.val(), t.val(), (b + t).g, h)
    }

    /// [`Self::hinge_local`] with the exact Hessian by second-order duals,
    /// projected to PSD unless [`HingeHessian::Exact`].
    fn hinge_second_order(
        &self,
        c: &HingeConst,
        e: [Vec3; 2],
        th: [f64; 2],
    ) -> (f64, f64, [f64; 8], Option<[[f64; 8]; 8]>) {
        // Each edge frame depends on 4 of the 8 variables: build it over
        // those (a quarter of the Hessian work), then embed.
        let frame = |j: usize| {
            let ev: [D2<4>; 3] = std::array::from_fn(|i| D2::var(e[j][i], i));
            let f = edge_frame(ev, D2::var(th[j], 3), c.tp[j], c.up[j]);
            let map = if j == 0 { [0, 1, 2, 6] } else { [3, 4, 5, 7] };
            f.map(|x| D2::<8>::embed(x, map))
        };
        let (b, t, _) = hinge_energy_frames(&frame(0), &frame(1), c);
        let s = b + t;
        let h = s.hessian();
        let h = match self.hessian {
            HingeHessian::Projected => project_psd(&h),
            _ => h,
        };
        (b.v, t.v, s.g, Some(h))
    }

    fn hinge_chunk(
        &self,
        q: &[f64],
        r: std::ops::Range<usize>,
        mut sink: Option<&mut BlockSink>,
    ) -> ChunkOut {
        let want_h = sink.is_some();
        let mut out = ChunkOut {
            energy: RodEnergies::default(),
            grad: Vec::with_capacity(11 * r.len()),
        };
        for k in r {
            let (b, t, g8, h8) = self.hinge_local(q, k, want_h);
            out.energy.bend += b;
            out.energy.twist += t;
            let dofs = self.hinge_dofs(k);
            for (i, &d) in dofs.iter().enumerate() {
                let g: f64 = HINGE_J[i].iter().map(|&(p, a)| a * g8[p]).sum();
                out.grad.push((d as u32, g));
            }
            if let (Some(h8), Some(sink)) = (h8, sink.as_deref_mut()) {
                let mut block = [0.0; 121];
                for i in 0..11 {
                    for j in 0..11 {
                        let mut s = 0.0;
                        for &(p, a) in &HINGE_J[i] {
                            for &(qq, b) in &HINGE_J[j] {
                                s += a * b * h8[p][qq];
                            }
                        }
                        block[i * 11 + j] = s;
                    }
                }
                sink.block(&dofs, &block);
            }
        }
        out
    }

    fn eval_parts(&self, q: &[f64], grad: &mut [f64], hess: Option<&mut Triplets>) -> RodEnergies {
        assert_eq!(
            q.len(),
            self.topo.num_dofs(),
            "rods: q has the wrong length"
        );
        assert_eq!(grad.len(), q.len(), "rods: grad has the wrong length");
        let (ne, nh) = (self.topo.num_edges(), self.topo.num_hinges());
        // Hessian blocks go straight to their fixed places in `hess`: 36
        // entries per edge, then 121 per hinge.
        let mut sink = hess.map(|t| t.reserve_sink(36 * ne + 121 * nh));
        let s = chunks(ne, 36, sink.as_mut(), |r, k| self.stretch_chunk(q, r, k));
        let h = chunks(nh, 121, sink.as_mut(), |r, k| self.hinge_chunk(q, r, k));
        debug_assert!(sink.as_ref().is_none_or(|k| k.remaining() == 0));
        let mut total = RodEnergies::default();
        for c in s.iter().chain(&h) {
            total.stretch += c.energy.stretch;
            total.bend += c.energy.bend;
            total.twist += c.energy.twist;
            for &(d, g) in &c.grad {
                grad[d as usize] += g;
            }
        }
        total
    }
}

/// Per-edge stretch stiffness and per-hinge `(B, beta, lbar)`.
fn stiffnesses(
    topo: &RodTopology,
    rest: &RodRest,
    params: &RodParams,
) -> (Vec<f64>, Vec<[f64; 3]>) {
    let ks = topo
        .edge_radius
        .iter()
        .map(|&r| params.stretch_stiffness(r))
        .collect();
    let hinge_k = topo
        .hinges
        .iter()
        .map(|h| {
            let [ea, eb] = h.edges;
            let r = 0.5 * (topo.edge_radius[ea] + topo.edge_radius[eb]);
            [
                params.bend_stiffness(r),
                params.twist_stiffness(r),
                0.5 * (rest.l0[ea] + rest.l0[eb]),
            ]
        })
        .collect();
    (ks, hinge_k)
}

/// Gauss-Newton Hessian `2 sum_k w_k grad d_k grad d_k^T` of `E = sum_k
/// w_k d_k^2` over the hinge's strains (the `d_k grad^2 d_k` terms
/// dropped): PSD by construction, exactly symmetric.
fn gauss_newton_block(d: &[D1<8>; 5], w: [f64; 5]) -> [[f64; 8]; 8] {
    let mut h = [[0.0; 8]; 8];
    for (dk, wk) in d.iter().zip(w) {
        for (i, row) in h.iter_mut().enumerate() {
            let a = 2.0 * wk * dk.g[i];
            for (hij, gj) in row.iter_mut().zip(&dk.g).skip(i) {
                *hij += a * gj;
            }
        }
    }
    let upper = h;
    for (i, row) in h.iter_mut().enumerate() {
        for (j, hij) in row.iter_mut().enumerate().take(i) {
            *hij = upper[j][i];
        }
    }
    h
}

/// Clamps the eigenvalues of a symmetric block at zero (a block already PSD
/// to within 1e-12 of its trace is returned unchanged).
fn project_psd(h: &[[f64; 8]; 8]) -> [[f64; 8]; 8] {
    let m = nalgebra::SMatrix::<f64, 8, 8>::from_fn(|i, j| 0.5 * (h[i][j] + h[j][i]));
    // Cheap test first: a block that is PSD up to 1e-12 of its trace
    // (Cholesky of the slightly shifted block succeeds) is kept as it is.
    let shift = 1e-12 * m.trace().abs() + f64::MIN_POSITIVE;
    let shifted = m + nalgebra::SMatrix::<f64, 8, 8>::identity() * shift;
    if shifted.cholesky().is_some() {
        return std::array::from_fn(|i| std::array::from_fn(|j| m[(i, j)]));
    }
    let eig = m.symmetric_eigen();
    let lam = eig.eigenvalues.map(|l| l.max(0.0));
    let p = eig.eigenvectors
        * nalgebra::SMatrix::<f64, 8, 8>::from_diagonal(&lam)
        * eig.eigenvectors.transpose();
    std::array::from_fn(|i| std::array::from_fn(|j| 0.5 * (p[(i, j)] + p[(j, i)])))
}

impl EnergyTerm for RodEnergy {
    fn name(&self) -> &'static str {
        "rods"
    }

    /// Energy (J), gradient, and with `hess` the per-element PSD-projected
    /// exact Hessian (see the module docs).
    fn eval(&self, q: &[f64], grad: &mut [f64], hess: Option<&mut Triplets>) -> f64 {
        self.eval_parts(q, grad, hess).total()
    }

    /// Keeps every edge inside the open half-space of its stored tangent
    /// (`t_stored . e(alpha) >= 0.1 t_stored . e(0)`): the time-parallel
    /// transport of the reference directors is singular when an edge turns
    /// round, and an edge cannot collapse to zero length on the way.
    fn max_step(&self, q: &[f64], dq: &[f64]) -> f64 {
        let mut alpha: f64 = 1.0;
        for (e, &ed) in self.topo.edges.iter().enumerate() {
            let tp = self.state.t[e];
            let (a, da) = (dot(tp, edge_vec(q, ed)), dot(tp, edge_vec(dq, ed)));
            if da < 0.0 && a > 0.0 {
                alpha = alpha.min(0.9 * a / -da);
            }
        }
        alpha
    }

    fn begin_iteration(&mut self, q: &[f64]) {
        self.state.update(&self.topo, q);
    }

    fn accept(&mut self, q: &[f64]) {
        self.state.update(&self.topo, q);
    }
}
