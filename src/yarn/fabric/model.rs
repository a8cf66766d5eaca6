//! A yarn-level swatch as the quasi-static solver sees it: discrete elastic
//! rods (stretch, bend, twist; `yarn::rods`), Kaldor contact
//! (`yarn::statics::ContactTerm`) and lumped masses, over one coordinate
//! vector `q` (positions, then one twist per edge).

use crate::geom::{MaterialOverrides, RestShape, Vec3, YarnMaterial, Yarns};
use crate::yarn::rods::{HingeHessian, RodEnergy, RodError, RodParams, RodRest, RodTopology};
use crate::yarn::sim::{YarnSimError, YarnSimParams};
use crate::yarn::statics::{
    evaluate, solve_static, Carry, ContactStats, ContactTerm, EnergyTerm, FrictionParams,
    FrictionTerm, StaticError, StaticStats, SymbolicCache, YarnStaticParams,
};

/// Smallest distance ratio (to 2r) a predicted start (the stretch test's
/// secant step, the relaxation's contraction) may bring a contact to
/// before it is dropped.
pub(crate) const PREDICTION_MIN_DISTANCE_RATIO: f64 = 0.8;

/// Material and solver parameters of a fabric (defaults: HYLC 2020 Table 1,
/// stockinette/rib, r = 1 mm, except the bending scale).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct FabricParams {
    /// Rod material: E 5e5 Pa, G 2e5 Pa (HYLC Table 1) and bend/twist scale
    /// 0.3, not HYLC's 1e-3: [`YarnSimParams::bend_scale`], whose
    /// documentation says why.
    pub rods: RodParams,
    /// Kaldor contact stiffness k_contact (J/m^2). Default 60.
    pub contact_stiffness: f64,
    /// Yarn density (kg/m^3) when the yarns carry no linear density.
    /// Default 120.
    pub density: f64,
    /// Yarn-yarn Coulomb friction (lagged IPC potential,
    /// `yarn::statics::friction`): mu 0.25 (dimensionless), stick distance
    /// 1e-5 m, one lag refresh per load step. On in the stretch and hang
    /// tests; the relaxation into contact runs frictionless (its rest state
    /// must be an energy minimum of rods + contact alone, so a reloaded
    /// swatch is at equilibrium without a friction history).
    pub friction: FrictionParams,
    /// Newton controls (force tolerance 1e-5 N, 1e-5 of a fabric test's
    /// ~1 N; per-vertex step clipping); the displacement cap defaults to
    /// [`MAX_MOVE_RADII`] smallest yarn radii (set by [`Fabric::new`] when
    /// infinite), lowered near contacts.
    pub solver: YarnStaticParams,
    /// How Newton's matrix takes the hinges' bend/twist Hessians. Default
    /// Gauss-Newton (PSD from first derivatives; the gradient and so every
    /// equilibrium are exact either way).
    pub hinge_hessian: HingeHessian,
}

impl Default for FabricParams {
    fn default() -> Self {
        let y = YarnSimParams::default();
        FabricParams {
            rods: RodParams {
                bend_scale: y.bend_scale,
                ..RodParams::default()
            },
            contact_stiffness: y.contact_stiffness,
            density: y.density,
            friction: FrictionParams::default(),
            solver: YarnStaticParams {
                force_tolerance: 1e-5,
                max_iterations: 400,
                clip_per_vertex: true,
                ..YarnStaticParams::default()
            },
            hinge_hessian: HingeHessian::default(),
        }
    }
}

impl FabricParams {
    /// The rod and contact material of these parameters.
    pub fn material(&self) -> YarnMaterial {
        YarnMaterial {
            young_modulus: self.rods.young_modulus,
            shear_modulus: self.rods.shear_modulus,
            bend_scale: self.rods.bend_scale,
            contact_stiffness: self.contact_stiffness,
        }
    }

    /// These parameters with the rods' and the contact's material set to `m`.
    pub fn with_material(&self, m: &YarnMaterial) -> FabricParams {
        let mut p = self.clone();
        p.rods.young_modulus = m.young_modulus;
        p.rods.shear_modulus = m.shear_modulus;
        p.rods.bend_scale = m.bend_scale;
        p.contact_stiffness = m.contact_stiffness;
        p
    }

    /// These parameters with the material `yarns` were relaxed under (when
    /// their rest shape records one, else this one's), then `overrides`
    /// applied; with the record of where each came from.
    pub fn for_yarns(
        &self,
        yarns: &Yarns,
        overrides: &MaterialOverrides,
    ) -> (FabricParams, MaterialChoice) {
        let recorded = yarns.rest.as_ref().and_then(|r| r.material);
        let material = overrides.apply(&recorded.unwrap_or_else(|| self.material()));
        let choice = MaterialChoice {
            material,
            source: if recorded.is_some() {
                "yarn file"
            } else {
                "defaults"
            },
            overridden: overrides.names(),
            rest_material: recorded.filter(|r| *r != material),
        };
        (self.with_material(&material), choice)
    }
}

/// The material a run used and where it came from (reports print it).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct MaterialChoice {
    pub material: YarnMaterial,
    /// `"yarn file"` (the rest shape's recorded material) or `"defaults"`.
    pub source: &'static str,
    /// Fields given on the command line (or in a job) instead.
    pub overridden: Vec<&'static str>,
    /// The material the yarns' rest shape was relaxed under, when it
    /// differs from `material`: the stored state is then not at rest and
    /// settles first.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rest_material: Option<YarnMaterial>,
}

impl MaterialChoice {
    /// A warning when the run's material is not the rest shape's.
    pub fn warning(&self, what: &str) -> Option<String> {
        let r = self.rest_material?;
        Some(format!(
            "{what}: its rest shape was relaxed under {r} and runs under {}: the stored state is \
             not at rest under this material and settles first",
            self.material
        ))
    }
}

/// Why a fabric computation failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FabricError {
    #[error("rods: {0}")]
    Rods(#[from] RodError),
    #[error("contact: {0}")]
    Contact(#[from] YarnSimError),
    #[error("{stage}: {source}")]
    Solve {
        stage: String,
        #[source]
        source: StaticError,
    },
    #[error("{0}")]
    Setup(String),
    #[error("{0}")]
    NoEquilibrium(String),
}

/// Default largest move of a vertex in one Newton iteration, in smallest
/// yarn radii: also the contact skin, so pairs farther than the radii plus
/// two of it cannot meet within an iteration. Nearer pairs bound their own
/// vertices' moves (`ContactTerm::limit_vertex_moves`). One radius, not
/// two: every iteration tests the candidate pairs within the radii plus two
/// skins (728K at two radii on the 26x26 rib stretched 30%, for ~23K in
/// contact); the shorter steps save relaxation iterations and cost the
/// stretch test a few (docs/performance.md).
pub const MAX_MOVE_RADII: f64 = 1.0;

/// Rods + contact + friction + masses of one yarn set, and its current
/// coordinates.
pub struct Fabric {
    pub rods: RodEnergy,
    pub contact: ContactTerm,
    /// Lagged friction, lagged at construction and by [`Fabric::begin_step`].
    pub friction: FrictionTerm,
    /// Coordinates at the start of the current load step (the friction's
    /// start positions).
    step_start: Vec<f64>,
    /// Elastic friction offsets carried into this step (`FrictionTerm::carry`).
    carry: Carry,
    /// Lumped mass per vertex (kg).
    pub mass: Vec<f64>,
    /// Current coordinates: 3 per vertex (m), then one twist per edge (rad).
    pub q: Vec<f64>,
    /// Smallest yarn radius (m).
    pub r_min: f64,
    pub params: FabricParams,
    cache: SymbolicCache,
}

/// Force residual of an equilibrium under gravity, as a fraction of the
/// heaviest vertex's weight ([`Fabric::resolve_weights`]).
pub const LOAD_TOLERANCE: f64 = 1e-2;

impl Fabric {
    /// `settle` tightened so that an equilibrium under gravity `g` (m/s²)
    /// resolves [`LOAD_TOLERANCE`] of the heaviest vertex's weight (also the
    /// Newton force tolerance): a vertex weighs ~1e-6 N, below the default
    /// tolerance, so a loaded swatch would otherwise count as settled at
    /// rest. Unchanged when `g` is 0.
    pub fn resolve_weights(&mut self, settle: &Settle, g: f64) -> Settle {
        let weight_max = self.mass.iter().fold(0.0, |m: f64, &w| m.max(w)) * g.abs();
        if !(weight_max > 0.0) {
            return *settle;
        }
        let s = Settle {
            tolerance: settle.tolerance.min(LOAD_TOLERANCE * weight_max),
            ..*settle
        };
        self.params.solver.force_tolerance = self.params.solver.force_tolerance.min(s.tolerance);
        s
    }

    /// The fabric of `yarns` at their positions, with their stored rest
    /// shape when they carry one, else the positions as rest.
    pub fn new(yarns: &Yarns, params: &FabricParams) -> Result<Fabric, FabricError> {
        let topo = RodTopology::new(yarns)?;
        let rest = match &yarns.rest {
            Some(shape) => {
                let rest = RodRest::from_shape(&topo, shape)?;
                rest.check_state(&topo, &yarns.points)?;
                rest
            }
            None => RodRest::from_positions(&topo, &yarns.points)?,
        };
        let q = topo.q_from_points(&yarns.points);
        let topo_vertices = topo.n_vertices;
        let mut rods = RodEnergy::new(topo, rest, &params.rods, &q)?;
        rods.set_hinge_hessian(params.hinge_hessian);
        let r_min = (0..yarns.num_points())
            .map(|v| yarns.radius_at(v))
            .fold(f64::INFINITY, f64::min);
        let ysp = YarnSimParams {
            contact_stiffness: params.contact_stiffness,
            density: params.density,
            ..YarnSimParams::default()
        };
        let mut p = params.clone();
        if !p.solver.max_displacement.is_finite() {
            p.solver.max_displacement = MAX_MOVE_RADII * r_min;
        }
        p.solver.position_points = Some(topo_vertices);
        let mut contact = ContactTerm::new(yarns, &ysp, p.solver.max_displacement)?;
        contact.set_rest_lengths(&rods.topology().edges, &rods.rest().l0)?;
        let mass = lumped_masses(yarns, params.density);
        if !params.friction.is_valid() {
            return Err(FabricError::Setup(format!(
                "friction parameters out of range (mu >= 0, stick distance > 0, lag updates <= 100): {:?}",
                params.friction
            )));
        }
        let mut fabric = Fabric {
            rods,
            contact,
            friction: FrictionTerm::new(&params.friction),
            step_start: q.clone(),
            carry: Carry::new(),
            mass,
            q,
            r_min,
            params: p,
            cache: SymbolicCache::default(),
        };
        fabric.begin_step();
        Ok(fabric)
    }

    /// Starts a load step at the current state: friction is lagged here
    /// (normal forces, tangent bases, start positions), each contact keeping
    /// the elastic offset it held at the end of the last step. Call it
    /// before moving clamps or predicting.
    pub fn begin_step(&mut self) {
        self.carry = self.friction.carry(&self.q);
        self.step_start = self.q.clone();
        self.refresh_friction();
    }

    /// Re-lags the friction's normal forces, tangent bases and contact set
    /// at the current state, keeping the step's start positions.
    pub fn refresh_friction(&mut self) {
        if !self.params.friction.is_on() {
            self.friction.set_contacts(Vec::new());
            return;
        }
        let q = self.q.clone();
        self.contact.begin_iteration(&q);
        self.friction
            .lag_carrying(&self.contact, &q, &self.step_start, &self.carry);
    }

    /// Replaces the rest state of the rods and, with its lengths, the
    /// arclength the contact integrates over.
    pub fn set_rest(&mut self, rest: RodRest) -> Result<(), FabricError> {
        self.contact
            .set_rest_lengths(&self.rods.topology().edges, &rest.l0)?;
        self.rods.set_rest(rest)?;
        Ok(())
    }

    pub fn num_vertices(&self) -> usize {
        self.rods.topology().n_vertices
    }

    pub fn point(&self, v: usize) -> Vec3 {
        [self.q[3 * v], self.q[3 * v + 1], self.q[3 * v + 2]]
    }

    pub fn points(&self) -> Vec<Vec3> {
        (0..self.num_vertices()).map(|v| self.point(v)).collect()
    }

    /// The rest shape the rods use now (to store with the curves).
    pub fn rest_shape(&self) -> RestShape {
        self.rods.rest().to_shape(self.rods.topology())
    }

    /// A fixed-coordinate mask with nothing clamped except one twist per
    /// curve (a free rod's constant twist is a null space, HYLC §5).
    pub fn twist_gauge(&self) -> Vec<bool> {
        let topo = self.rods.topology();
        let mut fixed = vec![false; self.q.len()];
        for c in &topo.curve_edges {
            if !c.is_empty() {
                fixed[topo.twist_dof(c.start)] = true;
            }
        }
        fixed
    }

    /// A fixed mask holding `clamped` vertices ([`Self::clamp`]) plus one
    /// twist per curve that no clamp holds (a free rod's constant twist is
    /// a null space, HYLC §5).
    pub fn clamped_and_gauged(&self, clamped: &[bool]) -> Vec<bool> {
        let mut fixed = vec![false; self.q.len()];
        self.clamp(&mut fixed, clamped);
        let topo = self.rods.topology();
        for c in &topo.curve_edges {
            if !c.is_empty() && !c.clone().any(|e| fixed[topo.twist_dof(e)]) {
                fixed[topo.twist_dof(c.start)] = true;
            }
        }
        fixed
    }

    /// Fixes the positions of `vertices` and the twists of the edges with
    /// both ends among them.
    pub fn clamp(&self, fixed: &mut [bool], vertices: &[bool]) {
        let topo = self.rods.topology();
        for (v, &c) in vertices.iter().enumerate() {
            if c {
                fixed[3 * v..3 * v + 3].iter_mut().for_each(|f| *f = true);
            }
        }
        for (e, [a, b]) in topo.edges.iter().enumerate() {
            if vertices[*a] && vertices[*b] {
                fixed[topo.twist_dof(e)] = true;
            }
        }
    }

    /// Newton equilibrium of rods + contact + `extra` terms with `fixed`
    /// coordinates held.
    pub fn solve(
        &mut self,
        extra: &mut [&mut dyn EnergyTerm],
        fixed: &[bool],
        stage: &str,
    ) -> Result<StaticStats, FabricError> {
        let mut terms: Vec<&mut dyn EnergyTerm> =
            vec![&mut self.rods, &mut self.contact, &mut self.friction];
        for t in extra.iter_mut() {
            terms.push(&mut **t);
        }
        solve_static(
            &mut terms,
            &mut self.q,
            fixed,
            &self.params.solver,
            &mut self.cache,
        )
        .map_err(|source| FabricError::Solve {
            stage: stage.to_string(),
            source,
        })
    }

    /// `dE/dq` of rods + contact + friction + `extra` at the current state
    /// (the energy includes the friction potential).
    pub fn gradient(&mut self, extra: &mut [&mut dyn EnergyTerm]) -> (f64, Vec<f64>) {
        let q = self.q.clone();
        self.contact.begin_iteration(&q);
        let mut terms: Vec<&mut dyn EnergyTerm> =
            vec![&mut self.rods, &mut self.contact, &mut self.friction];
        for t in extra.iter_mut() {
            terms.push(&mut **t);
        }
        let mut g = vec![0.0; q.len()];
        let e = evaluate(&terms, &q, &mut g, None);
        (e, g)
    }

    /// Largest `|dE/dq|` over the coordinates not `fixed` (N, or N m for
    /// twists), rods + contact + friction.
    pub fn static_residual(&mut self, fixed: &[bool]) -> f64 {
        self.residual_with(&mut [], fixed)
    }

    /// Largest free `|dE/dq|` of rods + contact + `extra`.
    fn residual_with(&mut self, extra: &mut [&mut dyn EnergyTerm], fixed: &[bool]) -> f64 {
        let (_, g) = self.gradient(extra);
        g.iter()
            .zip(fixed)
            .filter(|(_, f)| !**f)
            .map(|(g, _)| g.abs())
            .fold(0.0, f64::max)
    }

    /// One implicit-Euler step of size `dt` (Gast et al. 2015: the inertia
    /// term plus rods + contact + `extra`), from positions `prev` one step
    /// ago to the current ones; returns the positions before the step (the
    /// next call's `prev`).
    pub fn implicit_euler_step(
        &mut self,
        prev: &[f64],
        dt: f64,
        extra: &mut [&mut dyn EnergyTerm],
        fixed: &[bool],
        stage: &str,
    ) -> Result<Vec<f64>, FabricError> {
        self.begin_step();
        let cur = self.q[..3 * self.num_vertices()].to_vec();
        let target: Vec<f64> = cur.iter().zip(prev).map(|(c, p)| 2.0 * c - p).collect();
        let mut inertia = super::InertiaTerm::new(self.mass.clone(), target, dt);
        let mut terms: Vec<&mut dyn EnergyTerm> = vec![&mut inertia];
        for t in extra.iter_mut() {
            terms.push(&mut **t);
        }
        self.solve(&mut terms, fixed, stage)?;
        Ok(cur)
    }

    /// Elastic energy (rods + contact, J; friction is dissipation, not
    /// stored energy).
    pub fn elastic_energy(&mut self) -> f64 {
        let q = self.q.clone();
        self.contact.begin_iteration(&q);
        let terms: Vec<&mut dyn EnergyTerm> = vec![&mut self.rods, &mut self.contact];
        let mut g = vec![0.0; q.len()];
        evaluate(&terms, &q, &mut g, None)
    }

    /// Proximal Newton rounds (implicit-Euler steps of `dt` from rest,
    /// `extra` terms added) until the static residual of rods + contact +
    /// friction + `extra` is at most `tol` or `max_rounds` are spent. The
    /// inertia term only regularizes null and buckling modes; it vanishes
    /// at the end. With friction on, the lag is then refreshed at the
    /// equilibrium (start positions kept) and the settle repeated,
    /// `friction.lag_updates` times.
    pub fn settle(
        &mut self,
        extra: &mut [&mut dyn EnergyTerm],
        fixed: &[bool],
        settle: &Settle,
        stage: &str,
    ) -> Result<SettleStats, FabricError> {
        let mut out = self.settle_once(extra, fixed, settle, stage)?;
        if self.params.friction.is_on() {
            for _ in 0..self.params.friction.lag_updates {
                self.refresh_friction();
                let st = self.settle_once(extra, fixed, settle, stage)?;
                out = SettleStats {
                    rounds: out.rounds + st.rounds,
                    newton_iterations: out.newton_iterations + st.newton_iterations,
                    residual: st.residual,
                    converged: st.converged,
                    min_distance_ratio: out.min_distance_ratio.min(st.min_distance_ratio),
                };
            }
        }
        Ok(out)
    }

    fn settle_once(
        &mut self,
        extra: &mut [&mut dyn EnergyTerm],
        fixed: &[bool],
        settle: &Settle,
        stage: &str,
    ) -> Result<SettleStats, FabricError> {
        let n = self.num_vertices();
        let mut out = SettleStats {
            residual: f64::INFINITY,
            ..SettleStats::default()
        };
        if settle.direct_first {
            out.rounds += 1;
            // On failure `q` keeps the last accepted iterate: the rounds
            // go on from there.
            out.newton_iterations += self.solve_partly(extra, fixed, stage)?;
            out.min_distance_ratio = self.contact_stats().min_distance_ratio;
            out.residual = self.residual_with(extra, fixed);
            if out.residual <= settle.tolerance {
                out.converged = true;
                return Ok(out);
            }
        }
        for _ in 0..settle.max_rounds {
            let target = self.q[..3 * n].to_vec();
            let mut inertia = super::InertiaTerm::new(self.mass.clone(), target, settle.dt);
            let mut terms: Vec<&mut dyn EnergyTerm> = vec![&mut inertia];
            for t in extra.iter_mut() {
                terms.push(&mut **t);
            }
            // A round that stalls (no convergence, or no descent left at
            // rounding level) still moved toward equilibrium: the next round
            // restarts from there; only non-finite values end the settle.
            out.rounds += 1;
            out.newton_iterations += self.solve_partly(&mut terms, fixed, stage)?;
            out.min_distance_ratio = out
                .min_distance_ratio
                .min(self.contact_stats().min_distance_ratio);
            out.residual = self.residual_with(extra, fixed);
            if out.residual <= settle.tolerance {
                out.converged = true;
                break;
            }
        }
        Ok(out)
    }

    /// A Newton solve that may stop short: the iterations it made (`q`
    /// keeps the last accepted iterate when it did not converge or the line
    /// search stalled at rounding level); only other failures are errors.
    fn solve_partly(
        &mut self,
        extra: &mut [&mut dyn EnergyTerm],
        fixed: &[bool],
        stage: &str,
    ) -> Result<usize, FabricError> {
        match self.solve(extra, fixed, stage) {
            Ok(st) => Ok(st.iterations),
            Err(FabricError::Solve {
                source: StaticError::NotConverged { iterations, .. },
                ..
            }) => Ok(iterations),
            Err(FabricError::Solve {
                source: StaticError::LineSearch { iteration, .. },
                ..
            }) => Ok(iteration),
            Err(e) => Err(e),
        }
    }

    /// Moves `q` by `predict` (a predicted start for the next solve) and
    /// keeps the move only while every contact stays at or above
    /// `min_distance_ratio` x 2r; returns whether it was kept.
    pub(crate) fn try_prediction(
        &mut self,
        min_distance_ratio: f64,
        predict: impl FnOnce(&mut [f64]),
    ) -> bool {
        let start = self.q.clone();
        predict(&mut self.q);
        let kept = self.contact_stats().min_distance_ratio >= min_distance_ratio;
        if !kept {
            self.q = start;
        }
        kept
    }

    pub fn contact_stats(&mut self) -> ContactStats {
        let q = self.q.clone();
        self.contact.begin_iteration(&q);
        self.contact.stats(&q)
    }
}

/// Controls of [`Fabric::settle`].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Settle {
    /// Proximal step (s). Default 0.05.
    pub dt: f64,
    /// Most rounds. Default 30.
    pub max_rounds: usize,
    /// Static force residual that ends it (N). Default 1e-5.
    pub tolerance: f64,
    /// Try a plain Newton solve (no inertia) first and fall back to the
    /// proximal rounds from where it stopped. Default true: a clamped
    /// swatch has no free rigid modes and converges in a few iterations
    /// (a 5% stretch step of a 4.7K-vertex rib: 13 iterations, where the
    /// proximal rounds need ~10x more); a free one (relaxation) sets false.
    pub direct_first: bool,
}

impl Settle {
    /// Fails unless `st` reached 10x the tolerance (a stalled equilibrium
    /// is reported, never passed on as one).
    pub fn require(&self, st: &SettleStats, stage: &str) -> Result<(), FabricError> {
        if st.residual <= 10.0 * self.tolerance {
            Ok(())
        } else {
            Err(FabricError::NoEquilibrium(format!(
                "{stage}: no equilibrium after {} rounds ({} Newton iterations): largest force {:.3e} N (tolerance {:.1e} N)",
                st.rounds, st.newton_iterations, st.residual, self.tolerance
            )))
        }
    }
}

impl Default for Settle {
    fn default() -> Self {
        Settle {
            dt: 0.05,
            max_rounds: 30,
            tolerance: 1e-5,
            direct_first: true,
        }
    }
}

/// What [`Fabric::settle`] did.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct SettleStats {
    pub rounds: usize,
    pub newton_iterations: usize,
    /// Largest free static force at the end (N).
    pub residual: f64,
    pub converged: bool,
    /// Smallest contact distance ratio after any round.
    pub min_distance_ratio: f64,
}

impl Default for SettleStats {
    fn default() -> Self {
        SettleStats {
            rounds: 0,
            newton_iterations: 0,
            residual: f64::INFINITY,
            converged: false,
            min_distance_ratio: f64::INFINITY,
        }
    }
}

/// Lumped vertex masses: half of each segment's mass to each end (kg).
pub fn lumped_masses(yarns: &Yarns, density: f64) -> Vec<f64> {
    let mut m = vec![0.0; yarns.num_points()];
    for c in 0..yarns.num_curves() {
        let mu = match &yarns.linear_density {
            Some(ld) => ld[c],
            None => {
                let r = yarns.radius_at(yarns.curve_range(c).start);
                density * std::f64::consts::PI * r * r
            }
        };
        for [a, b] in yarns.segments_of(c) {
            let l = crate::geom::dist(yarns.points[a], yarns.points[b]);
            m[a] += 0.5 * mu * l;
            m[b] += 0.5 * mu * l;
        }
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn material_comes_from_the_rest_shape_then_the_overrides() {
        let mut y = Yarns::new();
        y.push_curve(&[[0.0; 3], [1e-3, 0.0, 0.0], [2e-3, 0.0, 0.0]], false, 1e-3);
        let base = FabricParams::default();
        let soft = MaterialOverrides {
            young_modulus: Some(1e5),
            ..Default::default()
        };
        // No rest shape: the base parameters' material, then the override.
        let (p, c) = base.for_yarns(&y, &soft);
        assert_eq!(
            (c.source, c.overridden.clone()),
            ("defaults", vec!["young_modulus"])
        );
        assert_eq!(p.rods.young_modulus, 1e5);
        assert_eq!(p.rods.bend_scale, base.rods.bend_scale);
        assert!(c.rest_material.is_none() && c.warning("y").is_none());
        // A recorded material wins over the base; an override over both.
        let recorded = YarnMaterial::from_values([5e6, 2e6, 0.1, 30.0]);
        y.rest = Some(RestShape {
            material: Some(recorded),
            ..Default::default()
        });
        let (p, c) = base.for_yarns(&y, &MaterialOverrides::default());
        assert_eq!((p.material(), c.source), (recorded, "yarn file"));
        assert!(c.warning("y").is_none());
        let (p, c) = base.for_yarns(&y, &soft);
        assert_eq!(p.rods.young_modulus, 1e5);
        assert_eq!(p.contact_stiffness, 30.0);
        assert_eq!(c.rest_material, Some(recorded));
        assert!(c.warning("y").unwrap().contains("E 5e6 Pa"));
        // Friction and solver controls stay the base's.
        assert_eq!(p.friction, base.friction);
    }
}
