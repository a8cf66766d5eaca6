//! Frame sequences `name.####.ext`: one file per frame, the `#` run replaced
//! by the zero-padded frame number (the run's length is the minimum width).

use std::path::{Path, PathBuf};

use super::codec::read_single_with;
use super::{atomic, encode, read_single, Format, IoError, ReadOptions, WriteOptions, YarnData};
use crate::geom::{YarnFrames, Yarns};

/// Frame rate used to turn sequence frame numbers into times (s) on read: time = frame / fps.
pub const SEQUENCE_FPS: f64 = 24.0;

/// The parts of a sequence pattern: file-name prefix, padding width, suffix.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Pattern {
    pub dir: PathBuf,
    pub prefix: String,
    pub width: usize,
    pub suffix: String,
}

impl Pattern {
    /// Parses the last run of `#` in the file name, e.g. `shot.####.ply`.
    pub fn parse(path: &Path) -> Option<Pattern> {
        let name = path.file_name()?.to_str()?;
        let end = name.rfind('#')? + 1;
        let start = name[..end].trim_end_matches('#').len();
        Some(Pattern {
            dir: path.parent().map(Path::to_path_buf).unwrap_or_default(),
            prefix: name[..start].to_string(),
            width: end - start,
            suffix: name[end..].to_string(),
        })
    }

    /// The path of frame `n`.
    pub fn path_of(&self, n: i64) -> PathBuf {
        let num = if n < 0 {
            format!("-{:0w$}", -n, w = self.width)
        } else {
            format!("{:0w$}", n, w = self.width)
        };
        self.dir
            .join(format!("{}{}{}", self.prefix, num, self.suffix))
    }

    /// The frame number of a file name matching this pattern.
    pub fn frame_of(&self, name: &str) -> Option<i64> {
        let digits = name
            .strip_prefix(&self.prefix)?
            .strip_suffix(&self.suffix)?;
        let body = digits.strip_prefix('-').unwrap_or(digits);
        if body.len() < self.width || !body.bytes().all(|b| b.is_ascii_digit()) {
            return None;
        }
        digits.parse().ok()
    }

    /// Existing frames on disk, sorted by frame number.
    pub fn existing_frames(&self) -> std::io::Result<Vec<(i64, PathBuf)>> {
        let dir = if self.dir.as_os_str().is_empty() {
            Path::new(".")
        } else {
            self.dir.as_path()
        };
        let mut frames: Vec<(i64, PathBuf)> = std::fs::read_dir(dir)?
            .filter_map(|e| e.ok())
            .filter_map(|e| {
                let name = e.file_name().into_string().ok()?;
                Some((self.frame_of(&name)?, self.dir.join(name)))
            })
            .collect();
        frames.sort();
        Ok(frames)
    }
}

/// Whether `path` names a frame sequence (its file name holds a `#`).
pub fn is_pattern(path: &Path) -> bool {
    path.file_name()
        .and_then(|n| n.to_str())
        .is_some_and(|n| n.contains('#'))
}

/// Reads every existing frame of a sequence. The first frame's curves become
/// the rest yarns; every frame (the first included) becomes a frame at
/// time = frame number / [`SEQUENCE_FPS`]. All frames must share one curve structure.
pub fn read_sequence(path: &Path, opts: &ReadOptions) -> Result<YarnData, IoError> {
    let pattern = Pattern::parse(path).expect("is_pattern checked");
    let frames = pattern.existing_frames().map_err(|source| IoError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    let Some((_, first_path)) = frames.first() else {
        return Err(IoError::Read {
            path: path.to_path_buf(),
            source: std::io::Error::new(
                std::io::ErrorKind::NotFound,
                "no frame file matches this sequence pattern",
            ),
        });
    };
    let mut data = read_single(first_path, opts)?;
    let mut seq = YarnFrames::new(data.yarns.num_points());
    for (n, p) in &frames {
        let mut frame = if p == first_path {
            data.clone()
        } else {
            // Welded by the first frame's map, not its own: a later frame
            // may have moved the first frame's repeated points apart, and
            // the sequence keeps one numbering.
            read_single_with(p, opts, false)?
        };
        if p != first_path && data.weld.is_input_topology(&frame.yarns) {
            frame.yarns.points = data.weld.pick(&frame.yarns.points);
            frame.yarns.offsets = data.yarns.offsets.clone();
            frame.yarns.closed = data.yarns.closed.clone();
        }
        if !frame.yarns.same_topology(&data.yarns) {
            return Err(IoError::Invalid {
                path: p.clone(),
                format: frame.format,
                source: crate::geom::GeomError::Layout(format!(
                    "curve structure differs from the sequence's first frame {} ({} curves / {} points vs {} / {})",
                    first_path.display(),
                    frame.yarns.num_curves(),
                    frame.yarns.num_points(),
                    data.yarns.num_curves(),
                    data.yarns.num_points()
                )),
            });
        }
        seq.push_frame(*n as f64 / SEQUENCE_FPS, &frame.yarns.points)
            .map_err(|source| IoError::Invalid {
                path: p.clone(),
                format: frame.format,
                source,
            })?;
    }
    data.frames = Some(seq);
    Ok(data)
}

/// Writes one file per frame (or the rest yarns as a single frame when there
/// are no frames), numbered from `opts.first_frame`. Returns the paths written.
pub fn write_sequence(
    path: &Path,
    format: Format,
    yarns: &Yarns,
    frames: Option<&YarnFrames>,
    opts: &WriteOptions,
) -> Result<Vec<PathBuf>, IoError> {
    let pattern = Pattern::parse(path).expect("is_pattern checked");
    // Every frame or none under its final name.
    atomic::all_or_nothing(|| write_frames(&pattern, format, yarns, frames, opts))
}

fn write_frames(
    pattern: &Pattern,
    format: Format,
    yarns: &Yarns,
    frames: Option<&YarnFrames>,
    opts: &WriteOptions,
) -> Result<Vec<PathBuf>, IoError> {
    let count = frames.map_or(1, |f| f.num_frames());
    let mut written = Vec::with_capacity(count);
    for i in 0..count {
        let out = pattern.path_of(opts.first_frame + i as i64);
        let posed;
        let y = match frames {
            Some(f) => {
                posed = yarns
                    .with_points(f.frame(i))
                    .map_err(|source| IoError::Invalid {
                        path: out.clone(),
                        format,
                        source,
                    })?;
                &posed
            }
            None => yarns,
        };
        let bytes = encode(format, y, opts).map_err(|source| IoError::Format {
            path: out.clone(),
            format,
            source,
        })?;
        atomic::write_bytes(&out, &bytes)?;
        written.push(out);
    }
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pattern_parse_and_format() {
        let p = Pattern::parse(Path::new("out/shot.####.ply")).unwrap();
        assert_eq!(
            (p.prefix.as_str(), p.width, p.suffix.as_str()),
            ("shot.", 4, ".ply")
        );
        assert_eq!(p.path_of(7), PathBuf::from("out/shot.0007.ply"));
        assert_eq!(p.path_of(12345), PathBuf::from("out/shot.12345.ply"));
        assert_eq!(p.frame_of("shot.0042.ply"), Some(42));
        assert_eq!(p.frame_of("shot.42.ply"), None);
        assert_eq!(p.frame_of("shot.00a2.ply"), None);
        assert_eq!(p.frame_of(".shot.0042.ply.tmp"), None);
        assert!(!is_pattern(Path::new("a/b#c/x.ply")));
    }
}
