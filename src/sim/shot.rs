//! The time loop of a shot: PD steps on a fixed schedule of frames, with
//! pins and colliders updated before every step and a callback at every
//! frame. What the shot is (placement, pins, colliders, a character) and
//! where its frames go belong to the caller (`pipeline::simulate`).
//!
//! Time: step `s` (1-based) ends at shot time `t0 + s dt` with `t0 = -preroll_steps dt`;
//! frame `k` (0 = the first frame, shot time 0) is reached after
//! `preroll_steps + k steps_per_frame` steps.

use super::contact::{EmbeddedPoints, NodeProjector, PointProjector};

/// The contacts of one step of the loop: node projections, or embedded
/// points and what they must stay out of (`PdSolver::step_with_point_contacts`).
pub trait StepContacts: NodeProjector {
    /// The embedded points the contacts act on instead of the nodes, and
    /// their projector; None (the default): the nodes.
    fn points(&self) -> Option<(&EmbeddedPoints, &dyn PointProjector)> {
        None
    }
}

impl StepContacts for super::contact::NoContact {}
impl StepContacts for super::collide::ColliderSet {}
use super::pd::{PdSolver, StepStats};
use super::SimError;
use crate::geom::Vec3;
use std::time::Instant;

/// When the steps and frames of a shot fall.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Schedule {
    /// Time step (s).
    pub dt: f64,
    /// Steps before the first frame (pre-roll).
    pub preroll_steps: usize,
    /// Steps per frame interval (at least 1).
    pub steps_per_frame: usize,
    /// Frame intervals after the first frame (last frame - first frame).
    pub frame_intervals: usize,
}

impl Schedule {
    /// Steps of the whole shot, pre-roll included (None on overflow).
    pub fn total_steps(&self) -> Option<usize> {
        self.frame_intervals
            .checked_mul(self.steps_per_frame)?
            .checked_add(self.preroll_steps)
    }

    /// Shot time (s) at the start of the loop (before the pre-roll).
    pub fn t0(&self) -> f64 {
        -(self.preroll_steps as f64) * self.dt
    }

    /// Shot time (s) after `s` steps.
    pub fn time(&self, s: usize) -> f64 {
        self.t0() + s as f64 * self.dt
    }

    /// The frame (0-based from the first) that `s` steps end on, if any.
    pub fn frame_at(&self, s: usize) -> Option<usize> {
        let k = s.checked_sub(self.preroll_steps)?;
        (k % self.steps_per_frame == 0).then_some(k / self.steps_per_frame)
    }

    /// The frame (0-based from the first) that step `s` leads up to.
    pub fn frame_of_step(&self, s: usize) -> usize {
        s.saturating_sub(self.preroll_steps)
            .div_ceil(self.steps_per_frame)
    }
}

/// Statistics of a loop.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LoopStats {
    /// Steps taken.
    pub steps: usize,
    /// Wall time of each step (ms).
    pub step_ms: Vec<f64>,
    /// Sum of the PD iterations over the steps.
    pub iterations_sum: u64,
    /// Most PD iterations of a step.
    pub iterations_max: u32,
    /// Steps that stopped at the iteration cap short of the tolerance
    /// ([`StepStats::capped`]).
    pub capped_steps: usize,
    /// Largest convergence measure at the end of a step
    /// ([`StepStats::convergence`], against `PdParams::tolerance`).
    pub convergence_max: f64,
    /// Largest implicit-Euler residual of a step (N).
    pub residual_max: f64,
    /// Largest end-of-step contact projection (m): how far a free node
    /// still inside a collider after the PD iterations was moved.
    pub correction_max: f64,
}

impl LoopStats {
    /// Adds one step.
    pub fn add(&mut self, st: &StepStats) {
        self.steps += 1;
        self.step_ms.push(st.ms);
        self.iterations_sum += st.iterations as u64;
        self.iterations_max = self.iterations_max.max(st.iterations);
        self.capped_steps += usize::from(st.capped);
        self.convergence_max = self.convergence_max.max(st.convergence);
        self.residual_max = self.residual_max.max(st.residual);
        self.correction_max = self.correction_max.max(st.max_projection);
    }

    /// Mean PD iterations per step (0 without steps).
    pub fn iterations_mean(&self) -> f64 {
        self.iterations_sum as f64 / self.steps.max(1) as f64
    }
}

/// Why a loop stopped.
#[derive(Debug)]
pub enum LoopError<E> {
    /// The solver diverged in step `step` (1-based), ending at shot time
    /// `time` (s), on the way to frame `frame` (0-based from the first).
    Diverged {
        step: usize,
        time: f64,
        frame: usize,
        source: SimError,
    },
    /// The update or the frame callback failed.
    Callback(E),
    /// `stop()` said so after `step` steps: the state passed in holds the
    /// positions and velocities after that step (checkpoint them).
    Stopped { step: usize },
}

/// What the frame callback of [`run`] gets.
#[derive(Debug)]
pub struct FrameState<'a, C> {
    /// The frame (0-based from the first frame of the schedule).
    pub frame: usize,
    /// Steps taken since the start of the loop (pre-roll included).
    pub step: usize,
    /// Node positions (m) and velocities (m/s) after `step` steps.
    pub x: &'a [Vec3],
    pub v: &'a [Vec3],
    /// The solver (for its warm start, [`PdSolver::warm_start`]).
    pub solver: &'a PdSolver,
    /// The contacts of the last step (`None` when the loop starts on a frame).
    pub contacts: Option<&'a C>,
    /// Wall time (ms) since the previous frame (or the start of the loop).
    pub ms: f64,
    /// Largest implicit-Euler residual (N) of the steps since the previous
    /// frame (NaN for none).
    pub residual: f64,
}

/// Runs the shot's steps `start_step + 1 ..= total` (0: from the start;
/// a checkpoint's step to resume): before step `s`, `update(s, t, pins)`
/// fills the pinned nodes' positions at its end time `t` (in the solver's
/// pinned order) and returns the contacts of the step (VH §8.5, projected in
/// the PD iterations); after every step that ends on a frame, and before the
/// first step when the loop starts on a frame, `on_frame` gets the state.
/// After every step (and its frame), `stop()` may end the loop with
/// [`LoopError::Stopped`]. `x`, `v`, `start_step` and the solver's warm
/// start ([`PdSolver::warm_start`]; its energy cache only saves an
/// evaluation) are the whole state of the loop: a checkpoint of them
/// resumes bit for bit. Returns the statistics of every step taken.
// The state, the schedule, where to start and the three callbacks are
// each the caller's; a struct of them would only be unpacked again.
#[allow(clippy::too_many_arguments)]
pub fn run<C, E>(
    solver: &mut PdSolver,
    x: &mut [Vec3],
    v: &mut [Vec3],
    schedule: &Schedule,
    start_step: usize,
    mut update: impl FnMut(usize, f64, &mut Vec<Vec3>) -> Result<C, E>,
    mut on_frame: impl FnMut(&FrameState<'_, C>) -> Result<(), E>,
    stop: &dyn Fn() -> bool,
) -> Result<LoopStats, LoopError<E>>
where
    C: StepContacts,
{
    let total = schedule.total_steps().ok_or_else(|| LoopError::Diverged {
        step: 0,
        time: schedule.t0(),
        frame: 0,
        source: SimError::Inconsistent("the shot has more steps than fit in memory".into()),
    })?;
    let mut stats = LoopStats {
        step_ms: Vec::with_capacity(total.saturating_sub(start_step).min(1 << 20)),
        ..LoopStats::default()
    };
    let mut since = Instant::now();
    let mut residual = f64::NAN;
    if let Some(k) = schedule.frame_at(start_step) {
        let state = FrameState {
            frame: k,
            step: start_step,
            x,
            v,
            solver,
            contacts: None,
            ms: 0.0,
            residual,
        };
        on_frame(&state).map_err(LoopError::Callback)?;
    }
    if stop() {
        return Err(LoopError::Stopped { step: start_step });
    }
    let mut pins = Vec::new();
    for s in start_step + 1..=total {
        let t = schedule.time(s);
        pins.clear();
        let contacts = update(s, t, &mut pins).map_err(LoopError::Callback)?;
        let st = match contacts.points() {
            Some((pts, pp)) => solver.step_with_point_contacts(x, v, &pins, pts, pp),
            None => solver.step_with_contacts(x, v, &pins, &contacts),
        }
        .map_err(|source| LoopError::Diverged {
            step: s,
            time: t,
            frame: schedule.frame_of_step(s),
            source,
        })?;
        stats.add(&st);
        residual = residual.max(st.residual);
        if let Some(k) = schedule.frame_at(s) {
            let state = FrameState {
                frame: k,
                step: s,
                x,
                v,
                solver,
                contacts: Some(&contacts),
                ms: since.elapsed().as_secs_f64() * 1e3,
                residual,
            };
            on_frame(&state).map_err(LoopError::Callback)?;
            since = Instant::now();
            residual = f64::NAN;
        }
        if s < total && stop() {
            return Err(LoopError::Stopped { step: s });
        }
    }
    Ok(stats)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::TetMesh;
    use crate::sim::contact::NoContact;
    use crate::sim::pd::PdParams;

    #[test]
    fn schedule_places_frames_after_the_preroll() {
        let s = Schedule {
            dt: 0.01,
            preroll_steps: 3,
            steps_per_frame: 2,
            frame_intervals: 2,
        };
        assert_eq!(s.total_steps(), Some(7));
        assert!((s.t0() + 0.03).abs() < 1e-15);
        let frames: Vec<_> = (0..=7).map(|k| s.frame_at(k)).collect();
        assert_eq!(
            frames,
            [None, None, None, Some(0), None, Some(1), None, Some(2)]
        );
        assert_eq!(s.frame_of_step(1), 0);
        assert_eq!(s.frame_of_step(4), 1);
        assert_eq!(s.frame_of_step(5), 1);
        assert_eq!(s.frame_of_step(6), 2);
    }

    /// A single 1 cm corner tet.
    fn one_tet() -> TetMesh {
        TetMesh {
            nodes: vec![
                [0.0, 0.0, 0.0],
                [0.01, 0.0, 0.0],
                [0.0, 0.01, 0.0],
                [0.0, 0.0, 0.01],
            ],
            tets: vec![[0, 1, 2, 3]],
        }
    }

    /// One free tet falling under gravity: the callbacks see every step and
    /// frame in order, and the positions of the frames are the solver's.
    #[test]
    fn loop_calls_back_in_order_and_counts_steps() {
        let mesh = one_tet();
        let schedule = Schedule {
            dt: 1.0 / 150.0,
            preroll_steps: 0,
            steps_per_frame: 3,
            frame_intervals: 2,
        };
        let params = PdParams {
            dt: schedule.dt,
            ..PdParams::default()
        };
        let mut solver = PdSolver::new(&mesh, &[1e-3; 4], &[1e3], &[1e3], &[], params).unwrap();
        let mut x = mesh.nodes.clone();
        let mut v = vec![[0.0; 3]; 4];
        let mut updates = Vec::new();
        let mut frames = Vec::new();
        let stats = run(
            &mut solver,
            &mut x,
            &mut v,
            &schedule,
            0,
            |s, t, _pins| {
                updates.push((s, t));
                Ok::<_, ()>(NoContact)
            },
            |f| {
                frames.push((f.frame, f.x[0][1], f.contacts.is_some()));
                Ok(())
            },
            &|| false,
        )
        .unwrap();
        assert_eq!(stats.steps, 6);
        assert_eq!(stats.step_ms.len(), 6);
        assert_eq!(
            updates.iter().map(|u| u.0).collect::<Vec<_>>(),
            [1, 2, 3, 4, 5, 6]
        );
        assert!((updates[5].1 - 6.0 / 150.0).abs() < 1e-12);
        assert_eq!(frames.iter().map(|f| f.0).collect::<Vec<_>>(), [0, 1, 2]);
        assert_eq!(frames[0], (0, 0.0, false));
        assert!(frames[1].2 && frames[2].2);
        // Falling: each frame lower than the one before.
        assert!(frames[1].1 < 0.0 && frames[2].1 < frames[1].1, "{frames:?}");
        assert_eq!(x[0][1], frames[2].1);
    }

    #[test]
    fn a_failing_update_stops_the_loop() {
        let mesh = one_tet();
        let schedule = Schedule {
            dt: 0.01,
            preroll_steps: 2,
            steps_per_frame: 1,
            frame_intervals: 3,
        };
        let mut solver = PdSolver::new(
            &mesh,
            &[1e-3; 4],
            &[1e3],
            &[1e3],
            &[],
            PdParams {
                dt: 0.01,
                ..PdParams::default()
            },
        )
        .unwrap();
        let mut x = mesh.nodes.clone();
        let mut v = vec![[0.0; 3]; 4];
        let mut seen = 0;
        let e = run(
            &mut solver,
            &mut x,
            &mut v,
            &schedule,
            0,
            |s, _, _| {
                if s == 3 {
                    Err("no pose")
                } else {
                    Ok(NoContact)
                }
            },
            |_| {
                seen += 1;
                Ok(())
            },
            &|| false,
        )
        .unwrap_err();
        assert!(matches!(e, LoopError::Callback("no pose")));
        // Frame 0 came after step 2; step 3 never ran.
        assert_eq!(seen, 1);
    }

    /// A loop stopped after some step and run again from that state (a
    /// fresh solver given the warm start, as a resumed process has) ends bit
    /// for bit where the uninterrupted loop ends; the resumed loop starts with the frame the
    /// state sits on.
    #[test]
    fn a_stopped_loop_resumes_bit_for_bit() {
        let mesh = one_tet();
        let schedule = Schedule {
            dt: 1.0 / 150.0,
            preroll_steps: 2,
            steps_per_frame: 3,
            frame_intervals: 3,
        };
        let params = PdParams {
            dt: schedule.dt,
            ..PdParams::default()
        };
        let solver = || PdSolver::new(&mesh, &[1e-3; 4], &[1e3], &[1e3], &[], params).unwrap();
        let pinless = |_: usize, _: f64, _: &mut Vec<Vec3>| Ok::<_, ()>(NoContact);
        let (mut x, mut v) = (mesh.nodes.clone(), vec![[0.0; 3]; 4]);
        run(
            &mut solver(),
            &mut x,
            &mut v,
            &schedule,
            0,
            pinless,
            |_| Ok(()),
            &|| false,
        )
        .unwrap();

        let (mut y, mut w) = (mesh.nodes.clone(), vec![[0.0; 3]; 4]);
        let last = std::cell::Cell::new(0);
        let mut stopped = solver();
        let e = run(
            &mut stopped,
            &mut y,
            &mut w,
            &schedule,
            0,
            |s, _, _| {
                last.set(s);
                Ok::<_, ()>(NoContact)
            },
            |_| Ok(()),
            &|| last.get() == 5,
        )
        .unwrap_err();
        assert!(matches!(e, LoopError::Stopped { step: 5 }), "{e:?}");
        let mut resumed = solver();
        resumed.set_warm_start(&stopped.warm_start()).unwrap();
        let mut frames = Vec::new();
        let stats = run(
            &mut resumed,
            &mut y,
            &mut w,
            &schedule,
            5,
            pinless,
            |f| {
                frames.push((f.frame, f.step, f.contacts.is_some()));
                Ok(())
            },
            &|| false,
        )
        .unwrap();
        assert_eq!(stats.steps, 6);
        assert_eq!(frames, [(1, 5, false), (2, 8, true), (3, 11, true)]);
        assert_eq!(x, y);
        assert_eq!(v, w);
        assert!(x[0][1] < 0.0);
    }
}
