//! Yarn-yarn Coulomb friction for the quasi-static solver: the lagged,
//! smoothed friction potential of IPC (Li et al. 2020, "Incremental
//! Potential Contact", §5, Eq. 13-16).
//!
//! Per contact (a segment pair in Kaldor contact at the lag), with the lagged
//! normal force magnitude `lambda`, the lagged closest-point parameters
//! `(s, t)` and the lagged tangent basis `T` (two unit vectors orthogonal to
//! the lagged normal force), the relative tangential displacement of the
//! closest points since the start of the load step is
//! `u = T^T [(1-s) da0 + s da1 - (1-t) db0 - t db1]` (`d* = x - x_start`),
//! and the friction potential is `D(u) = mu lambda f0(|u|)` with IPC's C1
//! smoothing (Eq. 15-16, `eps = eps_u`):
//! `f0(y) = -y^3 / (3 eps^2) + y^2 / eps + eps / 3` for `y < eps`, `y` above;
//! `f1 = f0' = 2y/eps - y^2/eps^2` below `eps`, 1 above. Below `eps_u` the
//! contact sticks (a stiff spring, force `mu lambda f1 <= mu lambda`);
//! above it slides with the constant force `mu lambda`.
//!
//! Hessian in `u` (2x2): `mu lambda [ (f1/y) I + (f1' y - f1)/y^3 u u^T ]`,
//! i.e. `mu lambda [ (2/eps - y/eps^2) I - u u^T / (eps^2 y) ]` when sticking
//! (eigenvalues `2(eps - y)/eps^2` and `2/eps - y/eps^2`, both >= 0) and
//! `mu lambda / y (I - u u^T / y^2)` when sliding: PSD as it stands, so the
//! 12x12 Hessian `J^T T H_u T^T J` is exact and PSD (IPC projects it; here
//! nothing needs projecting).
//!
//! Lagging scheme (IPC §5.2): `lambda`, `T`, `(s, t)` and the start
//! positions are fixed while Newton runs, so `D` is a smooth function of
//! `q`. The caller lags at the start of every load step (or implicit-Euler
//! step) from the state there ([`FrictionTerm::lag`] with `q == start`),
//! and may refresh `lambda`, `T`, `(s, t)` and the contact set from the new
//! equilibrium, keeping the start positions, and solve again (IPC's lagged
//! iterations; [`FrictionParams::lag_updates`]). Contacts that appear
//! within a step carry no friction until the next refresh.
//!
//! Carried anchors (our addition to IPC): plain IPC measures `u` from the
//! step start, so at every new step each contact's friction force starts
//! at zero and a loaded contact creeps by up to `eps_u` before it holds
//! again (IPC's `eps_v h` drift; a hanging swatch would creep ~eps_u per
//! implicit-Euler step). [`FrictionTerm::carry`] hands each contact's
//! elastic tangential offset (its `u` clipped to length `eps_u`: all of it
//! when sticking, the part that holds `mu lambda` when sliding) to the
//! next lag of the same segment pair, which adds it to `u` (projected onto
//! the new tangent plane). The force then continues across steps; only
//! slip beyond `eps_u` dissipates.

use super::contact::ContactTerm;
use super::term::{EnergyTerm, Triplets};
use crate::geom::vec3::{cross, dot, norm, scale};
use crate::geom::Vec3;
use crate::yarn::sim::contact::segment_closest_params;

/// Friction controls (SI units).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct FrictionParams {
    /// Coulomb coefficient mu of yarn-on-yarn friction (dimensionless; 0
    /// turns friction off). Default 0.25: wool and cotton yarn-on-yarn
    /// friction coefficients of about 0.2-0.3 are the usual textile figures
    /// (e.g. Gupta & El Mogahzy 1991, "Friction in fibrous materials",
    /// Textile Res. J. 61(9)); none of the project's papers states one:
    /// Sperl 2022 §5 and HYLC 2020 §5 leave friction out.
    pub mu: f64,
    /// Stick distance eps_u (m): tangential slip below it is elastic
    /// sticking, above it sliding at `mu lambda` (IPC §5.1, `eps_v h`).
    /// Default 1e-5 m, 1% of a 1 mm yarn radius (small against a load
    /// step's motion, large enough that Newton sees a smooth potential).
    pub stick_distance: f64,
    /// Lag refreshes per load step: after an equilibrium, `lambda`, the
    /// tangent bases and the contact set are recomputed there (start
    /// positions kept) and the equilibrium is solved again. Default 1.
    pub lag_updates: usize,
}

impl Default for FrictionParams {
    fn default() -> Self {
        FrictionParams {
            mu: 0.25,
            stick_distance: 1e-5,
            lag_updates: 1,
        }
    }
}

impl FrictionParams {
    /// Frictionless (`mu` = 0).
    pub fn off() -> FrictionParams {
        FrictionParams {
            mu: 0.0,
            ..FrictionParams::default()
        }
    }

    pub fn is_on(&self) -> bool {
        self.mu > 0.0
    }

    pub fn is_valid(&self) -> bool {
        self.mu.is_finite()
            && self.mu >= 0.0
            && self.stick_distance.is_finite()
            && self.stick_distance > 0.0
            && self.lag_updates <= 100
    }
}

/// One lagged frictional contact.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrictionContact {
    /// Vertices `(a0, a1, b0, b1)` of the two segments.
    pub vertices: [usize; 4],
    /// Closest-point parameters on segment A and B at the lag.
    pub s: f64,
    pub t: f64,
    /// Normal force magnitude lambda at the lag (N).
    pub normal_force: f64,
    /// Orthonormal tangent basis, orthogonal to the lagged normal force.
    pub basis: [Vec3; 2],
    /// Positions of the four vertices at the start of the step (m).
    pub start: [Vec3; 4],
    /// Carried elastic tangential offset (m, world frame, in the tangent
    /// plane) added to the displacement; zero for a new contact.
    pub offset: Vec3,
}

/// Elastic tangential offsets carried from one lag to the next, by the
/// segment pair's vertices `(a0, a1, b0, b1)`.
pub type Carry = std::collections::HashMap<[usize; 4], Vec3>;

/// The friction potential `sum mu lambda f0(|u|)` over lagged contacts.
#[derive(Debug, Clone, Default)]
pub struct FrictionTerm {
    /// Coulomb coefficient (dimensionless).
    pub mu: f64,
    /// eps_u (m).
    pub stick_distance: f64,
    contacts: Vec<FrictionContact>,
}

/// `f0` of IPC Eq. 15 (m).
pub(crate) fn f0(y: f64, eps: f64) -> f64 {
    if y < eps {
        -y * y * y / (3.0 * eps * eps) + y * y / eps + eps / 3.0
    } else {
        y
    }
}

/// `f1(y) / y` (1/m), finite at 0.
pub(crate) fn f1_over_y(y: f64, eps: f64) -> f64 {
    if y < eps {
        2.0 / eps - y / (eps * eps)
    } else {
        1.0 / y
    }
}

/// A unit vector pair spanning the plane orthogonal to unit `n`.
pub(crate) fn tangent_basis(n: Vec3) -> [Vec3; 2] {
    let k = (0..3)
        .min_by(|&a, &b| n[a].abs().total_cmp(&n[b].abs()))
        .unwrap_or(0);
    let mut e = [0.0; 3];
    e[k] = 1.0;
    let t1 = cross(n, e);
    let t1 = scale(t1, 1.0 / norm(t1));
    [t1, cross(n, t1)]
}

fn point(q: &[f64], v: usize) -> Vec3 {
    [q[3 * v], q[3 * v + 1], q[3 * v + 2]]
}

impl FrictionContact {
    /// Weights of the four vertices in the relative displacement.
    fn shape(&self) -> [f64; 4] {
        [1.0 - self.s, self.s, -(1.0 - self.t), -self.t]
    }

    /// Relative tangential displacement `u` (m) at `q`, carried offset
    /// included.
    pub fn slip(&self, q: &[f64]) -> [f64; 2] {
        let sh = self.shape();
        let mut d = self.offset;
        for (j, &w) in sh.iter().enumerate() {
            let x = point(q, self.vertices[j]);
            for c in 0..3 {
                d[c] += w * (x[c] - self.start[j][c]);
            }
        }
        [dot(self.basis[0], d), dot(self.basis[1], d)]
    }
}

impl FrictionTerm {
    /// A term without contacts.
    pub fn new(params: &FrictionParams) -> FrictionTerm {
        FrictionTerm {
            mu: params.mu,
            stick_distance: params.stick_distance,
            contacts: Vec::new(),
        }
    }

    pub fn contacts(&self) -> &[FrictionContact] {
        &self.contacts
    }

    pub fn set_contacts(&mut self, contacts: Vec<FrictionContact>) {
        self.contacts = contacts;
    }

    /// Lags the friction on the pairs `contact` has in contact at `q` (its
    /// candidate set must have been built at `q`: `begin_iteration`):
    /// normal forces, tangent bases and closest points from `q`, start
    /// positions from `start` (the state at the start of the load step;
    /// `q` itself when the step begins). Nothing when `mu` is 0.
    pub fn lag(&mut self, contact: &ContactTerm, q: &[f64], start: &[f64]) {
        self.lag_carrying(contact, q, start, &Carry::new());
    }

    /// The elastic offsets to carry into the next step's lag (module docs):
    /// per segment pair, `T u(q)` clipped to length `eps_u`.
    pub fn carry(&self, q: &[f64]) -> Carry {
        self.contacts
            .iter()
            .map(|c| {
                let w = elastic_offset(c.slip(q), &c.basis, self.stick_distance);
                (c.vertices, w)
            })
            .collect()
    }

    /// [`FrictionTerm::lag`], each contact starting from its segment pair's
    /// offset in `carry` (projected onto the new tangent plane) if any.
    pub fn lag_carrying(&mut self, contact: &ContactTerm, q: &[f64], start: &[f64], carry: &Carry) {
        self.contacts.clear();
        if !(self.mu > 0.0) {
            return;
        }
        for (ids, g) in contact.active_pair_gradients(q) {
            // Force of the contact on segment A: its magnitude is lambda,
            // its direction the normal (robust for parallel segments,
            // whose closest-point direction is not unique).
            let fa = [-(g[0] + g[3]), -(g[1] + g[4]), -(g[2] + g[5])];
            let lambda = norm(fa);
            if !(lambda > 0.0 && lambda.is_finite()) {
                continue;
            }
            let x = ids.map(|v| point(q, v));
            let (s, t) = segment_closest_params(x[0], x[1], x[2], x[3]);
            let basis = tangent_basis(scale(fa, 1.0 / lambda));
            let offset = carry
                .get(&ids)
                .map_or([0.0; 3], |w| onto_tangent_plane(*w, &basis));
            self.contacts.push(FrictionContact {
                vertices: ids,
                s,
                t,
                normal_force: lambda,
                basis,
                start: ids.map(|v| point(start, v)),
                offset,
            });
        }
    }

    /// `|u|` (m) of every contact at `q`.
    pub fn slips(&self, q: &[f64]) -> Vec<f64> {
        self.contacts
            .iter()
            .map(|c| {
                let u = c.slip(q);
                (u[0] * u[0] + u[1] * u[1]).sqrt()
            })
            .collect()
    }

    /// Sum of the contacts' sliding force bounds `mu lambda` (N).
    pub fn total_capacity(&self) -> f64 {
        self.mu * self.contacts.iter().map(|c| c.normal_force).sum::<f64>()
    }
}

/// The elastic part of a slip `u` (in the tangent `basis`) to carry into
/// the next lag: `T u` clipped to length `eps` (m, world frame).
pub(crate) fn elastic_offset(u: [f64; 2], basis: &[Vec3; 2], eps: f64) -> Vec3 {
    let y = (u[0] * u[0] + u[1] * u[1]).sqrt();
    let f = if y > eps { eps / y } else { 1.0 };
    std::array::from_fn(|i| f * (u[0] * basis[0][i] + u[1] * basis[1][i]))
}

/// `w` projected onto the plane spanned by the orthonormal `basis`.
pub(crate) fn onto_tangent_plane(w: Vec3, basis: &[Vec3; 2]) -> Vec3 {
    let (a, b) = (dot(w, basis[0]), dot(w, basis[1]));
    std::array::from_fn(|i| a * basis[0][i] + b * basis[1][i])
}

/// `T H_u T^T` (3x3, N/m): the PSD Hessian of `k f0(|u|)` (module docs)
/// with respect to the world displacement, `u = T^T d` in the tangent
/// `basis` T.
pub(crate) fn slip_hessian_world(
    k: f64,
    u: [f64; 2],
    eps: f64,
    basis: &[Vec3; 2],
) -> [[f64; 3]; 3] {
    let y = (u[0] * u[0] + u[1] * u[1]).sqrt();
    let fy = f1_over_y(y, eps);
    let mut hu = [[k * fy, 0.0], [0.0, k * fy]];
    if y > 0.0 {
        let cu = if y < eps {
            -k / (eps * eps * y)
        } else {
            -k / (y * y * y)
        };
        for a in 0..2 {
            for b in 0..2 {
                hu[a][b] += cu * u[a] * u[b];
            }
        }
    }
    let mut m = [[0.0; 3]; 3];
    for (a, ta) in basis.iter().enumerate() {
        for (b, tb) in basis.iter().enumerate() {
            for i in 0..3 {
                for l in 0..3 {
                    m[i][l] += hu[a][b] * ta[i] * tb[l];
                }
            }
        }
    }
    m
}

impl EnergyTerm for FrictionTerm {
    fn name(&self) -> &'static str {
        "friction"
    }

    fn eval(&self, q: &[f64], grad: &mut [f64], mut hess: Option<&mut Triplets>) -> f64 {
        let eps = self.stick_distance;
        let mut e = 0.0;
        for c in &self.contacts {
            let k = self.mu * c.normal_force;
            let u = c.slip(q);
            let y = (u[0] * u[0] + u[1] * u[1]).sqrt();
            e += k * f0(y, eps);
            let fy = f1_over_y(y, eps);
            // dD/du, then to the world and the four vertices.
            let gu = [k * fy * u[0], k * fy * u[1]];
            let gw: Vec3 = std::array::from_fn(|i| gu[0] * c.basis[0][i] + gu[1] * c.basis[1][i]);
            let sh = c.shape();
            for (j, &w) in sh.iter().enumerate() {
                for i in 0..3 {
                    grad[3 * c.vertices[j] + i] += w * gw[i];
                }
            }
            let Some(h) = hess.as_deref_mut() else {
                continue;
            };
            let m = slip_hessian_world(k, u, eps, &c.basis);
            let dofs: Vec<usize> = c
                .vertices
                .iter()
                .flat_map(|&v| [3 * v, 3 * v + 1, 3 * v + 2])
                .collect();
            let mut block = vec![0.0; 144];
            for (j1, &w1) in sh.iter().enumerate() {
                for (j2, &w2) in sh.iter().enumerate() {
                    for i in 0..3 {
                        for l in 0..3 {
                            block[(3 * j1 + i) * 12 + 3 * j2 + l] = w1 * w2 * m[i][l];
                        }
                    }
                }
            }
            h.push_block(&dofs, &block);
        }
        e
    }
}
