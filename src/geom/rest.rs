//! The rest (stress-free) shape of yarns as the yarn-level rod model sees it.
//!
//! A relaxed knit is held by contact: its yarns are bent and slightly
//! stretched, so its rest lengths, rest curvatures and rest twists are *not*
//! those of its current positions (Leaf 2018 §6.1 rest-length scaling; Sperl
//! 2022 §7.2 "a stable but slightly pre-tensed rest state"). Simulations start
//! from these values, never from positions alone. Only the knitvox HDF5
//! format stores them (`/rest`, schemas/yarns-hdf5.md).

use super::{GeomError, Vec3};

/// Rest shape of a set of yarns, in the order of [`super::Yarns::segments`]
/// (segments) and of the points (vertices). Lengths in metres; curvatures
/// are the dimensionless discrete curvatures `2 tan(phi / 2)` of discrete
/// elastic rods (Bergou et al. 2008), so they do not change with the unit.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RestShape {
    /// Per segment: rest length (m), > 0.
    pub lengths: Vec<f64>,
    /// Per segment: rest material director `d1` (unit, perpendicular to the
    /// segment's rest tangent): the twist-free (Bishop) frame of the rest
    /// curve, so rest twists are zero except where a closed curve's frame
    /// comes back rotated.
    pub directors: Vec<Vec3>,
    /// Per vertex: rest material curvature `(k1, k2)` in the material frame
    /// of the incoming segment, then of the outgoing one (Bergou et al. 2010);
    /// zeros at the ends of open curves, which have no hinge.
    pub curvature: Vec<[f64; 4]>,
    /// Per vertex: rest twist (rad); zero at open ends.
    pub twist: Vec<f64>,
    /// The material the rest shape was relaxed under, when recorded: the
    /// stored positions are an equilibrium of this rest shape under this
    /// material only (files written before it was recorded have none).
    pub material: Option<YarnMaterial>,
}

/// A yarn's rod and contact material (the parameters a relaxed rest shape
/// depends on; friction and density are the tests' and the yarns' own).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct YarnMaterial {
    /// Young's modulus `E` (Pa): stretch stiffness `E pi r^2` per yarn.
    pub young_modulus: f64,
    /// Shear modulus `G` (Pa).
    pub shear_modulus: f64,
    /// HYLC's `gamma` (dimensionless): bending `gamma E pi r^4 / 4` and
    /// twist `gamma G pi r^4 / 2` (N m^2).
    pub bend_scale: f64,
    /// Kaldor contact stiffness (J/m^2).
    pub contact_stiffness: f64,
}

impl YarnMaterial {
    /// Field names (as stored in files) with their accepted range: beyond
    /// them the yarn solvers' tolerances (1e-5 N) and step bounds are
    /// meaningless, so absurd values are refused instead of iterated on.
    pub const RANGES: [(&'static str, f64, f64); 4] = [
        ("young_modulus", 1e3, 1e12),
        ("shear_modulus", 1e3, 1e12),
        ("bend_scale", 1e-6, 10.0),
        ("contact_stiffness", 1e-3, 1e6),
    ];

    /// The values in the order of [`Self::RANGES`].
    pub fn values(&self) -> [f64; 4] {
        [
            self.young_modulus,
            self.shear_modulus,
            self.bend_scale,
            self.contact_stiffness,
        ]
    }

    /// The material of values in the order of [`Self::RANGES`].
    pub fn from_values(v: [f64; 4]) -> YarnMaterial {
        YarnMaterial {
            young_modulus: v[0],
            shear_modulus: v[1],
            bend_scale: v[2],
            contact_stiffness: v[3],
        }
    }

    /// The first field out of its range, as `(name, value, lo, hi)`.
    pub fn out_of_range(&self) -> Option<(&'static str, f64, f64, f64)> {
        Self::RANGES
            .iter()
            .zip(self.values())
            .find(|((_, lo, hi), v)| !(*lo..=*hi).contains(v))
            .map(|(&(name, lo, hi), v)| (name, v, lo, hi))
    }
}

impl std::fmt::Display for YarnMaterial {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "E {:e} Pa, G {:e} Pa, bend scale {}, contact stiffness {} J/m^2",
            self.young_modulus, self.shear_modulus, self.bend_scale, self.contact_stiffness
        )
    }
}

/// Per-field replacements of a yarn material (`None`: keep the field).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct MaterialOverrides {
    pub young_modulus: Option<f64>,
    pub shear_modulus: Option<f64>,
    pub bend_scale: Option<f64>,
    pub contact_stiffness: Option<f64>,
}

impl MaterialOverrides {
    fn values(&self) -> [Option<f64>; 4] {
        [
            self.young_modulus,
            self.shear_modulus,
            self.bend_scale,
            self.contact_stiffness,
        ]
    }

    /// `base` with the given fields replaced.
    pub fn apply(&self, base: &YarnMaterial) -> YarnMaterial {
        let mut v = base.values();
        for (x, o) in v.iter_mut().zip(self.values()) {
            if let Some(o) = o {
                *x = o;
            }
        }
        YarnMaterial::from_values(v)
    }

    /// Names of the replaced fields (as in [`YarnMaterial::RANGES`]).
    pub fn names(&self) -> Vec<&'static str> {
        YarnMaterial::RANGES
            .iter()
            .zip(self.values())
            .filter(|(_, o)| o.is_some())
            .map(|((n, _, _), _)| *n)
            .collect()
    }
}

impl RestShape {
    /// Checks the sizes against a yarn set (`segments`, `vertices`) and the
    /// values (finite, positive lengths, unit directors).
    pub fn validate(&self, segments: usize, vertices: usize) -> Result<(), GeomError> {
        if self.lengths.len() != segments || self.directors.len() != segments {
            return Err(GeomError::Layout(format!(
                "rest shape: {} lengths and {} directors for {segments} segments",
                self.lengths.len(),
                self.directors.len()
            )));
        }
        if self.curvature.len() != vertices || self.twist.len() != vertices {
            return Err(GeomError::Layout(format!(
                "rest shape: {} curvatures and {} twists for {vertices} vertices",
                self.curvature.len(),
                self.twist.len()
            )));
        }
        if let Some((s, l)) = self
            .lengths
            .iter()
            .enumerate()
            .find(|(_, l)| !(l.is_finite() && **l > 0.0))
        {
            return Err(GeomError::Layout(format!(
                "rest shape: segment {s}: rest length {l} is not a positive finite number"
            )));
        }
        if let Some((s, d)) = self.directors.iter().enumerate().find(|(_, d)| {
            let n2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
            !(n2.is_finite() && (n2 - 1.0).abs() < 1e-6)
        }) {
            return Err(GeomError::Layout(format!(
                "rest shape: segment {s}: director {d:?} is not a unit vector"
            )));
        }
        let bad_k = self
            .curvature
            .iter()
            .position(|k| !k.iter().all(|x| x.is_finite()));
        let bad_t = self.twist.iter().position(|t| !t.is_finite());
        if let Some(v) = bad_k.or(bad_t) {
            return Err(GeomError::Layout(format!(
                "rest shape: vertex {v}: curvature or twist is not finite"
            )));
        }
        if let Some((name, v, lo, hi)) = self.material.as_ref().and_then(|m| m.out_of_range()) {
            return Err(GeomError::Layout(format!(
                "rest shape: material {name} = {v} is outside [{lo:e}, {hi:e}]"
            )));
        }
        Ok(())
    }

    /// Applies a length scale `s` and a rotation `rot` (a proper rotation of
    /// the frame, e.g. the Z-up to Y-up map): lengths scale, directors
    /// rotate, curvatures and twists (dimensionless, in the material frame)
    /// stay.
    pub fn transform(&mut self, s: f64, rot: impl Fn(Vec3) -> Vec3) {
        self.lengths.iter_mut().for_each(|l| *l *= s);
        self.directors.iter_mut().for_each(|d| *d = rot(*d));
    }
}
