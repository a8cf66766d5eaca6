//! Parameters of the yarn-level simulator (SI units).
//!
//! Material values default to the stockinette row of HYLC (Sperl et al. 2020)
//! Table 1; contact, damping and time-step controls follow Leaf et al. 2018
//! §3.1 and Appendix A-B (Kaldor et al. 2008 model).

use super::YarnSimError;
use crate::geom::Vec3;

/// Every physical and numerical parameter of [`super::YarnSim`].
///
/// The yarn radius is not a parameter: it comes from the [`crate::geom::Yarns`]
/// (per curve or per vertex).
/// Deserializes from a table of field overrides (scene files' `[sim]`):
/// missing fields keep their defaults, unknown ones are errors.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct YarnSimParams {
    /// Young's modulus E of the yarn (Pa). Stretch stiffness is `E * pi r^2`
    /// (N). Default 5e5 Pa: HYLC Table 1, stockinette and rib.
    pub youngs_modulus: f64,
    /// Bending scale gamma multiplying the rod bending stiffness
    /// `E * pi r^4 / 4` (dimensionless; HYLC Eq. 23). Default 0.3, not
    /// HYLC Table 1's 1e-3: with 1e-3 a 6 cm rib stretched 30% pulls back
    /// with ~2e-4 N where fabrics need 0.1-5 N. 0.3 (1.2e-7 N m^2 at r = 1
    /// mm) lies inside Sperl 2022 §7.3.2's fitted range, 1e-3 to 10 times
    /// the base rod stiffness `k_s R^2 / 4`. Under a scale of 1 a 1x1 rib
    /// stretched 30% along the courses narrows only 0.029 (the fabric
    /// checks ask 0.05; 0.058 at 0.3, 0.052 when the relaxation contracts
    /// the swatch first), while the other stretch bounds hold at both. The quasi-static fabric takes the same
    /// value.
    pub bend_scale: f64,
    /// Contact stiffness k_contact of the Kaldor potential (kg/s^2 = J/m^2):
    /// `E_c = k_contact * int int f(d) ds ds'` over arclength (Leaf Eq. 9-10).
    /// Default 60: HYLC Table 1, stockinette and rib.
    pub contact_stiffness: f64,
    /// Mass density of the yarn (kg/m^3); linear density is `rho * pi r^2`
    /// unless the yarns carry a linear density. Default 120: HYLC Table 1,
    /// stockinette.
    pub density: f64,
    /// Mass-proportional global damping c (1/s): force `-c m v` per vertex,
    /// the lumped form of Leaf Eq. 11 (`c = 2 k_global / mu`). Integrated
    /// implicitly, so any value is stable. Default 2 /s (mild: a knit
    /// swatch's slow modes decay over about half a second; chosen, not
    /// published).
    pub global_damping: f64,
    /// Normal contact damping k_dn (kg/(m^2 s)) of Leaf Eq. 12 (force
    /// `-dD/dv` of the dissipation D as printed), applied to sample pairs in
    /// contact. Default 2e3: a fraction of critical damping for a yarn
    /// crossing at r = 0.4-1 mm with the default stiffness, and small enough
    /// that its explicit limit `2 m / c` stays above the stiffness limit
    /// (our choice; Leaf cites Kaldor 2008 Table 1, which the papers do not
    /// reproduce).
    pub contact_damping_normal: f64,
    /// Tangential contact damping k_dt (kg/(m^2 s)) of Leaf Eq. 12; acts as a
    /// viscous stand-in for friction. Default 2e2 (a tenth of k_dn; chosen).
    pub contact_damping_tangent: f64,
    /// Gravity (m/s^2), +Y up. Default [0, -9.81, 0].
    pub gravity: Vec3,
    /// Per-step displacement bound as a fraction eps of the yarn radius: no
    /// vertex (hence no point of a linear segment) moves more than `eps * r`
    /// in one step (Leaf Eq. 2, Appendix A). Default 0.1 (Leaf allows
    /// (0, 1]).
    pub max_step_displacement: f64,
    /// Largest time step (s). Default 4e-4 s: Leaf §3.1 default step.
    pub max_dt: f64,
    /// Smallest admissible time step (s); a step bound below it is reported
    /// as divergence. Default 1e-10 s.
    pub min_dt: f64,
    /// Courant factor applied to the explicit stability limit `2 / omega_max`
    /// of symplectic Euler (omega_max from a Gershgorin bound of the stiffness,
    /// recomputed every step including the contacts). The Gershgorin bound
    /// is an upper bound of omega_max^2, so any value below 1 is stable for
    /// the linearized system; default 0.7 leaves room for the contact
    /// stiffness changing within a step.
    pub cfl: f64,
    /// Contact skin as a fraction of the yarn radius: candidate pairs are
    /// found within `r_a + r_b + 2 skin` and reused until the accumulated
    /// maximum vertex motion exceeds `skin` (errata note on pair reuse;
    /// Leaf Algorithm 1). Default 0.5.
    pub contact_skin: f64,
    /// Segments closer along the same yarn than this arclength gap, in units
    /// of the sum of radii, do not interact by contact (Leaf: only
    /// |i - j| > 1; with segments shorter than 2r the nearest neighbours along
    /// the yarn overlap at rest and must be excluded too). Default 2.0.
    pub contact_exclusion: f64,
    /// Contact quadrature: largest sample spacing along a segment as a
    /// fraction of the radius; the sample count is odd (Simpson) and at least
    /// 3 (Leaf §3.1: N_S odd and N_S > L_min / 2r). Default 1.0.
    pub contact_sample_spacing: f64,
    /// Divergence guard: largest vertex speed (m/s). Default 1e3.
    pub max_speed: f64,
    /// Divergence guard: largest internal energy per vertex (J). Default 1.0
    /// (orders of magnitude above a fully stretched yarn).
    pub max_energy_per_vertex: f64,
    /// Most steps one `advance` call may take. Default 10_000_000.
    pub max_steps_per_advance: u64,
}

impl Default for YarnSimParams {
    fn default() -> Self {
        YarnSimParams {
            youngs_modulus: 5e5,
            bend_scale: 0.3,
            contact_stiffness: 60.0,
            density: 120.0,
            global_damping: 2.0,
            contact_damping_normal: 2e3,
            contact_damping_tangent: 2e2,
            gravity: [0.0, -9.81, 0.0],
            max_step_displacement: 0.1,
            max_dt: 4e-4,
            min_dt: 1e-10,
            cfl: 0.7,
            contact_skin: 0.5,
            contact_exclusion: 2.0,
            contact_sample_spacing: 1.0,
            max_speed: 1e3,
            max_energy_per_vertex: 1.0,
            max_steps_per_advance: 10_000_000,
        }
    }
}

impl YarnSimParams {
    /// Checks every field's range.
    pub fn validate(&self) -> Result<(), YarnSimError> {
        let nonneg = [
            ("youngs_modulus", self.youngs_modulus),
            ("bend_scale", self.bend_scale),
            ("contact_stiffness", self.contact_stiffness),
            ("global_damping", self.global_damping),
            ("contact_damping_normal", self.contact_damping_normal),
            ("contact_damping_tangent", self.contact_damping_tangent),
            ("contact_exclusion", self.contact_exclusion),
        ];
        for (name, v) in nonneg {
            if !(v.is_finite() && v >= 0.0) {
                return Err(YarnSimError::Param {
                    name,
                    message: format!("{v} is not a non-negative finite number"),
                });
            }
        }
        let pos = [
            ("density", self.density),
            ("max_step_displacement", self.max_step_displacement),
            ("max_dt", self.max_dt),
            ("min_dt", self.min_dt),
            ("cfl", self.cfl),
            ("contact_skin", self.contact_skin),
            ("contact_sample_spacing", self.contact_sample_spacing),
            ("max_speed", self.max_speed),
            ("max_energy_per_vertex", self.max_energy_per_vertex),
        ];
        for (name, v) in pos {
            if !(v > 0.0 && v.is_finite()) {
                return Err(YarnSimError::Param {
                    name,
                    message: format!("{v} is not a positive finite number"),
                });
            }
        }
        if self.min_dt > self.max_dt {
            return Err(YarnSimError::Param {
                name: "min_dt",
                message: format!(
                    "{} s is larger than max_dt ({} s)",
                    self.min_dt, self.max_dt
                ),
            });
        }
        if self.gravity.iter().any(|g| !g.is_finite()) {
            return Err(YarnSimError::Param {
                name: "gravity",
                message: format!("{:?} is not finite", self.gravity),
            });
        }
        if self.max_steps_per_advance == 0 {
            return Err(YarnSimError::Param {
                name: "max_steps_per_advance",
                message: "must be at least 1".into(),
            });
        }
        Ok(())
    }

    /// Parameters of the radius-scaled model (Leaf §6.2, Eq. 3-4, with the
    /// errata: positions, rest lengths and radii multiplied by `gamma`).
    ///
    /// With these values the scaled state `gamma * q` has exactly the energy
    /// of `q` under `self`, and the same kinetic energy, so the scaled model
    /// follows the same trajectory up to the spatial scale:
    /// bending stiffness `E I` -> x gamma (Leaf k'_bend = gamma k_bend; here it
    /// follows from `E' = gamma^-3 E` on `I' = gamma^4 I`), contact `k' = gamma^-2 k` (Leaf), stretch `E A / l` is
    /// kept energy-equal by `E' = gamma^-3 E` (our stretch energy carries the
    /// rest length, Leaf's penalty Eq. 1 does not), mass `m' = gamma^-2 m`
    /// (`rho' = gamma^-5 rho`), contact damping `gamma^-4` (Leaf), gravity
    /// `g' = gamma g`. Global damping is mass-proportional here, so it is
    /// unchanged (Leaf's `k'_global = gamma^-2 k_global` is the same rule on
    /// the mass-free form).
    pub fn radius_scaled(&self, gamma: f64) -> YarnSimParams {
        let g2 = gamma * gamma;
        YarnSimParams {
            youngs_modulus: self.youngs_modulus / (g2 * gamma),
            contact_stiffness: self.contact_stiffness / g2,
            density: self.density / (g2 * g2 * gamma),
            contact_damping_normal: self.contact_damping_normal / (g2 * g2),
            contact_damping_tangent: self.contact_damping_tangent / (g2 * g2),
            gravity: [
                self.gravity[0] * gamma,
                self.gravity[1] * gamma,
                self.gravity[2] * gamma,
            ],
            max_speed: self.max_speed * gamma,
            max_energy_per_vertex: self.max_energy_per_vertex,
            ..self.clone()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn infinite_and_inconsistent_values_are_refused() {
        assert!(YarnSimParams::default().validate().is_ok());
        let cases = [
            (
                YarnSimParams {
                    cfl: f64::INFINITY,
                    ..Default::default()
                },
                "cfl",
            ),
            (
                YarnSimParams {
                    density: f64::INFINITY,
                    ..Default::default()
                },
                "density",
            ),
            (
                YarnSimParams {
                    max_dt: f64::NAN,
                    ..Default::default()
                },
                "max_dt",
            ),
            (
                YarnSimParams {
                    min_dt: 1e-3,
                    max_dt: 1e-4,
                    ..Default::default()
                },
                "min_dt",
            ),
        ];
        for (p, key) in cases {
            match p.validate() {
                Err(YarnSimError::Param { name, .. }) => assert_eq!(name, key),
                other => panic!("{key}: {other:?}"),
            }
        }
    }
}
