//! Harmonic bases of VH §6.5 (Eq. 23-24): the `r` lowest eigenvectors of
//! the tet-mesh graph Laplacian (tets adjacent when they share a face;
//! `L = D - A`).
//!
//! The first basis vector is the normalized constant (so the rank-1 stage
//! fits a uniform material, as VH states); the others come from block
//! inverse (subspace) iteration with Rayleigh-Ritz on `L + σ I`, `σ` a tiny
//! shift that makes it SPD, factorized once by sparse Cholesky
//! ([`crate::linalg::cholesky::SparseCholesky`]), and are kept orthogonal to
//! the constant. Start vectors are a fixed pseudo-random block, so the
//! result is deterministic. Columns are orthonormal.

use std::collections::HashMap;

use faer::sparse::{SparseColMat, Triplet};
use faer::Mat;
use nalgebra::DMatrix;

use crate::geom::TetMesh;
use crate::linalg::cholesky::SparseCholesky;
use crate::linalg::LinalgError;

/// Why the harmonic basis could not be computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum HarmonicError {
    /// faer could not build the Laplacian from its entries.
    #[error(transparent)]
    Matrix(LinalgError),
    /// The shifted Laplacian could not be factored.
    #[error("Laplacian: {0}")]
    Laplacian(LinalgError),
}

/// Graph Laplacian of the tets' face adjacency: entries (row, col, value).
pub fn tet_laplacian(mesh: &TetMesh) -> Vec<(usize, usize, f64)> {
    let mut faces: HashMap<[u32; 3], Vec<usize>> = HashMap::new();
    for (t, tet) in mesh.tets.iter().enumerate() {
        for skip in 0..4 {
            let mut f = [0u32; 3];
            let mut k = 0;
            for (a, &v) in tet.iter().enumerate() {
                if a != skip {
                    f[k] = v;
                    k += 1;
                }
            }
            f.sort_unstable();
            faces.entry(f).or_default().push(t);
        }
    }
    let mut pairs: Vec<(usize, usize)> = faces
        .values()
        .filter(|ts| ts.len() == 2)
        .map(|ts| (ts[0].min(ts[1]), ts[0].max(ts[1])))
        .collect();
    pairs.sort_unstable();
    let mut degree = vec![0.0; mesh.num_tets()];
    let mut out = Vec::with_capacity(pairs.len() * 2 + degree.len());
    for &(a, b) in &pairs {
        out.push((a, b, -1.0));
        out.push((b, a, -1.0));
        degree[a] += 1.0;
        degree[b] += 1.0;
    }
    out.extend(degree.iter().enumerate().map(|(i, &d)| (i, i, d)));
    out
}

fn pseudo_random(i: usize, j: usize) -> f64 {
    let mut z = (i as u64)
        .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add((j as u64 + 1).wrapping_mul(0xBF58_476D_1CE4_E5B9));
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64 - 0.5
}

/// Orthonormalizes the columns of `x` against the constant vector and each
/// other (modified Gram-Schmidt, twice).
fn orthonormalize(x: &mut DMatrix<f64>) {
    let n = x.nrows();
    let c = 1.0 / (n as f64).sqrt();
    for _ in 0..2 {
        for j in 0..x.ncols() {
            let mean: f64 = x.column(j).sum() * c;
            x.column_mut(j).add_scalar_mut(-mean * c);
            for k in 0..j {
                let d = x.column(j).dot(&x.column(k));
                let ck = x.column(k).clone_owned();
                x.column_mut(j).axpy(-d, &ck, 1.0);
            }
            let nrm = x.column(j).norm();
            if nrm > 0.0 {
                x.column_mut(j).scale_mut(1.0 / nrm);
            }
        }
    }
}

/// The `r` lowest eigenvectors of [`tet_laplacian`] as the columns of an
/// `n_E x r` matrix (first column constant). `r` is capped at `n_E`.
pub fn harmonic_basis(mesh: &TetMesh, r: usize) -> Result<DMatrix<f64>, HarmonicError> {
    let n = mesh.num_tets();
    let r = r.min(n);
    let mut h = DMatrix::zeros(n, r);
    if r == 0 {
        return Ok(h);
    }
    h.column_mut(0).fill(1.0 / (n as f64).sqrt());
    if r == 1 {
        return Ok(h);
    }
    let lap = tet_laplacian(mesh);
    // Lower triangle of L + σ I for the Cholesky factor.
    let sigma = 1e-6;
    let trip: Vec<Triplet<usize, usize, f64>> = lap
        .iter()
        .filter(|(i, j, _)| i >= j)
        .map(|&(i, j, v)| Triplet::new(i, j, v + if i == j { sigma } else { 0.0 }))
        .collect();
    let lower = SparseColMat::try_new_from_triplets(n, n, &trip)
        .map_err(|e| HarmonicError::Matrix(LinalgError::InvalidPattern(e)))?;
    let chol = SparseCholesky::new(lower.as_ref()).map_err(HarmonicError::Laplacian)?;
    let apply_l = |x: &DMatrix<f64>| {
        let mut y = DMatrix::zeros(x.nrows(), x.ncols());
        for &(i, j, v) in &lap {
            for c in 0..x.ncols() {
                y[(i, c)] += v * x[(j, c)];
            }
        }
        y
    };
    // Block: the r - 1 wanted non-constant vectors plus a guard band.
    let want = r - 1;
    let p = (want + want.max(8)).min(n - 1);
    if p == 0 {
        return Ok(h);
    }
    let mut x = DMatrix::from_fn(n, p, pseudo_random);
    orthonormalize(&mut x);
    let mut last: Vec<f64> = vec![f64::INFINITY; want];
    for _ in 0..500 {
        let mut rhs = Mat::<f64>::from_fn(n, p, |i, j| x[(i, j)]);
        chol.solve_in_place(rhs.as_mut());
        x = DMatrix::from_fn(n, p, |i, j| rhs[(i, j)]);
        orthonormalize(&mut x);
        // Rayleigh-Ritz.
        let t = x.transpose() * apply_l(&x);
        let eig = (0.5 * (&t + t.transpose())).symmetric_eigen();
        let mut order: Vec<usize> = (0..p).collect();
        order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
        let v = DMatrix::from_fn(p, p, |i, j| eig.eigenvectors[(i, order[j])]);
        x = &x * v;
        let vals: Vec<f64> = order[..want].iter().map(|&k| eig.eigenvalues[k]).collect();
        let converged = vals
            .iter()
            .zip(&last)
            .all(|(a, b)| (a - b).abs() <= 1e-10 * (a.abs() + 1e-12));
        last = vals;
        if converged {
            break;
        }
    }
    for j in 0..want {
        h.set_column(j + 1, &x.column(j));
    }
    Ok(h)
}
