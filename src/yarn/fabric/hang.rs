//! Hanging: the swatch held by a clamp along its top edge (largest y) under
//! gravity (-y). It settles to equilibrium, then runs implicit-Euler steps
//! from rest to show that it stays there (a knit that slides apart keeps
//! moving).

use std::time::Instant;

use super::model::{Fabric, FabricError, FabricParams, Settle};
use super::rig::Rig;
use super::stretch::{vertex_forces, RigFrame};
use crate::geom::Yarns;
use crate::yarn::statics::{EnergyTerm, GravityTerm};

/// Controls of [`hang_test`].
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct HangParams {
    /// Depth of the top clamp (m). Default 8 mm.
    pub clamp_depth: f64,
    /// Gravity (m/s^2). Default 9.81.
    pub gravity: f64,
    /// Equilibrium controls (the force tolerance is lowered to 1% of the
    /// heaviest vertex's weight when that is smaller).
    pub settle: Settle,
    /// Implicit-Euler time after settling (s). Default 0.2.
    pub watch_time: f64,
    /// Its step (s). Default 0.01.
    pub dt: f64,
}

impl HangParams {
    /// Implicit-Euler steps watched after settling (one frame each).
    pub fn watch_steps(&self) -> usize {
        (self.watch_time / self.dt).round() as usize
    }
}

impl Default for HangParams {
    fn default() -> Self {
        HangParams {
            clamp_depth: 8e-3,
            gravity: 9.81,
            settle: Settle::default(),
            watch_time: 0.2,
            dt: 0.01,
        }
    }
}

/// What hanging did.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct HangResult {
    /// Drop of the lowest point / swatch height.
    pub sag_ratio: f64,
    /// Fastest vertex at the end of the watch (m/s).
    pub max_speed_m_s: f64,
    pub height_m: f64,
    pub width_m: f64,
    /// Weight of the swatch (N) and the clamp's vertical force (N).
    pub weight_n: f64,
    pub clamp_force_n: f64,
    pub newton_iterations: usize,
    pub residual_n: f64,
    pub min_distance_ratio: f64,
    pub seconds: f64,
}

impl HangParams {
    /// Checks every value's range before any work.
    pub fn check(&self) -> Result<(), FabricError> {
        let ok = self.clamp_depth.is_finite()
            && self.clamp_depth > 0.0
            && self.gravity.is_finite()
            && self.gravity.abs() <= 1000.0
            && self.dt.is_finite()
            && self.dt > 0.0
            && self.watch_time.is_finite()
            && self.watch_time >= 0.0
            && self.watch_time / self.dt <= 10_000.0;
        if ok {
            Ok(())
        } else {
            Err(FabricError::Setup(format!(
                "hang test parameters out of range (clamp depth > 0, |gravity| <= 1000, dt > 0, at most 10000 steps): {self:?}"
            )))
        }
    }
}

/// Hangs `yarns` (with their stored rest shape) by the top edge.
pub fn hang_test(
    yarns: &Yarns,
    fabric_params: &FabricParams,
    params: &HangParams,
    on_frame: &mut dyn FnMut(&RigFrame) -> Result<(), FabricError>,
) -> Result<HangResult, FabricError> {
    params.check()?;
    let t0 = Instant::now();
    let mut fabric = Fabric::new(yarns, fabric_params)?;
    let rig = Rig::new(
        &yarns.points,
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        params.clamp_depth,
    );
    let mut fixed = vec![false; fabric.q.len()];
    fabric.clamp(&mut fixed, &rig.high);
    let n = fabric.num_vertices();
    let mut gravity = GravityTerm {
        mass: fabric.mass.clone(),
        g: [0.0, -params.gravity, 0.0],
    };
    let external: Vec<_> = fabric
        .mass
        .iter()
        .map(|m| [0.0, -m * params.gravity, 0.0])
        .collect();
    let y_low0 = rig.s_min;
    let height = rig.s_max - rig.s_min;
    let settle = fabric.resolve_weights(&params.settle, params.gravity);
    let st = {
        let mut extra: [&mut dyn EnergyTerm; 1] = [&mut gravity];
        fabric.settle(&mut extra, &fixed, &settle, "hanging")?
    };
    settle.require(&st, "hanging")?;
    // One equilibrium frame to the writer; returns the clamp reactions.
    let mut emit = |fabric: &mut Fabric,
                    gravity: &mut GravityTerm,
                    index: usize|
     -> Result<Vec<crate::geom::Vec3>, FabricError> {
        let mut extra: [&mut dyn EnergyTerm; 1] = [gravity];
        let (_, g) = fabric.gradient(&mut extra);
        let reactions = vertex_forces(&g, &rig.high);
        let x = fabric.points();
        on_frame(&RigFrame {
            index,
            parameter: index as f64 * params.dt,
            points: &x,
            energy: fabric.elastic_energy(),
            reactions: reactions.clone(),
            external: external.clone(),
        })?;
        Ok(reactions)
    };
    let reactions = emit(&mut fabric, &mut gravity, 0)?;
    let clamp_force_n: f64 = reactions.iter().map(|f| f[1]).sum::<f64>().abs();
    let steps = params.watch_steps();
    let mut prev = fabric.q[..3 * n].to_vec();
    let mut max_speed: f64 = 0.0;
    for k in 0..steps {
        let cur = {
            let mut extra: [&mut dyn EnergyTerm; 1] = [&mut gravity];
            let stage = format!("hanging, step {k}");
            fabric.implicit_euler_step(&prev, params.dt, &mut extra, &fixed, &stage)?
        };
        max_speed = (0..n)
            .map(|v| {
                let d: f64 = (0..3)
                    .map(|c| (fabric.q[3 * v + c] - cur[3 * v + c]).powi(2))
                    .sum();
                d.sqrt() / params.dt
            })
            .fold(0.0, f64::max);
        prev = cur;
        emit(&mut fabric, &mut gravity, k + 1)?;
    }
    let x = fabric.points();
    let y_low = x.iter().map(|p| p[1]).fold(f64::INFINITY, f64::min);
    let cst = fabric.contact_stats();
    Ok(HangResult {
        sag_ratio: (y_low0 - y_low) / height,
        max_speed_m_s: max_speed,
        height_m: height,
        width_m: rig.mid_width(&yarns.points, 0.0),
        weight_n: fabric.mass.iter().sum::<f64>() * params.gravity,
        clamp_force_n,
        newton_iterations: st.newton_iterations,
        residual_n: st.residual,
        min_distance_ratio: st.min_distance_ratio.min(cst.min_distance_ratio),
        seconds: t0.elapsed().as_secs_f64(),
    })
}
