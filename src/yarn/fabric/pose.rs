//! Training poses of VH 2024 §8.6 (Fig. 19, after the HYLC data protocol)
//! run quasi-statically at yarn level: the clamped bands of a
//! [`PoseDriver`] move to their targets in `steps` equal increments of the
//! pose's amount, and the swatch is brought to equilibrium (rods, contact
//! and friction, [`Fabric::settle`]) at every increment. Each equilibrium is
//! one training frame: positions, elastic energy, the reactions of the
//! clamps and the external forces. Without [`PoseRunParams::gravity`] (the
//! HYLC protocol) there are none and the frames do not observe the
//! material's scale (the fit takes it from the clamp reactions); with it
//! every vertex carries its weight along the fabric's normal (the swatch
//! lying horizontal, as in a drape) and the sag between the clamps does
//! (VH trains mostly on frames of animations under gravity, §8.6).
//!
//! Frames: [`PoseDriver`] works in the scene frame (fabric in XZ, normal
//! +Y); a swatch lying in another coordinate plane (the pattern generator
//! writes XY, normal +Z) is turned into it for the run and every frame is
//! turned back, so the frames share the input yarns' coordinates.
//!
//! Pure: no files, no printing, no environment.

use std::convert::Infallible;
use std::time::Instant;

use super::model::{Fabric, FabricError, FabricParams, Settle};
use super::stretch::{vertex_forces, RigFrame};
use crate::geom::{Vec3, Yarns};
use crate::yarn::poses::{PoseDriver, PoseError, PoseKind, PoseParams};
use crate::yarn::statics::{EnergyTerm, GravityTerm};

/// Controls of [`run_pose`].
#[derive(Debug, Clone, PartialEq)]
pub struct PoseRunParams {
    /// The pose: kind, amount (strain, or rad for bends and twist; see
    /// [`default_amount`]), mirror, folds, band width. `ramp` is unused:
    /// the progress is the step index over `steps`.
    pub pose: PoseParams,
    /// Load steps from rest to the full amount (1 to 1000), or with
    /// [`Self::amounts`] from rest to the first listed amount and from each
    /// to the next. Default 10.
    pub steps: usize,
    /// Amplitudes the load path passes through in order, one frame family
    /// at several amplitudes (e.g. strains 0.02, 0.1, 0.2, 0.3); empty (the
    /// default): only `pose.amount`. When given, `pose.amount` is the last
    /// of them. At most [`MAX_AMOUNTS`].
    pub amounts: Vec<f64>,
    /// Equilibrium controls per step (force tolerance 1e-5 N).
    pub settle: Settle,
    /// Gravity (m/s², >= 0) along the fabric's normal, pulling toward
    /// -normal (pose frame -Y). Default 0: no external force.
    pub gravity: f64,
}

impl PoseRunParams {
    /// `kind` at its default amount ([`default_amount`]), 10 steps.
    pub fn new(kind: PoseKind) -> PoseRunParams {
        PoseRunParams {
            pose: PoseParams::new(kind, default_amount(kind).unwrap_or(0.0)),
            steps: 10,
            amounts: Vec::new(),
            settle: Settle::default(),
            gravity: 0.0,
        }
    }

    /// The amplitudes the load path stops at: [`Self::amounts`], else
    /// `[pose.amount]`.
    pub fn stops(&self) -> Vec<f64> {
        if self.amounts.is_empty() {
            vec![self.pose.amount]
        } else {
            self.amounts.clone()
        }
    }

    /// The pose's amount at every load step (one frame each): `steps` equal
    /// increments from rest to the first stop, then from each stop to the
    /// next.
    pub fn load_path(&self) -> Vec<f64> {
        let mut path = Vec::with_capacity(self.steps * self.stops().len());
        let mut prev = 0.0;
        for a in self.stops() {
            for j in 1..=self.steps {
                path.push(if j == self.steps {
                    a
                } else {
                    prev + (a - prev) * (j as f64 / self.steps as f64)
                });
            }
            prev = a;
        }
        path
    }

    /// The frames (from 0) at each stop, in the order of [`Self::stops`].
    pub fn stop_frames(&self) -> Vec<usize> {
        (1..=self.stops().len())
            .map(|i| i * self.steps - 1)
            .collect()
    }

    /// Checks the values that [`PoseDriver::new`] does not.
    pub fn check(&self) -> Result<(), PoseRunError> {
        if default_amount(self.pose.kind).is_none() {
            return Err(PoseRunError::Parameter(format!(
                "{:?} is not a training pose (give one of {})",
                self.pose.kind,
                TRAINING_KINDS.map(kind_name).join(", ")
            )));
        }
        if !(1..=1000).contains(&self.steps) {
            return Err(PoseRunError::Parameter(format!(
                "steps is {} (must be 1 to 1000)",
                self.steps
            )));
        }
        if self.amounts.len() > MAX_AMOUNTS {
            return Err(PoseRunError::Parameter(format!(
                "{} amounts listed (at most {MAX_AMOUNTS})",
                self.amounts.len()
            )));
        }
        if let Some(a) = self.amounts.iter().find(|a| !a.is_finite()) {
            return Err(PoseRunError::Parameter(format!("an amount is {a}")));
        }
        if let Some(last) = self.amounts.last() {
            if *last != self.pose.amount {
                return Err(PoseRunError::Parameter(format!(
                    "the pose's amount {} is not the last listed amount {last}",
                    self.pose.amount
                )));
            }
            if self.pose.kind == PoseKind::Cantilever && self.amounts.len() > 1 {
                return Err(PoseRunError::Parameter(
                    "cantilever is loaded by gravity alone: it takes no list of amounts".into(),
                ));
            }
        }
        if self.steps * self.stops().len() > MAX_LOAD_STEPS {
            return Err(PoseRunError::Parameter(format!(
                "{} load steps ({} per amount x {} amounts; at most {MAX_LOAD_STEPS})",
                self.steps * self.stops().len(),
                self.steps,
                self.stops().len()
            )));
        }
        if !(self.gravity.is_finite() && (0.0..=1000.0).contains(&self.gravity)) {
            return Err(PoseRunError::Parameter(format!(
                "gravity is {} m/s² (must be 0 to 1000)",
                self.gravity
            )));
        }
        if let Some(e) = self.pose.band_error() {
            return Err(PoseRunError::Parameter(e));
        }
        if self.pose.kind == PoseKind::Cantilever && !(self.gravity > 0.0) {
            return Err(PoseRunError::Parameter(
                "cantilever is loaded by gravity alone: give a gravity > 0".into(),
            ));
        }
        Ok(())
    }
}

/// Most amplitudes one pose run lists ([`PoseRunParams::amounts`]).
pub const MAX_AMOUNTS: usize = 100;

/// Most load steps (frames) of one pose run, over all its amplitudes.
pub const MAX_LOAD_STEPS: usize = 10_000;

/// The poses a training set is made of (VH §8.6 Fig. 19 and the uniaxial,
/// biaxial and shear deformations of the yarn-level literature), in
/// documentation order.
pub const TRAINING_KINDS: [PoseKind; 10] = [
    PoseKind::StretchCourses,
    PoseKind::StretchWales,
    PoseKind::Biaxial,
    PoseKind::Shear,
    PoseKind::BendCentral,
    PoseKind::BendDiagonal,
    PoseKind::Fan,
    PoseKind::Twist,
    PoseKind::MultiFold,
    PoseKind::Cantilever,
];

pub use crate::yarn::poses::kind_name;

/// The default amount of a training pose, `None` for the kinds that are not
/// training poses (`hang`, `free`): strains of 0.2 (stretches, shear, fan;
/// biaxial 0.1 per axis), within the 10-50% range fabrics are tested in
/// (Sperl 2022 §4.3); 0.8 rad for the bends and the twist; a fold height of
/// 0.3 fold lengths for the multi-fold.
pub fn default_amount(kind: PoseKind) -> Option<f64> {
    match kind {
        PoseKind::StretchCourses | PoseKind::StretchWales | PoseKind::Shear | PoseKind::Fan => {
            Some(0.2)
        }
        PoseKind::Biaxial => Some(0.1),
        PoseKind::BendCentral | PoseKind::BendDiagonal | PoseKind::Twist => Some(0.8),
        PoseKind::MultiFold => Some(0.3),
        // Loaded by gravity alone (PoseRunParams::gravity, required).
        PoseKind::Cantilever => Some(0.0),
        PoseKind::Hang | PoseKind::Free => None,
    }
}

/// Smallest distance between two yarn segments, over the sum of their
/// radii, that a pose's rest yarns may start at ([`run_pose`]); the
/// pull-through bound during a test is 0.75.
pub const MIN_START_DISTANCE_RATIO: f64 = 0.5;

/// Largest ratio of a swatch's thinnest bounding-box side to its middle
/// one that the poses take as flat: knitvox's 6 x 6 and 10 x 10 swatches
/// lie at 0.05-0.09 (curled stockinette included), the Yuksel glove at
/// 0.93.
pub const MAX_FLAT_RATIO: f64 = 0.4;

/// Why a pose run failed; `E` is the error of its frame callback (none
/// for the checks made before a run).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PoseRunError<E = Infallible> {
    /// The yarns are no flat swatch (a 3-D garment): their bounding box's
    /// thinnest side is more than [`MAX_FLAT_RATIO`] of its middle one,
    /// and clamped bands across a flat extent mean nothing there.
    #[error(
        "the yarns are no flat swatch: their bounding box is {:.4} x {:.4} x {:.4} m, its thinnest side \
         {:.2} of the middle one (a flat swatch's is under {MAX_FLAT_RATIO}); training poses clamp bands \
         across a flat swatch and mean nothing on a 3-D garment: fit a material card on a flat swatch of \
         its stitch (`knitvox card`) and carry it onto the garment with `knitvox embed --card` \
         (docs/guides/cards.md)",
        size[0], size[1], size[2], ratio
    )]
    NotFlat { size: [f64; 3], ratio: f64 },
    /// A parameter out of range (a usage error).
    #[error("pose parameter {0}")]
    Parameter(String),
    /// The pose does not fit the swatch (or its parameters are out of range).
    #[error("pose: {0}")]
    Pose(#[from] PoseError),
    /// The swatch cannot be modelled (rods, contact, friction parameters).
    #[error("yarn model: {0}")]
    Model(FabricError),
    /// A load step failed: no equilibrium, a failed Newton solve or a
    /// non-finite state.
    #[error("step {step} of {steps} (amount {amount:.4}): {source}")]
    Step {
        step: usize,
        steps: usize,
        amount: f64,
        #[source]
        source: FabricError,
    },
    /// The frame callback stopped the run with `error`.
    #[error("frame {step}: {error}")]
    Frame {
        step: usize,
        #[source]
        error: E,
    },
    /// The rest yarns pass through each other: two segments start closer
    /// than [`MIN_START_DISTANCE_RATIO`] x (rA + rB) (the swatch's fault).
    /// Their distance (m) and radius sum (m) say what radius would fit:
    /// yarns read with a radius too large for the file overlap at rest.
    #[error(
        "yarn model: the rest yarns pass through each other: two segments are {ratio:.3} x \
         (rA + rB) apart at rest ({distance_m:.3e} m apart, rA + rB = {radius_sum_m:.3e} m; below \
         {MIN_START_DISTANCE_RATIO}; a relaxed swatch keeps 0.86 or more): the yarn radius is \
         probably too large for these yarns (a radius of {fit:.2e} m would just touch there)",
        fit = distance_m / 2.0
    )]
    Crossing {
        ratio: f64,
        distance_m: f64,
        radius_sum_m: f64,
    },
}

impl PoseRunError {
    /// The same error as one of a run whose frame callback fails with `E`.
    pub fn in_run<E>(self) -> PoseRunError<E> {
        match self {
            PoseRunError::NotFlat { size, ratio } => PoseRunError::NotFlat { size, ratio },
            PoseRunError::Parameter(m) => PoseRunError::Parameter(m),
            PoseRunError::Pose(e) => PoseRunError::Pose(e),
            PoseRunError::Model(e) => PoseRunError::Model(e),
            PoseRunError::Step {
                step,
                steps,
                amount,
                source,
            } => PoseRunError::Step {
                step,
                steps,
                amount,
                source,
            },
            PoseRunError::Frame { error, .. } => match error {},
            PoseRunError::Crossing {
                ratio,
                distance_m,
                radius_sum_m,
            } => PoseRunError::Crossing {
                ratio,
                distance_m,
                radius_sum_m,
            },
        }
    }
}

impl<E> PoseRunError<E> {
    /// Whether the request (not the swatch) is at fault.
    pub fn is_usage(&self) -> bool {
        matches!(
            self,
            PoseRunError::Parameter(_)
                | PoseRunError::Pose(PoseError::Parameter(_))
                | PoseRunError::Pose(PoseError::Band(_))
        )
    }
}

/// Which coordinate plane a swatch lies in (the smallest extent of its
/// bounding box is its normal), and so how it turns into the pose frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum FabricPlane {
    /// Normal Y: already the pose frame.
    Xz,
    /// Normal Z (the pattern generator's frame): `(x, y, z) -> (x, z, -y)`.
    Xy,
    /// Normal X: `(x, y, z) -> (y, x, -z)` (courses taken along Y).
    Yz,
}

impl FabricPlane {
    /// The plane of `points` (their thinnest bounding-box axis is the
    /// normal; ties go to Y, then Z).
    pub fn of(points: &[Vec3]) -> FabricPlane {
        let Some(b) = crate::geom::bounds_of(points) else {
            return FabricPlane::Xz;
        };
        let e: Vec3 = std::array::from_fn(|k| b.max[k] - b.min[k]);
        if e[1] <= e[2] && e[1] <= e[0] {
            FabricPlane::Xz
        } else if e[2] <= e[0] {
            FabricPlane::Xy
        } else {
            FabricPlane::Yz
        }
    }

    /// Into the pose frame (a proper rotation).
    pub fn to_pose(self, p: Vec3) -> Vec3 {
        match self {
            FabricPlane::Xz => p,
            FabricPlane::Xy => [p[0], p[2], -p[1]],
            FabricPlane::Yz => [p[1], p[0], -p[2]],
        }
    }

    /// Back from the pose frame (the inverse of [`Self::to_pose`]).
    pub fn from_pose(self, p: Vec3) -> Vec3 {
        match self {
            FabricPlane::Xz => p,
            FabricPlane::Xy => [p[0], -p[2], p[1]],
            FabricPlane::Yz => [p[1], p[0], -p[2]],
        }
    }
}

/// One equilibrium step of a pose.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct PoseStep {
    /// 1 to `steps`.
    pub step: usize,
    /// The pose's amount reached at this step (`amount * step / steps`).
    pub amount: f64,
    /// Elastic energy, rods + contact (J).
    pub energy_j: f64,
    /// Per clamped band ([`PoseRun::bands`]): the total force the band's
    /// clamp exerts on the swatch (N, input frame).
    pub clamp_forces_n: Vec<Vec3>,
    /// Largest magnitude of `clamp_forces_n` (N).
    pub force_n: f64,
    pub newton_iterations: usize,
    /// Largest free static force at the end (N).
    pub residual_n: f64,
    pub contacts_per_vertex: f64,
    /// Smallest contact distance / (rA + rB) at the equilibrium.
    pub min_distance_ratio: f64,
    /// Wall time of the step (ms).
    pub ms: f64,
}

/// A whole pose run.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct PoseRun {
    pub plane: FabricPlane,
    pub vertices: usize,
    /// Clamped vertices.
    pub clamped_vertices: usize,
    /// Clamped bands: the rest centre (m, input frame) of each, in the
    /// order of [`PoseStep::clamp_forces_n`].
    pub bands: Vec<Vec3>,
    pub steps: Vec<PoseStep>,
    /// Smallest contact distance ratio over every step (pull-through < 0.75).
    pub min_distance_ratio: f64,
    pub seconds: f64,
}

/// Runs the pose on `yarns` (their stored rest shape when they carry one,
/// else their positions as rest), handing every equilibrium frame (steps 1
/// to `steps`, in the yarns' own coordinates) to `on_frame`; an error of
/// `on_frame` stops the run ([`PoseRunError::Frame`]).
pub fn run_pose<E>(
    yarns: &Yarns,
    fabric_params: &FabricParams,
    params: &PoseRunParams,
    on_frame: &mut dyn FnMut(&RigFrame) -> Result<(), E>,
) -> Result<PoseRun, PoseRunError<E>> {
    params.check().map_err(PoseRunError::in_run)?;
    if let Some(b) = crate::geom::bounds_of(&yarns.points) {
        let size: Vec3 = std::array::from_fn(|k| b.max[k] - b.min[k]);
        let mut sorted = size;
        sorted.sort_by(f64::total_cmp);
        let ratio = sorted[0] / sorted[1].max(f64::MIN_POSITIVE);
        if ratio > MAX_FLAT_RATIO {
            return Err(PoseRunError::NotFlat { size, ratio });
        }
    }
    let t0 = Instant::now();
    let plane = FabricPlane::of(&yarns.points);
    let mut posed = yarns.clone();
    posed.map_points(|p| plane.to_pose(p));
    if let Some(rest) = posed.rest.as_mut() {
        rest.transform(1.0, |d| plane.to_pose(d));
    }
    let rest = posed.points.clone();
    let path = params.load_path();
    let total = path.len();
    let driver_at = |amount: f64| {
        let mut p = params.pose;
        p.amount = amount;
        p.ramp = 0.0;
        PoseDriver::new(&rest, p)
    };
    let full = driver_at(params.pose.amount)?;
    let predictor = Predictor::new(&full, &rest);
    let mut fabric = Fabric::new(&posed, fabric_params).map_err(PoseRunError::Model)?;
    // Yarns that pass through each other at rest (a point moved across
    // another yarn) leave no load step an equilibrium to reach: the rounds
    // would run to their cap (a fuzzed asset: 62 rounds, 41 s) first.
    let cs = fabric.contact_stats();
    if cs.min_distance_ratio < MIN_START_DISTANCE_RATIO {
        return Err(PoseRunError::Crossing {
            ratio: cs.min_distance_ratio,
            distance_m: cs.min_distance_m,
            radius_sum_m: cs.min_distance_radius_sum_m,
        });
    }
    let n = fabric.num_vertices();
    let mut clamped = vec![false; n];
    full.pinned().iter().for_each(|&v| clamped[v] = true);
    let fixed = fabric.clamped_and_gauged(&clamped);
    let (band_of, band_centres) = bands(&full, &rest);
    // Its acceleration is set per step (`gravity_at`).
    let mut gravity = GravityTerm {
        mass: fabric.mass.clone(),
        g: [0.0; 3],
    };
    // The cantilever's load is its weight: the steps ramp gravity instead
    // of the (unused) amount. Other poses carry their full weight at every
    // step.
    let gravity_at = |k: usize| {
        if params.pose.kind == PoseKind::Cantilever {
            params.gravity * k as f64 / total as f64
        } else {
            params.gravity
        }
    };
    let settle = fabric.resolve_weights(&params.settle, params.gravity);

    let mut steps = Vec::with_capacity(total);
    let mut min_ratio = f64::INFINITY;
    let mut prev_field = rest.clone();
    for (k, &amount) in (1..=total).zip(&path) {
        let ts = Instant::now();
        let fail = |source| PoseRunError::Step {
            step: k,
            steps: total,
            amount,
            source,
        };
        let driver = driver_at(amount)?;
        if driver.pinned() != full.pinned() {
            return Err(PoseRunError::Parameter(format!(
                "the clamped bands change with the amount at step {k} (internal)"
            )));
        }
        // The load step starts at the last equilibrium (friction lags
        // there); free vertices move by the increment of the predicted
        // field, clamped ones go to their targets.
        fabric.begin_step();
        let field = predictor.field(&driver, &rest);
        for v in 0..n {
            for c in 0..3 {
                fabric.q[3 * v + c] += field[v][c] - prev_field[v][c];
            }
        }
        for (&v, t) in driver.pinned().iter().zip(driver.targets(1.0)) {
            fabric.q[3 * v..3 * v + 3].copy_from_slice(&t);
        }
        prev_field = field;
        let stage = format!("{} step {k}", kind_name(params.pose.kind));
        let g_k = gravity_at(k);
        gravity.g = [0.0, -g_k, 0.0];
        // The weights (pose frame -Y), as external forces in the input frame.
        let external: Vec<Vec3> = fabric
            .mass
            .iter()
            .map(|m| plane.from_pose([0.0, -m * g_k, 0.0]))
            .collect();
        let loads: &mut [&mut dyn EnergyTerm] = if params.gravity > 0.0 {
            &mut [&mut gravity]
        } else {
            &mut []
        };
        let st = fabric
            .settle(loads, &fixed, &settle, &stage)
            .map_err(fail)?;
        settle.require(&st, &stage).map_err(fail)?;
        // Clamp reactions balance the elastic forces and the clamped
        // vertices' own weight: the gradient of the total potential.
        let (_, g) = fabric.gradient(loads);
        let energy = fabric.elastic_energy();
        if !energy.is_finite() || g.iter().any(|x| !x.is_finite()) {
            return Err(fail(FabricError::NoEquilibrium(format!(
                "{stage}: the state is not finite (diverged)"
            ))));
        }
        let reactions: Vec<Vec3> = vertex_forces(&g, &clamped)
            .into_iter()
            .map(|f| plane.from_pose(f))
            .collect();
        let mut clamp_forces = vec![[0.0; 3]; band_centres.len()];
        for (v, f) in reactions.iter().enumerate() {
            if let Some(gi) = band_of[v] {
                (0..3).for_each(|c| clamp_forces[gi][c] += f[c]);
            }
        }
        let x: Vec<Vec3> = fabric
            .points()
            .into_iter()
            .map(|p| plane.from_pose(p))
            .collect();
        let cst = fabric.contact_stats();
        min_ratio = min_ratio
            .min(st.min_distance_ratio)
            .min(cst.min_distance_ratio);
        on_frame(&RigFrame {
            index: k,
            parameter: amount,
            points: &x,
            energy,
            reactions,
            external,
        })
        .map_err(|error| PoseRunError::Frame { step: k, error })?;
        let force = clamp_forces
            .iter()
            .map(|f| crate::geom::vec3::norm(*f))
            .fold(0.0, f64::max);
        steps.push(PoseStep {
            step: k,
            amount,
            energy_j: energy,
            clamp_forces_n: clamp_forces,
            force_n: force,
            newton_iterations: st.newton_iterations,
            residual_n: st.residual,
            contacts_per_vertex: cst.contacts_per_vertex,
            min_distance_ratio: cst.min_distance_ratio,
            ms: ts.elapsed().as_secs_f64() * 1e3,
        });
    }
    Ok(PoseRun {
        plane,
        vertices: n,
        clamped_vertices: full.pinned().len(),
        bands: band_centres.iter().map(|c| plane.from_pose(*c)).collect(),
        steps,
        min_distance_ratio: min_ratio,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// The clamped bands: each group of the pose split where its vertices
/// leave a gap of more than half its extent along an axis (the two end
/// bands of a bend share one map), and a band that rings the swatch (the
/// four edges of `biaxial`) split by nearest edge. Returns per vertex its
/// band and per band its rest centre (pose frame).
fn bands(driver: &PoseDriver, rest: &[Vec3]) -> (Vec<Option<usize>>, Vec<Vec3>) {
    let all = crate::geom::bounds_of(rest);
    let span: Vec3 = all
        .as_ref()
        .map_or([0.0; 3], |b| std::array::from_fn(|k| b.max[k] - b.min[k]));
    let mut parts: Vec<Vec<usize>> = Vec::new();
    for g in 0..driver.num_groups() {
        let mut todo = vec![driver.group_vertices(g).to_vec()];
        for (axis, &extent) in span.iter().enumerate() {
            todo = todo
                .into_iter()
                .flat_map(|b| split_at_gap(b, rest, axis, extent))
                .collect();
        }
        for b in todo {
            match &all {
                Some(box_) if rings(&b, rest, box_) => parts.extend(by_edge(b, rest, box_)),
                _ => parts.push(b),
            }
        }
    }
    let mut of = vec![None; rest.len()];
    let mut centres = Vec::with_capacity(parts.len());
    for (i, b) in parts.iter().enumerate() {
        let mut c = [0.0; 3];
        for &v in b {
            of[v] = Some(i);
            (0..3).for_each(|k| c[k] += rest[v][k] / b.len() as f64);
        }
        centres.push(c);
    }
    (of, centres)
}

/// `band` in two at its largest gap along `axis` when that gap exceeds half
/// its extent and a quarter of the swatch's `span` along it (not the gaps
/// between yarn vertices inside a band), else unchanged.
fn split_at_gap(mut band: Vec<usize>, rest: &[Vec3], axis: usize, span: f64) -> Vec<Vec<usize>> {
    band.sort_by(|&a, &b| rest[a][axis].total_cmp(&rest[b][axis]).then(a.cmp(&b)));
    let (Some(&lo), Some(&hi)) = (band.first(), band.last()) else {
        return vec![band];
    };
    let extent = rest[hi][axis] - rest[lo][axis];
    let gap = band
        .windows(2)
        .enumerate()
        .map(|(i, w)| (rest[w[1]][axis] - rest[w[0]][axis], i))
        .fold((0.0, 0), |a, b| if b.0 > a.0 { b } else { a });
    if extent > 0.0 && gap.0 > 0.5 * extent && gap.0 > 0.25 * span {
        let high = band.split_off(gap.1 + 1);
        vec![band, high]
    } else {
        vec![band]
    }
}

/// Whether `band` spans 90% of the swatch along both in-plane axes (X, Z)
/// while leaving its middle empty: a ring of edge bands.
fn rings(band: &[usize], rest: &[Vec3], all: &crate::geom::Bounds) -> bool {
    let Some(b) = crate::geom::bounds_of(&band.iter().map(|&v| rest[v]).collect::<Vec<_>>()) else {
        return false;
    };
    let spans = [0, 2]
        .iter()
        .all(|&k| b.max[k] - b.min[k] >= 0.9 * (all.max[k] - all.min[k]));
    let c = [0, 2].map(|k| 0.5 * (all.min[k] + all.max[k]));
    let h = [0, 2].map(|k| 0.25 * (all.max[k] - all.min[k]));
    let middle_empty = band
        .iter()
        .all(|&v| (rest[v][0] - c[0]).abs() > h[0] || (rest[v][2] - c[1]).abs() > h[1]);
    spans && middle_empty
}

/// `band` split by the nearest edge of the swatch: left, right (X), back,
/// front (Z); empty parts dropped.
fn by_edge(band: Vec<usize>, rest: &[Vec3], all: &crate::geom::Bounds) -> Vec<Vec<usize>> {
    let mut out = vec![Vec::new(); 4];
    for v in band {
        let p = rest[v];
        let d = [
            p[0] - all.min[0],
            all.max[0] - p[0],
            p[2] - all.min[2],
            all.max[2] - p[2],
        ];
        let e = (0..4).fold(0, |m, i| if d[i] < d[m] { i } else { m });
        out[e].push(v);
    }
    out.retain(|b| !b.is_empty());
    out
}

/// The starting guess of every step: each vertex follows the maps of the
/// (at most two) clamped groups nearest to it at rest, weighted linearly by
/// its distances to them; a single group's map (bends, biaxial) applies to
/// the whole swatch. For two bands at the ends this is the affine stretch,
/// shear or fan between them; for the fold lines, the zigzag.
struct Predictor {
    /// Per vertex: up to two (group, weight) pairs.
    weights: Vec<[(usize, f64); 2]>,
}

impl Predictor {
    fn new(driver: &PoseDriver, rest: &[Vec3]) -> Predictor {
        let groups = driver.num_groups();
        let weights = rest
            .iter()
            .map(|&p| {
                // Distance to the nearest vertex of each group.
                let mut d: Vec<(f64, usize)> = (0..groups)
                    .map(|g| {
                        let m = driver
                            .group_vertices(g)
                            .iter()
                            .map(|&v| crate::geom::dist(p, rest[v]))
                            .fold(f64::INFINITY, f64::min);
                        (m, g)
                    })
                    .collect();
                d.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                match d.as_slice() {
                    [] => [(0, 0.0), (0, 0.0)],
                    [(_, g)] => [(*g, 1.0), (*g, 0.0)],
                    [(d1, g1), (d2, g2), ..] => {
                        let s = d1 + d2;
                        if s > 0.0 {
                            [(*g1, d2 / s), (*g2, d1 / s)]
                        } else {
                            [(*g1, 1.0), (*g2, 0.0)]
                        }
                    }
                }
            })
            .collect();
        Predictor { weights }
    }

    /// The predicted positions (m) under `driver` at full progress.
    fn field(&self, driver: &PoseDriver, rest: &[Vec3]) -> Vec<Vec3> {
        if driver.num_groups() == 0 {
            return rest.to_vec();
        }
        rest.iter()
            .zip(&self.weights)
            .map(|(&p, w)| {
                let mut out = [0.0; 3];
                for &(g, wg) in w {
                    if wg > 0.0 {
                        let t = driver.group_target(g, p, 1.0);
                        (0..3).for_each(|c| out[c] += wg * t[c]);
                    }
                }
                out
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::yarn::pattern::{build_tile, builtin, lay_out, Layout, PatternParams};

    /// A small unrelaxed rib swatch as the pattern generator lays it
    /// out (XY plane), its positions as rest.
    fn rib(courses: usize, wales: usize) -> Yarns {
        let pat = builtin("rib1x1").unwrap();
        let tile = build_tile(&pat, &PatternParams::default()).unwrap();
        lay_out(
            &tile,
            &Layout {
                courses,
                wales,
                tube_radius: None,
                helix: false,
                separate_courses: false,
            },
        )
        .unwrap()
    }

    fn frictionless() -> FabricParams {
        FabricParams {
            friction: crate::yarn::statics::FrictionParams {
                mu: 0.0,
                ..FabricParams::default().friction
            },
            ..FabricParams::default()
        }
    }

    #[test]
    fn plane_rotations_are_proper_and_inverse() {
        for plane in [FabricPlane::Xz, FabricPlane::Xy, FabricPlane::Yz] {
            let p = [0.3, -1.2, 2.5];
            assert_eq!(plane.from_pose(plane.to_pose(p)), p, "{plane:?}");
            // Determinant +1: the image of x cross y is the image of z.
            let [ex, ey, ez] =
                [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]].map(|e| plane.to_pose(e));
            assert_eq!(crate::geom::vec3::cross(ex, ey), ez, "{plane:?}");
        }
        let flat_xy = [[0.0, 0.0, 0.0], [0.1, 0.05, 0.001]];
        assert_eq!(FabricPlane::of(&flat_xy), FabricPlane::Xy);
        assert_eq!(
            FabricPlane::to_pose(FabricPlane::Xy, [0.0, 0.0, 1.0]),
            [0.0, 1.0, 0.0]
        );
    }

    #[test]
    fn hang_free_and_bad_steps_are_parameter_errors() {
        let y = rib(2, 2);
        for kind in [PoseKind::Hang, PoseKind::Free] {
            let mut p = PoseRunParams::new(kind);
            p.pose.amount = 0.1;
            let e = run_pose(&y, &FabricParams::default(), &p, &mut |_| {
                Ok::<(), Infallible>(())
            })
            .unwrap_err();
            assert!(e.is_usage(), "{e}");
        }
        let mut p = PoseRunParams::new(PoseKind::Shear);
        p.steps = 0;
        let e = run_pose(&y, &FabricParams::default(), &p, &mut |_| {
            Ok::<(), Infallible>(())
        })
        .unwrap_err();
        assert!(e.is_usage() && e.to_string().contains("steps"), "{e}");
        let mut p = PoseRunParams::new(PoseKind::MultiFold);
        p.pose.amount = 0.7;
        let e = run_pose(&y, &FabricParams::default(), &p, &mut |_| {
            Ok::<(), Infallible>(())
        })
        .unwrap_err();
        assert!(e.is_usage(), "{e}");
    }

    #[test]
    fn a_list_of_amounts_loads_through_each_in_order() {
        let mut p = PoseRunParams::new(PoseKind::StretchCourses);
        p.steps = 2;
        p.amounts = vec![0.02, 0.1, 0.2];
        p.pose.amount = 0.2;
        let path = p.load_path();
        let want = [0.01, 0.02, 0.06, 0.1, 0.15, 0.2];
        assert_eq!(path.len(), want.len());
        for (a, w) in path.iter().zip(want) {
            assert!((a - w).abs() < 1e-15, "{path:?}");
        }
        assert_eq!(p.stop_frames(), [1, 3, 5]);
        for (f, a) in p.stop_frames().into_iter().zip(p.stops()) {
            assert_eq!(path[f], a, "a stop is reached exactly");
        }
        assert!(p.check().is_ok());
        // One amount: `steps` increments to it, as without a list.
        let mut one = PoseRunParams::new(PoseKind::Shear);
        one.steps = 4;
        one.pose.amount = 0.1;
        assert_eq!(one.load_path().len(), 4);
        assert_eq!(one.load_path()[3], 0.1);
        assert_eq!(one.stop_frames(), [3]);
        // Refused: a last amount other than the pose's, a NaN, a list for
        // the cantilever, too many frames.
        let mut bad = p.clone();
        bad.pose.amount = 0.3;
        assert!(bad
            .check()
            .unwrap_err()
            .to_string()
            .contains("last listed amount"));
        let mut bad = p.clone();
        bad.amounts[0] = f64::NAN;
        assert!(bad.check().is_err());
        let mut bad = PoseRunParams::new(PoseKind::Cantilever);
        bad.gravity = 9.81;
        bad.amounts = vec![0.0, 0.0];
        bad.pose.amount = 0.0;
        assert!(bad.check().unwrap_err().to_string().contains("cantilever"));
        let mut bad = p.clone();
        bad.steps = 1000;
        bad.amounts = vec![0.1; 11];
        bad.pose.amount = 0.1;
        assert!(bad.check().unwrap_err().to_string().contains("load steps"));
        // A run hands on one frame per load step, at the path's amounts.
        let y = rib(2, 2);
        let mut run = PoseRunParams::new(PoseKind::StretchCourses);
        run.steps = 1;
        run.amounts = vec![0.05, 0.1];
        run.pose.amount = 0.1;
        let mut seen = Vec::new();
        let r = run_pose(&y, &frictionless(), &run, &mut |f| {
            seen.push(f.parameter);
            Ok::<(), Infallible>(())
        })
        .unwrap();
        assert_eq!(seen, [0.05, 0.1]);
        assert_eq!(r.steps.len(), 2);
        assert!(r.steps[1].force_n > r.steps[0].force_n, "{:?}", r.steps);
    }

    /// A stretch along the courses: the right band moves by the amount
    /// times the width, the swatch pulls back harder at every step, the
    /// energy rises, the two clamps' forces balance, and the frames come
    /// back in the generator's XY frame.
    #[test]
    fn stretch_courses_moves_the_band_and_pulls_back_more_each_step() {
        let y = rib(3, 4);
        let fp = frictionless();
        let mut p = PoseRunParams::new(PoseKind::StretchCourses);
        p.pose.amount = 0.1;
        p.steps = 2;
        let b = crate::geom::bounds_of(&y.points).unwrap();
        let lx = b.max[0] - b.min[0];
        let right: Vec<bool> = y
            .points
            .iter()
            .map(|q| q[0] >= b.max[0] - p.pose.band * lx)
            .collect();
        let mut frames = Vec::new();
        let r = run_pose(&y, &fp, &p, &mut |f| {
            frames.push((f.points.to_vec(), f.reactions.clone()));
            Ok::<(), Infallible>(())
        })
        .unwrap();
        assert_eq!(r.plane, FabricPlane::Xy);
        assert_eq!((r.steps.len(), frames.len()), (2, 2));
        for (k, (x, reac)) in frames.iter().enumerate() {
            let want = 0.1 * lx * (k + 1) as f64 / 2.0;
            for v in (0..y.num_points()).filter(|&v| right[v]) {
                let d = [0, 1, 2].map(|c| x[v][c] - y.points[v][c]);
                assert!((d[0] - want).abs() < 1e-12 && d[1].abs() < 1e-12 && d[2].abs() < 1e-12);
            }
            let fx: f64 = (0..y.num_points())
                .filter(|&v| right[v])
                .map(|v| reac[v][0])
                .sum();
            let total: f64 = reac.iter().map(|f| f[0]).sum();
            assert!(fx > 0.0, "step {k}: right clamp force {fx} N");
            assert!(
                total.abs() <= 1e-3 * fx + 1e-6,
                "clamps do not balance: {total} of {fx}"
            );
        }
        let s = &r.steps;
        assert!(s[1].force_n > s[0].force_n && s[0].force_n > 0.0, "{s:?}");
        assert!(s[1].energy_j > s[0].energy_j, "{s:?}");
        assert!(r.min_distance_ratio > 0.75, "{}", r.min_distance_ratio);
    }

    /// With gravity every frame records each vertex's weight along -normal
    /// (input frame: the generator's XY swatch, so -Z), the clamps carry the
    /// whole weight, and the swatch sags between them; without it the
    /// frames carry no external force.
    #[test]
    fn gravity_loads_the_frames_and_the_clamps_carry_the_weight() {
        let y = rib(3, 4);
        let fp = frictionless();
        let run = |g: f64| {
            let mut p = PoseRunParams::new(PoseKind::StretchCourses);
            p.pose.amount = 0.05;
            p.steps = 1;
            p.gravity = g;
            let mut last = None;
            run_pose(&y, &fp, &p, &mut |f| {
                last = Some((f.points.to_vec(), f.reactions.clone(), f.external.clone()));
                Ok::<(), Infallible>(())
            })
            .unwrap();
            last.unwrap()
        };
        let (x0, _, e0) = run(0.0);
        assert!(e0.iter().all(|f| *f == [0.0; 3]));
        let (x, reactions, external) = run(9.81);
        let sum = |v: &[Vec3], c: usize| v.iter().map(|f| f[c]).sum::<f64>();
        let weight = -sum(&external, 2);
        assert!(weight > 0.0 && sum(&external, 0) == 0.0 && sum(&external, 1) == 0.0);
        let carried = sum(&reactions, 2);
        assert!(
            (carried - weight).abs() < 0.05 * weight,
            "clamps carry {carried} N of {weight} N"
        );
        let mean_z = |x: &[Vec3]| sum(x, 2) / x.len() as f64;
        let sag = mean_z(&x0) - mean_z(&x);
        let b = crate::geom::bounds_of(&y.points).unwrap();
        eprintln!(
            "mean sag {sag:.3e} m over a {:.3e} m span",
            b.max[0] - b.min[0]
        );
        assert!(sag > 1e-4, "{sag}");
        let mut p = PoseRunParams::new(PoseKind::StretchCourses);
        p.gravity = -1.0;
        assert!(p.check().is_err());
        // The cantilever is loaded by gravity alone.
        let p = PoseRunParams::new(PoseKind::Cantilever);
        assert!(p.check().unwrap_err().to_string().contains("gravity"));
    }

    /// A cantilever droops under its ramped weight: the free edge sinks
    /// further at every step (the generator's XY swatch: -Z is down) and the
    /// one clamp carries the weight of the step.
    #[test]
    fn a_cantilever_droops_more_as_its_weight_ramps_up() {
        let y = rib(3, 4);
        let mut p = PoseRunParams::new(PoseKind::Cantilever);
        p.gravity = 9.81;
        p.steps = 2;
        let b = crate::geom::bounds_of(&y.points).unwrap();
        let tip: Vec<usize> = (0..y.num_points())
            .filter(|&v| y.points[v][0] >= b.max[0] - 0.1 * (b.max[0] - b.min[0]))
            .collect();
        let mut drops = Vec::new();
        run_pose(&y, &frictionless(), &p, &mut |f| {
            let d = tip
                .iter()
                .map(|&v| y.points[v][2] - f.points[v][2])
                .sum::<f64>()
                / tip.len() as f64;
            let weight = -f.external.iter().map(|e| e[2]).sum::<f64>();
            let carried = f.reactions.iter().map(|r| r[2]).sum::<f64>();
            assert!(
                (carried - weight).abs() < 0.05 * weight,
                "{carried} vs {weight}"
            );
            drops.push((d, weight));
            Ok::<(), Infallible>(())
        })
        .unwrap();
        eprintln!("tip drops and weights: {drops:?}");
        assert!(drops[0].0 > 1e-4 && drops[1].0 > drops[0].0, "{drops:?}");
        assert!((drops[1].1 - 2.0 * drops[0].1).abs() < 1e-9 * drops[1].1);
    }

    /// The clamped bands the forces are summed over: the two ends of a
    /// stretch, of a bend (one map) and of a diagonal bend (corners), the
    /// four edges of a biaxial stretch, one per fold line.
    #[test]
    fn bands_split_shared_maps_into_their_ends() {
        let mut grid = Vec::new();
        for i in 0..=40 {
            for j in 0..=20 {
                grid.push([i as f64 * 0.0025, 0.0, j as f64 * 0.0025]);
            }
        }
        let count = |kind: PoseKind| {
            let mut p = PoseParams::new(kind, 0.2);
            p.band = 0.1;
            let d = PoseDriver::new(&grid, p).unwrap();
            let (of, centres) = bands(&d, &grid);
            assert_eq!(
                of.iter().filter(|b| b.is_some()).count(),
                d.pinned().len(),
                "{kind:?}: every clamped vertex in one band"
            );
            centres.len()
        };
        assert_eq!(count(PoseKind::StretchCourses), 2);
        assert_eq!(count(PoseKind::BendCentral), 2);
        assert_eq!(count(PoseKind::BendDiagonal), 2);
        assert_eq!(count(PoseKind::Twist), 2);
        assert_eq!(count(PoseKind::Biaxial), 4);
        assert_eq!(count(PoseKind::MultiFold), 4);
    }

    /// A step that reaches no equilibrium stops the run with an error
    /// naming the step; no frame is handed on for it.
    #[test]
    fn a_step_without_equilibrium_is_an_error_naming_it() {
        let y = rib(2, 2);
        let mut fp = FabricParams::default();
        fp.solver.max_iterations = 1;
        let mut p = PoseRunParams::new(PoseKind::StretchCourses);
        p.steps = 3;
        p.settle = Settle {
            max_rounds: 0,
            tolerance: 1e-12,
            ..Settle::default()
        };
        let mut frames = 0;
        let e = run_pose(&y, &fp, &p, &mut |_| {
            frames += 1;
            Ok::<(), Infallible>(())
        })
        .unwrap_err();
        assert!(
            matches!(
                e,
                PoseRunError::Step {
                    step: 1,
                    steps: 3,
                    ..
                }
            ),
            "{e}"
        );
        assert!(e.to_string().contains("step 1 of 3"), "{e}");
        assert!(!e.is_usage());
        assert_eq!(frames, 0);
    }
}
