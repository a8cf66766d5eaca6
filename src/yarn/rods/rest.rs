//! The rest state of the rods and their material parameters.

use super::frame::{hinge_terms, perpendicular, transport, EdgeFrame};
use super::{RodError, RodTopology};
use crate::geom::vec3::{norm, scale, sub};
use crate::geom::Vec3;

/// Rest state of the rods, plain arrays in SI units (stored with the curves so
/// that a simulation starts from it rather than from positions alone).
///
/// The material frame of edge `e` at rest is the reference frame `(d1, t x
/// d1)` with zero twist angle. Rest curvatures follow Bergou et al. 2010
/// (§4.1, "Discrete Viscous Threads"): the curvature binormal of hinge `i`
/// expressed in the material frames of both its edges.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RodRest {
    /// Per edge: rest length (m).
    pub l0: Vec<f64>,
    /// Per edge: rest reference director (unit vector perpendicular to the
    /// rest tangent); the rest material frame's first director.
    pub d1: Vec<[f64; 3]>,
    /// Per hinge: rest material curvature `(k1, k2)` in the frame of edge
    /// `i - 1`, then `(k1, k2)` in the frame of edge `i` (dimensionless,
    /// integrated curvature: `|kb| = 2 tan(phi / 2)`).
    pub kappa_bar: Vec<[f64; 4]>,
    /// Per hinge: rest twist (rad); zero at open-curve hinges of Bishop
    /// frames, the transport holonomy at a closed curve's closing hinge.
    pub m_bar: Vec<f64>,
}

impl RodRest {
    /// Rest state with twist-free (Bishop) material frames: the first edge's
    /// director is any unit vector perpendicular to it, transported along the
    /// curve by space-parallel transport (Bergou 2008 §4.2.2). The rest
    /// curvature is signed (it lives in the material frames), so mirror images
    /// are different rest shapes. A closed curve's closing hinge gets the
    /// transport holonomy as rest twist, so that the rest configuration has
    /// zero energy and zero gradient.
    pub fn from_positions(topo: &RodTopology, points: &[Vec3]) -> Result<RodRest, RodError> {
        if points.len() != topo.n_vertices {
            return Err(RodError::Length {
                what: "points",
                expected: topo.n_vertices,
                got: points.len(),
            });
        }
        let ne = topo.num_edges();
        let mut l0 = Vec::with_capacity(ne);
        let mut tangents = Vec::with_capacity(ne);
        for (e, &[a, b]) in topo.edges.iter().enumerate() {
            let d = sub(points[b], points[a]);
            let l = norm(d);
            if !(l > 0.0 && l.is_finite()) {
                return Err(RodError::DegenerateEdge { edge: e, length: l });
            }
            l0.push(l);
            tangents.push(scale(d, 1.0 / l));
        }
        let mut d1 = vec![[0.0; 3]; ne];
        for range in &topo.curve_edges {
            let Some(first) = range.clone().next() else {
                continue;
            };
            d1[first] = perpendicular(tangents[first]);
            for e in range.start + 1..range.end {
                d1[e] = transport(tangents[e - 1], tangents[e], d1[e - 1]);
            }
        }
        let mut kappa_bar = Vec::with_capacity(topo.num_hinges());
        let mut m_bar = Vec::with_capacity(topo.num_hinges());
        for h in &topo.hinges {
            let [ea, eb] = h.edges;
            let f = |e: usize| {
                EdgeFrame::new(scale(tangents[e], l0[e]), l0[e], tangents[e], d1[e], 0.0)
            };
            let (kappa, ref_twist) = hinge_terms(&f(ea), &f(eb));
            kappa_bar.push(kappa);
            m_bar.push(ref_twist);
        }
        Ok(RodRest {
            l0,
            d1,
            kappa_bar,
            m_bar,
        })
    }

    /// Multiplies each edge's rest length by `factors[e]` (rest-length
    /// scaling, Leaf et al. 2018 §6.1). Rest curvatures are integrated
    /// (dimensionless) and stay as they are.
    pub fn scale_lengths(&mut self, factors: &[f64]) -> Result<(), RodError> {
        if factors.len() != self.l0.len() {
            return Err(RodError::Length {
                what: "length factors",
                expected: self.l0.len(),
                got: factors.len(),
            });
        }
        if let Some((edge, &f)) = factors
            .iter()
            .enumerate()
            .find(|(_, f)| !(f.is_finite() && **f > 0.0))
        {
            return Err(RodError::BadParameter {
                what: "length factor",
                index: edge,
                value: f,
            });
        }
        for (l, f) in self.l0.iter_mut().zip(factors) {
            *l *= f;
        }
        Ok(())
    }

    /// Checks the array lengths against `topo` and the values for sanity.
    pub fn check(&self, topo: &RodTopology) -> Result<(), RodError> {
        let checks = [
            ("rest lengths", topo.num_edges(), self.l0.len()),
            ("rest directors", topo.num_edges(), self.d1.len()),
            ("rest curvatures", topo.num_hinges(), self.kappa_bar.len()),
            ("rest twists", topo.num_hinges(), self.m_bar.len()),
        ];
        for (what, expected, got) in checks {
            if expected != got {
                return Err(RodError::Length {
                    what,
                    expected,
                    got,
                });
            }
        }
        for (e, &l) in self.l0.iter().enumerate() {
            if !(l.is_finite() && l > 0.0) {
                return Err(RodError::BadParameter {
                    what: "rest length",
                    index: e,
                    value: l,
                });
            }
        }
        for (e, d) in self.d1.iter().enumerate() {
            let n = norm(*d);
            if !((n - 1.0).abs() < 1e-6) {
                return Err(RodError::BadParameter {
                    what: "rest director norm",
                    index: e,
                    value: n,
                });
            }
        }
        let finite = self.kappa_bar.iter().flatten().chain(&self.m_bar);
        if let Some((i, &v)) = finite.enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(RodError::BadParameter {
                what: "rest curvature or twist",
                index: i,
                value: v,
            });
        }
        Ok(())
    }
}

/// Material parameters of the rods (HYLC 2020 §5.1, Eq. 23: bending and
/// twisting scaled by `gamma = bend_scale` relative to stretching).
///
/// Defaults: HYLC Table 1, stockinette.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RodParams {
    /// Young's modulus `E` (Pa); default 5e5. Stretch stiffness per edge
    /// `E pi r^2` (N).
    pub young_modulus: f64,
    /// Shear modulus `G` (Pa); default 2e5.
    pub shear_modulus: f64,
    /// HYLC's `gamma` (dimensionless), scaling both the bending stiffness
    /// `gamma E pi r^4 / 4` (N m^2) and the twist stiffness
    /// `gamma G pi r^4 / 2` (N m^2); default 1e-3.
    pub bend_scale: f64,
}

impl Default for RodParams {
    fn default() -> Self {
        RodParams {
            young_modulus: 5e5,
            shear_modulus: 2e5,
            bend_scale: 1e-3,
        }
    }
}

impl RodParams {
    pub fn check(&self) -> Result<(), RodError> {
        let vals = [
            ("young_modulus", self.young_modulus),
            ("shear_modulus", self.shear_modulus),
            ("bend_scale", self.bend_scale),
        ];
        for (what, v) in vals {
            if !(v.is_finite() && v >= 0.0) {
                return Err(RodError::BadParameter {
                    what,
                    index: 0,
                    value: v,
                });
            }
        }
        Ok(())
    }

    /// Stretch stiffness `E A = E pi r^2` (N) for radius `r` (m).
    pub fn stretch_stiffness(&self, r: f64) -> f64 {
        self.young_modulus * std::f64::consts::PI * r * r
    }

    /// Bending stiffness `gamma E I = gamma E pi r^4 / 4` (N m^2).
    pub fn bend_stiffness(&self, r: f64) -> f64 {
        self.bend_scale * self.young_modulus * std::f64::consts::PI * r.powi(4) / 4.0
    }

    /// Twist stiffness `gamma G J = gamma G pi r^4 / 2` (N m^2).
    pub fn twist_stiffness(&self, r: f64) -> f64 {
        self.bend_scale * self.shear_modulus * std::f64::consts::PI * r.powi(4) / 2.0
    }
}
