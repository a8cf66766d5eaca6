//! Periodic tiles (Leaf §5), relaxation (free and periodic), local
//! rest-length scaling (Leaf §6.1) and the radius similarity transform (Leaf
//! §6.2, Eq. 3-4).
//!
//! The periodic model itself lives in [`super::model::Model::from_tile`]:
//! ghost (virtual) vertices are rigid lattice copies of real ones, rewritten
//! after every step (Leaf Algorithm 2); every element is owned by the tile
//! once (real-ghost contact pairs with weight 1/2, as each is also seen
//! mirrored), so the force on a real vertex is exactly its force in the
//! infinite tiling.

use super::integrate::YarnSim;
use super::params::YarnSimParams;
use super::YarnSimError;
use crate::geom::{Vec3, Yarns};
use crate::yarn::PeriodicTile;

/// Options of [`relax`] and [`relax_periodic`].
#[derive(Debug, Clone, PartialEq)]
pub struct RelaxOptions {
    /// Most time steps. Default 20_000.
    pub max_steps: u64,
    /// Converged when the largest vertex force falls below `force_tol` times
    /// the first step's (Leaf §3: |grad E_i| / |grad E_0| <= 0.1; default
    /// tighter, 1e-2).
    pub force_tol: f64,
    /// Global damping during relaxation (1/s), replacing the parameter's.
    /// Default 100 /s.
    pub damping: f64,
    /// Kinetic damping (dynamic relaxation): zero all velocities whenever the
    /// kinetic energy drops. Default true.
    pub kinetic_damping: bool,
    /// Per-segment rest-length factors (Leaf §6.1); `None`: all 1.
    pub rest_length_scale: Option<Vec<f64>>,
    /// Radius similarity factor gamma (Leaf §6.2): relax with radius
    /// `gamma r` and the Eq. 4 parameters, then scale positions (and the
    /// lattice) by `1 / gamma`; yarn length shrinks by gamma. Default 1.
    pub radius_scale: f64,
}

impl Default for RelaxOptions {
    fn default() -> Self {
        RelaxOptions {
            max_steps: 20_000,
            force_tol: 1e-2,
            damping: 100.0,
            kinetic_damping: true,
            rest_length_scale: None,
            radius_scale: 1.0,
        }
    }
}

/// What a relaxation did.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct RelaxStats {
    pub steps: u64,
    pub converged: bool,
    /// Largest vertex force at the first and last step (N).
    pub initial_residual: f64,
    pub final_residual: f64,
    /// Internal energy before and after (J), in the simulated (scaled) model.
    pub initial_energy: f64,
    pub final_energy: f64,
    /// Minimum over all steps of closest distance / (rA + rB).
    pub min_distance_ratio: f64,
    /// Mean and largest |l / l0 - 1| over segments at the end.
    pub mean_strain: f64,
    pub max_strain: f64,
    /// Simulated time (s).
    pub time: f64,
}

fn check_opts(o: &RelaxOptions) -> Result<(), YarnSimError> {
    if !(o.radius_scale > 0.0 && o.radius_scale.is_finite()) {
        return Err(YarnSimError::Param {
            name: "radius_scale",
            message: format!("{} is not a positive finite number", o.radius_scale),
        });
    }
    if !(o.force_tol >= 0.0) || !(o.damping >= 0.0 && o.damping.is_finite()) {
        return Err(YarnSimError::Param {
            name: "relax options",
            message: "force_tol and damping must be non-negative".into(),
        });
    }
    Ok(())
}

/// Radius-inflated copy of yarns (positions unchanged, Leaf §6.2).
fn inflate(y: &Yarns, gamma: f64) -> Yarns {
    let mut y = y.clone();
    for r in &mut y.radius {
        *r *= gamma;
    }
    if let Some(vr) = &mut y.vertex_radius {
        for r in vr {
            *r *= gamma;
        }
    }
    if let Some(ld) = &mut y.linear_density {
        // m' = gamma^-2 m on lengths l' = gamma l.
        for d in ld {
            *d /= gamma * gamma * gamma;
        }
    }
    y
}

fn sim_params(params: &YarnSimParams, o: &RelaxOptions) -> YarnSimParams {
    let mut p = params.radius_scaled(o.radius_scale);
    p.gravity = [0.0; 3];
    p.global_damping = o.damping;
    p
}

/// Largest vertex force (N) treated as zero by the relaxations.
pub const ABS_FORCE_TOL: f64 = 1e-12;

fn run(sim: &mut YarnSim, o: &RelaxOptions) -> Result<RelaxStats, YarnSimError> {
    let mut st = RelaxStats {
        min_distance_ratio: f64::INFINITY,
        initial_energy: sim.energy(),
        ..RelaxStats::default()
    };
    let mut prev_ke = 0.0;
    let mut r0 = 0.0;
    for k in 0..o.max_steps {
        let info = sim.step(f64::INFINITY)?;
        if k == 0 {
            r0 = info.residual;
            st.initial_residual = info.residual;
        }
        st.final_residual = info.residual;
        st.min_distance_ratio = st.min_distance_ratio.min(info.min_ratio);
        st.steps = k + 1;
        // Relative test (Leaf §3), or an absolute floor: forces below
        // ABS_FORCE_TOL are round-off for yarn stiffnesses of order 1 N (a
        // generated state with no contact and its own rest shape starts at
        // ~1e-19 N and is already at equilibrium).
        if info.residual <= o.force_tol * r0 || info.residual <= ABS_FORCE_TOL {
            st.converged = true;
            break;
        }
        if o.kinetic_damping {
            if info.kinetic < prev_ke {
                sim.v.iter_mut().for_each(|v| *v = [0.0; 3]);
                prev_ke = 0.0;
            } else {
                prev_ke = info.kinetic;
            }
        }
    }
    st.min_distance_ratio = st.min_distance_ratio.min(sim.min_distance_ratio());
    st.final_energy = sim.energy();
    let (mean, max) = sim.segment_strain();
    st.mean_strain = mean;
    st.max_strain = max;
    st.time = sim.time();
    Ok(st)
}

/// Relaxes free yarns to rest (no gravity, damped dynamics with kinetic
/// damping) and returns the relaxed yarns (scaled back by the radius
/// similarity factor) with statistics.
pub fn relax(
    yarns: &Yarns,
    params: &YarnSimParams,
    opts: &RelaxOptions,
) -> Result<(Yarns, RelaxStats), YarnSimError> {
    check_opts(opts)?;
    let g = opts.radius_scale;
    let y = inflate(yarns, g);
    let mut sim = YarnSim::with_rest_length_scale(
        &y,
        sim_params(params, opts),
        opts.rest_length_scale.as_deref(),
    )?;
    let st = run(&mut sim, opts)?;
    let mut out = yarns.clone();
    for (o, p) in out.points.iter_mut().zip(sim.positions()) {
        *o = [p[0] / g, p[1] / g, p[2] / g];
    }
    Ok((out, st))
}

/// Relaxes one periodic tile with periodic boundary conditions (fixed
/// lattice) and returns the relaxed tile (positions and lattice scaled back
/// by the radius similarity factor).
pub fn relax_periodic(
    tile: &PeriodicTile,
    params: &YarnSimParams,
    opts: &RelaxOptions,
) -> Result<(PeriodicTile, RelaxStats), YarnSimError> {
    check_opts(opts)?;
    let g = opts.radius_scale;
    let t = PeriodicTile {
        yarns: inflate(&tile.yarns, g),
        ..tile.clone()
    };
    let mut sim = YarnSim::new_periodic(
        &t,
        sim_params(params, opts),
        opts.rest_length_scale.as_deref(),
    )?;
    let st = run(&mut sim, opts)?;
    let mut out = tile.clone();
    for (o, p) in out.yarns.points.iter_mut().zip(sim.positions()) {
        *o = [p[0] / g, p[1] / g, p[2] / g];
    }
    for l in &mut out.lattice {
        *l = [l[0] / g, l[1] / g, l[2] / g];
    }
    Ok((out, st))
}

/// Tiles a periodic tile `ni x nj` times into free yarns, joining curves
/// across tile borders along `next`. Returns the yarns and the map
/// `index[(i * nj + j) * n + v]` from tile vertex `v` in copy (i, j) to its
/// vertex in the output.
pub fn tile_yarns(
    tile: &PeriodicTile,
    ni: usize,
    nj: usize,
) -> Result<(Yarns, Vec<usize>), YarnSimError> {
    tile.validate().map_err(YarnSimError::Tile)?;
    let y = &tile.yarns;
    y.validate()?;
    let nc = y.num_curves();
    let n = y.num_points();
    let [l0, l1] = tile.lattice;
    let mut prev = vec![(0usize, [0i32; 2]); nc];
    for (p, &(c, s)) in tile.next.iter().enumerate() {
        prev[c] = (p, s);
    }
    let inside = |i: i64, j: i64| i >= 0 && j >= 0 && (i as usize) < ni && (j as usize) < nj;
    let node = |c: usize, i: usize, j: usize| (i * nj + j) * nc + c;
    let mut visited = vec![false; ni * nj * nc];
    let mut out = Yarns::new();
    let mut vr: Vec<f64> = Vec::new();
    let mut dens: Vec<f64> = Vec::new();
    let mut index = vec![usize::MAX; ni * nj * n];
    let mut chains: Vec<(usize, usize, usize, bool)> = Vec::new();
    for pass in 0..2 {
        for i in 0..ni {
            for j in 0..nj {
                for c in 0..nc {
                    if visited[node(c, i, j)] {
                        continue;
                    }
                    let (_, ps) = prev[c];
                    let (pi, pj) = (i as i64 - ps[0] as i64, j as i64 - ps[1] as i64);
                    // Pass 0 starts open chains; pass 1 closes the cycles left.
                    if pass == 0 && inside(pi, pj) {
                        continue;
                    }
                    // Walk the chain.
                    let (mut cc, mut ci, mut cj) = (c, i, j);
                    let mut closed = false;
                    let mut pts: Vec<Vec3> = Vec::new();
                    let mut rads: Vec<f64> = Vec::new();
                    loop {
                        visited[node(cc, ci, cj)] = true;
                        let off = [
                            ci as f64 * l0[0] + cj as f64 * l1[0],
                            ci as f64 * l0[1] + cj as f64 * l1[1],
                            ci as f64 * l0[2] + cj as f64 * l1[2],
                        ];
                        for v in y.curve_range(cc) {
                            index[(ci * nj + cj) * n + v] = out.points.len() + pts.len();
                            let q = y.points[v];
                            pts.push([q[0] + off[0], q[1] + off[1], q[2] + off[2]]);
                            rads.push(y.radius_at(v));
                        }
                        let (nx, s) = tile.next[cc];
                        let (ni2, nj2) = (ci as i64 + s[0] as i64, cj as i64 + s[1] as i64);
                        if !inside(ni2, nj2) {
                            break;
                        }
                        let (ni2, nj2) = (ni2 as usize, nj2 as usize);
                        if visited[node(nx, ni2, nj2)] {
                            closed = (nx, ni2, nj2) == (c, i, j);
                            break;
                        }
                        (cc, ci, cj) = (nx, ni2, nj2);
                    }
                    out.push_curve(&pts, closed, y.radius[c]);
                    vr.extend_from_slice(&rads);
                    if let Some(d) = &y.linear_density {
                        dens.push(d[c]);
                    }
                    chains.push((c, i, j, closed));
                }
            }
        }
    }
    if y.vertex_radius.is_some() {
        out.vertex_radius = Some(vr);
    }
    if y.linear_density.is_some() {
        out.linear_density = Some(dens);
    }
    out.validate()?;
    Ok((out, index))
}

impl YarnSim {
    /// Mean and largest |l / l0 - 1| over stretch segments now.
    pub fn segment_strain(&self) -> (f64, f64) {
        let mut sum = 0.0;
        let mut max: f64 = 0.0;
        for s in &self.model.segs {
            let a = self.x[s.v[0] as usize];
            let b = self.x[s.v[1] as usize];
            let l = ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2) + (b[2] - a[2]).powi(2)).sqrt();
            let e = (l / s.l0 - 1.0).abs();
            sum += e;
            max = max.max(e);
        }
        (sum / self.model.segs.len().max(1) as f64, max)
    }
}
