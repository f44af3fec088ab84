//! File helpers: atomic writes (temp file + rename, so nothing already written is
//! ever left half-overwritten) and the whitespace-separated text tables of TUM RGB-D.

use crate::error::{Error, Result};
use std::io::Write;
use std::path::{Path, PathBuf};

/// Writes a file atomically: the content goes to `<path>.tmp` in the same
/// directory, is flushed to disk, then renamed over `path`.
pub fn write_atomic(path: impl AsRef<Path>, bytes: &[u8]) -> Result<()> {
    write_atomic_with(path, |w| w.write_all(bytes))
}

/// Like [`write_atomic`], with the content produced by a writer callback.
pub fn write_atomic_with(
    path: impl AsRef<Path>,
    fill: impl FnOnce(&mut std::io::BufWriter<std::fs::File>) -> std::io::Result<()>,
) -> Result<()> {
    let path = path.as_ref();
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    let tmp = temp_path(path);
    let result = (|| {
        let file = std::fs::File::create(&tmp)?;
        let mut w = std::io::BufWriter::new(file);
        fill(&mut w)?;
        let file = w.into_inner().map_err(|e| e.into_error())?;
        file.sync_all()?;
        std::fs::rename(&tmp, path)?;
        sync_parent(path)
    })();
    result.map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        Error::io(path, e)
    })
}

/// Flushes the directory entry of `path` (a rename or a new file) to disk, so that after a
/// power cut the folder holds either the old file or the new one. Directories cannot be
/// opened as files on every platform, and some file systems refuse to flush one (the
/// file itself is already on disk then); there it does nothing.
pub fn sync_parent(path: &Path) -> std::io::Result<()> {
    #[cfg(unix)]
    {
        use std::io::ErrorKind::{InvalidInput, PermissionDenied, Unsupported};
        let dir = path
            .parent()
            .filter(|d| !d.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        match std::fs::File::open(dir).and_then(|d| d.sync_all()) {
            Err(e) if !matches!(e.kind(), InvalidInput | PermissionDenied | Unsupported) => {
                return Err(e);
            }
            _ => {}
        }
    }
    #[cfg(not(unix))]
    let _ = path;
    Ok(())
}

/// The temporary sibling used by atomic writes: `dir/.name.tmp`.
pub fn temp_path(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!(".{name}.tmp"))
}

/// A folder of its own under the system's temporary folder, `sdf_<name>_<pid>`, removed
/// with everything in it when dropped: what tests write leaves nothing behind. While a
/// thread is panicking (a failing test) the folder stays for a look, and its path is
/// printed. Leftovers of an earlier process with the same id are removed first.
#[derive(Debug)]
pub struct ScratchDir(PathBuf);

impl ScratchDir {
    /// The folder, created empty.
    pub fn new(name: &str) -> std::io::Result<Self> {
        let dir = Self::unmade(name);
        std::fs::create_dir_all(&dir.0)?;
        Ok(dir)
    }

    /// The folder's path with nothing there (for a program that must create it), still
    /// removed when dropped.
    pub fn unmade(name: &str) -> Self {
        let path = std::env::temp_dir().join(format!("sdf_{name}_{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&path);
        ScratchDir(path)
    }

    pub fn path(&self) -> &Path {
        &self.0
    }
}

impl std::ops::Deref for ScratchDir {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<Path> for ScratchDir {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<std::ffi::OsStr> for ScratchDir {
    fn as_ref(&self) -> &std::ffi::OsStr {
        self.0.as_os_str()
    }
}

impl Drop for ScratchDir {
    fn drop(&mut self) {
        if std::thread::panicking() {
            eprintln!("kept {} (the test failed)", self.0.display());
        } else {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

/// A data line of a TUM-style text file: its 1-based line number and fields.
#[derive(Debug, Clone)]
pub struct Record<'a> {
    pub line: usize,
    pub fields: Vec<&'a str>,
}

/// Splits a TUM-style text file into records: `#` comment lines and blank lines
/// are skipped; fields are separated by whitespace or commas (as the benchmark's
/// own `associate.py` accepts).
pub fn records(text: &str) -> impl Iterator<Item = Record<'_>> {
    text.lines().enumerate().filter_map(|(i, line)| {
        let trimmed = line.trim();
        if trimmed.is_empty() || trimmed.starts_with('#') {
            return None;
        }
        let fields = trimmed
            .split(|c: char| c.is_whitespace() || c == ',')
            .filter(|f| !f.is_empty())
            .collect();
        Some(Record {
            line: i + 1,
            fields,
        })
    })
}

/// Reads a whole text file, naming it in the error.
pub fn read_text(path: impl AsRef<Path>) -> Result<String> {
    let path = path.as_ref();
    std::fs::read_to_string(path).map_err(|e| Error::io(path, e))
}

/// Parses a finite `f64` field, with an error naming file, line and field.
pub fn parse_f64(path: &Path, line: usize, what: &str, field: &str) -> Result<f64> {
    match field.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(_) => Err(Error::parse(
            path,
            line,
            format!("{what} is not finite: '{field}'"),
        )),
        Err(_) => Err(Error::parse(
            path,
            line,
            format!("{what} is not a number: '{field}'"),
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_skip_comments_and_blanks() {
        let text = "# header\n\n1.0 a\n  # indented comment\n2.0,b  c\n";
        let recs: Vec<_> = records(text).collect();
        assert_eq!(recs.len(), 2);
        assert_eq!(recs[0].line, 3);
        assert_eq!(recs[0].fields, vec!["1.0", "a"]);
        assert_eq!(recs[1].line, 5);
        assert_eq!(recs[1].fields, vec!["2.0", "b", "c"]);
    }

    #[test]
    fn atomic_write_replaces_and_leaves_no_temp() {
        let dir = std::env::temp_dir().join(format!("sdf_io_{}", std::process::id()));
        let path = dir.join("x.txt");
        write_atomic(&path, b"one").unwrap();
        write_atomic(&path, b"two").unwrap();
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "two");
        assert!(!temp_path(&path).exists());
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn scratch_dirs_are_removed_when_dropped_and_kept_when_a_test_fails() {
        let dir = ScratchDir::new("io_scratch").unwrap();
        let path = dir.to_path_buf();
        std::fs::create_dir_all(dir.join("a/b")).unwrap();
        std::fs::write(dir.join("a/b/c.txt"), "x").unwrap();
        // A second one of the same name starts empty (an earlier run's leftovers).
        std::mem::forget(dir);
        let again = ScratchDir::new("io_scratch").unwrap();
        assert!(again.is_dir() && !again.join("a").exists());
        drop(again);
        assert!(!path.exists());
        // Not made until asked, still removed.
        let unmade = ScratchDir::unmade("io_scratch_unmade");
        assert!(!unmade.exists());
        std::fs::create_dir_all(unmade.join("out")).unwrap();
        let path = unmade.to_path_buf();
        drop(unmade);
        assert!(!path.exists());
        // Dropped while its thread panics: kept.
        let kept = std::thread::spawn(|| {
            let d = ScratchDir::new("io_scratch_panic").unwrap();
            let p = d.to_path_buf();
            let _d = d;
            std::panic::panic_any(p);
        })
        .join()
        .unwrap_err();
        let kept = kept.downcast::<PathBuf>().unwrap();
        assert!(kept.is_dir());
        std::fs::remove_dir_all(*kept).unwrap();
    }

    #[test]
    fn parse_f64_rejects_nan_and_text() {
        let p = Path::new("f.txt");
        assert!(parse_f64(p, 3, "x", "nan").is_err());
        let e = parse_f64(p, 3, "x", "abc").unwrap_err().to_string();
        assert!(e.contains("f.txt:3"), "{e}");
        assert_eq!(parse_f64(p, 1, "x", "1.5").unwrap(), 1.5);
    }
}
