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
}
