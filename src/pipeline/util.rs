//! Small helpers that several stages share: file hashes for provenance,
//! statistics of timings and errors, the tet nodes that hold pinned yarn
//! vertices, pose names.

use std::path::Path;

use sha2::{Digest, Sha256};

use crate::geom::{Embedding, TetMesh};
use crate::io::IoError;
use crate::yarn::fabric::pose::kind_name;
use crate::yarn::poses::PoseKind;

/// SHA-256 of an input file, hex. The file is streamed (memory stays
/// small whatever its size) and must be a regular file: a FIFO or device
/// would never end.
pub fn sha256_file(path: &Path) -> Result<String, IoError> {
    let (mut file, _) = crate::io::input::open_regular(path, "input", None)?;
    let mut hasher = Sha256::new();
    let mut buf = vec![0u8; 1 << 16];
    loop {
        let n = match std::io::Read::read(&mut file, &mut buf) {
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(source) => {
                return Err(IoError::Read {
                    path: path.to_path_buf(),
                    source,
                })
            }
        };
        if n == 0 {
            break;
        }
        hasher.update(&buf[..n]);
    }
    Ok(hasher
        .finalize()
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect())
}

/// Root mean square and largest value of `d` (0 for none).
pub fn rms_max(d: &[f64]) -> (f64, f64) {
    let n = d.len().max(1) as f64;
    (
        (d.iter().map(|x| x * x).sum::<f64>() / n).sqrt(),
        d.iter().copied().fold(0.0, f64::max),
    )
}

/// Median (NaN for none).
pub fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        return f64::NAN;
    }
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// The nodes of every tet that holds a held yarn vertex, sorted.
pub fn held_nodes(mesh: &TetMesh, embedding: &Embedding, held: &[bool]) -> Vec<usize> {
    let mut is = vec![false; mesh.num_nodes()];
    for (v, _) in held.iter().enumerate().filter(|(_, h)| **h) {
        for &n in &mesh.tets[embedding.tet[v] as usize] {
            is[n as usize] = true;
        }
    }
    (0..is.len()).filter(|&i| is[i]).collect()
}

/// A pose kind that no schema name matches.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown pose {name:?} (one of {})", known.join(", "))]
pub struct UnknownPoseKind {
    /// The name as given.
    pub name: String,
    /// The names of the training poses.
    pub known: Vec<String>,
}

/// Parses a pose kind by its schema name (`stretch_courses`, ...).
pub fn parse_kind(s: &str) -> Result<PoseKind, UnknownPoseKind> {
    serde_json::from_value::<PoseKind>(serde_json::Value::String(s.to_string())).map_err(|_| {
        UnknownPoseKind {
            name: s.to_string(),
            known: crate::yarn::fabric::pose::TRAINING_KINDS
                .iter()
                .map(|k| kind_name(*k))
                .collect(),
        }
    })
}

#[cfg(test)]
mod tests {
    #[test]
    fn median_odd_even() {
        assert_eq!(super::median(vec![3.0, 1.0, 2.0]), 2.0);
        assert_eq!(super::median(vec![4.0, 1.0, 2.0, 3.0]), 2.5);
    }
}
