//! What a scene's motion is made of, read the same way off the yarn level's
//! frames and off a homogenized run's (its V2Y yarn positions): the yarns'
//! kinetic energy, the centre of mass's path, the support force (what,
//! besides gravity and the scene's mass damping, accelerates the centre of
//! mass: colliders and clamps), and the slip of the yarn vertices along the
//! colliders. A gap between the two runs then reads as energy, contact or
//! friction, not only as a distance.
//!
//! Both runs are measured by the same operator on the same yarn vertices
//! and lumped yarn masses, from their frames alone: velocities are
//! frame-differenced (`(y_k - y_{k-1}) / Δt` over each frame interval), so
//! the figures are those of motion sampled at the scene's frame rate. Pure.

use std::sync::Arc;

use crate::geom::vec3::{dot, norm, sub};
use crate::geom::Vec3;
use crate::io::plot;
use crate::yarn::sim::PointCollider;

/// A yarn vertex touches a collider when its signed distance is under
/// `(1 + CONTACT_SLACK)` times its yarn radius (both levels keep a touching
/// vertex about one radius outside).
pub const CONTACT_SLACK: f64 = 0.5;

/// The motion at one frame.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct MotionFrame {
    pub time: f64,
    /// `½ Σ m |Δy/Δt|²` over the interval ending at this frame (J); 0 at
    /// frame 0 (the rest state).
    pub kinetic_j: f64,
    /// Centre of mass (m).
    pub com: Vec3,
    /// Path length of the centre of mass from frame 0 to this frame (m).
    pub com_travel_m: f64,
    /// Support force at this frame (N): `M (v̄⁺ - v̄⁻) / Δt - M g + α M v`,
    /// with `v̄⁻`, `v̄⁺` the centre of mass's mean velocities over the
    /// intervals before and after it and `α` the scene's mass damping; None
    /// at the first and last frames.
    pub support_n: Option<Vec3>,
    /// Yarn vertices touching a collider ([`CONTACT_SLACK`]).
    pub contacts: usize,
    /// Mean slip path (m) of the touching vertices along the colliders from
    /// frame 0 to this frame: per interval, the mean over the vertices that
    /// touch the same collider at both its ends of the tangential part of
    /// their displacement relative to the collider's surface.
    pub slip_m: f64,
}

/// One run's motion, frame by frame, and its totals.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Motion {
    pub frames: Vec<MotionFrame>,
    /// Path length of the centre of mass over the run (m).
    pub com_travel_m: f64,
    /// Its fall: the last frame's centre of mass below the first's along
    /// gravity (m; 0 without gravity).
    pub com_drop_m: f64,
    pub peak_kinetic_j: f64,
    pub final_kinetic_j: f64,
    /// Mean slip path over the run (m).
    pub slip_m: f64,
    /// Largest support force over the frames (N).
    pub peak_support_n: f64,
    pub max_contacts: usize,
}

/// What a scene's frames are measured against: the yarns' lumped masses
/// (kg per vertex) and radii (m per vertex), gravity (m/s²), the scene's
/// mass damping (1/s) and its colliders.
pub struct MotionScene<'a> {
    pub masses: &'a [f64],
    pub radii: &'a [f64],
    pub gravity: Vec3,
    pub mass_damping: f64,
    pub colliders: &'a [Arc<dyn PointCollider>],
}

fn com(masses: &[f64], y: &[Vec3]) -> Vec3 {
    let m: f64 = masses.iter().sum::<f64>().max(f64::MIN_POSITIVE);
    let mut s = [0.0; 3];
    for (mi, p) in masses.iter().zip(y) {
        for c in 0..3 {
            s[c] += mi * p[c];
        }
    }
    s.map(|v| v / m)
}

/// The collider a vertex touches at time `t` (index), if any.
fn touching(scene: &MotionScene, p: Vec3, r: f64, t: f64) -> Option<(usize, Vec3)> {
    scene
        .colliders
        .iter()
        .enumerate()
        .map(|(i, c)| (i, c.signed_distance(p, t)))
        .filter(|(_, (d, _))| *d <= (1.0 + CONTACT_SLACK) * r)
        .min_by(|a, b| a.1 .0.total_cmp(&b.1 .0))
        .map(|(i, (_, n))| (i, n))
}

/// The motion of yarn frames `y` (one position per yarn vertex per frame)
/// at `times` (s). Frames must share the scene's vertex count.
pub fn measure(scene: &MotionScene, times: &[f64], y: &[&[Vec3]]) -> Motion {
    let nf = y.len().min(times.len());
    let total: f64 = scene.masses.iter().sum();
    let coms: Vec<Vec3> = (0..nf).map(|k| com(scene.masses, y[k])).collect();
    // Mean centre-of-mass velocity over interval k (frames k-1 .. k).
    let vbar = |k: usize| -> Vec3 {
        let dt = times[k] - times[k - 1];
        sub(coms[k], coms[k - 1]).map(|v| if dt > 0.0 { v / dt } else { 0.0 })
    };
    // The collider each vertex touches, per frame.
    let contact: Vec<Vec<Option<(usize, Vec3)>>> = (0..nf)
        .map(|k| {
            (0..y[k].len())
                .map(|v| touching(scene, y[k][v], scene.radii[v], times[k]))
                .collect()
        })
        .collect();
    let mut frames = Vec::with_capacity(nf);
    let (mut travel, mut slip) = (0.0, 0.0);
    for k in 0..nf {
        let mut kinetic = 0.0;
        if k > 0 {
            let dt = times[k] - times[k - 1];
            travel += norm(sub(coms[k], coms[k - 1]));
            let (mut slid, mut count) = (0.0, 0usize);
            for v in 0..y[k].len() {
                let d = sub(y[k][v], y[k - 1][v]);
                if dt > 0.0 {
                    kinetic += 0.5 * scene.masses[v] * dot(d, d) / (dt * dt);
                }
                if let (Some((a, _)), Some((b, n))) = (contact[k - 1][v], contact[k][v]) {
                    if a == b {
                        let tm = 0.5 * (times[k] + times[k - 1]);
                        let w = scene.colliders[a].velocity(y[k - 1][v], tm);
                        let rel: Vec3 = std::array::from_fn(|c| d[c] - w[c] * dt);
                        let dn = dot(rel, n);
                        let tangential: Vec3 = std::array::from_fn(|c| rel[c] - dn * n[c]);
                        slid += norm(tangential);
                        count += 1;
                    }
                }
            }
            if count > 0 {
                slip += slid / count as f64;
            }
        }
        let support_n = (k > 0 && k + 1 < nf).then(|| {
            let (vm, vp) = (vbar(k), vbar(k + 1));
            let dt = 0.5 * (times[k + 1] - times[k - 1]);
            let v: Vec3 = std::array::from_fn(|c| 0.5 * (vm[c] + vp[c]));
            std::array::from_fn(|c| {
                total * ((vp[c] - vm[c]) / dt.max(f64::MIN_POSITIVE) - scene.gravity[c])
                    + scene.mass_damping * total * v[c]
            })
        });
        frames.push(MotionFrame {
            time: times[k],
            kinetic_j: kinetic,
            com: coms[k],
            com_travel_m: travel,
            support_n,
            contacts: contact[k].iter().filter(|c| c.is_some()).count(),
            slip_m: slip,
        });
    }
    let g = norm(scene.gravity);
    let com_drop_m = match (coms.first(), coms.last()) {
        (Some(a), Some(b)) if g > 0.0 => dot(sub(*b, *a), scene.gravity) / g,
        _ => 0.0,
    };
    Motion {
        com_travel_m: travel,
        com_drop_m,
        peak_kinetic_j: frames.iter().map(|f| f.kinetic_j).fold(0.0, f64::max),
        final_kinetic_j: frames.last().map_or(0.0, |f| f.kinetic_j),
        slip_m: slip,
        peak_support_n: frames
            .iter()
            .filter_map(|f| f.support_n.map(norm))
            .fold(0.0, f64::max),
        max_contacts: frames.iter().map(|f| f.contacts).max().unwrap_or(0),
        frames,
    }
}

/// A homogenized run's motion against the yarn level's.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct MotionMatch {
    /// Largest distance between the two centres of mass over the frames,
    /// over the yarn level's centre-of-mass travel (0 is exact; None when
    /// the yarn level's centre of mass does not move).
    pub com_path_error: Option<f64>,
    /// Largest distance between the centres of mass (m).
    pub com_max_gap_m: f64,
    /// Centre-of-mass travel, homogenized over yarn level (1 is exact).
    pub com_travel_ratio: Option<f64>,
    /// Slip path, homogenized over yarn level; None when the yarn level
    /// does not slip.
    pub slip_ratio: Option<f64>,
    /// Peak kinetic energy, homogenized over yarn level.
    pub peak_kinetic_ratio: Option<f64>,
}

fn ratio(a: f64, b: f64) -> Option<f64> {
    (b > 0.0 && a.is_finite()).then(|| a / b)
}

/// How `ours` (a homogenized run) follows `truth` (the yarn level).
pub fn compare(truth: &Motion, ours: &Motion) -> MotionMatch {
    let gap = truth
        .frames
        .iter()
        .zip(&ours.frames)
        .map(|(a, b)| norm(sub(a.com, b.com)))
        .fold(0.0, f64::max);
    MotionMatch {
        com_path_error: ratio(gap, truth.com_travel_m),
        com_max_gap_m: gap,
        com_travel_ratio: ratio(ours.com_travel_m, truth.com_travel_m),
        // Under a micrometre of slip is no slip.
        slip_ratio: (truth.slip_m > 1e-6).then(|| ours.slip_m / truth.slip_m),
        peak_kinetic_ratio: ratio(ours.peak_kinetic_j, truth.peak_kinetic_j),
    }
}

/// The motion part of `validate`'s report: the yarn level's, the asset
/// material's and (when compared) the uniform material's, and how each
/// homogenized run follows the yarn level.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct MotionReport {
    pub yarn_level: Motion,
    pub homogenized: Motion,
    pub homogenized_match: MotionMatch,
    pub uniform: Option<Motion>,
    pub uniform_match: Option<MotionMatch>,
}

/// The report's line in words: where each centre of mass went and how far
/// the yarns slipped.
pub fn words(m: &MotionReport) -> String {
    let cm = |x: f64| format!("{:.2} cm", 100.0 * x);
    let mut s = format!(
        "motion: centre of mass travels {} at yarn level, {} homogenized (falls {} / {}; largest gap {}",
        cm(m.yarn_level.com_travel_m),
        cm(m.homogenized.com_travel_m),
        cm(m.yarn_level.com_drop_m),
        cm(m.homogenized.com_drop_m),
        cm(m.homogenized_match.com_max_gap_m),
    );
    if let Some(e) = m.homogenized_match.com_path_error {
        s += &format!(", {:.0}% of the yarn level's travel", 100.0 * e);
    }
    s += ")";
    if m.yarn_level.max_contacts > 0 || m.homogenized.max_contacts > 0 {
        s += &format!(
            "; slip along the colliders {} / {}; peak kinetic energy {:.3e} / {:.3e} J",
            cm(m.yarn_level.slip_m),
            cm(m.homogenized.slip_m),
            m.yarn_level.peak_kinetic_j,
            m.homogenized.peak_kinetic_j
        );
    }
    s
}

/// `motion.csv`: one row per frame, the yarn level's and the homogenized
/// run's quantities side by side (SI units; empty where undefined).
pub fn csv(m: &MotionReport) -> String {
    let mut out = String::from(
        "frame,time_s,kinetic_j_yarn,kinetic_j_homogenized,com_x_yarn,com_y_yarn,com_z_yarn,com_x_homogenized,com_y_homogenized,com_z_homogenized,com_travel_m_yarn,com_travel_m_homogenized,support_n_yarn,support_n_homogenized,contacts_yarn,contacts_homogenized,slip_m_yarn,slip_m_homogenized\n",
    );
    let f = |v: Option<f64>| v.map_or(String::new(), |x| format!("{x:.9e}"));
    for (k, (a, b)) in m
        .yarn_level
        .frames
        .iter()
        .zip(&m.homogenized.frames)
        .enumerate()
    {
        out += &format!(
            "{k},{:.9e},{:.9e},{:.9e},{:.9e},{:.9e},{:.9e},{:.9e},{:.9e},{:.9e},{:.9e},{:.9e},{},{},{},{},{:.9e},{:.9e}\n",
            a.time,
            a.kinetic_j,
            b.kinetic_j,
            a.com[0],
            a.com[1],
            a.com[2],
            b.com[0],
            b.com[1],
            b.com[2],
            a.com_travel_m,
            b.com_travel_m,
            f(a.support_n.map(norm)),
            f(b.support_n.map(norm)),
            a.contacts,
            b.contacts,
            a.slip_m,
            b.slip_m
        );
    }
    out
}

/// `motion.png`: kinetic energy, the centre of mass's fall and travel, the
/// support force and the slip against time, one curve per run.
pub fn figure(m: &MotionReport) -> plot::Figure {
    let runs: Vec<(&str, &Motion)> = [
        Some(("yarn level", &m.yarn_level)),
        Some(("homogenized, fitted", &m.homogenized)),
        m.uniform.as_ref().map(|u| ("homogenized, uniform", u)),
    ]
    .into_iter()
    .flatten()
    .collect();
    let panel = |y_label: &str, f: &dyn Fn(&MotionFrame) -> Option<f64>| plot::Panel {
        x_label: "time (s)".into(),
        y_label: y_label.into(),
        series: runs
            .iter()
            .enumerate()
            .map(|(i, (label, run))| plot::Series {
                label: (*label).into(),
                points: run
                    .frames
                    .iter()
                    .filter_map(|fr| f(fr).map(|v| [fr.time, v]))
                    .collect(),
                color: plot::PALETTE[i % plot::PALETTE.len()],
            })
            .collect(),
    };
    plot::Figure {
        title: "motion: yarn level against homogenized".into(),
        panels: vec![
            panel("kinetic energy (mJ)", &|f| Some(1e3 * f.kinetic_j)),
            panel("centre-of-mass travel (cm)", &|f| {
                Some(100.0 * f.com_travel_m)
            }),
            panel("support force (mN)", &|f| {
                f.support_n.map(|v| 1e3 * norm(v))
            }),
            panel("slip along colliders (cm)", &|f| Some(100.0 * f.slip_m)),
        ],
        size: (900, 1200),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::yarn::sim::{PlaneCollider, SphereCollider};

    fn scene<'a>(
        masses: &'a [f64],
        radii: &'a [f64],
        colliders: &'a [Arc<dyn PointCollider>],
        gravity: Vec3,
        mass_damping: f64,
    ) -> MotionScene<'a> {
        MotionScene {
            masses,
            radii,
            gravity,
            mass_damping,
            colliders,
        }
    }

    /// Two points in free fall from rest: the kinetic energy, the centre
    /// of mass's fall and a zero support force come out of the frames.
    #[test]
    fn free_fall_has_no_support_and_the_kinetic_energy_of_its_speed() {
        let g = [0.0, -9.81, 0.0];
        let (m, r) = ([0.002, 0.003], [0.001, 0.001]);
        let s = scene(&m, &r, &[], g, 0.0);
        let times: Vec<f64> = (0..6).map(|k| k as f64 / 30.0).collect();
        let frames: Vec<Vec<Vec3>> = times
            .iter()
            .map(|&t| {
                let dy = -0.5 * 9.81 * t * t;
                vec![[0.0, dy, 0.0], [0.1, 0.2 + dy, 0.0]]
            })
            .collect();
        let refs: Vec<&[Vec3]> = frames.iter().map(|f| f.as_slice()).collect();
        let mo = measure(&s, &times, &refs);
        let fall = 0.5 * 9.81 * times[5] * times[5];
        assert!((mo.com_drop_m - fall).abs() < 1e-12, "{}", mo.com_drop_m);
        assert!((mo.com_travel_m - fall).abs() < 1e-12);
        for f in &mo.frames[1..5] {
            let sn = norm(f.support_n.unwrap());
            assert!(sn < 1e-9, "free fall needs no support: {sn} N");
        }
        assert!(mo.frames[0].support_n.is_none() && mo.frames[5].support_n.is_none());
        // Interval 5's mean speed is g (t4 + t5) / 2.
        let v = 9.81 * (times[4] + times[5]) / 2.0;
        assert!((mo.final_kinetic_j - 0.5 * 0.005 * v * v).abs() < 1e-12);
        assert_eq!(mo.max_contacts, 0);
        assert_eq!(mo.slip_m, 0.0);
    }

    /// A point resting on a plane is held up by its weight, and one damped
    /// at constant speed is pushed by the damping force.
    #[test]
    fn resting_on_a_plane_is_held_by_the_weight_and_sliding_counts_slip() {
        let g = [0.0, -9.81, 0.0];
        let (m, r) = ([0.01], [0.001]);
        let plane: Arc<dyn PointCollider> = Arc::new(PlaneCollider {
            point: [0.0, 0.0, 0.0],
            normal: [0.0, 1.0, 0.0],
            friction: 0.3,
        });
        let cs = [plane];
        let times: Vec<f64> = (0..5).map(|k| k as f64 * 0.1).collect();
        // At rest, one radius above the plane.
        let rest: Vec<Vec<Vec3>> = times.iter().map(|_| vec![[0.0, 0.001, 0.0]]).collect();
        let refs: Vec<&[Vec3]> = rest.iter().map(|f| f.as_slice()).collect();
        let mo = measure(&scene(&m, &r, &cs, g, 0.0), &times, &refs);
        let up = mo.frames[2].support_n.unwrap();
        assert!((up[1] - 0.01 * 9.81).abs() < 1e-12 && up[0].abs() < 1e-15);
        assert_eq!(mo.max_contacts, 1);
        assert_eq!(mo.slip_m, 0.0);
        // Sliding along +x at 0.2 m/s with mass damping 2/s: 0.04 m of
        // slip, and a support force with a -x part against the damping.
        let slide: Vec<Vec<Vec3>> = times.iter().map(|&t| vec![[0.2 * t, 0.001, 0.0]]).collect();
        let refs: Vec<&[Vec3]> = slide.iter().map(|f| f.as_slice()).collect();
        let mo = measure(&scene(&m, &r, &cs, g, 2.0), &times, &refs);
        assert!((mo.slip_m - 0.08).abs() < 1e-12, "{}", mo.slip_m);
        let f = mo.frames[2].support_n.unwrap();
        assert!((f[0] - 2.0 * 0.01 * 0.2).abs() < 1e-12, "{f:?}");
        // Lifted off the plane: no contact, no slip.
        let off: Vec<Vec<Vec3>> = times.iter().map(|&t| vec![[0.2 * t, 0.01, 0.0]]).collect();
        let refs: Vec<&[Vec3]> = off.iter().map(|f| f.as_slice()).collect();
        let mo = measure(&scene(&m, &r, &cs, g, 0.0), &times, &refs);
        assert_eq!((mo.max_contacts, mo.slip_m), (0, 0.0));
    }

    /// Motion normal to a sphere's surface is no slip; motion along it is.
    #[test]
    fn slip_is_the_tangential_motion_on_the_surface() {
        let sphere: Arc<dyn PointCollider> = Arc::new(SphereCollider {
            center: [0.0, 0.0, 0.0],
            radius: 0.05,
            velocity: [0.0; 3],
            friction: 0.0,
        });
        let cs = [sphere];
        let (m, r) = ([0.01], [0.001]);
        let s = scene(&m, &r, &cs, [0.0; 3], 0.0);
        let times = [0.0, 0.1];
        let a = [[0.0, 0.0505, 0.0]];
        let pressed = [[0.0, 0.0502, 0.0]];
        let mo = measure(&s, &times, &[&a, &pressed]);
        assert!(mo.slip_m < 1e-15, "{}", mo.slip_m);
        let along = [[0.001, 0.0505, 0.0]];
        let mo = measure(&s, &times, &[&a, &along]);
        assert!((mo.slip_m - 0.001).abs() < 2e-5, "{}", mo.slip_m);
    }

    #[test]
    fn the_match_reads_the_gap_against_the_travel() {
        let g = [0.0, -9.81, 0.0];
        let (m, r) = ([1.0], [0.001]);
        let s = scene(&m, &r, &[], g, 0.0);
        let times = [0.0, 0.1, 0.2];
        let truth = measure(
            &s,
            &times,
            &[&[[0.0; 3]], &[[0.0, -0.1, 0.0]], &[[0.0, -0.2, 0.0]]],
        );
        let ours = measure(
            &s,
            &times,
            &[&[[0.0; 3]], &[[0.0, -0.1, 0.0]], &[[0.0, -0.25, 0.0]]],
        );
        let c = compare(&truth, &ours);
        assert!((c.com_path_error.unwrap() - 0.25).abs() < 1e-12);
        assert!((c.com_travel_ratio.unwrap() - 1.25).abs() < 1e-12);
        assert_eq!(c.slip_ratio, None);
        let same = compare(&truth, &truth);
        assert_eq!(same.com_path_error, Some(0.0));
    }
}
