//! Forward-mode automatic differentiation for the small hinge elements.
//!
//! The bend/twist energy of one hinge is written once, generic over [`Real`],
//! and evaluated with `f64` (value), [`D1`] (value + gradient) or [`D2`]
//! (value + gradient + dense Hessian) over its `N` local variables. This keeps
//! the derivatives exact for exactly the function whose value is evaluated
//! (reference frames included), which hand-derived DER Hessians are not.

use std::ops::{Add, Div, Mul, Neg, Sub};

/// The scalar operations the element energies use.
pub trait Real:
    Copy
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
{
    /// A constant (zero derivatives).
    fn cst(x: f64) -> Self;
    /// The value part.
    fn val(&self) -> f64;
    /// Multiplication by a constant.
    fn scale(self, s: f64) -> Self;
    /// Addition of a constant.
    fn add_c(self, c: f64) -> Self;
    fn sqrt(self) -> Self;
    fn sin_cos(self) -> (Self, Self);
    /// `atan2(self, x)`: the angle of the point `(x, self)`.
    fn atan2(self, x: Self) -> Self;
}

impl Real for f64 {
    #[inline]
    fn cst(x: f64) -> f64 {
        x
    }
    #[inline]
    fn val(&self) -> f64 {
        *self
    }
    #[inline]
    fn scale(self, s: f64) -> f64 {
        self * s
    }
    #[inline]
    fn add_c(self, c: f64) -> f64 {
        self + c
    }
    #[inline]
    fn sqrt(self) -> f64 {
        f64::sqrt(self)
    }
    #[inline]
    fn sin_cos(self) -> (f64, f64) {
        f64::sin_cos(self)
    }
    #[inline]
    fn atan2(self, x: f64) -> f64 {
        f64::atan2(self, x)
    }
}

/// First-order dual number over `N` variables.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct D1<const N: usize> {
    pub v: f64,
    pub g: [f64; N],
}

impl<const N: usize> D1<N> {
    /// The `i`-th independent variable with value `v`.
    pub fn var(v: f64, i: usize) -> Self {
        let mut g = [0.0; N];
        g[i] = 1.0;
        D1 { v, g }
    }
    /// `f(self)` given `f'` at the value.
    #[inline]
    fn chain(self, f: f64, df: f64) -> Self {
        let mut g = self.g;
        for x in g.iter_mut() {
            *x *= df;
        }
        D1 { v: f, g }
    }
}

impl<const N: usize> Add for D1<N> {
    type Output = Self;
    #[inline]
    fn add(mut self, o: Self) -> Self {
        self.v += o.v;
        for i in 0..N {
            self.g[i] += o.g[i];
        }
        self
    }
}
impl<const N: usize> Sub for D1<N> {
    type Output = Self;
    #[inline]
    fn sub(mut self, o: Self) -> Self {
        self.v -= o.v;
        for i in 0..N {
            self.g[i] -= o.g[i];
        }
        self
    }
}
impl<const N: usize> Neg for D1<N> {
    type Output = Self;
    #[inline]
    fn neg(self) -> Self {
        self.scale(-1.0)
    }
}
impl<const N: usize> Mul for D1<N> {
    type Output = Self;
    #[inline]
    fn mul(self, o: Self) -> Self {
        let mut g = [0.0; N];
        for i in 0..N {
            g[i] = self.v * o.g[i] + o.v * self.g[i];
        }
        D1 { v: self.v * o.v, g }
    }
}
impl<const N: usize> Div for D1<N> {
    type Output = Self;
    #[inline]
    fn div(self, o: Self) -> Self {
        let inv = 1.0 / o.v;
        self * o.chain(inv, -inv * inv)
    }
}

impl<const N: usize> Real for D1<N> {
    #[inline]
    fn cst(x: f64) -> Self {
        D1 { v: x, g: [0.0; N] }
    }
    #[inline]
    fn val(&self) -> f64 {
        self.v
    }
    #[inline]
    fn scale(self, s: f64) -> Self {
        self.chain(self.v * s, s)
    }
    #[inline]
    fn add_c(mut self, c: f64) -> Self {
        self.v += c;
        self
    }
    #[inline]
    fn sqrt(self) -> Self {
        let r = self.v.sqrt();
        self.chain(r, 0.5 / r)
    }
    #[inline]
    fn sin_cos(self) -> (Self, Self) {
        let (s, c) = self.v.sin_cos();
        (self.chain(s, c), self.chain(c, -s))
    }
    #[inline]
    fn atan2(self, x: Self) -> Self {
        let r2 = x.v * x.v + self.v * self.v;
        let (dy, dx) = (x.v / r2, -self.v / r2);
        let mut g = [0.0; N];
        for i in 0..N {
            g[i] = dy * self.g[i] + dx * x.g[i];
        }
        D1 {
            v: self.v.atan2(x.v),
            g,
        }
    }
}

/// Second-order dual number over `N` variables: value, gradient and the
/// Hessian. Only the upper triangle (`h[i][j]`, `j >= i`) is propagated
/// (half the work); [`D2::hessian`] returns the full symmetric matrix.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct D2<const N: usize> {
    pub v: f64,
    pub g: [f64; N],
    pub h: [[f64; N]; N],
}

impl<const N: usize> D2<N> {
    /// The `i`-th independent variable with value `v`.
    pub fn var(v: f64, i: usize) -> Self {
        let mut g = [0.0; N];
        g[i] = 1.0;
        D2 {
            v,
            g,
            h: [[0.0; N]; N],
        }
    }
    /// A dual over `M` variables seen as one over `N`: its variable `k` is
    /// variable `map[k]` here.
    pub fn embed<const M: usize>(d: &D2<M>, map: [usize; M]) -> Self {
        let mut out = D2::cst(d.v);
        for a in 0..M {
            out.g[map[a]] = d.g[a];
            for b in a..M {
                let (i, j) = (map[a].min(map[b]), map[a].max(map[b]));
                out.h[i][j] = d.h[a][b];
            }
        }
        out
    }

    /// The full symmetric Hessian (upper triangle mirrored).
    pub fn hessian(&self) -> [[f64; N]; N] {
        let mut h = self.h;
        for i in 0..N {
            for j in 0..i {
                h[i][j] = h[j][i];
            }
        }
        h
    }

    /// `f(self)` given `f'` and `f''` at the value.
    #[inline]
    fn chain(self, f: f64, df: f64, ddf: f64) -> Self {
        let mut out = D2 {
            v: f,
            g: [0.0; N],
            h: [[0.0; N]; N],
        };
        for i in 0..N {
            out.g[i] = df * self.g[i];
            let gi = ddf * self.g[i];
            for j in i..N {
                out.h[i][j] = df * self.h[i][j] + gi * self.g[j];
            }
        }
        out
    }
}

impl<const N: usize> Add for D2<N> {
    type Output = Self;
    #[inline]
    fn add(mut self, o: Self) -> Self {
        self.v += o.v;
        for i in 0..N {
            self.g[i] += o.g[i];
            for j in i..N {
                self.h[i][j] += o.h[i][j];
            }
        }
        self
    }
}
impl<const N: usize> Sub for D2<N> {
    type Output = Self;
    #[inline]
    fn sub(mut self, o: Self) -> Self {
        self.v -= o.v;
        for i in 0..N {
            self.g[i] -= o.g[i];
            for j in i..N {
                self.h[i][j] -= o.h[i][j];
            }
        }
        self
    }
}
impl<const N: usize> Neg for D2<N> {
    type Output = Self;
    #[inline]
    fn neg(self) -> Self {
        self.scale(-1.0)
    }
}
impl<const N: usize> Mul for D2<N> {
    type Output = Self;
    #[inline]
    fn mul(self, o: Self) -> Self {
        let mut out = D2 {
            v: self.v * o.v,
            g: [0.0; N],
            h: [[0.0; N]; N],
        };
        for i in 0..N {
            out.g[i] = self.v * o.g[i] + o.v * self.g[i];
            let (ai, bi) = (self.g[i], o.g[i]);
            for j in i..N {
                out.h[i][j] =
                    self.v * o.h[i][j] + o.v * self.h[i][j] + ai * o.g[j] + bi * self.g[j];
            }
        }
        out
    }
}
impl<const N: usize> Div for D2<N> {
    type Output = Self;
    #[inline]
    fn div(self, o: Self) -> Self {
        let inv = 1.0 / o.v;
        self * o.chain(inv, -inv * inv, 2.0 * inv * inv * inv)
    }
}

impl<const N: usize> Real for D2<N> {
    #[inline]
    fn cst(x: f64) -> Self {
        D2 {
            v: x,
            g: [0.0; N],
            h: [[0.0; N]; N],
        }
    }
    #[inline]
    fn val(&self) -> f64 {
        self.v
    }
    #[inline]
    fn scale(mut self, s: f64) -> Self {
        self.v *= s;
        for i in 0..N {
            self.g[i] *= s;
            for j in i..N {
                self.h[i][j] *= s;
            }
        }
        self
    }
    #[inline]
    fn add_c(mut self, c: f64) -> Self {
        self.v += c;
        self
    }
    #[inline]
    fn sqrt(self) -> Self {
        let r = self.v.sqrt();
        self.chain(r, 0.5 / r, -0.25 / (r * self.v))
    }
    #[inline]
    fn sin_cos(self) -> (Self, Self) {
        let (s, c) = self.v.sin_cos();
        (self.chain(s, c, -s), self.chain(c, -s, -c))
    }
    #[inline]
    fn atan2(self, x: Self) -> Self {
        // phi = atan2(y, x): phi_y = x / r2, phi_x = -y / r2,
        // phi_yy = -2xy / r2^2 = -phi_xx, phi_xy = (y^2 - x^2) / r2^2.
        let (y0, x0) = (self.v, x.v);
        let r2 = x0 * x0 + y0 * y0;
        let r4 = r2 * r2;
        let (py, px) = (x0 / r2, -y0 / r2);
        let pyy = -2.0 * x0 * y0 / r4;
        let pxx = -pyy;
        let pxy = (y0 * y0 - x0 * x0) / r4;
        let mut out = D2 {
            v: y0.atan2(x0),
            g: [0.0; N],
            h: [[0.0; N]; N],
        };
        for i in 0..N {
            out.g[i] = py * self.g[i] + px * x.g[i];
            let (yi, xi) = (self.g[i], x.g[i]);
            for j in i..N {
                let (yj, xj) = (self.g[j], x.g[j]);
                out.h[i][j] = py * self.h[i][j]
                    + px * x.h[i][j]
                    + pyy * yi * yj
                    + pxx * xi * xj
                    + pxy * (yi * xj + xi * yj);
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A test function using every operation.
    fn f<R: Real>(x: R, y: R) -> R {
        let (s, c) = (x * y).sin_cos();
        let r = (x * x + y * y).add_c(1.0).sqrt();
        y.atan2(x.add_c(0.3)) * s + c / r - x.scale(2.0) + (-y)
    }

    #[test]
    fn derivatives_match_finite_differences() {
        let (x0, y0) = (0.7, -1.3);
        let h = 1e-5;
        let fx = |dx: f64, dy: f64| f(x0 + dx, y0 + dy);
        let gx = (fx(h, 0.0) - fx(-h, 0.0)) / (2.0 * h);
        let gy = (fx(0.0, h) - fx(0.0, -h)) / (2.0 * h);
        let d1 = f(D1::<2>::var(x0, 0), D1::<2>::var(y0, 1));
        assert!((d1.g[0] - gx).abs() < 1e-8 && (d1.g[1] - gy).abs() < 1e-8);
        let d2 = f(D2::<2>::var(x0, 0), D2::<2>::var(y0, 1));
        let hess = d2.hessian();
        assert!((d2.v - fx(0.0, 0.0)).abs() < 1e-14);
        assert!((d2.g[0] - gx).abs() < 1e-8 && (d2.g[1] - gy).abs() < 1e-8);
        // Hessian against differences of the exact (D1) gradient.
        let g = |dx: f64, dy: f64| f(D1::<2>::var(x0 + dx, 0), D1::<2>::var(y0 + dy, 1)).g;
        for j in 0..2 {
            let (p, m) = if j == 0 {
                (g(h, 0.0), g(-h, 0.0))
            } else {
                (g(0.0, h), g(0.0, -h))
            };
            for i in 0..2 {
                let fd = (p[i] - m[i]) / (2.0 * h);
                assert!(
                    (hess[i][j] - fd).abs() < 1e-7,
                    "h[{i}][{j}] {} vs {fd}",
                    hess[i][j]
                );
            }
        }
    }
}
