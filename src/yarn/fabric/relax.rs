//! Relaxation of a generated pattern into a rest state held by contact
//! (Leaf 2018 §6.1, rest-length scaling): the rods' rest lengths shrink in
//! a few stages to `length_scale` times the generated ones, and after each
//! stage the swatch goes to equilibrium of rods + contact by proximal
//! Newton solves (implicit-Euler steps of size `dt` repeated until the
//! static force residual is small; the inertia term only regularizes the
//! free swatch's rigid modes and the buckling of loops on the way, it
//! vanishes at the end).
//!
//! The rest state handed on (Sperl 2022 §7.2, "a stable but slightly
//! pre-tensed rest state"): the scaled rest lengths (the yarns stay a
//! little stretched, held by contact) and the generated curves' bending and
//! twist rest shape, expressed in the relaxed material frames, so the
//! relaxed positions are an equilibrium of exactly the rest shape stored
//! with them: the loops' bending holds them against their neighbours.
//!
//! Friction is off during the relaxation (whatever `FabricParams::friction`
//! says): the relaxed state is then a minimum of the stored elastic energy.

use std::time::Instant;

use super::model::{Fabric, FabricError, FabricParams, Settle, PREDICTION_MIN_DISTANCE_RATIO};
use crate::geom::{RestShape, Yarns};
use crate::yarn::rods::{HingeHessian, RodRest};
use crate::yarn::statics::{ContactStats, EnergyTerm, FrictionParams};

/// Controls of [`relax_into_contact`].
/// [`RelaxParams::CHARACTER_REST_CURVATURE`] is the rest curvature that
/// shows a pattern's character.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RelaxParams {
    /// Final rest-length scale (dimensionless, Leaf §6.1). Default 0.8:
    /// with the fabric's default bending the generated loops then close
    /// onto each other (a 6x4 rib: 23% of vertices touching, 0.6 contacts
    /// per vertex; at 0.9 only 5% and 0.15, the loops shrink without
    /// jamming).
    pub length_scale: f64,
    /// Number of stages from 1 to `length_scale`. Default 3.
    pub stages: usize,
    /// Proximal (implicit-Euler) step (s). Default 0.05.
    pub dt: f64,
    /// Most proximal rounds per stage. Default 30.
    pub max_rounds: usize,
    /// Static force residual (N) that ends the last stage. Default 1e-5.
    pub force_tolerance: f64,
    /// Fraction of the generated curves' curvature the yarn keeps as its
    /// rest curvature (dimensionless, 0 = a straight yarn, 1 = the
    /// generated loops are its rest shape). HYLC §5.1 (Fig. 10): a yarn
    /// taken out of a knit keeps a bent rest shape, but not all of it; the
    /// part it does not keep is bending stress that curls a stockinette
    /// swatch's edges (the loops' bending is asymmetric through the fabric)
    /// and shortens garter. Default 1 (no character: the relaxed swatch
    /// lies flat, as the fabric tests clamp it). At 0.8 an 8x8 stockinette
    /// rolls its course ends to the back (-15 mm) and its top and bottom to
    /// the front (+3 mm), a rib stays flat (< 0.1 mm) and draws in to 0.87
    /// of its generated width, garter shortens to 0.76 of its height (rib
    /// 0.83, stockinette 0.86); a 6 x 10 cm rib stretched 30% along the
    /// courses narrows by 5.1% (3% at 1), but the rolled stockinette fails
    /// the weft stretch checks (compression 0.017, secant ratio 1.98). At
    /// 0.5 the stockinette rolls into a tube and garter buckles.
    pub rest_curvature: f64,
    /// The hinges' Hessian model in the relaxation's Newton solves. Default
    /// the projected exact Hessian: the relaxation's large bending moves
    /// converge in fewer iterations with the curvatures' second derivatives
    /// (the 26x26 rib: 89 Newton iterations and 33.8 s, against 130 and
    /// 37.2 s with Gauss-Newton, which the tests on a relaxed swatch use).
    pub hinge_hessian: HingeHessian,
    /// Start each stage's solve from the swatch contracted by the stage's
    /// length-scale ratio: a flat swatch in its plane, a tube (or any
    /// other shape) as a whole ([`contraction_axes`]). Default true.
    /// Without it a stage's Newton solve moves a large swatch's edges by
    /// centimetres and settles in a looser, stressed equilibrium that gets
    /// worse with the swatch's size: 1x1 ribs of 8, 16 and 26 stitches
    /// square ended with 19.8%, 12.6% and 11.1% of their vertices touching
    /// and 2.8e-8, 4.4e-8 and 9.6e-8 J of elastic energy per stitch. With
    /// it the 16 x 16 rib reaches 25.3% and 2.5e-8 J in 43 Newton
    /// iterations (120 without), the 26 x 26 29.2% and 2.5e-8 J in 69
    /// (126). Twelve stages without it reach that state at 4x the work.
    /// A 10 x 40 stockinette helix of radius 7 cm: 1.5e-5 -> 6.2e-7 J,
    /// 11.1% -> 21.8% touching, 152 -> 32 iterations.
    pub predict_contraction: bool,
}

impl Default for RelaxParams {
    fn default() -> Self {
        RelaxParams {
            length_scale: 0.8,
            stages: 3,
            dt: 0.05,
            max_rounds: 30,
            force_tolerance: 1e-5,
            rest_curvature: 1.0,
            hinge_hessian: HingeHessian::Projected,
            predict_contraction: true,
        }
    }
}

/// What the relaxation did.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RelaxIntoContactStats {
    pub length_scale: f64,
    pub stages: usize,
    /// Proximal rounds and Newton iterations over all stages.
    pub rounds: usize,
    pub newton_iterations: usize,
    /// Largest free static force at the end (N).
    pub residual: f64,
    /// Contact at the end.
    pub contact: ContactStats,
    /// Smallest distance ratio seen after any round (no pull-through: > 0.75).
    pub min_distance_ratio_seen: f64,
    /// Bounding-box size before and after (m).
    pub size_before: [f64; 3],
    pub size_after: [f64; 3],
    /// Elastic energy at the end (J).
    pub energy: f64,
    pub seconds: f64,
}

impl RelaxParams {
    /// A rest curvature fraction at which patterns show their character
    /// (see [`RelaxParams::rest_curvature`]).
    pub const CHARACTER_REST_CURVATURE: f64 = 0.8;

    /// The defaults with [`Self::CHARACTER_REST_CURVATURE`].
    pub fn with_character() -> RelaxParams {
        RelaxParams {
            rest_curvature: Self::CHARACTER_REST_CURVATURE,
            ..RelaxParams::default()
        }
    }

    /// Checks every value's range before any work.
    pub fn check(&self) -> Result<(), FabricError> {
        let ok = self.length_scale.is_finite()
            && self.length_scale > 0.5
            && self.length_scale <= 1.0
            && self.stages >= 1
            && self.stages <= 100
            && self.dt.is_finite()
            && self.dt > 0.0
            && self.max_rounds >= 1
            && self.force_tolerance.is_finite()
            && self.force_tolerance > 0.0
            && self.rest_curvature.is_finite()
            && (0.0..=1.0).contains(&self.rest_curvature);
        if ok {
            Ok(())
        } else {
            Err(FabricError::Setup(format!(
                "relaxation parameters out of range (length_scale in (0.5, 1], stages 1-100, dt > 0, rounds >= 1, tolerance > 0, rest_curvature in [0, 1]): {self:?}"
            )))
        }
    }
}

/// Relaxes `yarns` into contact; returns them at the relaxed positions with
/// the rest shape the simulator must use (`Yarns::rest`).
pub fn relax_into_contact(
    yarns: &Yarns,
    fabric_params: &FabricParams,
    params: &RelaxParams,
) -> Result<(Yarns, RelaxIntoContactStats), FabricError> {
    params.check()?;
    let t0 = Instant::now();
    let mut plain = yarns.clone();
    plain.rest = None;
    // Frictionless: the rest state must be an energy minimum of rods +
    // contact alone (a reloaded swatch has no friction history); friction
    // acts in the tests that load it.
    let frictionless = FabricParams {
        friction: FrictionParams::off(),
        hinge_hessian: params.hinge_hessian,
        ..fabric_params.clone()
    };
    let mut fabric = Fabric::new(&plain, &frictionless)?;
    let topo = fabric.rods.topology().clone();
    let generated = RodRest::from_positions(&topo, &yarns.points)?;
    let fixed = fabric.twist_gauge();
    let (mut rounds, mut iterations) = (0, 0);
    let mut min_seen = f64::INFINITY;
    let mut residual = f64::INFINITY;
    let axes = params
        .predict_contraction
        .then(|| contraction_axes(&yarns.points));
    let mut s_prev = 1.0;
    for stage in 1..=params.stages {
        let s = 1.0 - (1.0 - params.length_scale) * stage as f64 / params.stages as f64;
        // Lengths and curvatures reach their final values together.
        let f = stage as f64 / params.stages as f64;
        let kappa = 1.0 - (1.0 - params.rest_curvature) * f;
        let mut rest = generated.clone();
        rest.scale_lengths(&vec![s; topo.num_edges()])?;
        for k in &mut rest.kappa_bar {
            k.iter_mut().for_each(|x| *x *= kappa);
        }
        fabric.set_rest(rest)?;
        if let Some(axes) = &axes {
            predict_contraction(&mut fabric, axes, s / s_prev);
        }
        s_prev = s;
        let last = stage == params.stages;
        let tol = if last {
            params.force_tolerance
        } else {
            10.0 * params.force_tolerance
        };
        let settle = Settle {
            direct_first: false,
            dt: params.dt,
            max_rounds: params.max_rounds,
            tolerance: tol,
        };
        let st = fabric.settle(
            &mut [],
            &fixed,
            &settle,
            &format!("relaxation stage {stage}"),
        )?;
        rounds += st.rounds;
        iterations += st.newton_iterations;
        min_seen = min_seen.min(st.min_distance_ratio);
        residual = st.residual;
        if last {
            settle.require(&st, "relaxation")?;
        }
    }
    // The rest the relaxed state is an equilibrium of: scaled lengths, the
    // generated curvatures (times `rest_curvature`) and twists, expressed in the relaxed material
    // frames (stored as rest directors, so a reload with zero twist angles
    // has the same frames and energy). Replacing the curvatures by the
    // relaxed ones would drop the bending that holds the loops against
    // their neighbours (Sperl 2022 §8: a "slightly pre-tensed" rest state).
    let relaxed_points = fabric.points();
    let q = fabric.q.clone();
    fabric.rods.begin_iteration(&q);
    let mut rest = fabric.rods.rest().clone();
    rest.d1 = fabric.rods.material_directors(&q);
    let mut out = yarns
        .with_points(&relaxed_points)
        .map_err(|e| FabricError::Setup(e.to_string()))?;
    // Recorded with the shape: it is at rest under this material only.
    out.rest = Some(RestShape {
        material: Some(fabric_params.material()),
        ..rest.to_shape(&topo)
    });
    let contact = fabric.contact_stats();
    let energy = fabric.elastic_energy();
    let size = |y: &Yarns| y.bounds().map_or([0.0; 3], |b| b.size());
    Ok((
        out.clone(),
        RelaxIntoContactStats {
            length_scale: params.length_scale,
            stages: params.stages,
            rounds,
            newton_iterations: iterations,
            residual,
            contact,
            min_distance_ratio_seen: min_seen.min(contact.min_distance_ratio),
            size_before: size(yarns),
            size_after: size(&out),
            energy,
            seconds: t0.elapsed().as_secs_f64(),
        },
    ))
}

/// The axes (of x, y, z) the relaxation contracts a swatch along: a flat
/// swatch's two largest bounding-box sides, when the third is under a
/// quarter of the middle one (its thickness is the yarns' and does not
/// shrink); all three for a tube or any other shape, which shrinking every
/// rest length by the same factor contracts about as a whole (a uniform
/// scaling keeps the rods' angles, so it is the stress-free shape up to
/// the yarns' thickness).
fn contraction_axes(points: &[crate::geom::Vec3]) -> Vec<usize> {
    let Some(b) = crate::geom::bounds_of(points) else {
        return Vec::new();
    };
    let size = b.size();
    let mut axes = vec![0, 1, 2];
    axes.sort_by(|&a, &c| size[c].total_cmp(&size[a]));
    if size[axes[2]] < 0.25 * size[axes[1]] {
        axes.truncate(2);
    }
    axes
}

/// Scales the swatch along `axes` about its centroid by `ratio`, the
/// contraction the next stage's rest lengths ask for, so that its Newton
/// solve starts near the contracted state instead of moving a large
/// swatch's edges by centimetres. Kept only while every contact stays
/// above [`PREDICTION_MIN_DISTANCE_RATIO`].
fn predict_contraction(fabric: &mut Fabric, axes: &[usize], ratio: f64) {
    let n = fabric.num_vertices();
    if n == 0 {
        return;
    }
    fabric.try_prediction(PREDICTION_MIN_DISTANCE_RATIO, |q| {
        let mut centroid = [0.0; 3];
        for p in q[..3 * n].chunks_exact(3) {
            for &k in axes {
                centroid[k] += p[k] / n as f64;
            }
        }
        for p in q[..3 * n].chunks_exact_mut(3) {
            for &k in axes {
                p[k] = centroid[k] + ratio * (p[k] - centroid[k]);
            }
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_flat_swatch_contracts_in_its_plane_and_a_tube_as_a_whole() {
        let flat: Vec<[f64; 3]> = (0..20)
            .map(|i| {
                [
                    0.01 * (i % 5) as f64,
                    0.004 * (i / 5) as f64,
                    0.001 * (i % 2) as f64,
                ]
            })
            .collect();
        assert_eq!(contraction_axes(&flat), vec![0, 1]);
        // The same sheet standing in the x-z plane, longer along z.
        let standing: Vec<[f64; 3]> = flat.iter().map(|p| [p[0], p[2], 5.0 * p[1]]).collect();
        assert_eq!(contraction_axes(&standing), vec![2, 0]);
        let tube: Vec<[f64; 3]> = (0..40)
            .map(|i| {
                let a = i as f64 * 0.6;
                [0.05 * a.cos(), 0.002 * i as f64, 0.05 * a.sin()]
            })
            .collect();
        assert_eq!(contraction_axes(&tube).len(), 3);
        assert!(contraction_axes(&[]).is_empty());
    }
}
