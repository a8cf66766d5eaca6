//! Pinned vertices and scripted handles: a set of vertices whose positions
//! are prescribed over time by a rigid motion of their positions at the
//! moment the handle was attached.

use crate::geom::Vec3;

/// Why a handle does not fit the yarns or its motion is malformed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum HandleError {
    /// A handle vertex the yarns do not have.
    #[error("vertex {vertex} out of range ({vertices} vertices)")]
    VertexOutOfRange { vertex: usize, vertices: usize },
    /// The start time is not finite.
    #[error("start_time is not finite")]
    StartTime,
    /// A translation with a non-finite velocity or a negative duration.
    #[error("translate: velocity must be finite, duration >= 0")]
    Translate,
    /// A rotation with a non-finite centre or speed, or a zero axis.
    #[error("rotate: center, axis (nonzero) and angular velocity must be finite")]
    Rotate,
    /// A rotation with a negative duration.
    #[error("rotate: duration must be >= 0")]
    RotateDuration,
    /// A curve with no keys, or another number of times than points.
    #[error("follow_curve: {times} times for {points} points (need equal, at least 1)")]
    CurveKeys { times: usize, points: usize },
    /// A curve whose times do not start at 0 or do not increase.
    #[error("follow_curve: times must start at 0 and increase")]
    CurveTimes,
    /// A curve with a non-finite time or point.
    #[error("follow_curve: non-finite key")]
    CurveNonFinite,
    /// A pose group the pose driver does not have.
    #[error("pose group {group} of {groups}")]
    PoseGroup { group: usize, groups: usize },
    /// A handle on a periodic tile.
    #[error("handles are not supported on periodic tiles")]
    PeriodicTile,
}

/// How a handle moves its vertices (time `t` in seconds since the handle's
/// `start_time`; before it the vertices stay where they were attached).
#[derive(Debug, Clone, PartialEq)]
pub enum HandleMotion {
    /// Held in place (pins).
    Fixed,
    /// Constant velocity (m/s), for `duration` seconds (then held; `None`: forever).
    Translate {
        velocity: Vec3,
        duration: Option<f64>,
    },
    /// Rotation about the axis through `center` along `axis` at
    /// `angular_velocity` (rad/s, right-handed), for `duration` seconds.
    Rotate {
        center: Vec3,
        axis: Vec3,
        angular_velocity: f64,
        duration: Option<f64>,
    },
    /// Translation that follows a curve: at `times[k]` the vertices are
    /// displaced by `points[k] - points[0]`, linear in between, held after
    /// the last key. `times` increasing, starting at 0.
    FollowCurve { times: Vec<f64>, points: Vec<Vec3> },
    /// One clamped group of a scripted pose (`yarn::poses`: stretches,
    /// shear, VH Fig. 19 bends, fan, twist, multi-fold): every vertex
    /// follows the pose's map of its anchor (rest position) over time.
    Pose {
        driver: std::sync::Arc<crate::yarn::poses::PoseDriver>,
        group: usize,
    },
}

/// A scripted handle: vertices and their motion.
#[derive(Debug, Clone, PartialEq)]
pub struct Handle {
    /// Vertex indices (of the simulated yarns).
    pub vertices: Vec<usize>,
    pub motion: HandleMotion,
    /// Simulation time (s) at which the motion starts. Default 0.
    pub start_time: f64,
}

impl Handle {
    /// Pins `vertices` where they are.
    pub fn pin(vertices: Vec<usize>) -> Handle {
        Handle {
            vertices,
            motion: HandleMotion::Fixed,
            start_time: 0.0,
        }
    }

    /// Moves `vertices` at a constant velocity from time 0.
    pub fn translate(vertices: Vec<usize>, velocity: Vec3) -> Handle {
        Handle {
            vertices,
            motion: HandleMotion::Translate {
                velocity,
                duration: None,
            },
            start_time: 0.0,
        }
    }

    /// Checks the motion description.
    pub fn validate(&self, num_vertices: usize) -> Result<(), HandleError> {
        if let Some(&v) = self.vertices.iter().find(|&&v| v >= num_vertices) {
            return Err(HandleError::VertexOutOfRange {
                vertex: v,
                vertices: num_vertices,
            });
        }
        if !self.start_time.is_finite() {
            return Err(HandleError::StartTime);
        }
        let fin = |v: &Vec3| v.iter().all(|x| x.is_finite());
        match &self.motion {
            HandleMotion::Fixed => Ok(()),
            HandleMotion::Translate { velocity, duration } => {
                if !fin(velocity) || duration.is_some_and(|d| !(d >= 0.0)) {
                    return Err(HandleError::Translate);
                }
                Ok(())
            }
            HandleMotion::Rotate {
                center,
                axis,
                angular_velocity,
                duration,
            } => {
                let n = (axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]).sqrt();
                if !fin(center) || !(n > 0.0 && n.is_finite()) || !angular_velocity.is_finite() {
                    return Err(HandleError::Rotate);
                }
                if duration.is_some_and(|d| !(d >= 0.0)) {
                    return Err(HandleError::RotateDuration);
                }
                Ok(())
            }
            HandleMotion::FollowCurve { times, points } => {
                if times.is_empty() || times.len() != points.len() {
                    return Err(HandleError::CurveKeys {
                        times: times.len(),
                        points: points.len(),
                    });
                }
                if times[0] != 0.0 || times.windows(2).any(|w| !(w[1] > w[0])) {
                    return Err(HandleError::CurveTimes);
                }
                if !points.iter().all(fin) || !times.iter().all(|t| t.is_finite()) {
                    return Err(HandleError::CurveNonFinite);
                }
                Ok(())
            }
            HandleMotion::Pose { driver, group } => {
                if *group >= driver.num_groups() {
                    return Err(HandleError::PoseGroup {
                        group: *group,
                        groups: driver.num_groups(),
                    });
                }
                Ok(())
            }
        }
    }

    /// Position at simulation time `t` of a vertex attached at `anchor`.
    pub fn position(&self, anchor: Vec3, t: f64) -> Vec3 {
        let tau = (t - self.start_time).max(0.0);
        match &self.motion {
            HandleMotion::Fixed => anchor,
            HandleMotion::Translate { velocity, duration } => {
                let s = duration.map_or(tau, |d| tau.min(d));
                [
                    anchor[0] + s * velocity[0],
                    anchor[1] + s * velocity[1],
                    anchor[2] + s * velocity[2],
                ]
            }
            HandleMotion::Rotate {
                center,
                axis,
                angular_velocity,
                duration,
            } => {
                let s = duration.map_or(tau, |d| tau.min(d));
                let n = (axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]).sqrt();
                let k = [axis[0] / n, axis[1] / n, axis[2] / n];
                let th = angular_velocity * s;
                let p = [
                    anchor[0] - center[0],
                    anchor[1] - center[1],
                    anchor[2] - center[2],
                ];
                // Rodrigues' rotation formula.
                let (c, sn) = (th.cos(), th.sin());
                let kxp = [
                    k[1] * p[2] - k[2] * p[1],
                    k[2] * p[0] - k[0] * p[2],
                    k[0] * p[1] - k[1] * p[0],
                ];
                let kp = k[0] * p[0] + k[1] * p[1] + k[2] * p[2];
                let mut out = [0.0; 3];
                for i in 0..3 {
                    out[i] = center[i] + p[i] * c + kxp[i] * sn + k[i] * kp * (1.0 - c);
                }
                out
            }
            HandleMotion::Pose { driver, group } => driver.group_target(*group, anchor, tau),
            HandleMotion::FollowCurve { times, points } => {
                let last = times.len() - 1;
                let d = if tau >= times[last] {
                    points[last]
                } else {
                    let k = times.partition_point(|&x| x <= tau).max(1) - 1;
                    let a = (tau - times[k]) / (times[k + 1] - times[k]);
                    let (p, q) = (points[k], points[k + 1]);
                    [
                        p[0] + a * (q[0] - p[0]),
                        p[1] + a * (q[1] - p[1]),
                        p[2] + a * (q[2] - p[2]),
                    ]
                };
                [
                    anchor[0] + d[0] - points[0][0],
                    anchor[1] + d[1] - points[0][1],
                    anchor[2] + d[2] - points[0][2],
                ]
            }
        }
    }

    /// An upper bound of the speed (m/s) of any attached vertex, given the
    /// anchors, used for the per-step displacement bound.
    pub fn max_speed(&self, anchors: &[Vec3]) -> f64 {
        match &self.motion {
            HandleMotion::Fixed => 0.0,
            HandleMotion::Translate { velocity, .. } => {
                (velocity[0] * velocity[0] + velocity[1] * velocity[1] + velocity[2] * velocity[2])
                    .sqrt()
            }
            HandleMotion::Rotate {
                center,
                angular_velocity,
                ..
            } => {
                let rmax = anchors
                    .iter()
                    .map(|p| {
                        let d = [p[0] - center[0], p[1] - center[1], p[2] - center[2]];
                        (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
                    })
                    .fold(0.0, f64::max);
                angular_velocity.abs() * rmax
            }
            HandleMotion::Pose { driver, .. } => driver.max_speed(),
            HandleMotion::FollowCurve { times, points } => times
                .windows(2)
                .zip(points.windows(2))
                .map(|(t, p)| {
                    let d = [p[1][0] - p[0][0], p[1][1] - p[0][1], p[1][2] - p[0][2]];
                    (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() / (t[1] - t[0])
                })
                .fold(0.0, f64::max),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn motions_start_at_anchor_and_move() {
        let a = [1.0, 0.0, 0.0];
        let r = Handle {
            vertices: vec![0],
            motion: HandleMotion::Rotate {
                center: [0.0; 3],
                axis: [0.0, 0.0, 1.0],
                angular_velocity: std::f64::consts::FRAC_PI_2,
                duration: None,
            },
            start_time: 0.0,
        };
        let p = r.position(a, 1.0);
        assert!((p[0]).abs() < 1e-12 && (p[1] - 1.0).abs() < 1e-12);
        assert_eq!(r.position(a, 0.0), a);
        let f = Handle {
            vertices: vec![0],
            motion: HandleMotion::FollowCurve {
                times: vec![0.0, 1.0, 2.0],
                points: vec![[0.0; 3], [1.0, 0.0, 0.0], [1.0, 2.0, 0.0]],
            },
            start_time: 1.0,
        };
        assert_eq!(f.position(a, 0.5), a);
        let q = f.position(a, 2.5);
        assert!((q[0] - 2.0).abs() < 1e-12 && (q[1] - 1.0).abs() < 1e-12);
        assert!((f.max_speed(&[a]) - 2.0).abs() < 1e-12);
        assert!(f.validate(1).is_ok());
        assert!(Handle::pin(vec![3]).validate(2).is_err());
    }
}
