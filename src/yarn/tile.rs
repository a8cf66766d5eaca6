//! A periodic tile of yarn curves (Leaf et al. 2018 §5): the unit both the
//! stitch-pattern generator (`yarn::pattern`) produces and the periodic
//! relaxation of the yarn-level simulator (`yarn::sim`) works on.

use crate::geom::{Vec3, Yarns};

/// Why a periodic tile is not well formed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TileError {
    /// There is not one continuation per curve.
    #[error("{continuations} continuations for {curves} curves")]
    ContinuationCount { continuations: usize, curves: usize },
    /// Curve `curve` continues into a curve the tile does not have.
    #[error("curve {curve} continues into curve {into} of {curves}")]
    UnknownCurve {
        curve: usize,
        into: usize,
        curves: usize,
    },
    /// Two curves continue into curve `curve`.
    #[error("two curves continue into curve {curve}")]
    SharedContinuation { curve: usize },
    /// Curve `curve` is closed.
    #[error("curve {curve} is closed; tile curves must be open")]
    ClosedCurve { curve: usize },
    /// The lattice vectors (m) are not finite or are parallel.
    #[error("lattice vectors {a:?}, {b:?} span no area")]
    DegenerateLattice { a: Vec3, b: Vec3 },
}

/// One tile of a doubly periodic yarn pattern. Copies of the tile sit at
/// `i * lattice[0] + j * lattice[1]` for all integers `i`, `j`.
///
/// Every curve of `yarns` is open; its last point connects (by one yarn
/// segment) to the first point of curve `next[c].0` in the tile copy shifted
/// by `next[c].1` lattice steps. A course of a weft knit running along
/// `lattice[0]` that leaves the tile on the right and re-enters on the left
/// is `next[c] = (c, [1, 0])`.
#[derive(Debug, Clone, PartialEq)]
pub struct PeriodicTile {
    /// The tile's curves (internal frame: metres, +Y up), all open.
    pub yarns: Yarns,
    /// The two lattice vectors (m): `lattice[0]` along the wales' spacing
    /// direction (courses run along it), `lattice[1]` along the courses'
    /// spacing direction (wales run along it).
    pub lattice: [Vec3; 2],
    /// Continuation of every curve: (curve, lattice offset).
    pub next: Vec<(usize, [i32; 2])>,
}

impl PeriodicTile {
    /// Checks that `next` has one entry per curve, names existing curves,
    /// that no two curves continue into the same curve, that the curves are
    /// open, and that the lattice vectors are finite and independent.
    pub fn validate(&self) -> Result<(), TileError> {
        let n = self.yarns.num_curves();
        if self.next.len() != n {
            return Err(TileError::ContinuationCount {
                continuations: self.next.len(),
                curves: n,
            });
        }
        let mut seen = vec![false; n];
        for (c, &(to, _)) in self.next.iter().enumerate() {
            if to >= n {
                return Err(TileError::UnknownCurve {
                    curve: c,
                    into: to,
                    curves: n,
                });
            }
            if std::mem::replace(&mut seen[to], true) {
                return Err(TileError::SharedContinuation { curve: to });
            }
            if self.yarns.closed[c] {
                return Err(TileError::ClosedCurve { curve: c });
            }
        }
        let [a, b] = self.lattice;
        let cross = [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ];
        let area = (cross[0] * cross[0] + cross[1] * cross[1] + cross[2] * cross[2]).sqrt();
        if !(area.is_finite() && area > 0.0) {
            return Err(TileError::DegenerateLattice { a, b });
        }
        Ok(())
    }
}
