//! The lumped mass's rotational inertia against the yarns' (VH §5: the
//! lumped mass keeps the yarns' mass and centre of mass exactly, Eq. 2 with
//! linear shape functions, but not their second moments: a node carries
//! yarn mass from up to a voxel away, so a spin of the mesh has more
//! inertia than the same spin of the yarns).

use crate::geom::{Vec3, Yarns};
use nalgebra::{Matrix3, SymmetricEigen, Vector3};

/// Principal moments of inertia (kg m²) about the yarns' centre of mass.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct InertiaComparison {
    /// The yarns' principal moments, ascending (a line density along
    /// each segment).
    pub yarn_moments: [f64; 3],
    /// The lumped node masses' moments about the same centre and the same
    /// principal axes.
    pub lumped_moments: [f64; 3],
    /// The yarns' and the nodes' total mass (kg).
    pub yarn_mass: f64,
    pub lumped_mass: f64,
}

impl InertiaComparison {
    /// Lumped over yarn moment per principal axis, each per unit of its
    /// total mass (1: the same inertia; a line density off by a constant,
    /// as from another material density, does not change it).
    pub fn ratios(&self) -> [f64; 3] {
        let scale = self.yarn_mass / self.lumped_mass;
        std::array::from_fn(|k| scale * self.lumped_moments[k] / self.yarn_moments[k])
    }
}

/// Compares the inertia of the yarns (`segment_linear_density` in kg/m per
/// segment, in `yarns.segments()` order) with that of the node masses
/// (kg) at `nodes` (m). `None` without mass (yarns or nodes) or with a
/// degenerate (zero) principal moment.
pub fn compare_inertia(
    yarns: &Yarns,
    segment_linear_density: &[f64],
    nodes: &[Vec3],
    node_mass: &[f64],
) -> Option<InertiaComparison> {
    let v = |p: Vec3| Vector3::new(p[0], p[1], p[2]);
    let segs: Vec<[usize; 2]> = yarns.segments().collect();
    if segs.len() != segment_linear_density.len() || nodes.len() != node_mass.len() {
        return None;
    }
    let mut mass = 0.0;
    let mut first = Vector3::zeros();
    for (&[a, b], d) in segs.iter().zip(segment_linear_density) {
        let (pa, pb) = (v(yarns.points[a]), v(yarns.points[b]));
        let m = d * (pb - pa).norm();
        mass += m;
        first += m * 0.5 * (pa + pb);
    }
    let lumped_mass: f64 = node_mass.iter().sum();
    if !(mass > 0.0 && lumped_mass > 0.0) {
        return None;
    }
    let c = first / mass;
    // ∫ λ (x - c)(x - c)ᵀ ds over a straight segment: λ L ((a aᵀ + b bᵀ)/3
    // + (a bᵀ + b aᵀ)/6) with a, b its ends relative to c.
    let mut yarn = Matrix3::zeros();
    for (&[a, b], d) in segs.iter().zip(segment_linear_density) {
        let (pa, pb) = (v(yarns.points[a]) - c, v(yarns.points[b]) - c);
        let m = d * (pb - pa).norm();
        yarn += m
            * ((pa * pa.transpose() + pb * pb.transpose()) / 3.0
                + (pa * pb.transpose() + pb * pa.transpose()) / 6.0);
    }
    let mut lumped = Matrix3::zeros();
    for (p, m) in nodes.iter().zip(node_mass) {
        let r = v(*p) - c;
        lumped += *m * r * r.transpose();
    }
    let inertia = |j: Matrix3<f64>| Matrix3::identity() * j.trace() - j;
    let (iy, il) = (inertia(yarn), inertia(lumped));
    let eig = SymmetricEigen::new(iy);
    let mut order = [0usize, 1, 2];
    order.sort_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]));
    let yarn_moments = order.map(|i| eig.eigenvalues[i]);
    if !(yarn_moments[0] > 1e-12 * yarn_moments[2]) {
        return None;
    }
    let lumped_moments = order.map(|i| {
        let e = eig.eigenvectors.column(i);
        (e.transpose() * il * e)[(0, 0)]
    });
    Some(InertiaComparison {
        yarn_moments,
        lumped_moments,
        yarn_mass: mass,
        lumped_mass,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A straight yarn of length L and mass m has m L²/12 about its middle
    /// across it (and 0 along it: degenerate, so `None`); two parallel
    /// yarns 2 d apart add m d² each about the axis between them.
    #[test]
    fn straight_yarns_have_the_textbook_moments() {
        let l = 0.04;
        let d = 0.005;
        let mut yarns = Yarns::new();
        for z in [-d, d] {
            yarns.push_curve(
                &[[0.0, 0.0, z], [l / 2.0, 0.0, z], [l, 0.0, z]],
                false,
                1e-4,
            );
        }
        let lambda = 0.01;
        let m = lambda * l;
        let nodes = [[0.0, 0.0, 0.0]];
        let c = compare_inertia(&yarns, &[lambda; 4], &nodes, &[2.0 * m]).unwrap();
        // About x (along the yarns): 2 m d²; about z: 2 m L²/12; about y: both.
        let want = [
            2.0 * m * d * d,
            2.0 * m * l * l / 12.0,
            2.0 * m * (d * d + l * l / 12.0),
        ];
        for k in 0..3 {
            assert!(
                (c.yarn_moments[k] - want[k]).abs() < 1e-12 * want[2],
                "{c:?}"
            );
        }
        // One node at the yarns' end, holding all the mass: m r² about
        // each axis through the centre, r the distance to it.
        let r2 = (l / 2.0) * (l / 2.0);
        assert!((c.lumped_moments[0] - 0.0).abs() < 1e-15, "{c:?}");
        assert!(
            (c.lumped_moments[1] - 2.0 * m * r2).abs() < 1e-12 * want[2],
            "{c:?}"
        );
        assert!(c.ratios()[2] > 1.0);
        let mut single = Yarns::new();
        single.push_curve(&[[0.0; 3], [l, 0.0, 0.0]], false, 1e-4);
        assert!(compare_inertia(&single, &[lambda], &nodes, &[m]).is_none());
    }
}
