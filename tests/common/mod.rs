//! Scaffolding shared by the integration tests (each test file that needs it says
//! `mod common;`).
#![allow(dead_code)]

use std::path::{Path, PathBuf};

/// A path under the system's temporary folder unique to this test process,
/// `sdf_<group>_<name>_<pid>`, with nothing there (an earlier run's leftovers removed).
pub fn fresh_path(group: &str, name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("sdf_{group}_{name}_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// Like [`fresh_path`], the folder created empty.
pub fn fresh_dir(group: &str, name: &str) -> PathBuf {
    let d = fresh_path(group, name);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The crate's root folder.
pub fn manifest_dir() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}
