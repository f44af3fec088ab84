//! File helpers: bounded reading of every input (text and image files alike), atomic writes
//! (temp file + rename, so nothing already written is ever left half-overwritten), and the
//! whitespace-separated text tables of TUM RGB-D.
//!
//! # Input bounds
//!
//! Every text input (configs, camera files, sequence tables, trajectories, split lists, CSV
//! tables) is read by [`read_text`], every image by `read_image_bytes` (through
//! [`crate::imageio`]). Both refuse what is not a regular file (a FIFO, a device such as
//! `/dev/zero`, a socket, a directory) before opening it for reading, so an input can neither
//! block a run forever nor stream into memory without end, and both refuse a file larger than a
//! bound far above any real dataset's:
//!
//! * text files: at most `MAX_TEXT_BYTES` (64 MiB) and lines of at most `MAX_LINE_BYTES`
//!   (64 KiB). The largest text file of the datasets read here is a ground-truth trajectory:
//!   TUM RGB-D's largest `groundtruth.txt` is a few MB (100 Hz motion capture for a few
//!   minutes), a 7-Scenes `pose.txt` is 200 bytes, NYUv2's split lists a few kB; 64 MiB holds
//!   a 100 Hz trajectory of about two hours, or the tables of a million-frame sequence (the
//!   most a sequence may have: `crate::dataset::tum::MAX_SEQUENCE_FRAMES`). The bound also
//!   bounds what parsing allocates: a file of 64 MiB of the shortest possible trajectory lines
//!   parses into 4 million poses, 270 MB. Real lines are under 200 bytes (a TUM line is a
//!   stamp, a path and a few numbers; config lines are one setting).
//! * image files: at most `MAX_IMAGE_BYTES` (256 MiB). A 640x480 colour PNG of TUM RGB-D or
//!   7-Scenes is about 0.5 MB, its 16-bit depth PNG about 0.2 MB; an uncompressed 8-bit RGB
//!   image of 8192x8192 pixels is 192 MiB.
//!
//! Paths quoted in messages are shortened by [`short`] (a path of a table is whatever the file
//! says, and may be a megabyte long).

use crate::error::{Error, Result};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

/// Largest text file read (module docs: far above any real dataset's).
pub(crate) const MAX_TEXT_BYTES: u64 = 64 << 20;

/// Longest line of a text file read (module docs).
pub(crate) const MAX_LINE_BYTES: usize = 64 << 10;

/// Largest image file read (module docs).
pub(crate) const MAX_IMAGE_BYTES: u64 = 256 << 20;

/// Characters kept at each end of a path or value quoted in a message by [`short`].
pub(crate) const QUOTE_KEEP: usize = 100;

/// A path or value as quoted in a message, warning or report: whole when it is at most
/// `2 * QUOTE_KEEP + 20` characters long, else its first and last `QUOTE_KEEP` characters
/// around `...(N characters)...`, so that a path of a megabyte read from a table cannot
/// swell a message, `report.md` or `report.json`.
pub fn short(s: &str) -> String {
    let n = s.chars().count();
    if n <= 2 * QUOTE_KEEP + 20 {
        return s.to_string();
    }
    let head: String = s.chars().take(QUOTE_KEEP).collect();
    let tail: String = s.chars().skip(n - QUOTE_KEEP).collect();
    format!("{head}...({} characters)...{tail}", n - 2 * QUOTE_KEEP)
}

/// The 1-based line where TOML `text` sets `dotted` (`section.key`, the section possibly
/// dotted itself): the first `key = ...` under `[section]`. `None` when it is not written
/// there (a default, or an inline table).
pub(crate) fn toml_key_line(text: &str, dotted: &str) -> Option<usize> {
    let (section, key) = dotted.rsplit_once('.')?;
    let mut current = "";
    for (i, line) in text.lines().enumerate() {
        let t = line.trim();
        // A table header `[a.b]` (its name plain: a row `[8, 0.1],` of a multi-line array is
        // not one); `[[array]]` tables end the section.
        if let Some(name) = t
            .strip_prefix('[')
            .and_then(|h| h.split_once(']'))
            .map(|(name, rest)| (name.trim(), rest.trim()))
            .filter(|(_, rest)| rest.is_empty() || rest.starts_with('#') || rest == &"]")
            .map(|(name, _)| name)
        {
            let plain = name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.' | '['));
            if plain {
                current = if name.starts_with('[') { "" } else { name };
                continue;
            }
        }
        if current == section
            && let Some(rest) = t.strip_prefix(key)
            && rest.trim_start().starts_with('=')
        {
            return Some(i + 1);
        }
    }
    None
}

/// The line of the first `section.key` that `message` names and `text` sets
/// ([`toml_key_line`]), so a range error can point at the line to fix.
pub(crate) fn message_key_line(text: &str, message: &str) -> Option<usize> {
    message
        .split(|c: char| !(c.is_ascii_alphanumeric() || c == '_' || c == '.'))
        .filter(|w| w.contains('.') && w.starts_with(|c: char| c.is_ascii_lowercase()))
        .find_map(|w| toml_key_line(text, w.trim_end_matches('.')))
}

/// A configuration's range error: at the line that sets the key the message names, else at
/// the file.
pub(crate) fn config_error(path: &Path, text: &str, message: String) -> Error {
    match message_key_line(text, &message) {
        Some(line) => Error::parse(path, line, message),
        None => Error::invalid(path, message),
    }
}

/// [`short`] of a path as displayed.
pub(crate) fn short_path(path: &Path) -> String {
    short(&path.display().to_string())
}

/// What a file type that is not a regular file is, in words.
fn special_kind(ft: &std::fs::FileType) -> Option<&'static str> {
    if ft.is_file() {
        return None;
    }
    if ft.is_dir() {
        return Some("a directory");
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if ft.is_fifo() {
            return Some("a FIFO (named pipe)");
        }
        if ft.is_char_device() {
            return Some("a character device");
        }
        if ft.is_block_device() {
            return Some("a block device");
        }
        if ft.is_socket() {
            return Some("a socket");
        }
    }
    Some("not a regular file")
}

fn not_regular(path: &Path, what: &str, kind: &str) -> Error {
    Error::invalid(
        path,
        format!(
            "{kind}, not a regular file: refused as {what} (a stream or device could block the \
             run or never end)"
        ),
    )
}

/// Opens `path` for reading when it is a regular file (symbolic links followed), with its
/// length. A FIFO, device, socket or directory is refused before it is opened (opening a FIFO
/// for reading blocks until a writer comes); on Linux the file is also opened non-blocking
/// and checked again once open, so a FIFO swapped in between cannot block either. `what`
/// names the input in the message ("camera file", "image").
pub(crate) fn open_regular(path: &Path, what: &str) -> Result<(std::fs::File, u64)> {
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if let Some(kind) = special_kind(&meta.file_type()) {
        return Err(not_regular(path, what, kind));
    }
    let mut options = std::fs::OpenOptions::new();
    options.read(true);
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        use std::os::unix::fs::OpenOptionsExt;
        options.custom_flags(libc::O_NONBLOCK);
    }
    let file = options.open(path).map_err(|e| Error::io(path, e))?;
    let meta = file.metadata().map_err(|e| Error::io(path, e))?;
    if let Some(kind) = special_kind(&meta.file_type()) {
        return Err(not_regular(path, what, kind));
    }
    Ok((file, meta.len()))
}

/// Reads a whole regular file ([`open_regular`]) of at most `max` bytes; a longer one is an
/// error naming the file, its size and the bound, and nothing beyond `max + 1` bytes is read
/// (the length on disk may change or lie, as `/proc` files' does).
pub(crate) fn read_bounded(path: &Path, max: u64, what: &str) -> Result<Vec<u8>> {
    let (file, len) = open_regular(path, what)?;
    let too_large = |size: String| {
        Error::invalid(
            path,
            format!(
                "{size}: larger than the {} {what} may be here (see sdf_slam::io)",
                if max >= 1 << 20 {
                    format!("{} MiB", max >> 20)
                } else {
                    format!("{max} bytes")
                }
            ),
        )
    };
    if len > max {
        return Err(too_large(format!("{len} bytes")));
    }
    let mut bytes = Vec::with_capacity(len as usize);
    file.take(max + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| Error::io(path, e))?;
    if bytes.len() as u64 > max {
        return Err(too_large(format!("more than {max} bytes")));
    }
    Ok(bytes)
}

/// Reads an image file's bytes: a regular file of at most `max` bytes ([`MAX_IMAGE_BYTES`]
/// unless the caller knows a tighter bound).
pub(crate) fn read_image_bytes(path: &Path, max: u64) -> Result<Vec<u8>> {
    read_bounded(path, max.min(MAX_IMAGE_BYTES), "an image")
}

/// Reads a whole text file, naming it in the error: a regular file of at most
/// `MAX_TEXT_BYTES`, lines of at most `MAX_LINE_BYTES`, UTF-8 (module docs).
pub fn read_text(path: impl AsRef<Path>) -> Result<String> {
    let path = path.as_ref();
    let bytes = read_bounded(path, MAX_TEXT_BYTES, "a text file")?;
    check_lines(path, &bytes)?;
    String::from_utf8(bytes).map_err(|e| {
        let at = e.utf8_error().valid_up_to();
        let line = e.as_bytes()[..at].iter().filter(|&&b| b == b'\n').count() + 1;
        Error::parse(path, line, "not UTF-8 text (a binary file?)")
    })
}

/// An error naming the first line longer than [`MAX_LINE_BYTES`].
fn check_lines(path: &Path, bytes: &[u8]) -> Result<()> {
    let mut start = 0;
    let mut line = 1;
    loop {
        let end = bytes[start..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(bytes.len(), |k| start + k);
        if end - start > MAX_LINE_BYTES {
            return Err(Error::parse(
                path,
                line,
                format!(
                    "line is longer than {} KiB ({} bytes{}): not a text file of this kind",
                    MAX_LINE_BYTES >> 10,
                    end - start,
                    if end == bytes.len() {
                        ", no line break"
                    } else {
                        ""
                    }
                ),
            ));
        }
        if end == bytes.len() {
            return Ok(());
        }
        start = end + 1;
        line += 1;
    }
}

/// Writes a file atomically: the content goes to a temporary sibling unique to this write
/// (`temp_path`), is flushed to disk, then renamed over `path`.
pub fn write_atomic(path: impl AsRef<Path>, bytes: &[u8]) -> Result<()> {
    write_atomic_with(path, |w| w.write_all(bytes))
}

/// Like [`write_atomic`], with the content produced by a writer callback.
pub(crate) fn write_atomic_with(
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
pub(crate) fn sync_parent(path: &Path) -> std::io::Result<()> {
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

/// The temporary sibling used by atomic writes: `dir/.NAME.<pid>.<n>.tmp`, unique to this
/// process (its id) and to this write (a counter), so that two writers of the same file, in
/// one process or in two, never write into one temporary file: the last rename wins whole.
/// A name longer than 200 bytes is cut (at a character boundary) to keep the temporary name
/// within the 255 bytes file systems allow.
pub(crate) fn temp_path(path: &Path) -> PathBuf {
    static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let mut name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    if name.len() > 200 {
        let mut cut = 200;
        while !name.is_char_boundary(cut) {
            cut -= 1;
        }
        name.truncate(cut);
    }
    path.with_file_name(format!(".{name}.{}.{n}.tmp", std::process::id()))
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

    /// The folder's path.
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
    /// 1-based line number in the file.
    pub line: usize,
    /// The line's fields, in order.
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

/// Parses a finite `f64` field, with an error naming file, line and field.
pub(crate) fn parse_f64(path: &Path, line: usize, what: &str, field: &str) -> Result<f64> {
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
    fn a_range_error_points_at_the_line_that_sets_the_key() {
        let text = "seed = 1\n[room]\nheight = [2.0, 1.0]\n\n[motion]\n# a comment\nview_height = [0.3, 3.0]\n";
        assert_eq!(toml_key_line(text, "room.height"), Some(3));
        assert_eq!(toml_key_line(text, "motion.view_height"), Some(7));
        assert_eq!(toml_key_line(text, "motion.height"), None);
        assert_eq!(toml_key_line(text, "seed"), None);
        // Rows of a multi-line array are not table headers.
        let arrays =
            "[optimizer]\nlr_steps = [\n    [8, 0.1],\n]\nlr = -1.0\n[[data.train]]\nlr = 2\n";
        assert_eq!(toml_key_line(arrays, "optimizer.lr"), Some(5));
        assert_eq!(toml_key_line(arrays, "optimizer.lr_steps"), Some(2));
        let m = "motion.view_height = [0.3, 3.0] must satisfy motion.clearance (0.3) <= min";
        assert_eq!(message_key_line(text, m), Some(7));
        let e = config_error(Path::new("s.toml"), text, m.to_string()).to_string();
        assert!(e.starts_with("s.toml:7: motion.view_height"), "{e}");
        let e = config_error(Path::new("s.toml"), text, "scenes must be positive".into());
        assert!(e.to_string().starts_with("s.toml: scenes"), "{e}");
    }

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
        let names: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, vec![std::ffi::OsString::from("x.txt")]);
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn temporary_names_are_unique_per_process_and_write() {
        let p = Path::new("dir/model.bpk");
        let (a, b) = (temp_path(p), temp_path(p));
        assert_ne!(a, b);
        let pid = std::process::id().to_string();
        for t in [&a, &b] {
            let name = t.file_name().unwrap().to_str().unwrap();
            assert!(
                name.starts_with(".model.bpk.") && name.ends_with(".tmp"),
                "{name}"
            );
            assert!(name.contains(&format!(".{pid}.")), "{name}");
            assert_eq!(t.parent(), p.parent());
        }
        // Written from several threads at once: every write lands whole.
        let dir = ScratchDir::new("io_temp_race").unwrap();
        let target = dir.join("out.txt");
        std::thread::scope(|s| {
            for k in 0..8u8 {
                let target = &target;
                s.spawn(move || {
                    for _ in 0..20 {
                        write_atomic(target, &vec![b'a' + k; 4096]).unwrap();
                    }
                });
            }
        });
        let bytes = std::fs::read(&target).unwrap();
        assert_eq!(bytes.len(), 4096);
        assert!(bytes.iter().all(|&b| b == bytes[0]));
        // A 250-byte name still gives a temporary name the file system takes.
        let long = dir.join("n".repeat(250));
        write_atomic(&long, b"x").unwrap();
        assert_eq!(std::fs::read(&long).unwrap(), b"x");
    }

    #[test]
    fn text_inputs_are_bounded_and_special_files_refused() {
        let dir = ScratchDir::new("io_bounds").unwrap();
        let ok = dir.join("ok.txt");
        std::fs::write(&ok, "a b\n# c\n").unwrap();
        assert_eq!(read_text(&ok).unwrap(), "a b\n# c\n");
        // A directory.
        let e = read_text(dir.path()).unwrap_err().to_string();
        assert!(
            e.contains("a directory") && e.contains("not a regular file"),
            "{e}"
        );
        // An endless device: refused before a byte is read.
        #[cfg(unix)]
        {
            let e = read_text("/dev/zero").unwrap_err().to_string();
            assert!(
                e.contains("/dev/zero") && e.contains("character device"),
                "{e}"
            );
            let e = read_image_bytes(Path::new("/dev/zero"), MAX_IMAGE_BYTES)
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("character device") && e.contains("as an image"),
                "{e}"
            );
        }
        // A FIFO with no writer: refused at once, not waited on.
        #[cfg(all(target_os = "linux", target_env = "gnu"))]
        {
            let fifo = dir.join("fifo.txt");
            let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
            // SAFETY: a valid NUL-terminated path.
            assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
            let e = read_text(&fifo).unwrap_err().to_string();
            assert!(e.contains("fifo.txt") && e.contains("FIFO"), "{e}");
        }
        // A line without end, and one too long among short ones.
        let long = dir.join("long.txt");
        std::fs::write(&long, "x".repeat(MAX_LINE_BYTES + 1)).unwrap();
        let e = read_text(&long).unwrap_err().to_string();
        assert!(
            e.contains("long.txt:1") && e.contains("no line break"),
            "{e}"
        );
        std::fs::write(
            &long,
            format!("a\nb\n{}\nc\n", "y".repeat(MAX_LINE_BYTES + 1)),
        )
        .unwrap();
        let e = read_text(&long).unwrap_err().to_string();
        assert!(e.contains("long.txt:3") && e.contains("64 KiB"), "{e}");
        std::fs::write(&long, format!("{}\n", "y".repeat(MAX_LINE_BYTES))).unwrap();
        assert!(read_text(&long).is_ok());
        // Not UTF-8: the line named.
        std::fs::write(&long, b"ok\nok\n\xff\xfe\n").unwrap();
        let e = read_text(&long).unwrap_err().to_string();
        assert!(e.contains("long.txt:3") && e.contains("UTF-8"), "{e}");
        // Larger than the bound: refused from its length, nothing read.
        let e = read_bounded(&ok, 3, "a table").unwrap_err().to_string();
        assert!(
            e.contains("ok.txt: 8 bytes: larger than the 3 bytes a table"),
            "{e}"
        );
    }

    #[test]
    fn long_paths_are_shortened_in_messages() {
        assert_eq!(short("a/b.png"), "a/b.png");
        let long = format!("{}{}", "a".repeat(500_000), "z".repeat(500_000));
        let s = short(&long);
        assert!(s.len() < 300, "{}", s.len());
        assert!(s.starts_with(&"a".repeat(QUOTE_KEEP)) && s.ends_with(&"z".repeat(QUOTE_KEEP)));
        assert!(s.contains("(999800 characters)"), "{s}");
        // Character boundaries are kept.
        let wide = "é".repeat(1000);
        assert_eq!(
            short(&wide).chars().filter(|&c| c == 'é').count(),
            2 * QUOTE_KEEP
        );
        assert_eq!(short_path(Path::new(&long)), s);
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
