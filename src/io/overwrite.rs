//! Never overwrite an input: whether an output path is,
//! or resolves to, one of a command's inputs. Every command that writes
//! asks [`refuse_inputs`] before any work, with every input it knows of
//! (files named on the command line and files a scene refers to).

use std::path::{Path, PathBuf};

use super::sequence::Pattern;
use super::IoError;

/// Whether `a` and `b` name the same file: the same inode when both exist
/// (symlinks, `./`, `x/../`, hard links), else the same canonical folder
/// and file name.
pub fn same_file(a: &Path, b: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        if let (Ok(x), Ok(y)) = (std::fs::metadata(a), std::fs::metadata(b)) {
            return x.dev() == y.dev() && x.ino() == y.ino();
        }
    }
    match (canonical_place(a), canonical_place(b)) {
        (Some(x), Some(y)) => x == y,
        _ => false,
    }
}

/// The canonical folder of `p` joined with its file name (the file itself
/// need not exist).
pub fn canonical_place(p: &Path) -> Option<PathBuf> {
    let dir = p
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    Some(std::fs::canonicalize(dir).ok()?.join(p.file_name()?))
}

/// Whether writing `output` could replace `input`. Either may be a frame
/// sequence `name.####.ext`: an input sequence stands for its frames on
/// disk, an output sequence for every frame number it could write.
pub fn overlaps(input: &Path, output: &Path) -> bool {
    if same_file(input, output) {
        return true;
    }
    let files = match Pattern::parse(input) {
        Some(p) => p
            .existing_frames()
            .map(|v| v.into_iter().map(|(_, f)| f).collect())
            .unwrap_or_default(),
        None => vec![input.to_path_buf()],
    };
    let Some(q) = Pattern::parse(output) else {
        return files.iter().any(|f| same_file(f, output));
    };
    files.iter().any(|f| is_frame_of(f, &q))
}

/// Whether `file` (as named, or after resolving symlinks) lies where
/// pattern `q` writes and has a name it writes.
fn is_frame_of(file: &Path, q: &Pattern) -> bool {
    let Some(qdir) =
        canonical_place(&q.dir.join("x")).and_then(|p| p.parent().map(Path::to_path_buf))
    else {
        return false;
    };
    let named = canonical_place(file);
    let resolved = std::fs::canonicalize(file).ok();
    [named, resolved].into_iter().flatten().any(|p| {
        p.parent() == Some(qdir.as_path())
            && p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| q.frame_of(n).is_some())
    })
}

/// Refuses (an [`IoError::OutputIsInput`], exit 2) any output that could
/// replace one of the inputs.
pub fn refuse_inputs(outputs: &[&Path], inputs: &[&Path]) -> Result<(), IoError> {
    for o in outputs {
        if let Some(i) = inputs.iter().find(|i| overlaps(i, o)) {
            return Err(IoError::OutputIsInput {
                output: o.to_path_buf(),
                input: i.to_path_buf(),
            });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn aliases_of_an_input_are_refused() {
        let d = tempfile::tempdir().unwrap();
        let a = d.path().join("a.obj");
        std::fs::write(&a, "v 0 0 0\n").unwrap();
        std::fs::create_dir(d.path().join("sub")).unwrap();
        std::os::unix::fs::symlink(&a, d.path().join("sym.obj")).unwrap();
        std::fs::hard_link(&a, d.path().join("hard.obj")).unwrap();
        for alias in ["a.obj", "sub/../a.obj", "./a.obj", "sym.obj", "hard.obj"] {
            assert!(overlaps(&a, &d.path().join(alias)), "{alias}");
        }
        assert!(!overlaps(&a, &d.path().join("b.obj")));
        let e = refuse_inputs(&[&d.path().join("hard.obj")], &[&a]).unwrap_err();
        assert_eq!(e.class(), super::super::ErrorClass::Usage);
        assert!(e.to_string().contains("never overwrites an input"), "{e}");
    }

    #[test]
    fn sequences_overlap_their_frames() {
        let d = tempfile::tempdir().unwrap();
        let f1 = d.path().join("s.0001.ply");
        std::fs::write(&f1, "x").unwrap();
        let seq = d.path().join("s.####.ply");
        // An output sequence would write the input frame; an output frame
        // is one of an input sequence's frames.
        assert!(overlaps(&f1, &seq));
        assert!(overlaps(&seq, &f1));
        assert!(overlaps(&seq, &d.path().join("./s.####.ply")));
        assert!(!overlaps(&f1, &d.path().join("t.####.ply")));
        assert!(!overlaps(&seq, &d.path().join("s.0002.ply")));
    }
}
