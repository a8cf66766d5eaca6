//! Shot checkpoints (schemas/checkpoint.md): the full state of a shot's time
//! loop after some step, so a killed shot resumes and a frame chunk
//! continues where the previous chunk stopped.
//!
//! Layout: magic `KNITVOXCKPT\n`, format version (u32 LE), header length
//! `H` (u64 LE), `H` bytes of JSON header ([`CheckpointHeader`]), the
//! payload (f64 LE: positions, velocities, the written frames' node
//! positions, then the solver's warm start), and the SHA-256 of every byte before it. Written atomically
//! (temporary file, fsync, rename). Read as untrusted input: the header is
//! bounded, the payload size must match the header and the file length
//! before anything is allocated, the hash must match, and every number
//! must be finite.

use std::io::Read;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use super::IoError;
use crate::geom::Vec3;

/// The first bytes of a checkpoint.
pub const MAGIC: &[u8; 12] = b"KNITVOXCKPT\n";
/// The format version this build writes and reads.
pub const VERSION: u32 = 1;
/// Largest JSON header accepted (bytes): far above any real header (it
/// holds two numbers per written frame), small enough to read blindly.
pub const MAX_HEADER: u64 = 16 << 20;
/// File name extension of checkpoints.
pub const EXT: &str = "ckpt";

/// What a checkpoint says about itself (the JSON header).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CheckpointHeader {
    /// SHA-256 (hex) of the shot's parameters: asset and character file
    /// hashes, scene, step schedule, node count (not the frame range).
    pub key: String,
    /// The shot's first frame (farm frame number): shot time 0.
    pub shot_start: i64,
    /// PD steps taken since the start of the loop (pre-roll included).
    pub step: u64,
    /// Shot time (s) after `step` steps.
    pub time: f64,
    /// Tet nodes.
    pub nodes: u64,
    /// Frame numbers whose node positions follow the state (the frames
    /// the writing run had written, in order).
    pub series_frames: Vec<i64>,
    /// Values of the solver's warm start (`PdSolver::warm_start`).
    pub warm_start_len: u64,
    /// knitvox version that wrote it.
    pub knitvox: String,
}

/// A shot's state after `header.step` steps.
#[derive(Debug, Clone, PartialEq)]
pub struct Checkpoint {
    pub header: CheckpointHeader,
    /// Node positions (m).
    pub x: Vec<Vec3>,
    /// Node velocities (m/s).
    pub v: Vec<Vec3>,
    /// Shot times (s) of `header.series_frames` (in the payload, exact:
    /// JSON does not round-trip every f64).
    pub series_times: Vec<f64>,
    /// Node positions (m) of each of `header.series_frames`, frame after frame.
    pub series: Vec<Vec3>,
    /// The solver's warm start (the CPU backend's per-tet SVD `V`).
    pub warm_start: Vec<f64>,
}

fn bad(path: &Path, message: impl Into<String>) -> IoError {
    IoError::Unsupported {
        path: path.to_path_buf(),
        message: format!("not a usable knitvox checkpoint: {}", message.into()),
    }
}

fn read_err(path: &Path, source: std::io::Error) -> IoError {
    IoError::Read {
        path: path.to_path_buf(),
        source,
    }
}

/// The file name of the checkpoint of shot `key` starting at frame
/// `shot_start` after `step` steps: `knitvox-KEY16.START.STEP.ckpt` (the
/// step zero-padded to 10 digits so names sort by step).
pub fn file_name(key: &str, shot_start: i64, step: u64) -> String {
    let short = key.get(..16).unwrap_or(key);
    format!("knitvox-{short}.{shot_start}.{step:010}.{EXT}")
}

/// A checkpoint file found in a folder: its shot start and step (from the
/// name; the header is the authority).
#[derive(Debug, Clone, PartialEq)]
pub struct Found {
    pub path: PathBuf,
    pub shot_start: i64,
    pub step: u64,
}

/// The checkpoints of shot `key` in `dir` (by name), in no particular
/// order. A missing folder holds none.
pub fn list(dir: &Path, key: &str) -> Result<Vec<Found>, IoError> {
    let short = key.get(..16).unwrap_or(key);
    let prefix = format!("knitvox-{short}.");
    let entries = match std::fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(read_err(dir, e)),
    };
    let mut found = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|e| read_err(dir, e))?;
        let name = entry.file_name();
        let Some(rest) = name
            .to_str()
            .and_then(|n| n.strip_prefix(&prefix))
            .and_then(|n| n.strip_suffix(&format!(".{EXT}")))
        else {
            continue;
        };
        let Some((start, step)) = rest.rsplit_once('.') else {
            continue;
        };
        if let (Ok(shot_start), Ok(step)) = (start.parse(), step.parse()) {
            found.push(Found {
                path: entry.path(),
                shot_start,
                step,
            });
        }
    }
    Ok(found)
}

/// Writes `c` to `path` atomically.
pub fn write(path: &Path, c: &Checkpoint) -> Result<(), IoError> {
    let h = &c.header;
    let n = h.nodes as usize;
    let consistent = c.x.len() == n
        && c.v.len() == n
        && c.series_times.len() == h.series_frames.len()
        && c.series.len() == n * h.series_frames.len()
        && c.warm_start.len() as u64 == h.warm_start_len;
    if !consistent {
        return Err(IoError::Write {
            path: path.to_path_buf(),
            source: std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                "checkpoint arrays do not match its header",
            ),
        });
    }
    let header = serde_json::to_vec(h).map_err(|e| IoError::Write {
        path: path.to_path_buf(),
        source: std::io::Error::new(std::io::ErrorKind::InvalidInput, e.to_string()),
    })?;
    let payload = 8
        * (3 * (c.x.len() + c.v.len() + c.series.len())
            + c.series_times.len()
            + c.warm_start.len());
    let mut bytes = Vec::with_capacity(MAGIC.len() + 12 + header.len() + payload + 32);
    bytes.extend_from_slice(MAGIC);
    bytes.extend_from_slice(&VERSION.to_le_bytes());
    bytes.extend_from_slice(&(header.len() as u64).to_le_bytes());
    bytes.extend_from_slice(&header);
    let points = |ps: &[Vec3]| ps.iter().flatten().copied().collect::<Vec<f64>>();
    let values = [
        points(&c.x),
        points(&c.v),
        c.series_times.clone(),
        points(&c.series),
        c.warm_start.clone(),
    ];
    for k in values.iter().flatten() {
        bytes.extend_from_slice(&k.to_le_bytes());
    }
    let hash = Sha256::digest(&bytes);
    bytes.extend_from_slice(&hash);
    super::atomic::write_bytes(path, &bytes)
}

/// The fixed prefix: magic, version, header length.
const PREFIX: usize = 12 + 4 + 8;

/// Checks the prefix and header of `bytes` (at least the prefix and
/// header, of a file `file_len` bytes long) and returns the header and the
/// payload length it implies.
fn parse_header(
    path: &Path,
    bytes: &[u8],
    file_len: u64,
) -> Result<(CheckpointHeader, usize, u64), IoError> {
    if bytes.len() < PREFIX || &bytes[..12] != MAGIC {
        return Err(bad(path, "it does not start with KNITVOXCKPT"));
    }
    let version = u32::from_le_bytes(bytes[12..16].try_into().unwrap());
    if version != VERSION {
        return Err(bad(
            path,
            format!("format version {version}; this knitvox reads version {VERSION}"),
        ));
    }
    let hlen = u64::from_le_bytes(bytes[16..24].try_into().unwrap());
    if hlen > MAX_HEADER || PREFIX as u64 + hlen > file_len {
        return Err(bad(
            path,
            format!("header of {hlen} bytes in a file of {file_len} bytes"),
        ));
    }
    let end = PREFIX + hlen as usize;
    if bytes.len() < end {
        return Err(bad(path, "truncated header"));
    }
    let header: CheckpointHeader = serde_json::from_slice(&bytes[PREFIX..end])
        .map_err(|e| bad(path, format!("header: {e}")))?;
    // Payload length with checked arithmetic: a hostile header must not
    // overflow or make us allocate what the file does not hold.
    let vecs = (header.series_frames.len() as u64)
        .checked_add(2)
        .and_then(|k| k.checked_mul(header.nodes))
        .and_then(|k| k.checked_mul(3))
        .and_then(|k| k.checked_add(header.series_frames.len() as u64))
        .and_then(|k| k.checked_add(header.warm_start_len))
        .and_then(|k| k.checked_mul(8));
    let expected = vecs.and_then(|p| p.checked_add(end as u64 + 32));
    if expected != Some(file_len) {
        return Err(bad(
            path,
            format!(
                "{file_len} bytes, but its header ({} nodes, {} frames) needs {}",
                header.nodes,
                header.series_frames.len(),
                expected.map_or("more than fit in memory".into(), |e| e.to_string())
            ),
        ));
    }
    Ok((header, end, vecs.unwrap_or(0)))
}

/// Reads only the header of the checkpoint at `path` (the prefix, the
/// header, and the file length; the hash is checked by [`read`]).
pub fn read_header(path: &Path) -> Result<CheckpointHeader, IoError> {
    let mut f = std::fs::File::open(path).map_err(|e| read_err(path, e))?;
    let file_len = f.metadata().map_err(|e| read_err(path, e))?.len();
    let mut prefix = [0u8; PREFIX];
    f.read_exact(&mut prefix)
        .map_err(|_| bad(path, format!("{file_len} bytes: too short")))?;
    let hlen = u64::from_le_bytes(prefix[16..24].try_into().unwrap());
    if hlen > MAX_HEADER || PREFIX as u64 + hlen > file_len {
        return parse_header(path, &prefix, file_len).map(|h| h.0);
    }
    let mut bytes = prefix.to_vec();
    bytes.resize(PREFIX + hlen as usize, 0);
    f.read_exact(&mut bytes[PREFIX..])
        .map_err(|e| read_err(path, e))?;
    Ok(parse_header(path, &bytes, file_len)?.0)
}

/// Reads and checks the whole checkpoint at `path`; `max_bytes`: the
/// largest file accepted (the process's memory budget).
pub fn read(path: &Path, max_bytes: u64) -> Result<Checkpoint, IoError> {
    let file_len = std::fs::metadata(path)
        .map_err(|e| read_err(path, e))?
        .len();
    if file_len > max_bytes {
        return Err(bad(
            path,
            format!("{file_len} bytes, more than the memory budget of {max_bytes} bytes"),
        ));
    }
    let bytes = std::fs::read(path).map_err(|e| read_err(path, e))?;
    let (header, start, _) = parse_header(path, &bytes, bytes.len() as u64)?;
    let body = bytes.len() - 32;
    if Sha256::digest(&bytes[..body]).as_slice() != &bytes[body..] {
        return Err(bad(
            path,
            "its SHA-256 does not match its content (damaged or truncated)",
        ));
    }
    let values: Vec<f64> = bytes[start..body]
        .chunks_exact(8)
        .map(|b| f64::from_le_bytes(b.try_into().unwrap()))
        .collect();
    if let Some(i) = values.iter().position(|v| !v.is_finite()) {
        return Err(bad(path, format!("value {i} of its payload is not finite")));
    }
    if !header.time.is_finite() {
        return Err(bad(path, "the time in its header is not finite"));
    }
    let (n, nf) = (header.nodes as usize, header.series_frames.len());
    let points =
        |v: &[f64]| -> Vec<Vec3> { v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect() };
    let (x, rest) = values.split_at(3 * n);
    let (v, rest) = rest.split_at(3 * n);
    let (series_times, rest) = rest.split_at(nf);
    let (series, warm_start) = rest.split_at(3 * n * nf);
    Ok(Checkpoint {
        header,
        x: points(x),
        v: points(v),
        series_times: series_times.to_vec(),
        series: points(series),
        warm_start: warm_start.to_vec(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Checkpoint {
        Checkpoint {
            header: CheckpointHeader {
                key: "ab".repeat(32),
                shot_start: 1001,
                step: 42,
                time: 0.25,
                nodes: 2,
                series_frames: vec![1001, 1002],
                warm_start_len: 9,
                knitvox: "test".into(),
            },
            x: vec![[0.0, 1.0, 2.0], [3.0, 4.0, 5.0]],
            v: vec![[-1.0, 0.5, 0.0], [0.0, 0.0, 1e-9]],
            series_times: vec![0.0, 5.0 / 24.0],
            series: vec![[0.1; 3], [0.2; 3], [0.3; 3], [0.4; 3]],
            warm_start: (0..9).map(|k| k as f64 / 9.0).collect(),
        }
    }

    #[test]
    fn round_trip_and_listing_by_name() {
        let dir = tempfile::tempdir().unwrap();
        let c = sample();
        let name = file_name(&c.header.key, 1001, 42);
        assert_eq!(name, "knitvox-abababababababab.1001.0000000042.ckpt");
        let path = dir.path().join(&name);
        write(&path, &c).unwrap();
        assert_eq!(read(&path, 1 << 30).unwrap(), c);
        assert_eq!(read_header(&path).unwrap(), c.header);
        std::fs::write(dir.path().join("other.ckpt"), b"x").unwrap();
        let found = list(dir.path(), &c.header.key).unwrap();
        assert_eq!(
            found,
            [Found {
                path,
                shot_start: 1001,
                step: 42
            }]
        );
        assert!(list(&dir.path().join("none"), "ab").unwrap().is_empty());
    }

    /// Every kind of damage is refused with a message naming the file.
    #[test]
    fn damaged_files_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.ckpt");
        let c = sample();
        write(&path, &c).unwrap();
        let good = std::fs::read(&path).unwrap();
        let check = |bytes: &[u8], what: &str| {
            std::fs::write(&path, bytes).unwrap();
            let e = read(&path, 1 << 30).unwrap_err().to_string();
            assert!(e.contains("c.ckpt") && e.contains(what), "{what}: {e}");
        };
        check(&good[..good.len() - 1], "needs");
        check(b"hello", "KNITVOXCKPT");
        let mut flipped = good.clone();
        let k = good.len() - 40;
        flipped[k] ^= 1;
        check(&flipped, "SHA-256");
        let mut version = good.clone();
        version[12] = 9;
        check(&version, "version 9");
        let mut huge = good.clone();
        huge[16..24].copy_from_slice(&u64::MAX.to_le_bytes());
        check(&huge, "header of");
        // A NaN with a valid hash is still refused.
        let mut nan = c.clone();
        nan.v[1][2] = f64::NAN;
        write(&path, &nan).unwrap();
        let e = read(&path, 1 << 30).unwrap_err().to_string();
        assert!(e.contains("not finite"), "{e}");
        // A header claiming more nodes than the file holds.
        let mut lie = c.clone();
        lie.header.nodes = u64::MAX / 8;
        let h = serde_json::to_vec(&lie.header).unwrap();
        let mut bytes = MAGIC.to_vec();
        bytes.extend_from_slice(&VERSION.to_le_bytes());
        bytes.extend_from_slice(&(h.len() as u64).to_le_bytes());
        bytes.extend_from_slice(&h);
        check(&bytes, "needs");
        write(&path, &c).unwrap();
        let e = read(&path, 100).unwrap_err().to_string();
        assert!(e.contains("memory budget"), "{e}");
    }
}
