//! Benchmark and test scenes of the yarn-level simulator: the analytic
//! plain-weave swatch and the timed stretch that `knitvox bench yls` runs.

use super::{Handle, HandleMotion, YarnSim, YarnSimError, YarnSimParams};

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
    /// `2 contact_pairs / vertices`: a speed figure counts only with the
    /// contacts engaged (a relaxed knit has about 0.5-2).
    pub contacts_per_vertex: f64,
    /// Candidate pairs in the reused list at the end.
    pub candidate_pairs: usize,
    /// Minimum over the run of closest non-adjacent segment distance / 2r.
    pub min_distance_ratio: f64,
    /// Contact list rebuilds during the timed steps.
    pub rebuilds: u64,
    /// Median force evaluation (rods + contact + gather) per vertex (us).
    pub forces_us_per_vertex_step: f64,
    /// Mean time of one contact-pair rebuild (ms).
    pub rebuild_ms: f64,
    /// Mean wall time of the whole frames run (ms), when any were run.
    pub ms_per_frame_measured: Option<f64>,
    /// Minimum distance ratio over those frames.
    pub frames_min_distance_ratio: Option<f64>,
    /// Rayon threads.
    pub threads: usize,
}

/// Frame length of the benchmark and the VH comparison (s).
pub const BENCH_FRAME: f64 = 1.0 / 150.0;

/// Which analytic swatch [`bench`] runs on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum BenchGeometry {
    /// `yarn::analytic::knit_swatch_with_points`: unrelaxed stand-in knit
    /// whose courses start interpenetrating (contact pushes them apart and
    /// they end up out of contact), so it times a mostly contact-free run.
    KnitSwatch,
    /// [`plain_weave_swatch`] with both yarn families clamped at their ends:
    /// every crossing is in contact and pressed during the stretch (the
    /// contact-active case the VH / Leaf figures refer to).
    PlainWeave,
}

/// Options of [`bench`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BenchOptions {
    /// Target vertex count. Default 22_000 (VH Table 1 rib, 66K DOFs).
    pub vertices: usize,
    /// Timed steps. Default 200.
    pub steps: usize,
    /// Untimed steps before timing. Default 20.
    pub warmup: usize,
    /// Default [`BenchGeometry::PlainWeave`].
    pub geometry: BenchGeometry,
    /// Whole 1/150 s frames to run (and time) after the timed steps.
    /// Default 0.
    pub frames: usize,
}

impl Default for BenchOptions {
    fn default() -> Self {
        BenchOptions {
            vertices: 22_000,
            steps: 200,
            warmup: 20,
            geometry: BenchGeometry::PlainWeave,
            frames: 0,
        }
    }
}

/// An analytic plain weave: `n` warps along x and `n` wefts along y,
/// `spacing` apart, crimp amplitude `amp` (crossings `2 amp` apart),
/// `per` points per spacing, yarn radius `radius` (all m). Unrelaxed stand-in
/// for benchmarks and tests until `yarn::pattern` exists.
pub fn plain_weave_swatch(
    n: usize,
    spacing: f64,
    amp: f64,
    per: usize,
    radius: f64,
) -> crate::geom::Yarns {
    let pi = std::f64::consts::PI;
    let z = |x: f64, j: usize| amp * (pi * (x / spacing - 0.5) + pi * j as f64).cos();
    let mut y = crate::geom::Yarns::new();
    let m = n * per + 1;
    for j in 0..n {
        let pts: Vec<crate::geom::Vec3> = (0..m)
            .map(|k| {
                let x = k as f64 * spacing / per as f64;
                [x, (j as f64 + 0.5) * spacing, z(x, j)]
            })
            .collect();
        y.push_curve(&pts, false, radius);
    }
    for i in 0..n {
        let pts: Vec<crate::geom::Vec3> = (0..m)
            .map(|k| {
                let yy = k as f64 * spacing / per as f64;
                [(i as f64 + 0.5) * spacing, yy, -z(yy, i)]
            })
            .collect();
        y.push_curve(&pts, false, radius);
    }
    y
}

/// Uniaxial 30% stretch scene (over 1 s) with the default parameters, timed
/// per step: the first and last 3% (in x) of the swatch are clamped and the
/// right clamp moves (see [`stretch_scene`]); on the weave the weft ends are
/// pinned too.
pub fn bench(opts: &BenchOptions) -> Result<BenchReport, YarnSimError> {
    let r = 4e-4;
    let yarns = match opts.geometry {
        BenchGeometry::KnitSwatch => {
            crate::yarn::analytic::knit_swatch_with_points(opts.vertices.max(800))
        }
        BenchGeometry::PlainWeave => {
            // Crossings start 3% inside contact distance, so contact is active
            // from the first step and stays pressed by the clamps.
            let per = 5;
            let n = ((opts.vertices as f64 / (2.0 * per as f64)).sqrt().round() as usize).max(2);
            plain_weave_swatch(n, 4.0 * r, 0.97 * r, per, r)
        }
    };
    bench_yarns(&yarns, opts.geometry == BenchGeometry::PlainWeave, opts)
}

/// [`bench`] on given yarns (e.g. a knit tile read by `io` and tiled): the
/// 30% stretch scene of [`stretch_scene`] over 1 s; with `pin_y_ends` the
/// vertices at the smallest and largest y are pinned too.
pub fn bench_yarns(
    yarns: &crate::geom::Yarns,
    pin_y_ends: bool,
    opts: &BenchOptions,
) -> Result<BenchReport, YarnSimError> {
    let mut sim = stretch_scene(yarns, YarnSimParams::default(), 0.3, 1.0)?;
    if pin_y_ends {
        let b = yarns.bounds().ok_or(YarnSimError::Param {
            name: "yarns",
            message: "no points".into(),
        })?;
        let ends: Vec<usize> = (0..yarns.num_points())
            .filter(|&v| {
                let y = yarns.points[v][1];
                !sim.is_handled(v) && (y <= b.min[1] + 1e-12 || y >= b.max[1] - 1e-12)
            })
            .collect();
        sim.pin(&ends)?;
    }
    for _ in 0..opts.warmup {
        sim.step(f64::INFINITY)?;
    }
    let steps = opts.steps.max(1);
    let builds0 = sim.contacts.builds;
    let mut times = Vec::with_capacity(steps);
    let mut dts = Vec::with_capacity(steps);
    let mut min_ratio = f64::INFINITY;
    let mut active = 0;
    let mut force_times = Vec::with_capacity(steps);
    let mut build_time = 0.0;
    for _ in 0..steps {
        let t = std::time::Instant::now();
        let info = sim.step(f64::INFINITY)?;
        times.push(t.elapsed().as_secs_f64());
        force_times.push(info.t_force);
        build_time += info.t_build;
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
    let f_med = median(&mut force_times);
    let n = sim.num_vertices();
    let rebuilds = sim.contacts.builds - builds0;
    let (mut measured, mut frames_ratio) = (None, None);
    if opts.frames > 0 {
        let t = std::time::Instant::now();
        let mut m = f64::INFINITY;
        for _ in 0..opts.frames {
            m = m.min(sim.advance(BENCH_FRAME)?.min_distance_ratio);
        }
        measured = Some(t.elapsed().as_secs_f64() * 1e3 / opts.frames as f64);
        frames_ratio = Some(m);
    }
    let spf = (BENCH_FRAME / dt_med).ceil();
    Ok(BenchReport {
        vertices: n,
        steps,
        us_per_vertex_step: t_med * 1e6 / n as f64,
        ms_per_frame: t_med * spf * 1e3,
        steps_per_frame: spf,
        dt_median: dt_med,
        contact_pairs: active,
        contacts_per_vertex: 2.0 * active as f64 / n.max(1) as f64,
        candidate_pairs: sim.contacts.pairs.len(),
        min_distance_ratio: min_ratio,
        rebuilds,
        forces_us_per_vertex_step: f_med * 1e6 / n as f64,
        rebuild_ms: if rebuilds > 0 {
            build_time * 1e3 / rebuilds as f64
        } else {
            0.0
        },
        ms_per_frame_measured: measured,
        frames_min_distance_ratio: frames_ratio,
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
