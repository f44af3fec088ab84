//! One writer per output folder.
//!
//! Every command that writes an output folder (`slam --out`, a training run's folder, a
//! sweep's, `synth --out`, `train export/average --out`, `eval seg --out`) first takes
//! [`OutputLock::acquire`]: an exclusive advisory lock on `DIR/.sdf-slam.lock`
//! ([`LOCK_FILE`]). A second writer of the same folder fails at once, before it reads any
//! input, with an error that names the folder and the process that holds it:
//!
//! ```text
//! runs/x is being written by process 4242 (`slam --sequence ... --out runs/x`, since
//! 2026-05-04 10:12:03 UTC, 12 s ago): wait for it or choose another --out
//! ```
//!
//! The lock is the operating system's (`flock` on Linux and macOS, `LockFileEx` on Windows,
//! through [`std::fs::File::try_lock`]), not the file's existence: the kernel drops it when
//! the process ends, however it ends. A lock file left behind by a killed process therefore
//! holds no lock and the next writer simply takes it over (that is the stale-lock
//! detection). The file's text (`pid`, `command`, `started`) only serves the error message.
//! The lock is released, and the file removed, when the [`OutputLock`] is dropped; a folder
//! the lock created and nothing else filled is removed with it.
//!
//! Where the file system cannot lock (some network file systems), a warning says so and the
//! command goes on unlocked: two writers are then not detected.
//!
//! Within one process the lock is re-entrant ([`OutputLock::acquire`] of a folder this
//! process holds shares that lock), so a binary may lock its `--out` early and the library
//! (`ensure_held`, called by [`crate::training::RunDir::prepare`]) check it again.

use crate::error::{Error, Result};
use std::fs::{File, OpenOptions};
use std::io::{Read as _, Write as _};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::{SystemTime, UNIX_EPOCH};

/// The lock file's name inside the folder.
pub const LOCK_FILE: &str = ".sdf-slam.lock";

/// An exclusive lock on an output folder, held until dropped (module docs).
#[derive(Debug)]
pub struct OutputLock {
    key: PathBuf,
}

/// A folder this process holds.
struct Held {
    /// The folder, canonical.
    key: PathBuf,
    /// The folder as it was given (for removing it when it is left empty).
    dir: PathBuf,
    /// The locked file (None: the file system could not lock, we go on unlocked).
    file: Option<File>,
    /// Handles sharing the lock.
    count: usize,
    /// Held until the process ends ([`ensure_held`] took it): the kernel releases it then.
    forever: bool,
    /// Whether acquiring the lock created the folder.
    created: bool,
}

static HELD: Mutex<Vec<Held>> = Mutex::new(Vec::new());

fn held() -> std::sync::MutexGuard<'static, Vec<Held>> {
    HELD.lock().unwrap_or_else(|e| e.into_inner())
}

/// Who holds a folder's lock, as its lock file says.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Holder {
    /// Process id of the holder (`None` when the file does not give one).
    pub pid: Option<u32>,
    /// The holder's command line.
    pub command: Option<String>,
    /// `YYYY-MM-DD HH:MM:SS UTC`.
    pub started: Option<String>,
    /// Seconds since 1970, for "N s ago".
    pub started_unix: Option<u64>,
}

impl Holder {
    fn parse(text: &str) -> Holder {
        let get = |key: &str| {
            text.lines()
                .filter_map(|l| l.split_once('='))
                .find(|(k, _)| k.trim() == key)
                .map(|(_, v)| v.trim().to_string())
                .filter(|v| !v.is_empty())
        };
        Holder {
            pid: get("pid").and_then(|p| p.parse().ok()),
            command: get("command"),
            started: get("started"),
            started_unix: get("started_unix").and_then(|s| s.parse().ok()),
        }
    }

    fn describe(&self) -> String {
        let mut details = Vec::new();
        if let Some(c) = &self.command {
            details.push(format!("`{c}`"));
        }
        if let Some(s) = &self.started {
            let ago = self
                .started_unix
                .and_then(|t| unix_now().checked_sub(t))
                .map(|s| format!(", {}", ago(s)))
                .unwrap_or_default();
            details.push(format!("since {s}{ago}"));
        }
        let details = if details.is_empty() {
            String::new()
        } else {
            format!(" ({})", details.join(", "))
        };
        match self.pid {
            Some(pid) => format!("process {pid}{details}"),
            None => format!("another process{details}"),
        }
    }
}

fn ago(secs: u64) -> String {
    match secs {
        s if s < 120 => format!("{s} s ago"),
        s if s < 7200 => format!("{} min ago", s / 60),
        s => format!("{} h ago", s / 3600),
    }
}

impl OutputLock {
    /// Creates `dir` if needed and locks it for this process; `what` describes the writer
    /// for the error another writer gets (e.g. [`command_line`]). Fails when another process
    /// holds the folder, naming it; when `dir` is a file; or when the folder or the lock file
    /// cannot be created.
    pub fn acquire(dir: impl AsRef<Path>, what: &str) -> Result<OutputLock> {
        let key = lock(dir.as_ref(), what, true)?;
        Ok(OutputLock { key })
    }

    /// The locked folder (canonical).
    pub fn dir(&self) -> &Path {
        &self.key
    }
}

impl Drop for OutputLock {
    fn drop(&mut self) {
        let mut all = held();
        let Some(i) = all.iter().position(|h| h.key == self.key) else {
            return;
        };
        all[i].count = all[i].count.saturating_sub(1);
        if all[i].count > 0 || all[i].forever {
            return;
        }
        let h = all.swap_remove(i);
        drop(all);
        release(h);
    }
}

/// Removes the lock file (while still locked, so that nobody takes a lock on a file that is
/// going away unnoticed: see [`still_ours`]), unlocks, and removes the folder when the lock
/// made it and it stayed empty.
fn release(h: Held) {
    let path = h.key.join(LOCK_FILE);
    if let Some(file) = &h.file
        && still_ours(file, &h.key)
    {
        let _ = std::fs::remove_file(&path);
    }
    drop(h.file);
    if h.created {
        // Fails (and keeps the folder) unless it is empty.
        let _ = std::fs::remove_dir(&h.dir);
    }
}

/// Makes sure this process holds `dir`: nothing to do when it does (an [`OutputLock`] taken
/// earlier, by a binary), else the lock is taken and kept until the process ends. For
/// library code that writes a folder its caller may not have locked.
pub(crate) fn ensure_held(dir: impl AsRef<Path>, what: &str) -> Result<()> {
    lock(dir.as_ref(), what, false).map(|_| ())
}

/// Locks `dir` for this process (module docs) and returns its key. A folder this process
/// holds already is shared: one more handle when `count`, else nothing changes (a new lock
/// held until the process ends when it held none).
fn lock(dir: &Path, what: &str, count: bool) -> Result<PathBuf> {
    if dir.exists() && !dir.is_dir() {
        return Err(Error::invalid(
            dir,
            "the output path is a file, not a folder: choose another --out",
        ));
    }
    let created = !dir.exists();
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let key = std::fs::canonicalize(dir).map_err(|e| Error::io(dir, e))?;
    let mut all = held();
    if let Some(h) = all.iter_mut().find(|h| h.key == key) {
        if h.file.as_ref().is_some_and(|f| !still_ours(f, &key)) {
            // The folder (or its lock file) was removed under us and made again: lock the
            // new file.
            h.file = lock_file(&key, dir, what)?;
        }
        h.count += usize::from(count);
        return Ok(key);
    }
    let file = lock_file(&key, dir, what)?;
    all.push(Held {
        key: key.clone(),
        dir: dir.to_path_buf(),
        file,
        count: usize::from(count),
        forever: !count,
        created,
    });
    Ok(key)
}

/// Opens and locks `key/LOCK_FILE`, and writes who holds it. `Ok(None)`: the file system
/// cannot lock (warned).
fn lock_file(key: &Path, dir: &Path, what: &str) -> Result<Option<File>> {
    let path = key.join(LOCK_FILE);
    // A holder that removes its file while we open it leaves us a file nobody will find:
    // retry on the file that is there now.
    for _ in 0..20 {
        let mut file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .map_err(|e| Error::io(&path, e))?;
        match file.try_lock() {
            Ok(()) => {}
            Err(std::fs::TryLockError::WouldBlock) => {
                let mut text = String::new();
                let _ = file.read_to_string(&mut text);
                return Err(busy(dir, &Holder::parse(&text)));
            }
            Err(std::fs::TryLockError::Error(e)) => {
                eprintln!(
                    "warning: cannot lock {} ({e}): this file system does not lock files, so \
                     another process writing {} at the same time would not be detected",
                    path.display(),
                    dir.display()
                );
                return Ok(None);
            }
        }
        if !still_ours(&file, key) {
            continue;
        }
        let now = unix_now();
        let text = format!(
            "pid = {}\ncommand = {}\nstarted = {}\nstarted_unix = {now}\n",
            std::process::id(),
            one_line(what),
            utc_text(now)
        );
        file.set_len(0)
            .and_then(|()| file.write_all(text.as_bytes()))
            .map_err(|e| Error::io(&path, e))?;
        return Ok(Some(file));
    }
    Err(Error::msg(format!(
        "{}: the lock file {LOCK_FILE} keeps being removed and made again by another process: \
         wait for it or choose another --out",
        dir.display()
    )))
}

/// The error of a second writer.
fn busy(dir: &Path, holder: &Holder) -> Error {
    Error::msg(format!(
        "{} is being written by {}: wait for it or choose another --out",
        dir.display(),
        holder.describe()
    ))
}

/// Whether `file` is still the lock file of `key` (not removed, nor replaced by another).
fn still_ours(file: &File, key: &Path) -> bool {
    let path = key.join(LOCK_FILE);
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        match (file.metadata(), std::fs::metadata(&path)) {
            (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
            _ => false,
        }
    }
    #[cfg(not(unix))]
    {
        // Windows does not remove a file another handle holds open.
        let _ = file;
        path.is_file()
    }
}

/// Who holds `dir` now: `None` when nobody does (no lock file, or a stale one).
pub fn holder(dir: impl AsRef<Path>) -> Option<Holder> {
    let path = dir.as_ref().join(LOCK_FILE);
    let mut file = OpenOptions::new().read(true).write(true).open(path).ok()?;
    match file.try_lock() {
        Ok(()) => None,
        Err(std::fs::TryLockError::WouldBlock) => {
            let mut text = String::new();
            let _ = file.read_to_string(&mut text);
            Some(Holder::parse(&text))
        }
        Err(std::fs::TryLockError::Error(_)) => None,
    }
}

/// This process's command line (program name and arguments), on one line and at most 300
/// characters: what [`OutputLock::acquire`] records as the writer.
pub fn command_line() -> String {
    let mut args = std::env::args();
    let program = args
        .next()
        .map(|p| {
            Path::new(&p)
                .file_name()
                .map_or(p.clone(), |n| n.to_string_lossy().into_owned())
        })
        .unwrap_or_default();
    let line = std::iter::once(program)
        .chain(args)
        .collect::<Vec<_>>()
        .join(" ");
    one_line(&line)
}

fn one_line(s: &str) -> String {
    let s: String = s
        .chars()
        .map(|c| if c.is_control() { ' ' } else { c })
        .collect();
    if s.chars().count() > 300 {
        s.chars().take(297).collect::<String>() + "..."
    } else {
        s
    }
}

fn unix_now() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_secs())
}

/// `YYYY-MM-DD HH:MM:SS UTC` of seconds since 1970.
pub fn utc_text(secs: u64) -> String {
    let secs = secs as i64;
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    // Civil date from days since 1970-01-01 (H. Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02} {:02}:{:02}:{:02} UTC",
        rem / 3600,
        rem / 60 % 60,
        rem % 60
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn utc_text_is_the_civil_date() {
        assert_eq!(utc_text(0), "1970-01-01 00:00:00 UTC");
        assert_eq!(utc_text(951_782_400), "2000-02-29 00:00:00 UTC");
        assert_eq!(utc_text(1_709_210_096), "2024-02-29 12:34:56 UTC");
    }

    #[test]
    fn the_lock_is_reentrant_released_on_drop_and_names_its_holder() {
        let root = crate::io::ScratchDir::new("output_lock").unwrap();
        let dir = root.join("made/here");
        let a = OutputLock::acquire(&dir, "test a --out made/here").unwrap();
        let lock = dir.join(LOCK_FILE);
        assert!(lock.is_file());
        let text = std::fs::read_to_string(&lock).unwrap();
        assert!(
            text.contains(&format!("pid = {}", std::process::id())),
            "{text}"
        );
        assert!(text.contains("command = test a --out made/here"), "{text}");
        // The same process again: shared (another process would be refused: tests/one_writer.rs).
        let b = OutputLock::acquire(&dir, "test b").unwrap();
        ensure_held(&dir, "test c").unwrap();
        drop(a);
        assert!(lock.is_file(), "b still holds it");
        drop(b);
        assert!(!lock.exists());
        // The folder the lock made, left empty, is removed with it.
        assert!(!dir.exists());
        // A folder that was there, or got files, stays.
        let c = OutputLock::acquire(&dir, "test d").unwrap();
        std::fs::write(dir.join("report.json"), "{}").unwrap();
        drop(c);
        assert!(dir.join("report.json").is_file() && !lock.exists());
        // A file is not a folder.
        let file = dir.join("report.json");
        let e = OutputLock::acquire(&file, "x").unwrap_err().to_string();
        assert!(e.contains("is a file"), "{e}");
    }

    #[test]
    fn a_folder_removed_under_the_lock_is_locked_again() {
        let root = crate::io::ScratchDir::new("output_lock_removed").unwrap();
        let dir = root.join("run");
        let a = OutputLock::acquire(&dir, "test").unwrap();
        // What a caller that replaces the folder does.
        std::fs::remove_dir_all(&dir).unwrap();
        ensure_held(&dir, "test").unwrap();
        assert!(dir.join(LOCK_FILE).is_file());
        drop(a);
        assert!(!dir.join(LOCK_FILE).exists(), "released with the handle");
        // Taken by the library alone: held until the process ends.
        ensure_held(&dir, "test").unwrap();
        drop(OutputLock::acquire(&dir, "test").unwrap());
        assert!(dir.join(LOCK_FILE).is_file());
    }

    #[test]
    fn a_lock_file_without_a_lock_is_taken_over_and_a_holder_described() {
        let root = crate::io::ScratchDir::new("output_lock_stale").unwrap();
        // What a killed process leaves: the file, no lock.
        std::fs::write(
            root.join(LOCK_FILE),
            "pid = 999999\ncommand = slam --out x\nstarted = 2020-01-01 00:00:00 UTC\n",
        )
        .unwrap();
        assert_eq!(holder(&*root), None);
        let lock = OutputLock::acquire(&*root, "test").unwrap();
        let text = std::fs::read_to_string(root.join(LOCK_FILE)).unwrap();
        assert!(!text.contains("999999"), "{text}");
        drop(lock);
        let h = Holder::parse(
            "pid = 42\ncommand = train --config a.toml\nstarted = 2020-01-01 00:00:00 UTC\n",
        );
        let e = busy(Path::new("runs/x"), &h).to_string();
        assert_eq!(
            e,
            "runs/x is being written by process 42 (`train --config a.toml`, since 2020-01-01 \
             00:00:00 UTC): wait for it or choose another --out"
        );
        let e = busy(Path::new("runs/x"), &Holder::parse("")).to_string();
        assert!(e.contains("by another process: wait"), "{e}");
    }
}
