//! Saving and loading network weights: full-precision training checkpoints and
//! half-precision bundled weights (`model.bpk`, burnpack), with the training
//! config beside them (`config.toml`).

use crate::error::{Error, Result};
use burn::module::{Module, ModuleMapper, Param};
use burn::prelude::*;
use burn::tensor::DType;
use std::path::{Path, PathBuf};

/// Copies every float parameter to f16 on the flex device: burn-ndarray has no f16
/// tensors (casting there panics), so the copy works from a module on any backend.
struct ToF16;

impl ModuleMapper for ToF16 {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        param.map(|t| {
            let data = t.into_data().convert_dtype(DType::F16);
            Tensor::from_data(data, (&Device::flex(), DType::F16))
        })
    }
}

/// Saves a module with every float parameter in half precision (about half the size),
/// atomically (temp file + rename; the temp file is removed when saving fails).
pub fn save_f16<M: Module>(module: M, path: &Path) -> Result<()> {
    let tmp = crate::io::temp_path(path);
    if let Err(e) = module.map(&mut ToF16).save_file(&tmp) {
        let _ = std::fs::remove_file(&tmp);
        return Err(Error::invalid(path, format!("cannot save weights: {e}")));
    }
    std::fs::rename(&tmp, path).map_err(|e| Error::io(path, e))
}

/// Loads weights saved in any float precision into `module` (converted to the
/// module's own precision). `what` names the network for the error message.
pub fn load_into<M: Module>(module: M, path: &Path, what: &str, config: &Path) -> Result<M> {
    let record = burn::store::ModuleRecord::load(path)
        .map_err(|e| Error::invalid(path, format!("cannot read weights: {e}")))?;
    module
        .try_load_record(record.cast_to_module_dtype())
        .map_err(|e| {
            Error::invalid(
                path,
                format!(
                    "these weights do not fit the {what} described by {}: {e}",
                    config.display()
                ),
            )
        })
}

/// The weights file and training config of a checkpoint given as a `model.bpk`
/// file, a checkpoint folder, or a run folder (its newest checkpoint).
pub fn resolve_checkpoint(path: &Path) -> Result<(PathBuf, PathBuf)> {
    let dir = if path.is_file() {
        path.parent().map(Path::to_path_buf).unwrap_or_default()
    } else if path.join("model.bpk").is_file() {
        path.to_path_buf()
    } else if path.join("checkpoints/last.json").is_file() {
        let run = crate::training::RunDir {
            root: path.to_path_buf(),
            keep: 0,
        };
        match run.latest()? {
            Some(c) => c.dir,
            None => return Err(Error::invalid(path, "run folder has no checkpoint")),
        }
    } else {
        return Err(Error::invalid(
            path,
            "not a checkpoint: expected a model.bpk file, a folder holding one, or a training run folder",
        ));
    };
    let model = if path.is_file() {
        path.to_path_buf()
    } else {
        dir.join("model.bpk")
    };
    let config = dir.join("config.toml");
    if !config.is_file() {
        return Err(Error::invalid(
            &dir,
            "checkpoint has no config.toml beside its weights",
        ));
    }
    Ok((model, config))
}
