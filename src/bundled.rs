//! What `slam` uses when it is given nothing: the bundled network weights
//! (`weights/fpfdcnn`, `weights/sdfcnn`) and a synthetic default sequence
//! (`datasets/generated/default_sequence`), generated on first use; and the
//! files of the source tree that `train`'s default run and the examples read
//! ([`locate`]: configs, fixtures).
//!
//! Paths are relative to the crate root. They are looked up in the current
//! directory first and then in the crate's source folder (where `cargo run`
//! was built from), so the defaults work from the repository root and from
//! elsewhere on the machine that built the binary.

use crate::error::{Error, Result};
use crate::synth::{self, SynthConfig, TrajectoryKind};
use std::path::{Path, PathBuf};

/// The sequence run when none is given.
pub const DEFAULT_SEQUENCE: &str = "datasets/generated/default_sequence";
/// Bundled FPFDCNN weights (a checkpoint folder: `model.bpk` + `config.toml`).
pub const BUNDLED_FPFDCNN: &str = "weights/fpfdcnn";
/// Bundled SDFCNN weights (a checkpoint folder: `model.bpk` + `config.toml`).
pub const BUNDLED_SDFCNN: &str = "weights/sdfcnn";

/// Frames of the default sequence: 8 s at 30 Hz, about one period of the
/// hand-held sweep, so the camera comes back near its start.
pub(crate) const DEFAULT_SEQUENCE_FRAMES: usize = 240;

/// The folders a crate-relative path is looked up in, in order: the current
/// directory, then the crate's source folder.
pub(crate) fn search_roots() -> Vec<PathBuf> {
    let mut roots = vec![PathBuf::from(".")];
    let manifest = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    if manifest.is_dir() {
        roots.push(manifest);
    }
    roots
}

/// `rel` under the first of `roots` where `accept` holds.
pub(crate) fn find_in(
    roots: &[PathBuf],
    rel: &str,
    accept: impl Fn(&Path) -> bool,
) -> Option<PathBuf> {
    roots.iter().map(|r| r.join(rel)).find(|p| accept(p))
}

/// A checkpoint folder holding both `model.bpk` and `config.toml`.
pub(crate) fn is_checkpoint_folder(dir: &Path) -> bool {
    dir.join("model.bpk").is_file() && dir.join("config.toml").is_file()
}

/// The bundled weights folder `rel` (e.g. [`BUNDLED_SDFCNN`]) if it exists in
/// the current directory or the crate's source folder.
pub fn bundled_weights(rel: &str) -> Option<PathBuf> {
    find_in(&search_roots(), rel, is_checkpoint_folder).map(|p| tidy(&p))
}

/// A crate-relative file or folder that ships with the source tree (a fixture under
/// `datasets/fixtures/`, a config under `configs/`), looked up as the bundled weights are:
/// in the current directory, then in the crate's source folder. `None` where neither has it.
pub fn locate(rel: &str) -> Option<PathBuf> {
    find_in(&search_roots(), rel, |p| p.exists()).map(|p| tidy(&p))
}

/// Where the default sequence is read from: an existing
/// [`DEFAULT_SEQUENCE`] in the current directory or the crate's source folder;
/// `Err(path)` with the place to generate it (under the current directory)
/// when there is none.
pub fn default_sequence() -> std::result::Result<PathBuf, PathBuf> {
    match find_in(&search_roots(), DEFAULT_SEQUENCE, |p| {
        p.join("rgb.txt").is_file()
    }) {
        Some(p) => Ok(tidy(&p)),
        None => Err(PathBuf::from(DEFAULT_SEQUENCE)),
    }
}

/// `./x` as `x`.
fn tidy(p: &Path) -> PathBuf {
    p.strip_prefix(".")
        .map(Path::to_path_buf)
        .unwrap_or_else(|_| p.to_path_buf())
}

/// The synthetic generator's configuration of the default sequence: one room
/// (seed 1), a hand-held sweep of `DEFAULT_SEQUENCE_FRAMES` frames at
/// 640x480 with the TUM fr1 camera, Kinect-like sensor depth, exact depth and
/// NYU40 labels; no NYU-layout training images.
pub fn default_sequence_config() -> SynthConfig {
    let mut cfg = SynthConfig {
        seed: 1,
        scenes: 1,
        frames: DEFAULT_SEQUENCE_FRAMES,
        trajectory: TrajectoryKind::Sweep,
        camera: "fr1".into(),
        resolution: "640x480".into(),
        ..SynthConfig::default()
    };
    cfg.output.sequence = true;
    cfg.output.nyu = false;
    cfg.output.gt_depth = true;
    cfg
}

/// Generates the one sequence of `cfg` (one scene, sequence output) into the
/// new folder `dest` in the TUM RGB-D layout (with `labels/`, `depth_gt/`,
/// `groundtruth.txt`, `camera.toml` and `scene.json`). The generator writes
/// into a hidden sibling folder that is renamed to `dest` only when complete,
/// so an interrupted generation never leaves a partial sequence at `dest`.
pub fn generate_sequence(
    cfg: &SynthConfig,
    dest: &Path,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<synth::Summary> {
    if cfg.scenes != 1 || !cfg.output.sequence {
        return Err(Error::msg(
            "generating one sequence needs scenes = 1 and output.sequence = true",
        ));
    }
    if dest.exists() {
        return Err(Error::invalid(
            dest,
            "already exists; remove it to generate the sequence again",
        ));
    }
    let name = dest
        .file_name()
        .ok_or_else(|| Error::invalid(dest, "not a folder name"))?
        .to_string_lossy()
        .into_owned();
    let parent = match dest.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    std::fs::create_dir_all(&parent).map_err(|e| Error::io(&parent, e))?;
    let staging = parent.join(format!(".{name}.partial"));
    if staging.exists() {
        // Left by an interrupted generation.
        std::fs::remove_dir_all(&staging).map_err(|e| Error::io(&staging, e))?;
    }
    let result = synth::generate(cfg, &staging, progress).and_then(|summary| {
        let seq = staging.join("seq_000");
        std::fs::rename(&seq, dest).map_err(|e| Error::io(dest, e))?;
        Ok(summary)
    });
    let _ = std::fs::remove_dir_all(&staging);
    result
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lookup_prefers_the_first_root_and_needs_complete_checkpoints() {
        let base = std::env::temp_dir().join(format!("sdf_defaults_{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&base);
        let (a, b) = (base.join("a"), base.join("b"));
        for r in [&a, &b] {
            std::fs::create_dir_all(r.join("weights/sdfcnn")).unwrap();
            std::fs::write(r.join("weights/sdfcnn/model.bpk"), b"x").unwrap();
        }
        let roots = vec![a.clone(), b.clone()];
        // No config.toml anywhere: not a checkpoint.
        assert_eq!(find_in(&roots, BUNDLED_SDFCNN, is_checkpoint_folder), None);
        std::fs::write(b.join("weights/sdfcnn/config.toml"), b"").unwrap();
        assert_eq!(
            find_in(&roots, BUNDLED_SDFCNN, is_checkpoint_folder),
            Some(b.join(BUNDLED_SDFCNN))
        );
        std::fs::write(a.join("weights/sdfcnn/config.toml"), b"").unwrap();
        assert_eq!(
            find_in(&roots, BUNDLED_SDFCNN, is_checkpoint_folder),
            Some(a.join(BUNDLED_SDFCNN))
        );
        assert_eq!(tidy(Path::new("./x/y")), PathBuf::from("x/y"));
        assert!(search_roots()[1].join("Cargo.toml").is_file());
        std::fs::remove_dir_all(&base).ok();
    }

    #[test]
    fn locate_finds_files_of_the_source_tree_only() {
        // Tests run in the crate root, and the crate's folder is the second root anyway.
        let fixture = locate("datasets/fixtures/nyuv2").expect("the NYUv2 fixture");
        assert!(fixture.join("000433_rgb.png").is_file());
        assert!(locate("configs/train/sdfcnn_tiny.toml").is_some_and(|p| p.is_file()));
        assert_eq!(locate("datasets/fixtures/no_such_fixture"), None);
    }

    #[test]
    fn default_sequence_config_is_valid_and_sequence_only() {
        let cfg = default_sequence_config();
        cfg.validate().unwrap();
        assert_eq!(cfg.camera().unwrap().width, 640);
        assert_eq!(synth::work_units(&cfg), DEFAULT_SEQUENCE_FRAMES as u64);
    }
}
