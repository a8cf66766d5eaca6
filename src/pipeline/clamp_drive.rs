//! Where the homogenized runs put a pose's held tet nodes, so that `fit`
//! solves its equilibria under the boundary conditions the fitted material
//! will later be driven by.
//!
//! `validate` (and a shot's pins) move every tet node that holds a clamped
//! yarn vertex with its band: the band's map of the node's rest position
//! ([`PoseDriver::group_target`]). `fit` used to pin those nodes at the shape
//! fit (Y2V) of each frame instead, i.e. where the yarns in their tets
//! happened to be: up to 1.3 mm off the band's map on a 10% shear under
//! gravity of a 10 x 10 stockinette (3.2 mm voxels), whose boundary layer
//! then sagged with the yarns for free. A field fitted to that shear run
//! itself matched its frames at 0.14 yarn diameters RMS in `fit`'s
//! equilibria, but 0.34 when `validate` drove the same material
//! (docs/fidelity.md); with the nodes where the band puts them, `fit`'s
//! equilibrium gives the 0.34 that `validate` does.

use crate::geom::{Asset, Vec3};
use crate::pipeline::util::held_nodes;
use crate::yarn::fabric::pose::FabricPlane;
use crate::yarn::poses::{PoseDriver, PoseError, PoseParams};

/// The bands of one training pose, able to place its held tet nodes per
/// frame.
pub struct ClampDrive {
    plane: FabricPlane,
    /// Per tet node, the band that holds it ([`node_groups`]).
    group: Vec<Option<usize>>,
    source: DriveSource,
}

enum DriveSource {
    /// A yls run (its scene stored in the file): one driver, each frame at
    /// its time.
    Scene { driver: PoseDriver, times: Vec<f64> },
    /// A `knitvox train` pose: frame `f` is load step `f + 1`, whose bands
    /// sit at the full progress of the pose at `frame_amounts[f]`
    /// (`yarn::fabric::pose::run_pose`), in the pose frame.
    Record {
        params: PoseParams,
        frame_amounts: Vec<f64>,
        posed_rest: Vec<Vec3>,
    },
}

impl ClampDrive {
    /// The bands of a yls scene's pose on the asset's rest yarns (the scene
    /// frame is the rest frame, as `validate` runs it); `times` are the
    /// frames' times (s).
    pub fn from_scene(
        asset: &Asset,
        params: PoseParams,
        times: Vec<f64>,
    ) -> Result<ClampDrive, PoseError> {
        let driver = PoseDriver::new(&asset.rest_yarns.points, params)?;
        Ok(ClampDrive {
            plane: FabricPlane::Xz,
            group: node_groups(asset, &driver),
            source: DriveSource::Scene { driver, times },
        })
    }

    /// The bands of a `knitvox train` pose record (`params` at the pose's
    /// full amount, the amount of each frame) on the asset's rest yarns,
    /// turned into the pose frame as the run turned them.
    pub fn from_record(
        asset: &Asset,
        params: PoseParams,
        frame_amounts: Vec<f64>,
    ) -> Result<ClampDrive, PoseError> {
        let rest = &asset.rest_yarns.points;
        let plane = FabricPlane::of(rest);
        let posed_rest: Vec<Vec3> = rest.iter().map(|p| plane.to_pose(*p)).collect();
        let driver = PoseDriver::new(&posed_rest, params)?;
        Ok(ClampDrive {
            plane,
            group: node_groups(asset, &driver),
            source: DriveSource::Record {
                params,
                frame_amounts,
                posed_rest,
            },
        })
    }

    /// Frames this drive can place (a record's load steps; every frame of
    /// a scene run).
    pub fn covers(&self, num_frames: usize) -> bool {
        match &self.source {
            DriveSource::Scene { times, .. } => times.len() == num_frames,
            DriveSource::Record { frame_amounts, .. } => frame_amounts.len() == num_frames,
        }
    }

    /// Where the band holding node `i` puts it at frame `f` (m, input
    /// frame), for each of `nodes` (the asset's rest nodes) in `pinned`;
    /// None for a pinned node no band holds.
    pub fn targets(
        &self,
        f: usize,
        nodes: &[Vec3],
        pinned: &[usize],
    ) -> Result<Vec<Option<Vec3>>, PoseError> {
        let place = |driver: &PoseDriver, t: f64| -> Vec<Option<Vec3>> {
            pinned
                .iter()
                .map(|&i| {
                    self.group[i].map(|g| {
                        let anchor = self.plane.to_pose(nodes[i]);
                        self.plane.from_pose(driver.group_target(g, anchor, t))
                    })
                })
                .collect()
        };
        match &self.source {
            DriveSource::Scene { driver, times } => Ok(place(driver, times[f])),
            DriveSource::Record {
                params,
                frame_amounts,
                posed_rest,
            } => {
                let mut p = *params;
                p.amount = frame_amounts[f];
                let driver = PoseDriver::new(posed_rest, p)?;
                // `run_pose` holds each step's bands at `targets(1.0)`; the
                // default ramp is 1 s, so t = 1 is full progress.
                Ok(place(&driver, 1.0))
            }
        }
    }
}

/// For every tet node, the pose's band (clamp group) that holds it: the
/// first band holding a yarn vertex in one of the node's tets.
pub fn node_groups(asset: &Asset, driver: &PoseDriver) -> Vec<Option<usize>> {
    let mut group = vec![None; asset.mesh.num_nodes()];
    for g in 0..driver.num_groups() {
        let mut held = vec![false; asset.embedding.num_vertices()];
        for &v in driver.group_vertices(g) {
            held[v] = true;
        }
        for i in held_nodes(&asset.mesh, &asset.embedding, &held) {
            group[i].get_or_insert(g);
        }
    }
    group
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::embed::EmbedParams;
    use crate::geom::vec3::{norm, sub};
    use crate::io::{ReadOptions, WriteOptions};
    use crate::yarn::analytic::{knit_swatch, SwatchParams};
    use crate::yarn::poses::PoseKind;

    /// A 4 x 5 knit swatch laid flat in the fabric frame (XZ), embedded in
    /// 2.5 mm voxels.
    fn asset() -> Asset {
        let mut y = knit_swatch(&SwatchParams {
            courses: 4,
            wales: 5,
            points_per_loop: 12,
            with_ring: false,
            ..SwatchParams::default()
        });
        y.map_points(|p| FabricPlane::Xy.to_pose(p));
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sw.ply");
        crate::io::write_path(&path, &y, None, &WriteOptions::default()).unwrap();
        let params = EmbedParams {
            voxel_size: Some(2.5e-3),
            ..EmbedParams::default()
        };
        crate::pipeline::asset::build_asset(&path, &ReadOptions::default(), &params, "test")
            .unwrap()
            .0
    }

    /// A `train` record's frame `f` is load step `f + 1`: the moving band's
    /// nodes translate by `(f + 1) / steps` of the full stretch along the
    /// courses, the held band's stay, and every node of a band moves alike.
    #[test]
    fn a_recorded_stretch_moves_its_band_nodes_step_by_step() {
        let a = asset();
        let steps = 4;
        let amounts = (1..=steps).map(|f| 0.1 * f as f64 / steps as f64).collect();
        let drive =
            ClampDrive::from_record(&a, PoseParams::new(PoseKind::StretchCourses, 0.1), amounts)
                .unwrap();
        assert!(drive.covers(steps) && !drive.covers(steps + 1));
        let pinned: Vec<usize> = (0..a.mesh.num_nodes())
            .filter(|&i| drive.group[i].is_some())
            .collect();
        assert!(pinned.len() > 10, "{} held nodes", pinned.len());
        let plane = FabricPlane::of(&a.rest_yarns.points);
        let moves = |f: usize| -> Vec<Vec3> {
            let t = drive.targets(f, &a.mesh.nodes, &pinned).unwrap();
            pinned
                .iter()
                .zip(t)
                .map(|(&i, p)| plane.to_pose(sub(p.unwrap(), a.mesh.nodes[i])))
                .collect()
        };
        let last = moves(steps - 1);
        let full = last.iter().map(|d| norm(*d)).fold(0.0, f64::max);
        assert!(full > 1e-3, "the moving band moves {full} m");
        let (mut held, mut moving) = (0, 0);
        for f in 0..steps {
            let want = full * (f + 1) as f64 / steps as f64;
            for d in moves(f) {
                if norm(d) < 1e-12 {
                    held += 1;
                } else {
                    moving += 1;
                    // Along the courses (pose X), by the step's share.
                    assert!((d[0] - want).abs() < 1e-9 * full, "{d:?} vs {want}");
                    assert!(d[1].abs() < 1e-12 && d[2].abs() < 1e-12, "{d:?}");
                }
            }
        }
        assert!(held > 0 && moving > 0, "held {held}, moving {moving}");
        // A node no band holds has no target.
        let free = (0..a.mesh.num_nodes())
            .find(|&i| drive.group[i].is_none())
            .unwrap();
        assert_eq!(
            drive.targets(0, &a.mesh.nodes, &[free]).unwrap(),
            vec![None]
        );
    }

    /// A scene's frames are placed at their times: at t = 0 every band node
    /// is at rest, halfway through the ramp the moving band is halfway.
    #[test]
    fn a_scene_places_band_nodes_at_the_frame_times() {
        let a = asset();
        let mut p = PoseParams::new(PoseKind::Shear, 0.1);
        p.ramp = 0.3;
        let drive = ClampDrive::from_scene(&a, p, vec![0.0, 0.15, 0.3]).unwrap();
        assert!(drive.covers(3) && !drive.covers(2));
        let pinned: Vec<usize> = (0..a.mesh.num_nodes())
            .filter(|&i| drive.group[i].is_some())
            .collect();
        let largest = |f: usize| {
            let t = drive.targets(f, &a.mesh.nodes, &pinned).unwrap();
            pinned
                .iter()
                .zip(t)
                .map(|(&i, p)| norm(sub(p.unwrap(), a.mesh.nodes[i])))
                .fold(0.0, f64::max)
        };
        assert_eq!(largest(0), 0.0);
        // Halfway through the smoothstep ramp the band is halfway.
        let (mid, end) = (largest(1), largest(2));
        assert!(end > 0.0 && (mid / end - 0.5).abs() < 1e-9, "{mid} {end}");
    }
}
