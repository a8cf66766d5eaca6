//! The folders of a watch root (schemas/watch.md).

use std::path::{Path, PathBuf};

use crate::io::IoError;

/// The folders under ROOT.
#[derive(Debug, Clone)]
pub struct Paths {
    pub root: PathBuf,
    pub inbox: PathBuf,
    pub work: PathBuf,
    pub done: PathBuf,
    pub failed: PathBuf,
    pub out: PathBuf,
}

impl Paths {
    pub fn new(root: &Path) -> Paths {
        Paths {
            root: root.to_path_buf(),
            inbox: root.join("inbox"),
            work: root.join("work"),
            done: root.join("done"),
            failed: root.join("failed"),
            out: root.join("out"),
        }
    }

    /// Creates the folders that are missing.
    pub fn create(&self) -> Result<(), IoError> {
        for d in [&self.inbox, &self.work, &self.done, &self.failed, &self.out] {
            std::fs::create_dir_all(d).map_err(|source| IoError::Write {
                path: d.clone(),
                source,
            })?;
        }
        Ok(())
    }
}
