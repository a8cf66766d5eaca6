//! Clamp forces in `validate`: what each clamped band holds the fabric with,
//! at yarn level and on the homogenized mesh, frame by frame.
//!
//! Positions barely see a material's stiffness when clamps drive the
//! motion (a pose held by Dirichlet bands has nearly the same shape under a
//! stiffer or softer material); the force on the clamps does, as a tensile
//! tester reads it. Both levels count only internal forces: at yarn level
//! the rods, contact and friction gradient summed over the band's vertices
//! ([`crate::yarn::fabric::RodDynamics::band_forces`]), on the mesh the
//! elastic gradient summed over the band's held nodes (the four nodes of
//! each tet that holds a clamped yarn vertex). Within a band the pair
//! forces cancel, so what is compared is what the free fabric transmits to
//! the clamp; the band's own weight and inertia are left out on both sides.

use crate::fit::elastic::MaterialFields;
use crate::geom::{TetMesh, Vec3};
use crate::sim::SimError;

/// Per frame, the resultant elastic force (N) on each band's held nodes of
/// `mesh` at the node positions `frames[f]`; `group[i]` is node `i`'s band
/// (None: free), `bands` their number.
pub fn mesh_band_forces(
    mesh: &TetMesh,
    gamma: &MaterialFields,
    group: &[Option<usize>],
    bands: usize,
    frames: &[Vec<Vec3>],
) -> Result<Vec<Vec<Vec3>>, SimError> {
    let model = gamma.model(mesh)?;
    frames
        .iter()
        .map(|x| {
            let g = model.gradient(x)?;
            let mut f = vec![[0.0; 3]; bands];
            for (gi, b) in g.iter().zip(group) {
                if let Some(b) = b.filter(|b| *b < bands) {
                    for c in 0..3 {
                        f[b][c] += gi[c];
                    }
                }
            }
            Ok(f)
        })
        .collect()
}

/// Where the yarn level's clamp force peaks: the frame (from 1; frame 0 is
/// the rest state) and band of the largest force, and that force (N).
/// None when every force is zero.
pub fn peak(yarn: &[Vec<Vec3>]) -> Option<(usize, usize, Vec3)> {
    let mut best: Option<(usize, usize, Vec3)> = None;
    let mut top = 0.0;
    for (f, bands) in yarn.iter().enumerate().skip(1) {
        for (b, v) in bands.iter().enumerate() {
            let m = crate::geom::vec3::norm(*v);
            if m > top {
                top = m;
                best = Some((f, b, *v));
            }
        }
    }
    best
}

/// How a homogenized run's clamp forces match the yarn level's.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct ForceMatch {
    /// The mesh's force on the peak band at the peak frame, along the yarn
    /// level's force there, over that force's size: 1 is exact, 0.5 half
    /// the force.
    pub peak_ratio: f64,
    /// `sqrt(Σ |F_mesh - F_yarn|² / Σ |F_yarn|²)` over frames 1.. and
    /// bands: 0 is exact.
    pub relative_error: f64,
}

/// `mesh` against `yarn` (both `[frame][band]`, the same shape) with the
/// yarn level's peak `at` ([`peak`]). None when the shapes differ.
pub fn compare(
    yarn: &[Vec<Vec3>],
    mesh: &[Vec<Vec3>],
    at: (usize, usize, Vec3),
) -> Option<ForceMatch> {
    let same = yarn.len() == mesh.len() && yarn.iter().zip(mesh).all(|(a, b)| a.len() == b.len());
    if !same {
        return None;
    }
    let (mut num, mut den) = (0.0, 0.0);
    for (a, b) in yarn.iter().zip(mesh).skip(1) {
        for (y, m) in a.iter().zip(b) {
            num += (0..3).map(|c| (m[c] - y[c]).powi(2)).sum::<f64>();
            den += (0..3).map(|c| y[c].powi(2)).sum::<f64>();
        }
    }
    let (f, b, y) = at;
    let y2: f64 = (0..3).map(|c| y[c] * y[c]).sum();
    let along: f64 = (0..3).map(|c| mesh[f][b][c] * y[c]).sum();
    (den > 0.0 && y2 > 0.0).then(|| ForceMatch {
        peak_ratio: along / y2,
        relative_error: (num / den).sqrt(),
    })
}

/// Per frame, the force (N) on the peak band along the peak's direction.
pub fn along_peak(forces: &[Vec<Vec3>], at: (usize, usize, Vec3)) -> Vec<f64> {
    let (_, b, y) = at;
    let n = crate::geom::vec3::norm(y);
    forces
        .iter()
        .map(|f| {
            f.get(b)
                .map_or(0.0, |v| (0..3).map(|c| v[c] * y[c]).sum::<f64>() / n)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_peak_skips_the_rest_frame_and_the_ratio_reads_along_it() {
        let yarn = vec![
            vec![[9.0, 0.0, 0.0], [0.0; 3]],
            vec![[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]],
            vec![[3.0, 4.0, 0.0], [-3.0, -4.0, 0.0]],
        ];
        let at = peak(&yarn).unwrap();
        assert_eq!((at.0, at.1), (2, 0));
        // Half the force along the peak, any amount across it.
        let mut mesh = yarn.clone();
        mesh[2][0] = [1.5 - 4.0, 2.0 + 3.0, 7.0];
        let m = compare(&yarn, &mesh, at).unwrap();
        assert!((m.peak_ratio - 0.5).abs() < 1e-12, "{m:?}");
        assert!(m.relative_error > 0.0);
        let exact = compare(&yarn, &yarn, at).unwrap();
        assert_eq!(exact.relative_error, 0.0);
        assert_eq!(exact.peak_ratio, 1.0);
        let a = along_peak(&yarn, at);
        assert!(
            a.iter()
                .zip([5.4, 0.6, 5.0])
                .all(|(x, y)| (x - y).abs() < 1e-12),
            "{a:?}"
        );
        assert!(compare(&yarn, &mesh[..2], at).is_none());
        assert!(peak(&[vec![[0.0; 3]], vec![[0.0; 3]]]).is_none());
    }
}
