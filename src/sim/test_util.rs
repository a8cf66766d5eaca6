//! Test helpers of the `sim` unit tests: a tiny deterministic generator and
//! random rest tets.

use nalgebra::{Matrix3, Rotation3, Vector3};

use super::element::TetRest;

/// splitmix64: a tiny deterministic generator.
pub(crate) struct Rng(pub(crate) u64);

impl Rng {
    /// Uniform in [0, 1).
    pub(crate) fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Uniform in [-1, 1).
    pub(crate) fn sym(&mut self) -> f64 {
        2.0 * self.next() - 1.0
    }
    /// Log-uniform in [lo, hi).
    pub(crate) fn log_uniform(&mut self, lo: f64, hi: f64) -> f64 {
        (lo.ln() + (hi.ln() - lo.ln()) * self.next()).exp()
    }
    /// Entries uniform in [-1, 1).
    pub(crate) fn mat(&mut self) -> Matrix3<f64> {
        Matrix3::from_fn(|_, _| self.sym())
    }
    /// A random unit vector.
    pub(crate) fn unit(&mut self) -> [f64; 3] {
        let v = Vector3::new(self.sym(), self.sym(), self.sym()).normalize();
        [v[0], v[1], v[2]]
    }
    /// A rotation about a random axis by up to ~5 rad.
    pub(crate) fn rotation(&mut self) -> Matrix3<f64> {
        Rotation3::new(Vector3::new(self.sym(), self.sym(), self.sym()) * 3.0).into_inner()
    }
}

/// A random positively oriented rest tet of size `scale` (m), not too flat.
pub(crate) fn random_rest(scale: f64, rng: &mut Rng) -> TetRest {
    loop {
        let dm = rng.mat() * scale;
        let det = dm.determinant();
        if det > 0.05 * scale.powi(3) {
            return TetRest {
                nodes: [0, 1, 2, 3],
                dm_inv: dm.try_inverse().unwrap(),
                volume: det / 6.0,
            };
        }
    }
}
