//! Triangle-mesh distance queries: closest points on triangles, a
//! bounding-volume hierarchy over a mesh's triangles, and signed distances
//! from the angle-weighted pseudo-normal of the closest feature (face, edge
//! or vertex; Bærentzen & Aanæs 2005, "Signed distance computation using the
//! angle weighted pseudonormal"), exact for closed, consistently oriented
//! meshes. On an open mesh a point is outside when it is on the front side of
//! the closest feature (for a boundary edge: of its one triangle). Used by the
//! PD colliders (`sim::collide`), the pins that ride on a character's skin
//! (`anim::pins`) and the yarn-level colliders.
//!
//! Pure math: no files, no printing.

// `!(a > b)` is deliberate throughout: it also rejects NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]
// Small fixed-size loops over x, y, z read better indexed.
#![allow(clippy::needless_range_loop)]

use super::vec3::{add, cross, dot, norm, scale, sub};
use super::Vec3;

/// Why a mesh cannot be posed as a collider.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum BvhError {
    /// Another number of positions than the mesh has vertices.
    #[error("{positions} positions for a mesh of {vertices} vertices")]
    PositionCount { positions: usize, vertices: usize },
    /// A vertex position is not finite.
    #[error("vertex {vertex} is not finite")]
    NonFinite { vertex: usize },
    /// Another number of previous positions than the mesh has vertices.
    #[error("{positions} previous positions for a mesh of {vertices} vertices")]
    PreviousCount { positions: usize, vertices: usize },
    /// A previous vertex position is not finite.
    #[error("previous vertex {vertex} is not finite")]
    PreviousNonFinite { vertex: usize },
}

/// `a / |a|`, or None for a zero or non-finite vector.
pub(crate) fn normalized(a: Vec3) -> Option<Vec3> {
    let n = norm(a);
    (n > 0.0 && n.is_finite()).then(|| scale(a, 1.0 / n))
}

/// Which part of a triangle a closest point lies on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Feature {
    /// Corner `k` (0, 1, 2) of the triangle.
    Vertex(u8),
    /// Edge `k` from corner `k` to corner `(k + 1) % 3`.
    Edge(u8),
    /// The interior.
    Face,
}

/// Closest point to `p` on triangle `(a, b, c)` and the feature it lies on
/// (Ericson, "Real-Time Collision Detection", §5.1.5). Degenerate
/// triangles fall back to their closest edge.
pub fn closest_point_on_triangle(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> (Vec3, Feature) {
    let ab = sub(b, a);
    let ac = sub(c, a);
    let ap = sub(p, a);
    let d1 = dot(ab, ap);
    let d2 = dot(ac, ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return (a, Feature::Vertex(0));
    }
    let bp = sub(p, b);
    let d3 = dot(ab, bp);
    let d4 = dot(ac, bp);
    if d3 >= 0.0 && d4 <= d3 {
        return (b, Feature::Vertex(1));
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return (add(a, scale(ab, v)), Feature::Edge(0));
    }
    let cp = sub(p, c);
    let d5 = dot(ab, cp);
    let d6 = dot(ac, cp);
    if d6 >= 0.0 && d5 <= d6 {
        return (c, Feature::Vertex(2));
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return (add(a, scale(ac, w)), Feature::Edge(2));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (add(b, scale(sub(c, b), w)), Feature::Edge(1));
    }
    let denom = va + vb + vc;
    if !(denom.abs() > 0.0) || !denom.is_finite() {
        // Degenerate (collinear) triangle: the closest of its three edges.
        let mut best = (a, Feature::Vertex(0), f64::INFINITY);
        for (k, (s, e)) in [(a, b), (b, c), (c, a)].into_iter().enumerate() {
            let q = closest_on_segment(p, s, e);
            let d = dot(sub(p, q), sub(p, q));
            if d < best.2 {
                best = (q, Feature::Edge(k as u8), d);
            }
        }
        return (best.0, best.1);
    }
    let v = vb / denom;
    let w = vc / denom;
    (add(a, add(scale(ab, v), scale(ac, w))), Feature::Face)
}

/// Barycentric weights of `p` (a point of the triangle's plane) in `(a, b,
/// c)`; a third each for a degenerate triangle.
fn barycentric(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> [f64; 3] {
    let (ab, ac, ap) = (sub(b, a), sub(c, a), sub(p, a));
    let (d00, d01, d11) = (dot(ab, ab), dot(ab, ac), dot(ac, ac));
    let (d20, d21) = (dot(ap, ab), dot(ap, ac));
    let den = d00 * d11 - d01 * d01;
    if !(den > 0.0) || !den.is_finite() {
        return [1.0 / 3.0; 3];
    }
    let v = (d11 * d20 - d01 * d21) / den;
    let w = (d00 * d21 - d01 * d20) / den;
    [1.0 - v - w, v, w]
}

fn closest_on_segment(p: Vec3, a: Vec3, b: Vec3) -> Vec3 {
    let ab = sub(b, a);
    let l2 = dot(ab, ab);
    if !(l2 > 0.0) {
        return a;
    }
    let t = (dot(sub(p, a), ab) / l2).clamp(0.0, 1.0);
    add(a, scale(ab, t))
}

/// Axis-aligned box.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Aabb {
    min: Vec3,
    max: Vec3,
}

impl Aabb {
    const EMPTY: Aabb = Aabb {
        min: [f64::INFINITY; 3],
        max: [f64::NEG_INFINITY; 3],
    };
    fn grow(&mut self, p: Vec3) {
        for k in 0..3 {
            self.min[k] = self.min[k].min(p[k]);
            self.max[k] = self.max[k].max(p[k]);
        }
    }
    fn union(&mut self, o: &Aabb) {
        self.grow(o.min);
        self.grow(o.max);
    }
    /// Squared distance from `p` to the box (0 inside).
    fn dist2(&self, p: Vec3) -> f64 {
        let mut d = 0.0;
        for k in 0..3 {
            let e = (self.min[k] - p[k]).max(p[k] - self.max[k]).max(0.0);
            d += e * e;
        }
        d
    }
}

/// One BVH node: a leaf holds `count > 0` triangles starting at `start` in
/// the permuted triangle order; an inner node's children are `start` and
/// `start + 1`... stored explicitly as `left`, `right`.
#[derive(Debug, Clone, Copy)]
struct BvhNode {
    bounds: Aabb,
    left: u32,
    right: u32,
    start: u32,
    count: u32,
}

/// Triangles per BVH leaf.
const LEAF_SIZE: usize = 4;

/// The topology of a triangle mesh, computed once and shared by its poses:
/// for every triangle edge the triangles that share it.
#[derive(Debug, Clone, PartialEq)]
pub struct MeshTopology {
    triangles: Vec<[u32; 3]>,
    /// `edge_faces[3 t + k]`: the triangles (including `t`) sharing edge `k`
    /// of triangle `t`, as a range into `edge_face_list`.
    edge_faces: Vec<(u32, u32)>,
    edge_face_list: Vec<u32>,
    num_vertices: usize,
    /// Whether every edge has exactly two triangles (closed 2-manifold).
    closed: bool,
}

impl MeshTopology {
    /// Topology of `triangles` over `num_vertices` vertices. Triangles with
    /// an out-of-range or repeated corner are dropped (returned count).
    pub fn new(triangles: &[[u32; 3]], num_vertices: usize) -> (MeshTopology, usize) {
        let tris: Vec<[u32; 3]> = triangles
            .iter()
            .copied()
            .filter(|t| {
                t.iter().all(|&i| (i as usize) < num_vertices)
                    && t[0] != t[1]
                    && t[1] != t[2]
                    && t[0] != t[2]
            })
            .collect();
        let dropped = triangles.len() - tris.len();
        // (sorted edge, triangle) pairs, sorted: equal edges are adjacent.
        let mut edges: Vec<((u32, u32), u32, u8)> = Vec::with_capacity(tris.len() * 3);
        for (t, tri) in tris.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                edges.push(((a.min(b), a.max(b)), t as u32, k as u8));
            }
        }
        edges.sort_unstable();
        let mut edge_faces = vec![(0u32, 0u32); tris.len() * 3];
        let mut edge_face_list = Vec::with_capacity(edges.len());
        let mut closed = true;
        let mut i = 0;
        while i < edges.len() {
            let mut j = i;
            while j < edges.len() && edges[j].0 == edges[i].0 {
                j += 1;
            }
            closed &= j - i == 2;
            let start = edge_face_list.len() as u32;
            edge_face_list.extend(edges[i..j].iter().map(|e| e.1));
            let end = edge_face_list.len() as u32;
            for e in &edges[i..j] {
                edge_faces[3 * e.1 as usize + e.2 as usize] = (start, end);
            }
            i = j;
        }
        (
            MeshTopology {
                triangles: tris,
                edge_faces,
                edge_face_list,
                num_vertices,
                closed,
            },
            dropped,
        )
    }

    /// Like [`MeshTopology::new`], but vertices at bit-identical positions
    /// (`positions`, e.g. the bind pose) are merged first: exporters split
    /// vertices along UV and normal seams (Fox.glb has no shared vertex at
    /// all), which would leave every edge a boundary and the pseudo-normal
    /// signs open-mesh approximations. The triangles then use the first
    /// vertex of every merged group, so posed positions stay indexed as before.
    pub fn welded(triangles: &[[u32; 3]], positions: &[Vec3]) -> (MeshTopology, usize) {
        let mut order: Vec<u32> = (0..positions.len() as u32).collect();
        let key = |i: u32| positions[i as usize].map(f64::to_bits);
        order.sort_by_key(|&i| (key(i), i));
        let mut canon: Vec<u32> = (0..positions.len() as u32).collect();
        let mut i = 0;
        while i < order.len() {
            let mut j = i + 1;
            while j < order.len() && key(order[j]) == key(order[i]) {
                canon[order[j] as usize] = order[i];
                j += 1;
            }
            i = j;
        }
        let remapped: Vec<[u32; 3]> = triangles
            .iter()
            .map(|t| t.map(|v| canon.get(v as usize).copied().unwrap_or(v)))
            .collect();
        MeshTopology::new(&remapped, positions.len())
    }

    /// The (valid) triangles.
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }
    /// Whether every edge is shared by exactly two triangles.
    pub fn is_closed(&self) -> bool {
        self.closed
    }
    /// Vertex count the topology was built for.
    pub fn num_vertices(&self) -> usize {
        self.num_vertices
    }
}

/// A triangle mesh at one pose with its BVH and pseudo-normals.
#[derive(Debug, Clone)]
pub struct MeshCollider {
    positions: Vec<Vec3>,
    triangles: Vec<[u32; 3]>,
    face_normals: Vec<Vec3>,
    /// Per triangle edge (`3 t + k`): sum of the unit normals of the
    /// triangles sharing it (angle weight π each).
    edge_normals: Vec<Vec3>,
    /// Angle-weighted vertex pseudo-normals.
    vertex_normals: Vec<Vec3>,
    nodes: Vec<BvhNode>,
    /// Triangle indices in BVH leaf order.
    order: Vec<u32>,
    /// Vertex positions at the start of the time step (m), for the surface
    /// motion friction acts against; None: the mesh rests.
    previous: Option<Vec<Vec3>>,
}

/// Result of a closest-point query on a mesh.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshHit {
    /// Closest surface point (m).
    pub point: Vec3,
    /// Triangle it lies on.
    pub triangle: usize,
    /// Feature of that triangle.
    pub feature: Feature,
    /// Signed distance (m): negative inside.
    pub signed_distance: f64,
    /// Unit outward direction at the hit: `(p - q)/|p - q|` flipped to the
    /// outside, or the pseudo-normal when `p` is on the surface.
    pub outward: Vec3,
}

impl MeshCollider {
    /// Poses `topology` at `positions` (m, one per vertex of the topology).
    /// Errors when the counts differ or a position is not finite.
    pub fn new(topology: &MeshTopology, positions: &[Vec3]) -> Result<MeshCollider, BvhError> {
        if positions.len() != topology.num_vertices {
            return Err(BvhError::PositionCount {
                positions: positions.len(),
                vertices: topology.num_vertices,
            });
        }
        if let Some(i) = positions
            .iter()
            .position(|p| !p.iter().all(|c| c.is_finite()))
        {
            return Err(BvhError::NonFinite { vertex: i });
        }
        let tris = &topology.triangles;
        let nt = tris.len();
        let mut face_normals = Vec::with_capacity(nt);
        let mut vertex_normals = vec![[0.0; 3]; positions.len()];
        for t in tris {
            let p = t.map(|i| positions[i as usize]);
            let n = normalized(cross(sub(p[1], p[0]), sub(p[2], p[0]))).unwrap_or([0.0; 3]);
            face_normals.push(n);
            for k in 0..3 {
                let e1 = normalized(sub(p[(k + 1) % 3], p[k]));
                let e2 = normalized(sub(p[(k + 2) % 3], p[k]));
                if let (Some(e1), Some(e2)) = (e1, e2) {
                    let angle = dot(e1, e2).clamp(-1.0, 1.0).acos();
                    let v = &mut vertex_normals[t[k] as usize];
                    *v = add(*v, scale(n, angle));
                }
            }
        }
        let mut edge_normals = vec![[0.0; 3]; nt * 3];
        for (i, en) in edge_normals.iter_mut().enumerate() {
            let (s, e) = topology.edge_faces[i];
            for &f in &topology.edge_face_list[s as usize..e as usize] {
                *en = add(*en, face_normals[f as usize]);
            }
        }
        // BVH over triangle boxes, median split on the longest centroid axis.
        let boxes: Vec<Aabb> = tris
            .iter()
            .map(|t| {
                let mut b = Aabb::EMPTY;
                for &i in t {
                    b.grow(positions[i as usize]);
                }
                b
            })
            .collect();
        let centroids: Vec<Vec3> = boxes
            .iter()
            .map(|b| scale(add(b.min, b.max), 0.5))
            .collect();
        let mut order: Vec<u32> = (0..nt as u32).collect();
        let mut nodes = Vec::with_capacity(2 * nt / LEAF_SIZE + 1);
        if nt > 0 {
            build(&mut nodes, &mut order, 0, nt, &boxes, &centroids);
        }
        Ok(MeshCollider {
            positions: positions.to_vec(),
            triangles: tris.clone(),
            face_normals,
            edge_normals,
            vertex_normals,
            nodes,
            order,
            previous: None,
        })
    }

    /// The same pose with the vertex positions (m) of the start of the time
    /// step, so that [`Self::surface_motion`] sees how the surface moved.
    /// Errors when the counts differ or a position is not finite.
    pub fn with_previous(mut self, previous: &[Vec3]) -> Result<MeshCollider, BvhError> {
        if previous.len() != self.positions.len() {
            return Err(BvhError::PreviousCount {
                positions: previous.len(),
                vertices: self.positions.len(),
            });
        }
        if let Some(i) = previous
            .iter()
            .position(|p| !p.iter().all(|c| c.is_finite()))
        {
            return Err(BvhError::PreviousNonFinite { vertex: i });
        }
        self.previous = Some(previous.to_vec());
        Ok(self)
    }

    /// Displacement (m) over the time step of the surface point `hit` (the
    /// same barycentric point of its triangle at the previous pose); zero
    /// without a previous pose.
    pub fn surface_motion(&self, hit: &MeshHit) -> Vec3 {
        let Some(prev) = &self.previous else {
            return [0.0; 3];
        };
        let tri = self.triangles[hit.triangle];
        let [a, b, c] = tri.map(|i| self.positions[i as usize]);
        let w = barycentric(hit.point, a, b, c);
        let mut u = [0.0; 3];
        for (k, &i) in tri.iter().enumerate() {
            let d = sub(self.positions[i as usize], prev[i as usize]);
            u = add(u, scale(d, w[k]));
        }
        u
    }

    /// The posed vertex positions (m).
    pub fn positions(&self) -> &[Vec3] {
        &self.positions
    }
    /// The triangles.
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }
    /// Unit normal of triangle `t` (zero for a degenerate one).
    pub fn face_normal(&self, t: usize) -> Vec3 {
        self.face_normals[t]
    }

    /// Closest point on the mesh to `p` (None for a mesh without triangles).
    pub fn closest(&self, p: Vec3) -> Option<MeshHit> {
        if self.nodes.is_empty() {
            return None;
        }
        let mut best: Option<(f64, usize, Vec3, Feature)> = None;
        let mut stack: Vec<u32> = Vec::with_capacity(64);
        stack.push(0);
        while let Some(ni) = stack.pop() {
            let node = &self.nodes[ni as usize];
            let bound = best.map_or(f64::INFINITY, |b| b.0);
            if node.bounds.dist2(p) > bound {
                continue;
            }
            if node.count > 0 {
                for &t in &self.order[node.start as usize..(node.start + node.count) as usize] {
                    let tri = self.triangles[t as usize].map(|i| self.positions[i as usize]);
                    let (q, f) = closest_point_on_triangle(p, tri[0], tri[1], tri[2]);
                    let d = sub(p, q);
                    let d2 = dot(d, d);
                    // Ties go to the lower triangle index: deterministic.
                    let better = match best {
                        None => true,
                        Some((bd, bt, _, _)) => d2 < bd || (d2 == bd && (t as usize) < bt),
                    };
                    if better {
                        best = Some((d2, t as usize, q, f));
                    }
                }
            } else {
                // Visit the nearer child first (pushed last).
                let (l, r) = (node.left, node.right);
                let dl = self.nodes[l as usize].bounds.dist2(p);
                let dr = self.nodes[r as usize].bounds.dist2(p);
                if dl <= dr {
                    stack.push(r);
                    stack.push(l);
                } else {
                    stack.push(l);
                    stack.push(r);
                }
            }
        }
        let (d2, t, q, feature) = best?;
        let pn = self.pseudo_normal(t, feature);
        let d = d2.sqrt();
        let diff = sub(p, q);
        let inside = dot(diff, pn) < 0.0;
        let outward = if d > 0.0 {
            let u = scale(diff, 1.0 / d);
            if inside {
                scale(u, -1.0)
            } else {
                u
            }
        } else {
            normalized(pn).unwrap_or(self.face_normals[t])
        };
        Some(MeshHit {
            point: q,
            triangle: t,
            feature,
            signed_distance: if inside { -d } else { d },
            outward,
        })
    }

    /// The angle-weighted pseudo-normal of a feature of triangle `t` (not unit).
    fn pseudo_normal(&self, t: usize, f: Feature) -> Vec3 {
        match f {
            Feature::Face => self.face_normals[t],
            Feature::Edge(k) => self.edge_normals[3 * t + k as usize],
            Feature::Vertex(k) => self.vertex_normals[self.triangles[t][k as usize] as usize],
        }
    }
}

fn build(
    nodes: &mut Vec<BvhNode>,
    order: &mut [u32],
    start: usize,
    end: usize,
    boxes: &[Aabb],
    centroids: &[Vec3],
) -> u32 {
    let mut bounds = Aabb::EMPTY;
    let mut cb = Aabb::EMPTY;
    for &t in &order[start..end] {
        bounds.union(&boxes[t as usize]);
        cb.grow(centroids[t as usize]);
    }
    let idx = nodes.len() as u32;
    nodes.push(BvhNode {
        bounds,
        left: 0,
        right: 0,
        start: start as u32,
        count: (end - start) as u32,
    });
    if end - start <= LEAF_SIZE {
        return idx;
    }
    let ext = sub(cb.max, cb.min);
    let axis = if ext[0] >= ext[1] && ext[0] >= ext[2] {
        0
    } else if ext[1] >= ext[2] {
        1
    } else {
        2
    };
    let mid = (start + end) / 2;
    order[start..end].select_nth_unstable_by(mid - start, |&a, &b| {
        centroids[a as usize][axis]
            .total_cmp(&centroids[b as usize][axis])
            .then(a.cmp(&b))
    });
    let left = build(nodes, order, start, mid, boxes, centroids);
    let right = build(nodes, order, mid, end, boxes, centroids);
    let n = &mut nodes[idx as usize];
    n.left = left;
    n.right = right;
    n.count = 0;
    idx
}

#[cfg(test)]
mod tests {
    use super::*;

    fn brute(m: &MeshCollider, p: Vec3) -> f64 {
        m.triangles()
            .iter()
            .map(|t| {
                let q = closest_point_on_triangle(
                    p,
                    m.positions[t[0] as usize],
                    m.positions[t[1] as usize],
                    m.positions[t[2] as usize],
                )
                .0;
                norm(sub(p, q))
            })
            .fold(f64::INFINITY, f64::min)
    }

    #[test]
    fn triangle_regions() {
        let (a, b, c) = ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
        let (q, f) = closest_point_on_triangle([0.2, 0.2, 1.0], a, b, c);
        assert_eq!(f, Feature::Face);
        assert!(norm(sub(q, [0.2, 0.2, 0.0])) < 1e-15);
        assert_eq!(
            closest_point_on_triangle([-1.0, -1.0, 0.0], a, b, c).1,
            Feature::Vertex(0)
        );
        assert_eq!(
            closest_point_on_triangle([0.5, -1.0, 0.0], a, b, c),
            ([0.5, 0.0, 0.0], Feature::Edge(0))
        );
        assert_eq!(
            closest_point_on_triangle([1.0, 1.0, 0.0], a, b, c).1,
            Feature::Edge(1)
        );
        // Degenerate triangle: no NaN.
        let (q, _) = closest_point_on_triangle([0.5, 1.0, 0.0], a, b, [2.0, 0.0, 0.0]);
        assert!(q.iter().all(|x| x.is_finite()));
    }

    #[test]
    fn topology_of_a_tetrahedron_is_closed() {
        let tris = [[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]];
        let (t, dropped) = MeshTopology::new(&tris, 4);
        assert!(t.is_closed());
        assert_eq!(dropped, 0);
        let (t, dropped) = MeshTopology::new(&[[0, 1, 2], [0, 1, 9]], 3);
        assert!(!t.is_closed());
        assert_eq!(dropped, 1);
    }

    #[test]
    fn bvh_matches_brute_force_on_a_soup() {
        // Deterministic pseudo-random soup.
        let mut s = 12345u64;
        let mut rnd = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut pos = Vec::new();
        let mut tris = Vec::new();
        for t in 0..300u32 {
            let c = [rnd(), rnd(), rnd()];
            for _ in 0..3 {
                pos.push([c[0] + 0.1 * rnd(), c[1] + 0.1 * rnd(), c[2] + 0.1 * rnd()]);
            }
            tris.push([3 * t, 3 * t + 1, 3 * t + 2]);
        }
        let (topo, _) = MeshTopology::new(&tris, pos.len());
        let m = MeshCollider::new(&topo, &pos).unwrap();
        for _ in 0..200 {
            let p = [2.0 * rnd() - 0.5, 2.0 * rnd() - 0.5, 2.0 * rnd() - 0.5];
            let h = m.closest(p).unwrap();
            assert!((h.signed_distance.abs() - brute(&m, p)).abs() < 1e-12);
        }
    }
}
