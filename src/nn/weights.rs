//! Saving and loading network weights: full-precision training checkpoints and
//! half-precision bundled weights (`model.bpk`, burnpack), with the training
//! config beside them (`config.toml`).

use crate::error::{Error, Result};
use burn::module::{Module, ModuleMapper, Param};
use burn::prelude::*;
use burn::tensor::DType;
use std::path::Path;

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
    save_atomic(module.map(&mut ToF16), path)
}

/// Saves a module's weights as they are, atomically (temp file + rename; the temp file is
/// removed when saving fails).
pub fn save_atomic<M: Module>(module: M, path: &Path) -> Result<()> {
    let tmp = crate::io::temp_path(path);
    if let Err(e) = module.save_file(&tmp) {
        let _ = std::fs::remove_file(&tmp);
        return Err(Error::invalid(path, format!("cannot save weights: {e}")));
    }
    let synced = std::fs::File::open(&tmp).and_then(|f| f.sync_all());
    if let Err(e) = synced {
        let _ = std::fs::remove_file(&tmp);
        return Err(Error::io(path, e));
    }
    std::fs::rename(&tmp, path).map_err(|e| Error::io(path, e))?;
    crate::io::sync_parent(path).map_err(|e| Error::io(path, e))
}

/// Loads weights saved in any float precision into `module` (converted to the
/// module's own precision). `what` names the network for the error message.
pub(crate) fn load_into<M: Module>(module: M, path: &Path, what: &str, config: &Path) -> Result<M> {
    let record = burn::store::ModuleRecord::load(path)
        .map_err(|e| Error::invalid(path, format!("cannot read weights: {e}")))?;
    let module = module
        .try_load_record(record.cast_to_module_dtype())
        .map_err(|e| {
            Error::invalid(
                path,
                format!(
                    "these weights do not fit the {what} described by {}: {e}",
                    config.display()
                ),
            )
        })?;
    check_finite_weights(&module, path)?;
    Ok(module)
}

/// Refuses weights holding a NaN or an infinity (a training run that diverged, a damaged
/// file): the error names the file and the first tensors, by module path.
pub(crate) fn check_finite_weights<M: Module>(module: &M, path: &Path) -> Result<()> {
    struct Check {
        stack: Vec<String>,
        bad: Vec<String>,
    }
    impl burn::module::ModuleVisitor for Check {
        fn enter_module(&mut self, name: &str, _container_type: &str) {
            self.stack.push(name.to_string());
        }
        fn exit_module(&mut self, _name: &str, _container_type: &str) {
            self.stack.pop();
        }
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            let finite = param
                .val()
                .into_data()
                .convert_dtype(DType::F32)
                .iter::<f32>()
                .all(f32::is_finite);
            if !finite {
                self.bad.push(self.stack.join("."));
            }
        }
    }
    let mut check = Check {
        stack: Vec::new(),
        bad: Vec::new(),
    };
    module.visit(&mut check);
    if check.bad.is_empty() {
        return Ok(());
    }
    let shown: Vec<&str> = check.bad.iter().take(5).map(String::as_str).collect();
    Err(Error::invalid(
        path,
        format!(
            "{} weight tensors hold NaN or infinite values ({}{}): the weights are unusable",
            check.bad.len(),
            shown.join(", "),
            if check.bad.len() > shown.len() {
                ", ..."
            } else {
                ""
            }
        ),
    ))
}

/// The element-wise mean of the float parameters of `models`, which must share one
/// architecture: the weight averaging of SWA (Izmailov et al. 2018, "Averaging Weights
/// Leads to Wider Optima") over the last checkpoints of a run. `names` label the models
/// in the error a shape mismatch gives. A network with batch norm would need its running
/// statistics recomputed on training data after averaging; this function does not do that.
pub fn average_modules<M: Module>(models: Vec<M>, names: &[String]) -> Result<M> {
    struct Collect(Vec<(Vec<usize>, Vec<f32>)>);
    impl burn::module::ModuleVisitor for Collect {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            let t = param.val();
            let dims = t.dims().to_vec();
            let values = t
                .into_data()
                .convert_dtype(DType::F32)
                .try_into_vec::<f32>()
                .expect("converted to f32 above");
            self.0.push((dims, values));
        }
    }
    /// Puts the means back in visiting order; a parameter whose shape differs from its mean's
    /// (or a missing mean) is left as it was and recorded, and becomes an error below.
    struct Replace {
        means: std::vec::IntoIter<(Vec<usize>, Vec<f32>)>,
        mismatched: bool,
    }
    impl ModuleMapper for Replace {
        fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
            let next = self.means.next();
            param.map(|t| match next {
                Some((dims, mean)) if dims == t.dims() => {
                    let device = t.device();
                    Tensor::from_data(TensorData::new(mean, t.shape()), &device)
                }
                _ => {
                    self.mismatched = true;
                    t
                }
            })
        }
    }
    let mut models = models.into_iter();
    let Some(first) = models.next() else {
        return Err(Error::msg("nothing to average: no checkpoints given"));
    };
    let mut sum = Collect(Vec::new());
    first.visit(&mut sum);
    let mut count = 1usize;
    for (k, model) in models.enumerate() {
        let mut other = Collect(Vec::new());
        model.visit(&mut other);
        let name = names.get(k + 1).map(String::as_str).unwrap_or("?");
        if other.0.len() != sum.0.len() || other.0.iter().zip(&sum.0).any(|(a, b)| a.0 != b.0) {
            return Err(Error::msg(format!(
                "{name}: its parameters do not have the shapes of {}'s, so the two cannot be averaged",
                names
                    .first()
                    .map(String::as_str)
                    .unwrap_or("the first checkpoint")
            )));
        }
        for ((_, acc), (_, v)) in sum.0.iter_mut().zip(other.0) {
            for (a, b) in acc.iter_mut().zip(v) {
                *a += b;
            }
        }
        count += 1;
    }
    let means: Vec<(Vec<usize>, Vec<f32>)> = sum
        .0
        .into_iter()
        .map(|(dims, mut v)| {
            v.iter_mut().for_each(|x| *x /= count as f32);
            (dims, v)
        })
        .collect();
    let mut replace = Replace {
        means: means.into_iter(),
        mismatched: false,
    };
    let mean = first.map(&mut replace);
    if replace.mismatched || replace.means.next().is_some() {
        return Err(Error::msg(
            "averaging: the module's parameters were not mapped in the order they were read",
        ));
    }
    Ok(mean)
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::{Linear, LinearConfig};

    fn linear(weight: [[f32; 2]; 3], bias: [f32; 2]) -> Linear {
        #[allow(deprecated)]
        let device = Device::ndarray();
        Linear {
            weight: Param::from_tensor(Tensor::from_data(weight, &device)),
            bias: Some(Param::from_tensor(Tensor::from_data(bias, &device))),
        }
    }

    #[test]
    fn non_finite_weights_are_refused_naming_the_tensor() {
        let good = linear([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]], [1.0, -1.0]);
        check_finite_weights(&good, Path::new("w.bpk")).unwrap();
        let bad = linear([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]], [f32::NAN, -1.0]);
        let e = check_finite_weights(&bad, Path::new("w.bpk"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("w.bpk") && e.contains("1 weight tensors") && e.contains("bias"),
            "{e}"
        );
        let inf = linear([[f32::INFINITY, 2.0], [3.0, 4.0], [5.0, 6.0]], [1.0, -1.0]);
        let e = check_finite_weights(&inf, Path::new("w.bpk"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("weight"), "{e}");
    }

    #[test]
    fn averaging_takes_the_mean_of_every_parameter() {
        let a = linear([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]], [1.0, -1.0]);
        let b = linear([[3.0, 2.0], [1.0, 0.0], [5.0, -6.0]], [2.0, 1.0]);
        let c = linear([[2.0, 2.0], [2.0, 2.0], [2.0, 0.0]], [0.0, 3.0]);
        let names = ["a".to_string(), "b".to_string(), "c".to_string()];
        let mean = average_modules(vec![a, b, c], &names).unwrap();
        let w = mean.weight.val().into_data().try_into_vec::<f32>().unwrap();
        assert_eq!(w, vec![2.0, 2.0, 2.0, 2.0, 4.0, 0.0]);
        let bias = mean
            .bias
            .unwrap()
            .val()
            .into_data()
            .try_into_vec::<f32>()
            .unwrap();
        assert_eq!(bias, vec![1.0, 1.0]);
    }

    #[test]
    fn averaging_different_architectures_is_an_error_naming_them() {
        #[allow(deprecated)]
        let device = Device::ndarray();
        let a = LinearConfig::new(3, 2).init(&device);
        let b = LinearConfig::new(2, 3).init(&device);
        let names = ["runs/a".to_string(), "runs/b".to_string()];
        let err = average_modules(vec![a, b], &names).unwrap_err().to_string();
        assert!(err.contains("runs/b") && err.contains("runs/a"), "{err}");
        assert!(average_modules::<Linear>(vec![], &[]).is_err());
    }
}
