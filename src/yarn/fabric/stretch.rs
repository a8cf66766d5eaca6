//! The clamped uniaxial stretch test of Sperl 2022 §4.1: a swatch held by
//! two clamps, one fixed, the other moved along the stretch axis in steps,
//! quasi-statically (equilibrium at every step). Measured per step: the
//! stretch of the gauge section, the force on the moving clamp and the
//! orthogonal compression `c = 1 - w / w0` of the middle of the swatch.

use std::time::Instant;

use super::model::{Fabric, FabricError, FabricParams, Settle, PREDICTION_MIN_DISTANCE_RATIO};
use super::rig::{along, Direction, Rig};
use crate::geom::{Vec3, Yarns};

/// Controls of [`stretch_test`].
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct StretchParams {
    pub direction: Direction,
    /// Largest stretch of the gauge section (dimensionless). Default 0.5.
    pub max_stretch: f64,
    /// Load steps from 0 to `max_stretch`. Default 10.
    pub steps: usize,
    /// Depth of each clamp (m). Default 8 mm.
    pub clamp_depth: f64,
    /// Equilibrium controls per step.
    pub settle: Settle,
    /// Implicit-Euler steps of `settle.dt` holding the last stretch, to
    /// check that the equilibrium holds (energy does not drain away).
    /// Default 4.
    pub hold_steps: usize,
    /// Unloading steps after the hold, from `max_stretch` back to 0
    /// (friction makes the unloading force lower than the loading one: the
    /// hysteresis of Sperl 2022 §3, Miguel 2013). Default 0: none.
    pub release_steps: usize,
    /// Conditioning cycles before the measured loading: each loads to
    /// `max_stretch` and unloads to 0 in `steps` steps each way, as cyclic
    /// strip tests condition a specimen before they read it (EN 14704-1).
    /// With friction each cycle unloads along a lower path (hysteresis).
    /// The measured curve's compression stays relative to the width before
    /// any cycle. Default 0: the first loading is measured (Sperl 2022
    /// §4.3).
    pub conditioning_cycles: usize,
    /// Start each loading step's Newton solve from the last step's motion
    /// scaled to this one (a secant predictor) where it keeps contacts
    /// apart, instead of the affine stretch; unloading stays affine.
    /// Default true: a rib's 5% steps to 30% need 10-13% fewer Newton
    /// iterations (26x26 rib: 136 against 152), to the same forces and
    /// compressions to 3 digits.
    pub secant_predictor: bool,
}

impl Default for StretchParams {
    fn default() -> Self {
        StretchParams {
            direction: Direction::Weft,
            max_stretch: 0.5,
            steps: 10,
            clamp_depth: 8e-3,
            settle: Settle::default(),
            hold_steps: 4,
            release_steps: 0,
            conditioning_cycles: 0,
            secant_predictor: true,
        }
    }
}

/// One load step.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct StretchPoint {
    pub stretch: f64,
    /// Force the swatch pulls the moving clamp back with (N).
    pub force_n: f64,
    /// `1 - w / w0` at the middle of the gauge section.
    pub compression: f64,
    /// Elastic energy (J).
    pub energy_j: f64,
    pub newton_iterations: usize,
    /// Largest free static force (N).
    pub residual_n: f64,
    pub contacts_per_vertex: f64,
    pub min_distance_ratio: f64,
}

/// The whole test.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct StretchResult {
    pub direction: Direction,
    /// Swatch extent across and along the stretch axis at rest (m).
    pub width_m: f64,
    pub length_m: f64,
    /// Free length between the clamps at rest (m).
    pub gauge_m: f64,
    pub vertices: usize,
    pub points: Vec<StretchPoint>,
    /// Relative change of the elastic energy over the hold at the last
    /// stretch (negative: energy lost).
    pub hold_energy_change: f64,
    /// Unloading steps (`StretchParams::release_steps`), from the largest
    /// stretch down to 0; empty when none.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub release: Vec<StretchPoint>,
    /// Per conditioning cycle, its load and unload steps in order (empty
    /// when `conditioning_cycles` is 0); their frames are not written.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub conditioning: Vec<Vec<StretchPoint>>,
    /// Smallest contact distance ratio over every step (pull-through < 0.75).
    pub min_distance_ratio: f64,
    pub seconds: f64,
}

/// One equilibrium frame, for writers.
pub struct RigFrame<'a> {
    pub index: usize,
    /// The load parameter (stretch, or time in s).
    pub parameter: f64,
    pub points: &'a [Vec3],
    pub energy: f64,
    /// Per vertex: force the clamps exert on it (N), zero where free.
    pub reactions: Vec<Vec3>,
    /// Per vertex: external force (gravity, N).
    pub external: Vec<Vec3>,
}

impl StretchParams {
    /// Checks every value's range before any work.
    pub fn check(&self) -> Result<(), FabricError> {
        let ok = self.max_stretch.is_finite()
            && self.max_stretch > 0.0
            && self.max_stretch <= 3.0
            && (1..=1000).contains(&self.steps)
            && self.clamp_depth.is_finite()
            && self.clamp_depth > 0.0
            && self.hold_steps <= 1000
            && self.release_steps <= 1000
            && self.conditioning_cycles <= 100;
        if ok {
            Ok(())
        } else {
            Err(FabricError::Setup(format!(
                "stretch test parameters out of range (max stretch in (0, 3], steps 1-1000, clamp depth > 0, hold and release steps <= 1000, conditioning cycles <= 100): {self:?}"
            )))
        }
    }
}

/// Per-vertex 3-vectors of `g` on the vertices in `mask` (zero elsewhere).
pub(crate) fn vertex_forces(g: &[f64], mask: &[bool]) -> Vec<Vec3> {
    mask.iter()
        .enumerate()
        .map(|(v, &m)| {
            if m {
                [g[3 * v], g[3 * v + 1], g[3 * v + 2]]
            } else {
                [0.0; 3]
            }
        })
        .collect()
}

/// Runs the stretch test on `yarns` (their stored rest shape is used).
pub fn stretch_test(
    yarns: &Yarns,
    fabric_params: &FabricParams,
    params: &StretchParams,
    on_frame: &mut dyn FnMut(&RigFrame) -> Result<(), FabricError>,
) -> Result<StretchResult, FabricError> {
    params.check()?;
    let t0 = Instant::now();
    let mut fabric = Fabric::new(yarns, fabric_params)?;
    let (axis, transverse) = params.direction.axes();
    let rig = Rig::new(&yarns.points, axis, transverse, params.clamp_depth);
    if rig.gauge() <= 0.0 {
        return Err(FabricError::Setup(format!(
            "the swatch is {:.4} m long along the {} axis: too short for two {:.4} m clamps",
            rig.s_max - rig.s_min,
            params.direction.name(),
            params.clamp_depth
        )));
    }
    let clamped = rig.any_clamped();
    let mut fixed = vec![false; fabric.q.len()];
    fabric.clamp(&mut fixed, &clamped);
    let w0 = rig.mid_width(&yarns.points, 0.0);
    let mut points = Vec::with_capacity(params.steps + 1);
    let mut min_ratio = f64::INFINITY;
    let mut offset = 0.0;
    let mut last_step: Option<LoadIncrement> = None;
    // `index` None: a conditioning step, whose frame is not handed on.
    let mut step_to = |fabric: &mut Fabric,
                       index: Option<usize>,
                       stretch: f64,
                       offset: &mut f64|
     -> Result<StretchPoint, FabricError> {
        let target = stretch * rig.gauge();
        let start = fabric.q.clone();
        // The load step starts at the last equilibrium (friction lags
        // there), before the predictor moves anything.
        fabric.begin_step();
        let last = last_step.as_ref().filter(|_| params.secant_predictor);
        predict_step(fabric, &rig, last, *offset, target);
        let du = target - *offset;
        *offset = target;
        let stage = format!("stretch {stretch:.3}");
        let st = fabric.settle(&mut [], &fixed, &params.settle, &stage)?;
        params.settle.require(&st, &stage)?;
        let (_, g) = fabric.gradient(&mut []);
        let energy = fabric.elastic_energy();
        let reactions = vertex_forces(&g, &clamped);
        let force: f64 = reactions
            .iter()
            .zip(&rig.high)
            .filter(|(_, h)| **h)
            .map(|(f, _)| along(*f, axis))
            .sum();
        let x = fabric.points();
        let cst = fabric.contact_stats();
        last_step = Some(LoadIncrement {
            dq: fabric.q.iter().zip(&start).map(|(a, b)| a - b).collect(),
            du,
            end_distance_ratio: cst.min_distance_ratio,
        });
        min_ratio = min_ratio
            .min(st.min_distance_ratio)
            .min(cst.min_distance_ratio);
        if let Some(index) = index {
            on_frame(&RigFrame {
                index,
                parameter: stretch,
                points: &x,
                energy,
                reactions,
                external: vec![[0.0; 3]; x.len()],
            })?;
        }
        Ok(StretchPoint {
            stretch,
            force_n: force,
            compression: 1.0 - rig.mid_width(&x, *offset) / w0,
            energy_j: energy,
            newton_iterations: st.newton_iterations,
            residual_n: st.residual,
            contacts_per_vertex: cst.contacts_per_vertex,
            min_distance_ratio: cst.min_distance_ratio,
        })
    };
    let at = |k: usize| params.max_stretch * k as f64 / params.steps as f64;
    let mut conditioning = Vec::with_capacity(params.conditioning_cycles);
    for _ in 0..params.conditioning_cycles {
        let path = (1..=params.steps).chain((0..params.steps).rev());
        let cycle = path
            .map(|k| step_to(&mut fabric, None, at(k), &mut offset))
            .collect::<Result<Vec<_>, _>>()?;
        conditioning.push(cycle);
    }
    for step in 0..=params.steps {
        points.push(step_to(&mut fabric, Some(step), at(step), &mut offset)?);
    }
    let hold_energy_change = hold(&mut fabric, &fixed, params)?;
    let mut release = Vec::with_capacity(params.release_steps);
    for k in 1..=params.release_steps {
        let stretch = params.max_stretch * (1.0 - k as f64 / params.release_steps as f64);
        release.push(step_to(
            &mut fabric,
            Some(params.steps + k),
            stretch,
            &mut offset,
        )?);
    }
    Ok(StretchResult {
        direction: params.direction,
        width_m: w0,
        length_m: rig.s_max - rig.s_min,
        gauge_m: rig.gauge(),
        vertices: fabric.num_vertices(),
        points,
        hold_energy_change,
        release,
        conditioning,
        min_distance_ratio: min_ratio,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// The motion of the last load step: coordinates `dq` (positions, then
/// twists) for a clamp move of `du` (m), and the smallest contact distance
/// ratio of the equilibrium it ended at (where the next step starts).
struct LoadIncrement {
    dq: Vec<f64>,
    du: f64,
    end_distance_ratio: f64,
}

/// Predicts the equilibrium after moving the high clamp from `from` to `to`:
/// while loading, the last step's motion scaled to this one (a secant
/// predictor: knit does not stretch affinely, its loops turn and the
/// swatch narrows, and the last step's motion carries that) when the last
/// step loaded too and the prediction keeps every contact above
/// [`PREDICTION_MIN_DISTANCE_RATIO`]; else the affine stretch. Unloading stays
/// affine: extrapolated, a release step pushed loops back past where they
/// had come from, and a frictionless rib released from 10% settled at -2.3e-4
/// N instead of -4.4e-5 N (another of the knit's equilibria). The clamps
/// move exactly either way (the last step's motion held the low clamp and
/// moved the high one by `du`).
fn predict_step(fabric: &mut Fabric, rig: &Rig, last: Option<&LoadIncrement>, from: f64, to: f64) {
    let du = to - from;
    if let Some(inc) = last.filter(|inc| inc.du > 0.0 && du > 0.0) {
        let scale = du / inc.du;
        let min_ratio = PREDICTION_MIN_DISTANCE_RATIO.min(inc.end_distance_ratio);
        let secant = |q: &mut [f64]| {
            for (q, d) in q.iter_mut().zip(&inc.dq) {
                *q += scale * d;
            }
        };
        if fabric.try_prediction(min_ratio, secant) {
            return;
        }
    }
    predict(fabric, rig, from, to);
}

/// Moves the high clamp from `from` to `to` (m along the axis) and the free
/// vertices by the affine stretch of the gauge section (a good start for
/// Newton; while loading it never brings two yarns closer along the axis,
/// while unloading by at most the step's strain).
fn predict(fabric: &mut Fabric, rig: &Rig, from: f64, to: f64) {
    let s0 = rig.s_min + rig.clamp_depth;
    let s1 = rig.s_max - rig.clamp_depth + from;
    let du = to - from;
    for v in 0..fabric.num_vertices() {
        if rig.low[v] {
            continue;
        }
        let s = along(fabric.point(v), rig.axis);
        let frac = if rig.high[v] {
            1.0
        } else {
            ((s - s0) / (s1 - s0)).clamp(0.0, 1.0)
        };
        for c in 0..3 {
            fabric.q[3 * v + c] += frac * du * rig.axis[c];
        }
    }
}

/// Implicit-Euler steps holding the current clamps from rest; returns the
/// relative change of the elastic energy.
fn hold(fabric: &mut Fabric, fixed: &[bool], params: &StretchParams) -> Result<f64, FabricError> {
    let e0 = fabric.elastic_energy();
    let n = fabric.num_vertices();
    let dt = params.settle.dt;
    let mut prev = fabric.q[..3 * n].to_vec();
    for k in 0..params.hold_steps {
        prev = fabric.implicit_euler_step(&prev, dt, &mut [], fixed, &format!("hold step {k}"))?;
    }
    let e1 = fabric.elastic_energy();
    Ok(if e0 > 0.0 { (e1 - e0) / e0 } else { 0.0 })
}
