//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

/// The external test data folder (`$KNITVOX_EXTERNAL_DATA`, else `../shared/data`
/// beside the checkout) joined with `sub`. Under CI (`CI` set) a missing folder
/// fails the test; elsewhere the test is skipped with a loud message.
pub fn external_data(sub: &str) -> Option<PathBuf> {
    let root = std::env::var_os("KNITVOX_EXTERNAL_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data"));
    let dir = root.join(sub);
    if dir.is_dir() {
        return Some(dir);
    }
    let msg = format!(
        "external test data not found at {} (set KNITVOX_EXTERNAL_DATA to the shared data folder)",
        dir.display()
    );
    if std::env::var_os("CI").is_some() {
        panic!("{msg}");
    }
    eprintln!("\n!!!!!!!! SKIPPED: {msg} !!!!!!!!\n");
    None
}

/// Requires an external tool (node, python3 with h5py). Under CI its absence
/// fails the test; elsewhere the test is skipped loudly.
pub fn require_tool(available: bool, what: &str) -> bool {
    if available {
        return true;
    }
    let msg = format!("{what} is not available (run `bash .ci/setup-debian test`)");
    if std::env::var_os("CI").is_some() {
        panic!("{msg}");
    }
    eprintln!("\n!!!!!!!! SKIPPED: {msg} !!!!!!!!\n");
    false
}

/// Path of the built knitvox binary (for tests that run the real CLI).
pub fn knitvox_bin() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_knitvox"))
}
