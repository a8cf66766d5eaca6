//! Domains of the domain-decomposed global step (VH §7.2): a partition of
//! the tets, and the boundary nodes (nodes touched by tets of two or more
//! domains, the `x^(b)` of VH Eq. 29-34).
//!
//! Either automatic, by recursive coordinate bisection of the tet centroids
//! ([`Partition::bisect`]), or from given per-tet domain ids such as the
//! asset's `CellData/domain` ([`Partition::from_ids`]). Both are
//! deterministic (ties broken by tet index).

use super::SimError;
use crate::geom::Vec3;

/// Default target of nodes per domain for [`Partition::bisect`]: domains of
/// a few thousand nodes keep the per-domain Cholesky factors and
/// eigen-solves small while the boundary (and so the reduced system) stays a
/// modest fraction of the mesh. VH Table 1 uses 1-14 domains for 13K-165K
/// nodes, i.e. several thousand nodes per domain.
pub const DEFAULT_NODES_PER_DOMAIN: usize = 4000;

/// A partition of the tets into domains.
#[derive(Debug, Clone, PartialEq)]
pub struct Partition {
    /// Domain (0-based, dense) of every tet.
    pub tet_domain: Vec<u32>,
    /// Number of domains (every id below it has at least one tet).
    pub num_domains: usize,
    /// Whether each node is touched by tets of two or more domains.
    pub boundary: Vec<bool>,
}

impl Partition {
    /// Recursive coordinate bisection of the tets by centroid into
    /// `ceil(num_nodes / nodes_per_domain)` domains (at least 1, at most one
    /// per tet): each split cuts the longest axis of the centroids' bounding
    /// box at the tet count proportional to the domains on either side.
    pub fn bisect(
        nodes: &[Vec3],
        tets: &[[usize; 4]],
        nodes_per_domain: usize,
    ) -> Result<Partition, SimError> {
        check_tets(nodes.len(), tets)?;
        if nodes_per_domain == 0 {
            return Err(SimError::Inconsistent(
                "nodes_per_domain must be at least 1".into(),
            ));
        }
        let used = {
            let mut u = vec![false; nodes.len()];
            tets.iter().flatten().for_each(|&a| u[a] = true);
            u.iter().filter(|&&b| b).count()
        };
        let d = used.div_ceil(nodes_per_domain).clamp(1, tets.len().max(1));
        let centroids: Vec<Vec3> = tets
            .iter()
            .map(|t| std::array::from_fn(|k| t.iter().map(|&a| nodes[a][k]).sum::<f64>() / 4.0))
            .collect();
        let mut tet_domain = vec![0u32; tets.len()];
        let mut ids: Vec<usize> = (0..tets.len()).collect();
        split(&centroids, &mut ids, d, 0, &mut tet_domain);
        Ok(Self::finish(nodes.len(), tets, tet_domain))
    }

    /// A partition from given per-tet domain ids (any `u32` values; they are
    /// renumbered densely in increasing order).
    pub fn from_ids(
        num_nodes: usize,
        tets: &[[usize; 4]],
        ids: &[u32],
    ) -> Result<Partition, SimError> {
        check_tets(num_nodes, tets)?;
        if ids.len() != tets.len() {
            return Err(SimError::Inconsistent(format!(
                "{} domain ids for {} tets",
                ids.len(),
                tets.len()
            )));
        }
        let mut distinct = ids.to_vec();
        distinct.sort_unstable();
        distinct.dedup();
        let tet_domain = ids
            .iter()
            .map(|i| distinct.binary_search(i).unwrap_or(0) as u32)
            .collect();
        Ok(Self::finish(num_nodes, tets, tet_domain))
    }

    fn finish(num_nodes: usize, tets: &[[usize; 4]], tet_domain: Vec<u32>) -> Partition {
        let num_domains = tet_domain
            .iter()
            .map(|&d| d as usize + 1)
            .max()
            .unwrap_or(0);
        // First domain seen per node; a second distinct one makes it boundary.
        let mut first = vec![u32::MAX; num_nodes];
        let mut boundary = vec![false; num_nodes];
        for (t, &d) in tets.iter().zip(&tet_domain) {
            for &a in t {
                if first[a] == u32::MAX {
                    first[a] = d;
                } else if first[a] != d {
                    boundary[a] = true;
                }
            }
        }
        Partition {
            tet_domain,
            num_domains,
            boundary,
        }
    }
}

fn check_tets(n: usize, tets: &[[usize; 4]]) -> Result<(), SimError> {
    if let Some((t, a)) = tets
        .iter()
        .enumerate()
        .find_map(|(t, q)| q.iter().find(|&&a| a >= n).map(|&a| (t, a)))
    {
        return Err(SimError::Inconsistent(format!(
            "tet {t} uses node {a} but the mesh has {n} nodes"
        )));
    }
    Ok(())
}

/// Assigns domains `first..first + d` to the tets `ids`.
fn split(c: &[Vec3], ids: &mut [usize], d: usize, first: u32, out: &mut [u32]) {
    if d <= 1 || ids.len() <= 1 {
        ids.iter().for_each(|&t| out[t] = first);
        return;
    }
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for &t in ids.iter() {
        for k in 0..3 {
            lo[k] = lo[k].min(c[t][k]);
            hi[k] = hi[k].max(c[t][k]);
        }
    }
    let axis = (0..3)
        .max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b])).then(b.cmp(&a)))
        .unwrap_or(0);
    ids.sort_by(|&a, &b| c[a][axis].total_cmp(&c[b][axis]).then(a.cmp(&b)));
    let dl = d / 2;
    let cut = (ids.len() * dl / d).clamp(1, ids.len() - 1);
    let (l, r) = ids.split_at_mut(cut);
    split(c, l, dl, first, out);
    split(c, r, d - dl, first + dl as u32, out);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn two_tets_two_domains_share_a_face() {
        let nodes = vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
            [5.0, 5.0, 5.0],
        ];
        let tets = vec![[0, 1, 2, 3], [1, 2, 3, 4]];
        let p = Partition::bisect(&nodes, &tets, 1).unwrap();
        assert_eq!(p.num_domains, 2);
        assert_ne!(p.tet_domain[0], p.tet_domain[1]);
        assert_eq!(p.boundary, vec![false, true, true, true, false]);
        let q = Partition::from_ids(5, &tets, &[7, 7]).unwrap();
        assert_eq!(q.num_domains, 1);
        assert_eq!(q.tet_domain, vec![0, 0]);
        assert!(q.boundary.iter().all(|b| !b));
        assert!(Partition::from_ids(5, &tets, &[1]).is_err());
        assert!(Partition::from_ids(4, &tets, &[1, 2]).is_err());
    }
}
