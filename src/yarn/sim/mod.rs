//! The reference yarn-level simulator (YLS): polyline rods with stretching
//! and bending with rest curvature (HYLC §5.1), Kaldor yarn-yarn contact
//! (Leaf Eq. 9-10) with contact and global damping (Leaf Eq. 11-12),
//! gravity, pins and scripted handles, plane and sphere colliders (any
//! [`PointCollider`]), periodic tiles (Leaf §5), relaxation with local
//! rest-length scaling and the radius similarity transform (Leaf §6).
//!
//! Time integration is symplectic Euler with an adaptive step that bounds
//! every vertex's motion to `eps * r` per step (Leaf Eq. 2), so yarns cannot
//! pass through each other; see [`integrate`] for why.
//!
//! Pure: no files, no printing, no environment.

pub mod colliders;
pub mod contact;
pub mod damping;
pub mod handles;
pub mod integrate;
pub(crate) mod model;
pub mod params;
pub mod periodic;
pub mod rod;

pub use colliders::{PlaneCollider, PointCollider, SphereCollider};
pub use handles::{Handle, HandleMotion};
pub use integrate::{EnergyTerms, FrameStats, Timings, YarnSim};
pub use params::YarnSimParams;
pub use periodic::{relax, relax_periodic, tile_yarns, RelaxOptions, RelaxStats};

use crate::geom::GeomError;

/// Errors of the yarn-level simulator.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum YarnSimError {
    /// The yarns are not well formed.
    #[error("invalid yarns: {0}")]
    Geom(#[from] GeomError),
    /// The periodic tile is not well formed.
    #[error("invalid periodic tile: {0}")]
    Tile(String),
    /// A parameter or input value out of range.
    #[error("invalid {name}: {message}")]
    Param { name: &'static str, message: String },
    /// A handle description that does not fit the yarns.
    #[error("invalid handle: {0}")]
    Handle(String),
    /// The simulation diverged at time step `step` (1-based, counted over the
    /// simulator's life) at simulated time `time`; `vertex` is the worst vertex.
    #[error("yarn simulation diverged at step {step} (t = {time} s), worst vertex {vertex}: {reason}")]
    Diverged {
        step: u64,
        time: f64,
        vertex: usize,
        reason: String,
    },
}

/// Result of [`bench`] (what `knitvox bench yls --json` prints).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct BenchReport {
    pub vertices: usize,
    /// Steps timed (after warm-up).
    pub steps: usize,
    /// Median wall time per step divided by the vertex count (us).
    pub us_per_vertex_step: f64,
    /// Median step time times `steps_per_frame` (ms) for a 1/150 s frame.
    pub ms_per_frame: f64,
    /// Steps a 1/150 s frame needs at the median step size.
    pub steps_per_frame: f64,
    /// Median step size (s).
    pub dt_median: f64,
    /// Segment pairs in contact at the end.
    pub contact_pairs: usize,
    /// Candidate pairs in the reused list at the end.
    pub candidate_pairs: usize,
    /// Minimum over the run of closest non-adjacent segment distance / 2r.
    pub min_distance_ratio: f64,
    /// Contact list rebuilds during the timed steps.
    pub rebuilds: u64,
    /// Rayon threads.
    pub threads: usize,
}

/// Frame length of the benchmark and the VH comparison (s).
pub const BENCH_FRAME: f64 = 1.0 / 150.0;

/// Uniaxial stretch scene on the analytic knit swatch (about `vertices`
/// vertices; `yarn::analytic::knit_swatch_with_points`): the first and last
/// few vertices of every course are handles, the right ones move apart along
/// the courses at 30% of the width per second. Times `steps` steps after
/// `warmup` untimed ones.
pub fn bench(vertices: usize, steps: usize, warmup: usize) -> Result<BenchReport, YarnSimError> {
    let yarns = crate::yarn::analytic::knit_swatch_with_points(vertices.max(800));
    let mut sim = stretch_scene(&yarns, YarnSimParams::default(), 0.3, 1.0)?;
    for _ in 0..warmup {
        sim.step(f64::INFINITY)?;
    }
    let builds0 = sim.contacts.builds;
    let mut times = Vec::with_capacity(steps);
    let mut dts = Vec::with_capacity(steps);
    let mut min_ratio = f64::INFINITY;
    let mut active = 0;
    for _ in 0..steps.max(1) {
        let t = std::time::Instant::now();
        let info = sim.step(f64::INFINITY)?;
        times.push(t.elapsed().as_secs_f64());
        dts.push(info.dt);
        min_ratio = min_ratio.min(info.min_ratio);
        active = info.active_pairs;
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(|a, b| a.total_cmp(b));
        v[v.len() / 2]
    };
    let t_med = median(&mut times);
    let dt_med = median(&mut dts);
    let n = sim.num_vertices();
    let spf = (BENCH_FRAME / dt_med).ceil();
    Ok(BenchReport {
        vertices: n,
        steps: times.len(),
        us_per_vertex_step: t_med * 1e6 / n as f64,
        ms_per_frame: t_med * spf * 1e3,
        steps_per_frame: spf,
        dt_median: dt_med,
        contact_pairs: active,
        candidate_pairs: sim.contacts.pairs.len(),
        min_distance_ratio: min_ratio,
        rebuilds: sim.contacts.builds - builds0,
        threads: rayon::current_num_threads(),
    })
}

/// Uniaxial stretch along x: on every open curve the vertices within
/// `grip` of each end (in x, 3% of the swatch width) are clamped; the right
/// clamp moves at `strain / duration * width` m/s for `duration` seconds.
pub fn stretch_scene(
    yarns: &crate::geom::Yarns,
    params: YarnSimParams,
    strain: f64,
    duration: f64,
) -> Result<YarnSim, YarnSimError> {
    let mut sim = YarnSim::new(yarns, params)?;
    let b = yarns.bounds().ok_or(YarnSimError::Param {
        name: "yarns",
        message: "no points".into(),
    })?;
    let width = b.size()[0];
    let grip = 0.03 * width;
    let (mut left, mut right) = (Vec::new(), Vec::new());
    for (v, p) in yarns.points.iter().enumerate() {
        if p[0] <= b.min[0] + grip {
            left.push(v);
        } else if p[0] >= b.max[0] - grip {
            right.push(v);
        }
    }
    sim.pin(&left)?;
    sim.add_handle(Handle {
        vertices: right,
        motion: HandleMotion::Translate {
            velocity: [strain * width / duration, 0.0, 0.0],
            duration: Some(duration),
        },
        start_time: 0.0,
    })?;
    Ok(sim)
}
