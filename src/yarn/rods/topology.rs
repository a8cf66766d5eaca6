//! Which vertices, edges and hinges make up the rods.

use super::RodError;
use crate::geom::{Vec3, Yarns};

/// One hinge: an interior vertex of a rod and its two edges.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Hinge {
    /// Vertices `[previous, centre, next]` along the rod.
    pub vertices: [usize; 3],
    /// Global edge indices `[i - 1, i]` (edge `i - 1` ends at the centre
    /// vertex, edge `i` starts there).
    pub edges: [usize; 2],
}

/// The rods of a [`Yarns`] collection: one rod per curve.
///
/// Edge `e` of the whole collection runs `edges[e] = [v0, v1]`; a closed curve
/// has an extra edge from its last vertex to its first. Open curves have a
/// hinge at every interior vertex, closed curves at every vertex. Generalized
/// coordinates follow `yarn::statics`: positions `q[3v..3v + 3]`, then the
/// twist of edge `e` at `q[3 * n_vertices + e]`.
#[derive(Debug, Clone, PartialEq)]
pub struct RodTopology {
    /// Number of vertices (all curves).
    pub n_vertices: usize,
    /// Per edge: its two vertices, in curve order.
    pub edges: Vec<[usize; 2]>,
    /// Per edge: the yarn radius (m), mean of its two vertices' radii.
    pub edge_radius: Vec<f64>,
    /// The hinges, curve by curve.
    pub hinges: Vec<Hinge>,
    /// Per curve: its range of edges.
    pub curve_edges: Vec<std::ops::Range<usize>>,
    /// Per curve: whether it is closed.
    pub closed: Vec<bool>,
}

impl RodTopology {
    /// One rod per curve of `yarns`. Fails on a malformed collection (too few
    /// points, bad radius, inconsistent offsets).
    pub fn new(yarns: &Yarns) -> Result<RodTopology, RodError> {
        yarns.validate()?;
        let mut edges = Vec::with_capacity(yarns.num_segments());
        let mut edge_radius = Vec::with_capacity(yarns.num_segments());
        let mut hinges = Vec::new();
        let mut curve_edges = Vec::with_capacity(yarns.num_curves());
        for c in 0..yarns.num_curves() {
            let r = yarns.curve_range(c);
            let closed = yarns.closed[c];
            let first = edges.len();
            let n = r.len();
            let ne = if closed { n } else { n - 1 };
            for k in 0..ne {
                let (a, b) = (r.start + k, r.start + (k + 1) % n);
                edges.push([a, b]);
                edge_radius.push(0.5 * (yarns.radius_at(a) + yarns.radius_at(b)));
            }
            // Hinge at vertex k + 1 (open) between edges k and k + 1; a
            // closed curve also has hinges at its first vertex (edges ne - 1
            // and 0). The closing hinge comes last so that the rest frames'
            // holonomy lands there (see `RodRest::from_positions`).
            let nh = if closed { n } else { n - 2 };
            for k in 0..nh {
                let (ea, eb) = (first + k, first + (k + 1) % ne);
                hinges.push(Hinge {
                    vertices: [edges[ea][0], edges[ea][1], edges[eb][1]],
                    edges: [ea, eb],
                });
            }
            curve_edges.push(first..edges.len());
        }
        Ok(RodTopology {
            n_vertices: yarns.num_points(),
            edges,
            edge_radius,
            hinges,
            curve_edges,
            closed: yarns.closed.clone(),
        })
    }

    pub fn num_edges(&self) -> usize {
        self.edges.len()
    }

    pub fn num_hinges(&self) -> usize {
        self.hinges.len()
    }

    /// Length of `q`: 3 per vertex plus 1 per edge.
    pub fn num_dofs(&self) -> usize {
        3 * self.n_vertices + self.edges.len()
    }

    /// Index in `q` of edge `e`'s twist angle.
    #[inline]
    pub fn twist_dof(&self, e: usize) -> usize {
        3 * self.n_vertices + e
    }

    /// `q` for the given positions and zero twists.
    pub fn q_from_points(&self, points: &[Vec3]) -> Vec<f64> {
        let mut q = Vec::with_capacity(self.num_dofs());
        for p in points {
            q.extend_from_slice(p);
        }
        q.resize(self.num_dofs(), 0.0);
        q
    }
}
