//! The clamp-force term of a frame's loss: what a tensile tester reads.
//!
//! A pose driven by clamps has nearly the same shape under a stiff material
//! and a soft one, so the positions of VH Eq. 10 barely see the scale or
//! the knit material's stiffening; the force each clamped band holds does.
//! Per held band `b` of a frame, the wrench of the homogenized clamp forces
//! `c_i = ∂E/∂x_i - f_ext_i` on its nodes (resultant force, and moment
//! about the band's centroid over a length `L`, so that both are forces)
//! is compared with the yarn level's:
//!
//! `ε_F = w Σ_b |W_b(x, γ) - R_b|²`,  `W_b = Σ_{i ∈ b} A_i c_i`,
//! `A_i = [I; [r_i]ₓ / L]` (6 x 3), `r_i = x_i - x̄_b`.
//!
//! The held nodes do not move, so `A_i` is constant and `W_b` is linear in
//! the clamp forces. With the free DOFs at equilibrium (`g_f(x_f, γ) = 0`),
//! `dW/dγ = A (C_h - K_hf K_ff⁻¹ C_f)` (`K_hf = ∂c_h/∂x_f`, `C = ∂g/∂γ` on
//! the held and the free rows), which [`super::adjoint::linearize`]
//! computes with one solve per wrench component. Units: `W`, `R` in N,
//! `w` in m³/N², so `ε_F` is in the loss's m³.

use crate::geom::Vec3;

/// One held band's target: its nodes (held in the frame) and the yarn
/// level's wrench on them (N; force, then moment / `L`).
#[derive(Debug, Clone, PartialEq)]
pub struct BandForce {
    pub nodes: Vec<usize>,
    pub target: [f64; 6],
}

/// The clamp-force term of one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct ForceTarget {
    /// The held bands compared (their nodes must be pinned in the frame).
    pub bands: Vec<BandForce>,
    /// `L` (m, > 0): the length that makes a moment a force (the mesh's
    /// size).
    pub length: f64,
    /// `w` (m³/N², >= 0).
    pub weight: f64,
}

/// Resultant force and moment (about the band's centroid, divided by
/// `length`) of the node forces `f` over `band` at positions `x`, as one
/// 6-vector.
pub fn wrench(band: &[usize], x: &[Vec3], f: &[Vec3], length: f64) -> [f64; 6] {
    let c = centroid(band, x);
    let mut w = [0.0; 6];
    for &i in band {
        let r: Vec3 = std::array::from_fn(|d| x[i][d] - c[d]);
        let m = crate::geom::vec3::cross(r, f[i]);
        for d in 0..3 {
            w[d] += f[i][d];
            w[3 + d] += m[d] / length;
        }
    }
    w
}

fn centroid(band: &[usize], x: &[Vec3]) -> Vec3 {
    let k = band.len().max(1) as f64;
    std::array::from_fn(|d| band.iter().map(|&i| x[i][d]).sum::<f64>() / k)
}

/// `A_i` of every node of `band` at positions `x`: row `w` of the wrench
/// takes `Σ_d a[w][d] c_i[d]` from node `i`'s clamp force.
pub(crate) fn wrench_coefficients(band: &[usize], x: &[Vec3], length: f64) -> Vec<[[f64; 3]; 6]> {
    let c = centroid(band, x);
    band.iter()
        .map(|&i| {
            let r: Vec3 = std::array::from_fn(|d| x[i][d] - c[d]);
            let l = length;
            [
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.0, 0.0, 1.0],
                // (r × c)_x = r_y c_z - r_z c_y, and so on.
                [0.0, -r[2] / l, r[1] / l],
                [r[2] / l, 0.0, -r[0] / l],
                [-r[1] / l, r[0] / l, 0.0],
            ]
        })
        .collect()
}

impl ForceTarget {
    /// Per band, `W_b - R_b` (N) for the energy gradient `grad` (N, every
    /// node) and external forces `f_ext` (N) at positions `x`.
    pub fn residuals(&self, x: &[Vec3], grad: &[Vec3], f_ext: &[Vec3]) -> Vec<[f64; 6]> {
        let clamp: Vec<Vec3> = grad
            .iter()
            .zip(f_ext)
            .map(|(a, b)| std::array::from_fn(|d| a[d] - b[d]))
            .collect();
        self.bands
            .iter()
            .map(|b| {
                let w = wrench(&b.nodes, x, &clamp, self.length);
                std::array::from_fn(|k| w[k] - b.target[k])
            })
            .collect()
    }

    /// `ε_F = w Σ_b |W_b - R_b|²` (m³).
    pub fn loss(&self, x: &[Vec3], grad: &[Vec3], f_ext: &[Vec3]) -> f64 {
        self.weight
            * self
                .residuals(x, grad, f_ext)
                .iter()
                .flatten()
                .map(|v| v * v)
                .sum::<f64>()
    }

    /// `Σ_b |R_b|²` (N²): the scale of the relative misfit.
    pub fn target_norm2(&self) -> f64 {
        self.bands
            .iter()
            .flat_map(|b| b.target)
            .map(|v| v * v)
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_wrench_coefficients_reproduce_the_wrench() {
        let x: Vec<Vec3> = vec![
            [0.0, 0.0, 0.0],
            [0.01, 0.002, -0.003],
            [0.004, 0.02, 0.001],
            [0.3, 0.3, 0.3],
        ];
        let f: Vec<Vec3> = vec![
            [0.1, -0.2, 0.3],
            [0.5, 0.1, -0.4],
            [-0.2, 0.7, 0.05],
            [9.0; 3],
        ];
        let band = [0usize, 1, 2];
        let w = wrench(&band, &x, &f, 0.05);
        let a = wrench_coefficients(&band, &x, 0.05);
        for k in 0..6 {
            let v: f64 = band
                .iter()
                .zip(&a)
                .map(|(&i, ai)| (0..3).map(|d| ai[k][d] * f[i][d]).sum::<f64>())
                .sum();
            assert!((v - w[k]).abs() <= 1e-14, "row {k}: {v} against {}", w[k]);
        }
        // The moment about the centroid is not trivially zero here.
        assert!(w[3..].iter().any(|m| m.abs() > 1e-3), "{w:?}");
    }
}
