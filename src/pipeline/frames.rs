//! The one frame writer of the stages: yarn positions go to it frame by
//! frame as a stage computes them ([`FrameSink`]), so no stage holds every
//! frame's yarns in memory.
//!
//! Every file is written atomically (temporary, fsync, rename). Inside
//! [`io::atomic::all_or_nothing`] each frame file (or the one HDF5 file)
//! stays a registered temporary until the stage succeeds, and then all get
//! their final names together; outside one (a resumable shot) each frame
//! file gets its final name as soon as it is complete, and the one HDF5
//! file when the writer finishes.

use std::path::{Path, PathBuf};

use crate::geom::{Vec3, Yarns};
use crate::io::{self, h5, sequence::Pattern, IoError, WriteOptions};

/// Where a stage's frames go, one at a time, in frame order.
pub trait FrameSink {
    /// One frame: its number (a farm frame number, or a step index for
    /// `export`), shot time (s) and yarn positions (m).
    fn push(&mut self, frame: i64, time: f64, points: &[Vec3]) -> Result<(), IoError>;
}

/// How [`YarnFrameWriter`] lays out its files.
enum Layout {
    /// One file per frame, named by the frame number.
    PerFrame {
        pattern: Pattern,
        written: Vec<PathBuf>,
    },
    /// One knitvox HDF5 file streaming every frame.
    Hdf5(h5::FrameWriter),
}

/// Writes yarn frames: a `name.####.ext` sequence (any writable format,
/// numbered by frame) or one `.h5` file.
pub struct YarnFrameWriter<'a> {
    rest: &'a Yarns,
    opts: WriteOptions,
    layout: Layout,
}

impl<'a> YarnFrameWriter<'a> {
    /// A writer for `path`: a knitvox HDF5 file holds every frame; any
    /// other writable format needs a `name.####.ext` pattern. `rest`: the
    /// yarns whose positions the frames replace; `opts`: units and up axis
    /// of bcc, obj and ply files (`first_frame` is ignored: frames carry
    /// their numbers).
    pub fn create(
        path: &Path,
        rest: &'a Yarns,
        opts: &WriteOptions,
    ) -> Result<YarnFrameWriter<'a>, IoError> {
        let format = io::format_of(path)?;
        if !format.is_writable() {
            return Err(IoError::Unsupported {
                path: path.to_path_buf(),
                message: format!("knitvox reads {format} but does not write it; write bcc, obj, ply, gltf, glb or h5"),
            });
        }
        let layout = if format.holds_frames() {
            Layout::Hdf5(h5::FrameWriter::create(path, rest)?)
        } else {
            let pattern = Pattern::parse(path).ok_or_else(|| IoError::Unsupported {
                path: path.to_path_buf(),
                message: "frames need a sequence name.####.ext or an .h5 file".into(),
            })?;
            Layout::PerFrame {
                pattern,
                written: Vec::new(),
            }
        };
        Ok(YarnFrameWriter {
            rest,
            opts: opts.clone(),
            layout,
        })
    }

    /// Frame files `pattern` (numbered by frame), whatever characters the
    /// pattern's name holds.
    pub fn per_frame(pattern: Pattern, rest: &'a Yarns, opts: &WriteOptions) -> Self {
        YarnFrameWriter {
            rest,
            opts: opts.clone(),
            layout: Layout::PerFrame {
                pattern,
                written: Vec::new(),
            },
        }
    }

    /// The final file of `frame` in a per-frame sequence (`None` for one
    /// HDF5 file, which is written whole).
    pub fn frame_path(&self, frame: i64) -> Option<PathBuf> {
        match &self.layout {
            Layout::PerFrame { pattern, .. } => Some(pattern.path_of(frame)),
            Layout::Hdf5(_) => None,
        }
    }

    /// Lists `path`, a frame file an earlier run of a resumed shot wrote,
    /// among the files of this output (per-frame sequences).
    pub fn adopt(&mut self, path: PathBuf) {
        if let Layout::PerFrame { written, .. } = &mut self.layout {
            written.push(path);
        }
    }

    /// The frame files of a per-frame sequence so far, adopted ones first
    /// (empty for one HDF5 file).
    pub fn written(&self) -> &[PathBuf] {
        match &self.layout {
            Layout::PerFrame { written, .. } => written,
            Layout::Hdf5(_) => &[],
        }
    }

    /// Ends the output and returns the files written (still temporaries
    /// inside an `all_or_nothing` until it commits).
    pub fn finish(self) -> Result<Vec<PathBuf>, IoError> {
        match self.layout {
            Layout::PerFrame { written, .. } => Ok(written),
            Layout::Hdf5(w) => Ok(vec![w.finish()?]),
        }
    }
}

impl FrameSink for YarnFrameWriter<'_> {
    fn push(&mut self, frame: i64, time: f64, points: &[Vec3]) -> Result<(), IoError> {
        match &mut self.layout {
            Layout::Hdf5(w) => w.push(time, points),
            Layout::PerFrame { pattern, written } => {
                let path = pattern.path_of(frame);
                let posed = self.rest.with_points(points).map_err(|e| IoError::Write {
                    path: path.clone(),
                    source: std::io::Error::new(std::io::ErrorKind::InvalidInput, e.to_string()),
                })?;
                written.extend(io::write_path(&path, &posed, None, &self.opts)?);
                Ok(())
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::YarnFrames;
    use crate::yarn::analytic::{knit_swatch, SwatchParams};

    fn swatch() -> Yarns {
        knit_swatch(&SwatchParams {
            courses: 2,
            wales: 2,
            ..SwatchParams::default()
        })
    }

    fn shifted(y: &Yarns, dy: f64) -> Vec<Vec3> {
        y.points.iter().map(|p| [p[0], p[1] + dy, p[2]]).collect()
    }

    /// The streamed sequence reads back as the frames pushed, under the
    /// frame numbers given, and nothing is visible before the commit.
    #[test]
    fn sequence_frames_are_named_by_number_and_committed_together() {
        let dir = tempfile::tempdir().unwrap();
        let y = swatch();
        let path = dir.path().join("f.####.ply");
        let files = io::atomic::all_or_nothing(|| {
            let mut w = YarnFrameWriter::create(&path, &y, &WriteOptions::default())?;
            w.push(1001, 0.0, &shifted(&y, 0.0))?;
            w.push(1003, 2.0 / 24.0, &shifted(&y, 0.01))?;
            assert!(!dir.path().join("f.1001.ply").exists());
            w.finish()
        })
        .unwrap();
        assert_eq!(
            files,
            [dir.path().join("f.1001.ply"), dir.path().join("f.1003.ply")]
        );
        let back = io::read_path(&dir.path().join("f.1003.ply"), &Default::default()).unwrap();
        let dy = back.yarns.points[0][1] - y.points[0][1];
        assert!((dy - 0.01).abs() < 1e-6, "{dy}");
    }

    /// One HDF5 file holds the frames in order with their times.
    #[test]
    fn hdf5_frames_stream_into_one_file() {
        let dir = tempfile::tempdir().unwrap();
        let y = swatch();
        let path = dir.path().join("f.h5");
        let mut expected = YarnFrames::new(y.num_points());
        io::atomic::all_or_nothing(|| {
            let mut w = YarnFrameWriter::create(&path, &y, &WriteOptions::default())?;
            for k in 0..3 {
                let p = shifted(&y, 0.001 * k as f64);
                w.push(k, k as f64 / 24.0, &p)?;
                expected.push_frame(k as f64 / 24.0, &p).unwrap();
            }
            w.finish()
        })
        .unwrap();
        let back = io::read_path(&path, &Default::default()).unwrap();
        let frames = back.frames.unwrap();
        assert_eq!(frames.num_frames(), 3);
        assert_eq!(frames.times, expected.times);
        assert_eq!(frames.frame(2), expected.frame(2));
    }

    #[test]
    fn a_single_file_format_without_pattern_is_refused() {
        let y = swatch();
        let e = YarnFrameWriter::create(Path::new("x.ply"), &y, &WriteOptions::default())
            .err()
            .unwrap();
        assert!(
            matches!(&e, IoError::Unsupported { message, .. } if message.contains("####")),
            "{e}"
        );
    }
}
