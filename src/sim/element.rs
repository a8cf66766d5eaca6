//! One tet element's kinematics shared by the energy, its Hessian and the
//! fibre families: rest data, the map from `∂E/∂F` to node gradients, and the
//! 12-dimensional element vectors and matrices.

use nalgebra::{Matrix3, SMatrix, SVector, Vector3};

/// Rest data of one tet.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TetRest {
    /// Node indices.
    pub nodes: [usize; 4],
    /// `Dm⁻¹` (1/m).
    pub dm_inv: Matrix3<f64>,
    /// Rest volume `V_e` (m³), positive.
    pub volume: f64,
}

/// 12x12 element matrix (node-major: row `3 a + c` is coordinate `c` of node `a`).
pub type Mat12 = SMatrix<f64, 12, 12>;
/// 12-vector of node gradients (same layout as [`Mat12`]).
pub type Vec12 = SVector<f64, 12>;

/// Maps `∂E/∂F` of a tet to the gradients (N) at its four nodes:
/// `H = (∂E/∂F) Dm⁻ᵀ`, nodes 1-3 get the columns of `H`, node 0 minus their sum.
pub fn node_gradients(de_df: &Matrix3<f64>, dm_inv: &Matrix3<f64>) -> [Vector3<f64>; 4] {
    let h = de_df * dm_inv.transpose();
    let (c1, c2, c3) = (
        h.column(0).into_owned(),
        h.column(1).into_owned(),
        h.column(2).into_owned(),
    );
    [-(c1 + c2 + c3), c1, c2, c3]
}

/// `c_a = ∇N_a · d` of a fibre direction `d`: `F d = Σ_a c_a x_a` (1/m).
pub fn node_coefficients(rest: &TetRest, d: &[f64; 3]) -> [f64; 4] {
    let c = rest.dm_inv * Vector3::new(d[0], d[1], d[2]);
    [-(c[0] + c[1] + c[2]), c[0], c[1], c[2]]
}
