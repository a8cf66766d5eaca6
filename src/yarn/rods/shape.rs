//! Conversion between the rods' rest state ([`RodRest`], per edge and per
//! hinge) and the file-level rest shape ([`RestShape`], per segment and per
//! vertex, schemas/yarns-hdf5.md `/yarns/rest`). Edges are the yarns'
//! segments in the same order; each hinge sits at its centre vertex, and
//! vertices without a hinge (open ends) carry zeros.

use super::{RodError, RodRest, RodTopology};
use crate::geom::RestShape;

impl RodRest {
    /// The per-segment / per-vertex form stored with the yarns.
    pub fn to_shape(&self, topo: &RodTopology) -> RestShape {
        let mut curvature = vec![[0.0; 4]; topo.n_vertices];
        let mut twist = vec![0.0; topo.n_vertices];
        for (h, hinge) in topo.hinges.iter().enumerate() {
            curvature[hinge.vertices[1]] = self.kappa_bar[h];
            twist[hinge.vertices[1]] = self.m_bar[h];
        }
        RestShape {
            lengths: self.l0.clone(),
            directors: self.d1.clone(),
            curvature,
            twist,
            material: None,
        }
    }

    /// The rods' rest state from a stored rest shape of the same yarns.
    pub fn from_shape(topo: &RodTopology, shape: &RestShape) -> Result<RodRest, RodError> {
        shape.validate(topo.num_edges(), topo.n_vertices)?;
        let rest = RodRest {
            l0: shape.lengths.clone(),
            d1: shape.directors.clone(),
            kappa_bar: topo
                .hinges
                .iter()
                .map(|h| shape.curvature[h.vertices[1]])
                .collect(),
            m_bar: topo
                .hinges
                .iter()
                .map(|h| shape.twist[h.vertices[1]])
                .collect(),
        };
        rest.check(topo)?;
        Ok(rest)
    }

    /// Checks that `points` are a state of this rest shape: every segment
    /// within [`REST_LENGTH_RATIO`] of its rest length either way. A
    /// stored rest shape comes with an equilibrium of it (`pattern` keeps
    /// the lengths to 0.1%; a relaxation's rest-length scale is above 0.5),
    /// so a segment off by more is a moved point or a changed length: a
    /// test or training pose would start far from rest and record the
    /// snap back as the load's motion (a rest point moved 4 mm: it ends
    /// the first 5% step 5.3 mm from where the file put it, the median
    /// vertex 2.4 mm).
    pub fn check_state(&self, topo: &RodTopology, points: &[[f64; 3]]) -> Result<(), RodError> {
        for (e, (&[a, b], &rest)) in topo.edges.iter().zip(&self.l0).enumerate() {
            let length = crate::geom::dist(points[a], points[b]);
            let ratio = length / rest;
            // NaN (a non-finite point) is outside too.
            if !(1.0 / REST_LENGTH_RATIO..=REST_LENGTH_RATIO).contains(&ratio) {
                return Err(RodError::RestMismatch {
                    edge: e,
                    vertices: [a, b],
                    length,
                    rest,
                });
            }
        }
        Ok(())
    }
}

/// Largest factor between a segment's length at the yarns' positions and
/// its stored rest length ([`RodRest::check_state`]).
pub const REST_LENGTH_RATIO: f64 = 2.0;

/// Checks that `yarns` are a state of their stored rest shape, when they
/// carry one ([`RodRest::check_state`]); the rods models do so when built,
/// and a stage that hands the yarns on checks them first, to name the file
/// they came from.
pub fn check_rest_state(yarns: &crate::geom::Yarns) -> Result<(), RodError> {
    let Some(shape) = &yarns.rest else {
        return Ok(());
    };
    let topo = RodTopology::new(yarns)?;
    RodRest::from_shape(&topo, shape)?.check_state(&topo, &yarns.points)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::Yarns;

    #[test]
    fn shape_round_trip_keeps_every_value_at_its_vertex() {
        let mut y = Yarns::new();
        let open: Vec<[f64; 3]> = (0..7)
            .map(|i| {
                let t = i as f64 * 0.7;
                [t.cos() * 0.01, t.sin() * 0.01, 0.002 * t]
            })
            .collect();
        y.push_curve(&open, false, 1e-3);
        let ring: Vec<[f64; 3]> = (0..9)
            .map(|i| {
                let t = i as f64 * std::f64::consts::TAU / 9.0;
                [
                    0.05 + 0.01 * t.cos(),
                    0.012 * t.sin(),
                    0.003 * (2.0 * t).sin(),
                ]
            })
            .collect();
        y.push_curve(&ring, true, 1e-3);
        let topo = RodTopology::new(&y).unwrap();
        let rest = RodRest::from_positions(&topo, &y.points).unwrap();
        let shape = rest.to_shape(&topo);
        // Segment order: lengths are the yarns' segment lengths.
        for (l, [a, b]) in shape.lengths.iter().zip(y.segments()) {
            assert!((l - crate::geom::dist(y.points[a], y.points[b])).abs() < 1e-15);
        }
        // Open ends have no hinge.
        assert_eq!(shape.curvature[0], [0.0; 4]);
        assert_eq!(shape.curvature[6], [0.0; 4]);
        assert!(shape.curvature[3].iter().any(|k| *k != 0.0));
        let back = RodRest::from_shape(&topo, &shape).unwrap();
        assert_eq!(back, rest);
        // A shape of other yarns is refused.
        let mut short = shape.clone();
        short.lengths.pop();
        assert!(RodRest::from_shape(&topo, &short).is_err());
    }

    #[test]
    fn positions_must_be_a_state_of_the_rest_shape() {
        let mut y = Yarns::new();
        let line: Vec<[f64; 3]> = (0..6).map(|i| [1e-3 * i as f64, 0.0, 0.0]).collect();
        y.push_curve(&line, false, 1e-4);
        let topo = RodTopology::new(&y).unwrap();
        let rest = RodRest::from_positions(&topo, &y.points).unwrap();
        rest.check_state(&topo, &y.points).unwrap();
        // Stretched or shrunk by up to the ratio: still a state of it.
        for s in [
            1.0 / REST_LENGTH_RATIO * 1.001,
            0.8,
            1.3,
            REST_LENGTH_RATIO * 0.999,
        ] {
            let scaled: Vec<[f64; 3]> = y.points.iter().map(|p| p.map(|c| c * s)).collect();
            rest.check_state(&topo, &scaled).unwrap();
        }
        // A point moved by 3 mm: its first segment is named.
        let mut moved = y.points.clone();
        moved[3][1] += 3e-3;
        match rest.check_state(&topo, &moved) {
            Err(RodError::RestMismatch {
                edge,
                vertices,
                length,
                rest,
            }) => {
                assert_eq!((edge, vertices), (2, [2, 3]));
                assert!(
                    (rest - 1e-3).abs() < 1e-15 && length > 3e-3,
                    "{length} {rest}"
                );
            }
            other => panic!("{other:?}"),
        }
        // Beyond the ratio either way, and non-finite positions.
        for s in [0.45, 2.2, f64::NAN] {
            let scaled: Vec<[f64; 3]> = y.points.iter().map(|p| p.map(|c| c * s)).collect();
            assert!(rest.check_state(&topo, &scaled).is_err(), "scale {s}");
        }
    }
}
