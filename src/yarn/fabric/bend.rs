//! The pear-loop bending test of Sperl 2022 §4.3 (Peirce 1930): the swatch
//! of the stretch test, clamped at both ends, bent by bringing the clamps
//! together; for each inter-clamp distance `d` the aspect ratio `r = h / p`
//! of the loop (height `h`, width `p`).
//!
//! Rig (as in Sperl Fig. 4): both clamps hold the swatch vertically, side by
//! side at distance `d` (between the fabric's mid-surfaces), and the fabric
//! leaves both pointing down: the loop hangs below the clamps, gravity
//! along the loop's height. In knitvox coordinates the swatch lies in the
//! xy plane; the loop is formed in the plane of the test axis and +z, with
//! +z up (gravity `-g z`), and the swatch's +z face inside the loop (its
//! ends are lifted like a strip picked up from a table).
//!
//! Setup (not measured): the flat swatch is mapped, in increments small
//! enough for the rods' reference frames to follow, through circular arcs
//! of growing turn (clamps turning up) to a half circle, then through
//! two-radius "pear" curves (below) to the largest distance. From there the
//! clamps come together quasi-statically: at each distance the same
//! curve family predicts the move and Newton finds the equilibrium under
//! gravity with both clamps held.

use std::f64::consts::{FRAC_PI_2, FRAC_PI_3, PI};
use std::time::Instant;

use super::model::{Fabric, FabricError, FabricParams, Settle};
use super::rig::{along, Direction, Rig};
use super::stretch::{vertex_forces, RigFrame};
use crate::geom::{Vec3, Yarns};
use crate::yarn::statics::{EnergyTerm, GravityTerm};

/// Controls of [`bend_test`].
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct BendParams {
    /// Which swatch axis runs round the loop (the test direction).
    pub direction: Direction,
    /// First (largest) inter-clamp distance (m). Default 3.4 cm, the
    /// largest of Sperl §5.2's targets.
    pub max_distance: f64,
    /// Last (smallest) inter-clamp distance (m). Default 1.0 cm: Sperl's
    /// 0.3 cm is below the ~4 mm thickness of a knit of 1 mm yarns, whose
    /// legs would overlap at the clamps; it must exceed the swatch's
    /// thickness.
    pub min_distance: f64,
    /// Intervals from `max_distance` to `min_distance` (`steps + 1`
    /// distances). Default 6 (Sperl's 7 targets).
    pub steps: usize,
    /// Depth of each clamp (m). Default 8 mm.
    pub clamp_depth: f64,
    /// Gravity (m/s^2), down along the loop's height. Default 9.81.
    pub gravity: f64,
    /// Largest turn of a yarn tangent per setup increment (rad), so the
    /// rods' reference frames follow by parallel transport. Default 0.25.
    pub max_turn: f64,
    /// Equilibrium controls (force tolerance lowered to 1% of the heaviest
    /// vertex's weight when that is smaller).
    pub settle: Settle,
}

impl Default for BendParams {
    fn default() -> Self {
        BendParams {
            direction: Direction::Weft,
            max_distance: 0.034,
            min_distance: 0.010,
            steps: 6,
            clamp_depth: 8e-3,
            gravity: 9.81,
            max_turn: 0.25,
            settle: Settle::default(),
        }
    }
}

impl BendParams {
    /// Checks every value's range before any work (the swatch-dependent
    /// limits are checked by [`bend_test`]).
    pub fn check(&self) -> Result<(), FabricError> {
        let ok = self.min_distance.is_finite()
            && self.min_distance > 0.0
            && self.max_distance.is_finite()
            && self.max_distance > self.min_distance
            && (1..=1000).contains(&self.steps)
            && self.clamp_depth.is_finite()
            && self.clamp_depth > 0.0
            && self.gravity.is_finite()
            && self.gravity.abs() <= 1000.0
            && self.max_turn.is_finite()
            && self.max_turn >= 0.01
            && self.max_turn <= 1.0;
        if ok {
            Ok(())
        } else {
            Err(FabricError::Setup(format!(
                "bend test parameters out of range (0 < min distance < max distance, steps 1-1000, clamp depth > 0, |gravity| <= 1000, max turn in [0.01, 1] rad): {self:?}"
            )))
        }
    }
}

/// One clamp distance at equilibrium.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct BendPoint {
    /// Distance between the clamps' mid-planes (m).
    pub clamp_distance_m: f64,
    /// Loop height `h`: from the clamps' lower edge to the lowest yarn
    /// centreline point (m).
    pub height_m: f64,
    /// Loop width `p`: horizontal extent of the yarn centrelines below the
    /// clamps, along the test axis (m).
    pub width_m: f64,
    /// `h / p` (Sperl 2022 §4.3).
    pub aspect_ratio: f64,
    /// Force each clamp exerts on the swatch (N): [along the test axis,
    /// from the low-end clamp toward the other; up]. The two vertical
    /// parts carry the swatch's weight.
    pub low_clamp_force_n: [f64; 2],
    pub high_clamp_force_n: [f64; 2],
    /// Elastic energy, rods + contact (J).
    pub energy_j: f64,
    pub newton_iterations: usize,
    /// Largest free static force, gravity included (N).
    pub residual_n: f64,
    pub contacts_per_vertex: f64,
    pub min_distance_ratio: f64,
}

/// The whole test.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct BendResult {
    pub direction: Direction,
    /// Swatch extent across and along the test axis at rest (m).
    pub width_m: f64,
    pub length_m: f64,
    /// Free length between the clamps (m).
    pub gauge_m: f64,
    /// Extent of the yarns across the swatch plane, radii included (m).
    pub thickness_m: f64,
    pub vertices: usize,
    /// Weight of the swatch (N).
    pub weight_n: f64,
    /// Largest distance the setup curves reach with this gauge (half
    /// circle, `2 gauge / pi`, m).
    pub half_circle_distance_m: f64,
    /// Setup increments from the flat swatch to the first distance.
    pub setup_increments: usize,
    pub points: Vec<BendPoint>,
    /// Smallest contact distance ratio over every step (pull-through < 0.75).
    pub min_distance_ratio: f64,
    pub seconds: f64,
}

/// Where the swatch is on its way from flat to the loop: `lambda` in
/// [0, pi] is a circular arc of turn `lambda` over the gauge; beyond, the
/// two-radius pear curve of `beta = lambda - pi`.
#[derive(Debug, Clone, Copy)]
struct LoopCurve {
    depth: f64,
    gauge: f64,
    lambda: f64,
}

/// Largest `beta` of the pear family: the clamps meet at 60 degrees.
const BETA_MAX: f64 = FRAC_PI_3;

impl LoopCurve {
    /// Pieces of constant curvature over the gauge, `(length, curvature)`,
    /// and the heading at the gauge's start.
    ///
    /// Pear curve: from the low clamp heading down, an arc of radius `R`
    /// turning outward by `beta`, the bottom arc of radius `R` turning back
    /// by `pi + 2 beta`, and the mirror of the first arc into the high
    /// clamp. Equal radii and the symmetry give `R = gauge / (pi + 4 beta)`
    /// and `d = 2 R (2 cos beta - 1)`: a half circle at `beta = 0`, a
    /// closed neck at 60 degrees, in between a pear-shaped loop.
    fn pieces(&self) -> (Vec<(f64, f64)>, f64) {
        let g = self.gauge;
        if self.lambda <= PI {
            (vec![(g, self.lambda / g)], -0.5 * self.lambda)
        } else {
            let b = self.lambda - PI;
            let r = g / (PI + 4.0 * b);
            (
                vec![
                    (r * b, -1.0 / r),
                    (r * (PI + 2.0 * b), 1.0 / r),
                    (r * b, -1.0 / r),
                ],
                -FRAC_PI_2,
            )
        }
    }

    /// Distance between the clamps' mid-planes (m): the gauge's chord,
    /// horizontal by symmetry.
    fn distance(&self) -> f64 {
        self.walk(self.gauge).0[0]
    }

    /// Position (relative to the gauge start) and heading at arclength
    /// `s` of the gauge (clamped to it).
    fn walk(&self, s: f64) -> ([f64; 2], f64) {
        let (pieces, mut phi) = self.pieces();
        let mut p = [0.0, 0.0];
        let mut left = s.clamp(0.0, self.gauge);
        for (len, k) in pieces {
            let l = left.min(len);
            if k.abs() * l < 1e-12 {
                p[0] += l * phi.cos();
                p[1] += l * phi.sin();
            } else {
                p[0] += ((phi + k * l).sin() - phi.sin()) / k;
                p[1] -= ((phi + k * l).cos() - phi.cos()) / k;
            }
            phi += k * l;
            left -= l;
            if left <= 0.0 {
                break;
            }
        }
        (p, phi)
    }

    /// Mid-surface point `(u, v)` and unit normal (toward the inside of
    /// the loop) at arclength `sigma` from the low end of the swatch, with
    /// `u = 0` halfway between the clamps and `v = 0` at their lower edge
    /// (both ends of the gauge are at the same height by symmetry); the
    /// clamped ends continue the gauge's end tangents straight.
    fn frame(&self, sigma: f64) -> ([f64; 2], [f64; 2]) {
        let half = 0.5 * self.distance();
        let s = sigma - self.depth;
        let (p, phi) = if s < 0.0 {
            let phi0 = self.pieces().1;
            ([s * phi0.cos(), s * phi0.sin()], phi0)
        } else if s > self.gauge {
            let (end, phi1) = self.walk(self.gauge);
            let e = s - self.gauge;
            ([end[0] + e * phi1.cos(), end[1] + e * phi1.sin()], phi1)
        } else {
            self.walk(s)
        };
        ([p[0] - half, p[1]], [-phi.sin(), phi.cos()])
    }
}

/// The curve parameter `lambda` of the pear family whose clamp distance is
/// `d` (below the half circle's `2 gauge / pi`): bisection on the
/// decreasing `d(beta) = 2 gauge (2 cos beta - 1) / (pi + 4 beta)`.
fn lambda_for_distance(gauge: f64, d: f64) -> f64 {
    let dist = |beta: f64| 2.0 * gauge * (2.0 * beta.cos() - 1.0) / (PI + 4.0 * beta);
    let (mut lo, mut hi) = (0.0, BETA_MAX);
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if dist(mid) > d {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    PI + 0.5 * (lo + hi)
}

/// The swatch's material coordinates on the flat rig and where a loop
/// curve puts them.
struct Placement {
    axis: Vec3,
    transverse: Vec3,
    /// Per vertex: arclength from the low end, transverse coordinate,
    /// offset from the mid-plane (m).
    material: Vec<[f64; 3]>,
    /// World position of the loop origin (u = v = 0).
    origin: Vec3,
}

const UP: Vec3 = [0.0, 0.0, 1.0];

impl Placement {
    fn new(points: &[Vec3], rig: &Rig, z_mid: f64) -> Placement {
        let material = points
            .iter()
            .map(|&p| {
                [
                    along(p, rig.axis) - rig.s_min,
                    along(p, rig.transverse),
                    p[2] - z_mid,
                ]
            })
            .collect();
        // The flat "curve" (lambda = 0) puts every vertex back where it is.
        let u0 = rig.s_min + rig.clamp_depth + 0.5 * rig.gauge();
        let origin = [u0 * rig.axis[0], u0 * rig.axis[1], u0 * rig.axis[2] + z_mid];
        Placement {
            axis: rig.axis,
            transverse: rig.transverse,
            material,
            origin,
        }
    }

    /// World position of vertex `v` on `curve`.
    fn place(&self, curve: &LoopCurve, v: usize) -> Vec3 {
        let [sigma, t, zeta] = self.material[v];
        let (m, n) = curve.frame(sigma);
        let (u, w) = (m[0] + zeta * n[0], m[1] + zeta * n[1]);
        let mut x = self.origin;
        for c in 0..3 {
            x[c] += u * self.axis[c] + w * UP[c] + t * self.transverse[c];
        }
        x
    }

    /// Loop coordinates (along the axis from the middle between the
    /// clamps, height above their lower edge) of a world point.
    fn loop_coords(&self, x: Vec3) -> (f64, f64) {
        let d = [
            x[0] - self.origin[0],
            x[1] - self.origin[1],
            x[2] - self.origin[2],
        ];
        (along(d, self.axis), along(d, UP))
    }
}

/// Runs the pear-loop test on `yarns` (their stored rest shape is used;
/// without one the flat positions are the rest).
pub fn bend_test(
    yarns: &Yarns,
    fabric_params: &FabricParams,
    params: &BendParams,
    on_frame: &mut dyn FnMut(&RigFrame) -> Result<(), FabricError>,
) -> Result<BendResult, FabricError> {
    params.check()?;
    let t0 = Instant::now();
    let mut fabric = Fabric::new(yarns, fabric_params)?;
    let (axis, transverse) = params.direction.axes();
    let rig = Rig::new(&yarns.points, axis, transverse, params.clamp_depth);
    let gauge = rig.gauge();
    let (z_lo, z_hi) = yarns
        .points
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(p[2]), hi.max(p[2]))
        });
    let r_max = (0..yarns.num_points())
        .map(|v| yarns.radius_at(v))
        .fold(0.0, f64::max);
    let thickness = z_hi - z_lo + 2.0 * r_max;
    let half_circle = 2.0 * gauge / PI;
    if gauge <= 0.0 || params.max_distance >= half_circle {
        return Err(FabricError::Setup(format!(
            "the swatch's free length along the {} axis is {gauge:.4} m: a loop with its clamps {:.4} m apart needs more than pi/2 x that ({:.4} m)",
            params.direction.name(),
            params.max_distance,
            0.5 * PI * params.max_distance
        )));
    }
    if params.min_distance <= thickness {
        return Err(FabricError::Setup(format!(
            "the smallest clamp distance {:.4} m is not above the swatch's thickness {thickness:.4} m: the loop's legs would overlap at the clamps",
            params.min_distance
        )));
    }
    let place = Placement::new(&yarns.points, &rig, 0.5 * (z_lo + z_hi));
    let n = fabric.num_vertices();
    let curve = |lambda: f64| LoopCurve {
        depth: params.clamp_depth,
        gauge,
        lambda,
    };
    let set_positions = |fabric: &mut Fabric, from: &LoopCurve, to: &LoopCurve| {
        for v in 0..n {
            let (a, b) = (place.place(from, v), place.place(to, v));
            for c in 0..3 {
                fabric.q[3 * v + c] += b[c] - a[c];
            }
        }
    };

    // Setup: flat -> half circle (clamp ends turn by pi/2) -> first pear,
    // each increment followed by a frame update (parallel transport).
    let first = lambda_for_distance(gauge, params.max_distance);
    let arc_steps = (FRAC_PI_2 / params.max_turn).ceil() as usize;
    let pear_steps = (3.0 * (first - PI) / params.max_turn).ceil().max(1.0) as usize;
    let mut lambdas: Vec<f64> = (1..=arc_steps)
        .map(|k| PI * k as f64 / arc_steps as f64)
        .collect();
    lambdas.extend((1..=pear_steps).map(|k| PI + (first - PI) * k as f64 / pear_steps as f64));
    let mut at = curve(0.0);
    for &l in &lambdas {
        let next = curve(l);
        set_positions(&mut fabric, &at, &next);
        let q = fabric.q.clone();
        fabric.rods.begin_iteration(&q);
        at = next;
    }

    let clamped = rig.any_clamped();
    let mut fixed = vec![false; fabric.q.len()];
    fabric.clamp(&mut fixed, &clamped);
    let mut gravity = GravityTerm {
        mass: fabric.mass.clone(),
        g: [0.0, 0.0, -params.gravity],
    };
    let external: Vec<Vec3> = fabric
        .mass
        .iter()
        .map(|m| [0.0, 0.0, -m * params.gravity])
        .collect();
    // The loop's shape is the balance of bending and weight, so the weight
    // must be resolved.
    let settle = fabric.resolve_weights(&params.settle, params.gravity);

    let mut points = Vec::with_capacity(params.steps + 1);
    let mut min_ratio = f64::INFINITY;
    for k in 0..=params.steps {
        let d = params.max_distance
            - (params.max_distance - params.min_distance) * k as f64 / params.steps as f64;
        let next = curve(lambda_for_distance(gauge, d));
        set_positions(&mut fabric, &at, &next);
        at = next;
        let stage = format!("bend, clamps {d:.4} m apart");
        let st = {
            let mut extra: [&mut dyn EnergyTerm; 1] = [&mut gravity];
            fabric.settle(&mut extra, &fixed, &settle, &stage)?
        };
        settle.require(&st, &stage)?;
        let g = {
            let mut extra: [&mut dyn EnergyTerm; 1] = [&mut gravity];
            fabric.gradient(&mut extra).1
        };
        let reactions = vertex_forces(&g, &clamped);
        let x = fabric.points();
        let (height, width) = loop_size(&place, &x);
        let aspect_ratio = height / width;
        if !(aspect_ratio.is_finite() && aspect_ratio > 0.0) {
            return Err(FabricError::NoEquilibrium(format!(
                "{stage}: no loop (height {height:.4e} m, width {width:.4e} m)"
            )));
        }
        let clamp_force = |mask: &[bool]| {
            reactions
                .iter()
                .zip(mask)
                .filter(|(_, m)| **m)
                .fold([0.0, 0.0], |s, (f, _)| {
                    [s[0] + along(*f, axis), s[1] + along(*f, UP)]
                })
        };
        let energy = fabric.elastic_energy();
        let cst = fabric.contact_stats();
        min_ratio = min_ratio
            .min(st.min_distance_ratio)
            .min(cst.min_distance_ratio);
        points.push(BendPoint {
            clamp_distance_m: d,
            height_m: height,
            width_m: width,
            aspect_ratio,
            low_clamp_force_n: clamp_force(&rig.low),
            high_clamp_force_n: clamp_force(&rig.high),
            energy_j: energy,
            newton_iterations: st.newton_iterations,
            residual_n: st.residual,
            contacts_per_vertex: cst.contacts_per_vertex,
            min_distance_ratio: cst.min_distance_ratio,
        });
        on_frame(&RigFrame {
            index: k,
            parameter: d,
            points: &x,
            energy,
            reactions,
            external: external.clone(),
        })?;
    }
    Ok(BendResult {
        direction: params.direction,
        width_m: rig.mid_width(&yarns.points, 0.0),
        length_m: rig.s_max - rig.s_min,
        gauge_m: gauge,
        thickness_m: thickness,
        vertices: n,
        weight_n: fabric.mass.iter().sum::<f64>() * params.gravity,
        half_circle_distance_m: half_circle,
        setup_increments: lambdas.len(),
        points,
        min_distance_ratio: min_ratio,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// Loop height (clamps' lower edge to the lowest centreline point) and
/// width (extent along the axis of the centrelines below the clamps).
fn loop_size(place: &Placement, x: &[Vec3]) -> (f64, f64) {
    let mut low = 0.0f64;
    let (mut u_lo, mut u_hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for &p in x {
        let (u, v) = place.loop_coords(p);
        low = low.min(v);
        if v < 0.0 {
            u_lo = u_lo.min(u);
            u_hi = u_hi.max(u);
        }
    }
    (-low, (u_hi - u_lo).max(0.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn curve(lambda: f64) -> LoopCurve {
        LoopCurve {
            depth: 0.008,
            gauge: 0.084,
            lambda,
        }
    }

    #[test]
    fn flat_curve_is_the_identity_and_the_half_circle_stands_on_its_clamps() {
        let c = curve(0.0);
        let (p, n) = c.frame(0.03);
        assert!((p[0] - (0.03 - 0.008 - 0.042)).abs() < 1e-12 && p[1].abs() < 1e-12);
        assert!(n[0].abs() < 1e-12 && (n[1] - 1.0).abs() < 1e-12);
        let h = curve(PI);
        assert!((h.distance() - 2.0 * 0.084 / PI).abs() < 1e-12);
        // The clamped ends hang straight above the gauge's ends.
        let (low, _) = h.frame(0.0);
        let (high, _) = h.frame(0.1);
        assert!((low[0] + 0.084 / PI).abs() < 1e-12 && (low[1] - 0.008).abs() < 1e-12);
        assert!((high[0] - 0.084 / PI).abs() < 1e-12 && (high[1] - 0.008).abs() < 1e-12);
        // The bottom of the half circle.
        let (bottom, nb) = h.frame(0.008 + 0.042);
        assert!(bottom[0].abs() < 1e-12 && (bottom[1] + 0.084 / PI).abs() < 1e-12);
        assert!(nb[0].abs() < 1e-12 && (nb[1] - 1.0).abs() < 1e-12);
    }

    #[test]
    fn pear_curves_close_at_the_distance_they_are_solved_for() {
        for d in [0.034, 0.02, 0.01, 0.003] {
            let c = curve(lambda_for_distance(0.084, d));
            assert!((c.distance() - d).abs() < 1e-9, "{d} -> {}", c.distance());
            // Symmetric: both gauge ends at the clamps' lower edge, the end
            // tangent pointing up.
            let (end, phi) = c.walk(0.084);
            assert!(end[1].abs() < 1e-12, "{end:?}");
            assert!((phi - FRAC_PI_2).abs() < 1e-12, "{phi}");
            // Unit normals; arclength preserved (chord of a small step).
            let (a, _) = c.frame(0.03);
            let (b, nb) = c.frame(0.03 + 1e-6);
            let l = ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2)).sqrt();
            assert!((l - 1e-6).abs() < 1e-12, "{l}");
            assert!((nb[0].hypot(nb[1]) - 1.0).abs() < 1e-12);
        }
    }
}
