//! The scale stage: a search over one common factor of the whole material
//! field before the stages of VH §6.3, for samples whose loss sees the
//! scale (frames with external forces).
//!
//! Why: a loaded frame's displacement goes roughly as `1/γ`, so the
//! linearized steps of the additive stages overshoot to negative `γ` when the
//! start is decades too stiff, and the line search and the
//! Levenberg-Marquardt term then shorten every step. Measured on a joint fit
//! of a stretch, a bend and a cantilever under gravity (10 x 10 stockinette,
//! 1,568 nodes): the uniform r = 1 stage used all its 62 iterations going
//! from 1.08e-3 to 2.15e-5 m³ and was still falling. A walk in factors of two
//! finds the decade in a handful of solves, each warm-started from the last
//! equilibrium (a continuation: a cantilever's Newton fails from a start
//! decades away), and a golden-section search on `ln c` refines it.
//! Without external forces the loss of a static frame does not depend on
//! the scale (Dirichlet equilibria depend only on ratios of `γ`), so the
//! stage is not run.

use std::time::Instant;

use super::gauss_newton::{SampleFit, StageReport};
use super::types::Evaluated;

/// Golden-section iterations after the walk (one solve each, after two to
/// start): the bracket of `ln c`, 2 ln 2 wide, shrinks to 0.618^9 of that,
/// within a factor 1.02 on `c`.
const REFINE_ITERATIONS: usize = 8;

/// Most doublings (or halvings) of the walk: 2^40 ≈ 1e12.
const MAX_WALK: usize = 40;

impl SampleFit<'_> {
    /// The best common factor `c` of `ev.gamma` (loss at `c γ`), with the
    /// stage report ("scale"). Trials whose equilibrium fails, or that take
    /// any `γ` below the floor, count as increases; `ev` is returned
    /// unchanged when no factor lowers the loss.
    pub(super) fn scale_stage(&self, ev: Evaluated) -> (Evaluated, StageReport) {
        let start = Instant::now();
        let mut rep = StageReport {
            name: "scale".into(),
            parameters: 1,
            losses: vec![ev.loss],
            stop: super::gauss_newton::StageStop::SearchDone,
            ..Default::default()
        };
        let base = ev.gamma.clone();
        let mut best = (0.0f64, ev);
        let step = std::f64::consts::LN_2;
        // The walk: the direction that lowers the loss (the first step
        // taken, best.0), while it does.
        for d in [step, -step] {
            if let Some(t) = self.try_scale(&base, d, &best.1, &mut rep) {
                if t.loss < best.1.loss {
                    best = (d, t);
                    break;
                }
            }
        }
        let direction = best.0;
        if direction != 0.0 {
            for _ in 1..MAX_WALK {
                let next = best.0 + direction;
                match self.try_scale(&base, next, &best.1, &mut rep) {
                    Some(t) if t.loss < best.1.loss => best = (next, t),
                    _ => break,
                }
            }
        }
        // The minimum of ln c lies within one step of the best point; the
        // trials keep the best as they go.
        let bracket = (best.0 - step, best.0 + step);
        let refined = crate::fit::golden::golden_section(bracket, REFINE_ITERATIONS, false, |x| {
            Ok::<_, std::convert::Infallible>(self.scale_loss(&base, x, &mut best, &mut rep))
        });
        let Ok(_) = refined;
        rep.final_residual = best.1.residual;
        rep.ms = start.elapsed().as_secs_f64() * 1e3;
        (best.1, rep)
    }

    /// The loss at `e^ln_c γ` (infinite when the trial fails); keeps it as
    /// the best when it is lower.
    fn scale_loss(
        &self,
        base: &[f64],
        ln_c: f64,
        best: &mut (f64, Evaluated),
        rep: &mut StageReport,
    ) -> f64 {
        match self.try_scale(base, ln_c, &best.1, rep) {
            Some(t) => {
                let loss = t.loss;
                if loss < best.1.loss {
                    *best = (ln_c, t);
                }
                loss
            }
            None => f64::INFINITY,
        }
    }

    /// Equilibria at `e^ln_c γ`, warm-started from `from`; records the trial.
    fn try_scale(
        &self,
        base: &[f64],
        ln_c: f64,
        from: &Evaluated,
        rep: &mut StageReport,
    ) -> Option<Evaluated> {
        rep.iterations += 1;
        let c = ln_c.exp();
        let gamma: Vec<f64> = base.iter().map(|g| g * c).collect();
        if !gamma
            .iter()
            .all(|g| g.is_finite() && *g >= self.params.gamma_floor)
        {
            return None;
        }
        let t = self.evaluate(&gamma, &from.xs).ok()?;
        rep.newton_iterations += t.newton;
        if t.loss < from.loss {
            rep.losses.push(t.loss);
            rep.methods.push("scale".into());
            if let Some(report) = self.progress {
                report(&super::types::FitProgress {
                    sample: self.sample.name.clone(),
                    stage: rep.name.clone(),
                    iteration: rep.iterations,
                    method: "scale".into(),
                    loss: t.loss,
                    ms: 0.0,
                    direction_ms: 0.0,
                    halvings: 0,
                });
            }
        }
        Some(t)
    }
}
