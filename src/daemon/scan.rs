//! The inbox: which entries are drops, what kind, and whether they are
//! complete (schemas/watch.md, "Readiness").
//!
//! A drop is taken only after its signature (size and mtime of every file
//! in it) is unchanged across two scans at least `settle` apart: a
//! half-copied file keeps growing or being touched, so it is never taken
//! (docs/design.md, pipeline conventions: polling is the truth).

use std::collections::{BTreeMap, HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant, SystemTime};

use crate::io::Format;

/// What a drop is.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DropKind {
    /// A yarn file (`NAME.bcc`, ...) with an optional `NAME.job.toml` sidecar.
    Yarns {
        file: String,
        sidecar: Option<String>,
    },
    /// A job manifest file in the inbox (`NAME.toml`, `NAME.job.toml`).
    Manifest { file: String },
    /// A job folder `NAME/` holding `job.toml` and its inputs.
    Folder { dir: String },
    /// A sidecar `NAME.job.toml` without `[garment] yarns` and without its
    /// yarn file yet: waits for it.
    Sidecar { file: String },
    /// Not something knitvox runs (goes to failed/).
    Unknown { file: String },
}

/// One drop in the inbox.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Drop {
    /// The job name: outputs go to `out/NAME/`.
    pub name: String,
    pub kind: DropKind,
}

impl Drop {
    /// The inbox entries (file or folder names) that make up this drop.
    pub fn entries(&self) -> Vec<String> {
        match &self.kind {
            DropKind::Yarns { file, sidecar } => {
                let mut v = vec![file.clone()];
                v.extend(sidecar.clone());
                v
            }
            DropKind::Manifest { file }
            | DropKind::Sidecar { file }
            | DropKind::Unknown { file } => vec![file.clone()],
            DropKind::Folder { dir } => vec![dir.clone()],
        }
    }

    /// Whether the daemon runs it (a lone sidecar waits).
    pub fn runnable(&self) -> bool {
        !matches!(self.kind, DropKind::Sidecar { .. })
    }
}

/// Names the daemon never takes: hidden files (`.x`, the dot-prefixed
/// temporaries of atomic writers) and the partial names of common copy
/// tools and editors.
pub fn ignored(name: &str) -> bool {
    const PARTIAL: [&str; 8] = [
        "~",
        ".tmp",
        ".part",
        ".partial",
        ".crdownload",
        ".swp",
        ".download",
        ".filepart",
    ];
    name.starts_with('.')
        || name.starts_with('#')
        || name.starts_with('~')
        || PARTIAL
            .iter()
            .any(|s| name.to_ascii_lowercase().ends_with(s))
}

fn is_yarn_file(name: &str) -> bool {
    Format::from_path(Path::new(name)).is_some()
}

/// Splits `NAME.job.toml` / `NAME.toml` into NAME.
fn manifest_stem(name: &str) -> Option<&str> {
    name.strip_suffix(".job.toml")
        .or_else(|| name.strip_suffix(".toml"))
        .filter(|s| !s.is_empty())
}

/// Whether a TOML text names its garment's yarns (a full manifest rather
/// than a sidecar). Unparsable text counts as a manifest: running it
/// reports the error with its line.
fn names_yarns(text: &str) -> bool {
    match text.parse::<toml::Table>() {
        Ok(t) => t
            .get("garment")
            .and_then(|g| g.as_table())
            .is_some_and(|g| g.contains_key("yarns")),
        Err(_) => true,
    }
}

/// Groups the inbox's entries into drops (sorted by name, so every daemon
/// sees the same order). `entries` are (name, is_dir); `read` gives a
/// manifest's text (sidecar detection).
pub fn classify(entries: &[(String, bool)], read: impl Fn(&str) -> Option<String>) -> Vec<Drop> {
    let mut names: Vec<&(String, bool)> = entries.iter().filter(|(n, _)| !ignored(n)).collect();
    names.sort();
    let yarn_stems: HashMap<&str, &str> = names
        .iter()
        .filter(|(n, d)| !d && is_yarn_file(n))
        .filter_map(|(n, _)| Path::new(n).file_stem()?.to_str().map(|s| (s, n.as_str())))
        .collect();
    let mut drops = Vec::new();
    let mut sidecars_given = HashSet::new();
    for (n, is_dir) in names {
        let kind = if *is_dir {
            DropKind::Folder { dir: n.clone() }
        } else if let Some(stem) = n.strip_suffix(".job.toml") {
            if yarn_stems.contains_key(stem) {
                continue; // a sidecar: part of its yarn file's drop
            }
            match read(n) {
                Some(t) if !names_yarns(&t) => DropKind::Sidecar { file: n.clone() },
                _ => DropKind::Manifest { file: n.clone() },
            }
        } else if n.ends_with(".toml") {
            DropKind::Manifest { file: n.clone() }
        } else if is_yarn_file(n) {
            let stem = Path::new(n)
                .file_stem()
                .and_then(|s| s.to_str())
                .unwrap_or(n);
            let side = format!("{stem}.job.toml");
            // A sidecar goes with the first yarn file of its stem only.
            let sidecar = (entries.iter().any(|(e, d)| !d && *e == side)
                && sidecars_given.insert(side.clone()))
            .then_some(side);
            DropKind::Yarns {
                file: n.clone(),
                sidecar,
            }
        } else {
            DropKind::Unknown { file: n.clone() }
        };
        let name = match &kind {
            DropKind::Folder { dir } => dir.clone(),
            DropKind::Manifest { file } | DropKind::Sidecar { file } => {
                manifest_stem(file).unwrap_or(file).to_string()
            }
            DropKind::Yarns { file, .. } | DropKind::Unknown { file } => Path::new(file)
                .file_stem()
                .and_then(|s| s.to_str())
                .unwrap_or(file)
                .to_string(),
        };
        drops.push(Drop { name, kind });
    }
    unique_names(&mut drops, |_, _| None);
    drops
}

/// Gives drops that would share a job name distinct names: the first (in
/// name order) keeps NAME, a later one is named by its entry's full name
/// (`dup.obj` beside `dup.bcc`). `given` returns the name a drop was given
/// at an earlier scan, which it keeps while it waits.
pub fn unique_names(drops: &mut [Drop], given: impl Fn(&str, &str) -> Option<String>) {
    let mut used: HashSet<String> = HashSet::new();
    for d in drops.iter_mut() {
        let first = d.entries().into_iter().next().unwrap_or_default();
        if let Some(name) = given(&first, &d.name).filter(|n| !used.contains(n)) {
            d.name = name;
        } else if used.contains(&d.name) && !used.contains(&first) {
            d.name = first;
        }
        used.insert(d.name.clone());
    }
}

/// The first symlink of a drop entry (the entry itself, or inside a
/// folder drop) that leads out of the drop: an entry that is a symlink
/// always does (its target is not the drop), a link inside a folder when
/// it resolves (or dangles) outside the folder. Nothing is read.
pub fn link_outside(path: &Path) -> Option<PathBuf> {
    let meta = std::fs::symlink_metadata(path).ok()?;
    if meta.file_type().is_symlink() {
        return Some(path.to_path_buf());
    }
    if !meta.is_dir() {
        return None;
    }
    let top = std::fs::canonicalize(path).ok()?;
    fn walk(dir: &Path, top: &Path, depth: usize) -> Option<PathBuf> {
        for e in std::fs::read_dir(dir).ok()?.flatten() {
            let p = e.path();
            let Ok(t) = e.file_type() else { continue };
            if t.is_symlink() {
                match std::fs::canonicalize(&p) {
                    Ok(r) if r.starts_with(top) => {}
                    _ => return Some(p),
                }
            } else if t.is_dir() && depth < 64 {
                if let Some(p) = walk(&p, top, depth + 1) {
                    return Some(p);
                }
            }
        }
        None
    }
    walk(path, &top, 0)
}

/// Size and mtime of every file of an entry (recursively for a folder).
pub type Signature = BTreeMap<PathBuf, (u64, SystemTime)>;

/// The signature of `path` (file or folder); `None` when it vanished or
/// cannot be read (it is looked at again next scan).
pub fn signature(path: &Path) -> Option<Signature> {
    let mut sig = Signature::new();
    fn walk(base: &Path, rel: &Path, sig: &mut Signature) -> std::io::Result<()> {
        // `base.join("")` would add a '/', which a plain file refuses.
        let p = if rel.as_os_str().is_empty() {
            base.to_path_buf()
        } else {
            base.join(rel)
        };
        let m = std::fs::symlink_metadata(&p)?;
        if m.is_dir() {
            // A folder's own mtime changes when files are added or renamed.
            sig.insert(rel.to_path_buf(), (0, m.modified()?));
            for e in std::fs::read_dir(&p)? {
                walk(base, &rel.join(e?.file_name()), sig)?;
            }
        } else {
            sig.insert(rel.to_path_buf(), (m.len(), m.modified()?));
        }
        Ok(())
    }
    walk(path, Path::new(""), &mut sig).ok()?;
    Some(sig)
}

/// Lists a folder's entries as (name, is_dir); names that are not UTF-8
/// are skipped (they cannot name a job).
pub fn list(dir: &Path) -> std::io::Result<Vec<(String, bool)>> {
    let mut v = Vec::new();
    for e in std::fs::read_dir(dir)? {
        let e = e?;
        if let Ok(name) = e.file_name().into_string() {
            let is_dir = e.file_type().map(|t| t.is_dir()).unwrap_or(false);
            v.push((name, is_dir));
        }
    }
    v.sort();
    Ok(v)
}

/// Whether `path` lies on a network filesystem (NFS, SMB/CIFS, FUSE
/// mounts such as sshfs), where inotify sees no changes made by other
/// hosts: the daemon then polls only.
pub fn network_filesystem(path: &Path) -> bool {
    #[cfg(target_os = "linux")]
    {
        use std::os::unix::ffi::OsStrExt;
        let Ok(c) = std::ffi::CString::new(path.as_os_str().as_bytes()) else {
            return false;
        };
        // SAFETY: statfs fills the zeroed struct; c is a valid C string.
        let mut s: libc::statfs = unsafe { std::mem::zeroed() };
        if unsafe { libc::statfs(c.as_ptr(), &mut s) } != 0 {
            return false;
        }
        const NETWORK: [i64; 6] = [
            0x6969,                // NFS
            0x517B,                // SMB
            0xFF53_4D42u32 as i64, // CIFS
            0xFE53_4D42u32 as i64, // SMB2
            0x6573_5546,           // FUSE
            0x0102_1997,           // 9p (v9fs)
        ];
        #[allow(clippy::unnecessary_cast)]
        NETWORK.contains(&(s.f_type as i64))
    }
    #[cfg(not(target_os = "linux"))]
    {
        let _ = path;
        false
    }
}

/// Remembers each entry's signature between scans.
#[derive(Debug, Default)]
pub struct Stability {
    seen: HashMap<String, (Signature, Instant)>,
    /// The job name each waiting drop (by its first entry) was given.
    pub names: HashMap<String, String>,
}

/// What [`Stability::observe`] says about an entry.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Readiness {
    /// Unchanged across two scans at least `settle` apart.
    Stable,
    /// New or changed: look again at the returned instant.
    Settling(Instant),
}

impl Stability {
    /// Records `sig` for `entry` seen at `now`.
    pub fn observe(
        &mut self,
        entry: &str,
        sig: Signature,
        now: Instant,
        settle: Duration,
    ) -> Readiness {
        match self.seen.get(entry) {
            Some((old, since)) if *old == sig => {
                if now.duration_since(*since) >= settle {
                    Readiness::Stable
                } else {
                    Readiness::Settling(*since + settle)
                }
            }
            _ => {
                self.seen.insert(entry.to_string(), (sig, now));
                Readiness::Settling(now + settle)
            }
        }
    }

    /// Forgets entries that are no longer in the inbox.
    pub fn retain(&mut self, present: &[(String, bool)]) {
        self.seen.retain(|k, _| present.iter().any(|(n, _)| n == k));
        self.names
            .retain(|k, _| present.iter().any(|(n, _)| n == k));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn files(names: &[&str]) -> Vec<(String, bool)> {
        names.iter().map(|n| (n.to_string(), false)).collect()
    }

    #[test]
    fn hidden_and_partial_names_are_ignored() {
        for n in [
            ".a.bcc",
            ".a.bcc.x1.tmp",
            "a.bcc.part",
            "a.bcc~",
            "#a#",
            "a.crdownload",
        ] {
            assert!(ignored(n), "{n}");
        }
        for n in ["a.bcc", "job.toml", "a.b.ply"] {
            assert!(!ignored(n), "{n}");
        }
    }

    #[test]
    fn drops_group_yarns_with_their_sidecar() {
        let e = files(&[
            "b.job.toml",
            "b.ply",
            "c.toml",
            "d.job.toml",
            "e.txt",
            "s.job.toml",
        ]);
        let read = |n: &str| {
            Some(match n {
                "d.job.toml" => "[garment]\nyarns = \"x.bcc\"\n".to_string(),
                _ => "[embed]\nmax_voxels = 10\n".to_string(),
            })
        };
        let d = classify(&e, read);
        let kinds: Vec<(&str, &DropKind)> = d.iter().map(|d| (d.name.as_str(), &d.kind)).collect();
        assert_eq!(
            kinds,
            vec![
                (
                    "b",
                    &DropKind::Yarns {
                        file: "b.ply".into(),
                        sidecar: Some("b.job.toml".into())
                    }
                ),
                (
                    "c",
                    &DropKind::Manifest {
                        file: "c.toml".into()
                    }
                ),
                (
                    "d",
                    &DropKind::Manifest {
                        file: "d.job.toml".into()
                    }
                ),
                (
                    "e",
                    &DropKind::Unknown {
                        file: "e.txt".into()
                    }
                ),
                (
                    "s",
                    &DropKind::Sidecar {
                        file: "s.job.toml".into()
                    }
                ),
            ]
        );
        assert!(!d[4].runnable());
        assert_eq!(d[0].entries(), vec!["b.ply", "b.job.toml"]);
    }

    #[test]
    fn an_entry_is_stable_only_after_two_equal_scans_settle_apart() {
        let mut s = Stability::default();
        let t0 = Instant::now();
        let settle = Duration::from_millis(500);
        let sig = |len| Signature::from([(PathBuf::new(), (len, SystemTime::UNIX_EPOCH))]);
        assert!(matches!(
            s.observe("a", sig(1), t0, settle),
            Readiness::Settling(_)
        ));
        // Same size, too soon.
        let soon = t0 + Duration::from_millis(100);
        assert_eq!(
            s.observe("a", sig(1), soon, settle),
            Readiness::Settling(t0 + settle)
        );
        // Grew: the clock restarts.
        let t1 = t0 + Duration::from_millis(600);
        assert_eq!(
            s.observe("a", sig(2), t1, settle),
            Readiness::Settling(t1 + settle)
        );
        assert_eq!(
            s.observe("a", sig(2), t1 + settle, settle),
            Readiness::Stable
        );
        s.retain(&[]);
        assert!(matches!(
            s.observe("a", sig(2), t1 + settle, settle),
            Readiness::Settling(_)
        ));
    }

    #[test]
    fn a_folder_signature_sees_a_growing_file() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path().join("job");
        std::fs::create_dir(&d).unwrap();
        std::fs::write(d.join("a.bcc"), "x").unwrap();
        let s1 = signature(&d).unwrap();
        std::fs::write(d.join("a.bcc"), "xy").unwrap();
        let s2 = signature(&d).unwrap();
        assert_ne!(s1, s2);
        assert_eq!(s2.len(), 2);
        let file = signature(&d.join("a.bcc")).unwrap();
        assert_eq!(file[Path::new("")].0, 2);
        assert!(signature(&dir.path().join("gone")).is_none());
    }
}
