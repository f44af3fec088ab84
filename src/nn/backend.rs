//! The backends a network can run on. ndarray is the default (the users' requirement); flex
//! is selectable and usually faster on a CPU. The GPU backends sit behind Cargo features so
//! that the default build stays CPU-only: `wgpu` (Vulkan, Metal, DX12 through the wgpu crate)
//! and `cuda` (NVIDIA, through CubeCL). A binary built without one answers `--backend wgpu`
//! with an error naming the feature, never with another backend.

use burn::prelude::Device;
use serde::{Deserialize, Serialize};

/// A Burn backend.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Eq, Hash, Serialize, Deserialize, clap::ValueEnum,
)]
#[serde(rename_all = "lowercase")]
pub enum BackendKind {
    /// burn-ndarray (CPU).
    #[default]
    Ndarray,
    /// burn-flex (CPU).
    Flex,
    /// burn-wgpu: the first high-performance adapter wgpu finds (Cargo feature `wgpu`).
    Wgpu,
    /// burn-cuda: the first NVIDIA GPU (Cargo feature `cuda`).
    Cuda,
}

/// Why a backend cannot run here.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum BackendError {
    /// The binary was built without the backend's Cargo feature.
    #[error(
        "backend `{0}` is not compiled into this binary: rebuild with `cargo build --release \
         --features {0}` (README, *GPU*)"
    )]
    NotCompiled(BackendKind),
    /// Training asked of a backend where that network's training has not been shown to
    /// follow the CPU's.
    #[error(
        "{network} training on `{backend}` is refused: it has not been shown to follow the \
         CPU's there (docs/training.md, *GPU*); train it on flex or ndarray"
    )]
    NoTraining {
        /// The backend asked for.
        backend: BackendKind,
        /// The network to be trained.
        network: &'static str,
    },
    /// The backend is compiled in but finds no device.
    #[error("backend `{backend}` found no usable device: {reason}")]
    NoDevice {
        /// The backend asked for.
        backend: BackendKind,
        /// The driver's answer.
        reason: String,
    },
}

impl From<BackendError> for crate::error::Error {
    fn from(e: BackendError) -> Self {
        crate::error::Error::wrap(e)
    }
}

impl BackendKind {
    /// Every backend, compiled in or not.
    pub const ALL: [BackendKind; 4] = [Self::Ndarray, Self::Flex, Self::Wgpu, Self::Cuda];

    /// Whether this binary was built with the backend.
    pub fn is_compiled(self) -> bool {
        match self {
            BackendKind::Ndarray | BackendKind::Flex => true,
            BackendKind::Wgpu => cfg!(feature = "wgpu"),
            BackendKind::Cuda => cfg!(feature = "cuda"),
        }
    }

    /// Whether the backend computes on a GPU (or a GPU driver emulated on the CPU).
    pub fn is_gpu(self) -> bool {
        matches!(self, BackendKind::Wgpu | BackendKind::Cuda)
    }

    /// The inference device. The GPU runtimes start on the first call (once per process);
    /// a missing feature or device is an error here, before any data is read.
    pub fn device(self) -> Result<Device, BackendError> {
        match self {
            #[allow(deprecated)] // ndarray is deprecated upstream but required here.
            BackendKind::Ndarray => Ok(Device::ndarray()),
            BackendKind::Flex => Ok(Device::flex()),
            BackendKind::Wgpu => gpu::wgpu(),
            BackendKind::Cuda => gpu::cuda(),
        }
    }

    /// The training device (with automatic differentiation).
    pub fn autodiff_device(self) -> Result<Device, BackendError> {
        Ok(self.device()?.autodiff())
    }

    /// Checks that `network` may train on this backend: both networks on the CPU backends and
    /// on wgpu (`tests/gpu_backends.rs` compares their training steps and the tiny configs'
    /// losses with flex's); cuda is refused, never built here. Needs no device: a backend the
    /// build lacks gets [`BackendError::NotCompiled`].
    pub fn check_training(self, network: &'static str) -> Result<(), BackendError> {
        let checked = match self {
            BackendKind::Ndarray | BackendKind::Flex => true,
            BackendKind::Wgpu => true,
            BackendKind::Cuda => false,
        };
        if !self.is_compiled() {
            Err(BackendError::NotCompiled(self))
        } else if !checked {
            Err(BackendError::NoTraining {
                backend: self,
                network,
            })
        } else {
            Ok(())
        }
    }

    /// Checks that the backend can run here (see [`BackendKind::device`]).
    pub fn check(self) -> Result<(), BackendError> {
        self.device().map(drop)
    }
}

impl std::fmt::Display for BackendKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            BackendKind::Ndarray => "ndarray",
            BackendKind::Flex => "flex",
            BackendKind::Wgpu => "wgpu",
            BackendKind::Cuda => "cuda",
        })
    }
}

/// Whether `device` is one of the CPU backends (possibly wrapped in autodiff), where this
/// crate's own kernels (`nn::conv2d`, `nn::max_pool2d`) may replace Burn's.
pub(crate) fn is_cpu(device: &Device) -> bool {
    let inner = device.clone().without_autodiff();
    #[allow(deprecated)] // ndarray is deprecated upstream but the project's default backend.
    let ndarray = Device::ndarray();
    inner == ndarray || inner == Device::flex()
}

/// A wgpu device other than the default adapter (a [`super::devices`] entry), opened and
/// probed once per process.
pub(crate) fn wgpu_at(selector: super::devices::Selector) -> Result<Device, BackendError> {
    gpu::wgpu_at(selector)
}

/// The `n`-th CUDA device, opened and probed once per process.
pub(crate) fn cuda_at(n: usize) -> Result<Device, BackendError> {
    gpu::cuda_at(n)
}

mod gpu {
    use super::{BackendError, BackendKind};
    use crate::nn::devices::Selector;
    use burn::prelude::Device;

    /// Devices opened by selector, each once per process (a wgpu runtime cannot be
    /// initialised twice).
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    fn once_at(
        backend: BackendKind,
        key: Selector,
        start: impl FnOnce() -> Result<Device, String>,
    ) -> Result<Device, BackendError> {
        use std::collections::HashMap;
        use std::sync::{Mutex, OnceLock};
        type Opened = Mutex<HashMap<(BackendKind, Selector), Result<Device, String>>>;
        static OPENED: OnceLock<Opened> = OnceLock::new();
        let mut opened = OPENED
            .get_or_init(Default::default)
            .lock()
            .unwrap_or_else(|p| p.into_inner());
        opened
            .entry((backend, key))
            .or_insert_with(|| start().and_then(|d| probe(&d).map(|()| d)))
            .clone()
            .map_err(|reason| BackendError::NoDevice { backend, reason })
    }

    #[cfg(feature = "wgpu")]
    pub fn wgpu_at(selector: Selector) -> Result<Device, BackendError> {
        use burn::tensor::DeviceKind;
        let kind = match selector {
            Selector::Default => return wgpu(),
            Selector::Discrete(n) => DeviceKind::DiscreteGpu(n),
            Selector::Integrated(n) => DeviceKind::IntegratedGpu(n),
            Selector::Virtual(n) => DeviceKind::VirtualGpu(n),
            Selector::Cpu => DeviceKind::Cpu,
        };
        once_at(BackendKind::Wgpu, selector, || {
            Device::wgpu_options()
                .device_kind(kind)
                .init()
                .map_err(|e| e.to_string())
        })
    }

    #[cfg(not(feature = "wgpu"))]
    pub fn wgpu_at(_: Selector) -> Result<Device, BackendError> {
        Err(BackendError::NotCompiled(BackendKind::Wgpu))
    }

    #[cfg(feature = "cuda")]
    pub fn cuda_at(n: usize) -> Result<Device, BackendError> {
        once_at(BackendKind::Cuda, Selector::Discrete(n), || {
            Ok(Device::cuda(n))
        })
    }

    #[cfg(not(feature = "cuda"))]
    pub fn cuda_at(_: usize) -> Result<Device, BackendError> {
        Err(BackendError::NotCompiled(BackendKind::Cuda))
    }

    /// Starts a GPU runtime once per process (wgpu's cannot be initialised twice) and keeps
    /// its device, or the driver's answer when there is none or it cannot compute.
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    fn once(
        cell: &'static std::sync::OnceLock<Result<Device, String>>,
        backend: BackendKind,
        start: impl FnOnce() -> Result<Device, String>,
    ) -> Result<Device, BackendError> {
        cell.get_or_init(|| start().and_then(|d| probe(&d).map(|()| d)))
            .clone()
            .map_err(|reason| BackendError::NoDevice { backend, reason })
    }

    /// Runs the reduction the losses use ([`crate::nn::sum_all`]) on `device`. An adapter can
    /// start and still lack what Burn's kernels need (without a Vulkan driver wgpu took a GL
    /// adapter here whose first atomic sum panicked in a worker thread); a panic or a wrong sum
    /// becomes an error, its panic message kept out of the output.
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    fn probe(device: &Device) -> Result<(), String> {
        use std::panic::{AssertUnwindSafe, catch_unwind, set_hook, take_hook};
        let hook = take_hook();
        set_hook(Box::new(|_| {}));
        let run = catch_unwind(AssertUnwindSafe(|| {
            crate::nn::sum_all(burn::tensor::Tensor::<1>::ones([1 << 20], device))
                .try_into_scalar::<f32>()
        }));
        set_hook(hook);
        // The driver's message in one line (Burn's spans several).
        let one_line = |s: String| {
            let parts: Vec<&str> = s.lines().map(str::trim).filter(|l| !l.is_empty()).collect();
            parts.join(" ").chars().take(400).collect::<String>()
        };
        match run {
            Ok(Ok(v)) if v == (1 << 20) as f32 => Ok(()),
            Ok(Ok(v)) => Err(format!("a test sum gave {v} instead of {}", 1 << 20)),
            Ok(Err(e)) => Err(one_line(format!("{e:?}"))),
            Err(p) => Err(crate::error::panic_message(p.as_ref())
                .map_or_else(|| "the runtime failed to start".into(), one_line)),
        }
    }

    /// The first high-performance adapter wgpu finds.
    #[cfg(feature = "wgpu")]
    pub fn wgpu() -> Result<Device, BackendError> {
        static DEVICE: std::sync::OnceLock<Result<Device, String>> = std::sync::OnceLock::new();
        once(&DEVICE, BackendKind::Wgpu, || {
            Device::wgpu_options().init().map_err(|e| e.to_string())
        })
    }

    #[cfg(not(feature = "wgpu"))]
    pub fn wgpu() -> Result<Device, BackendError> {
        Err(BackendError::NotCompiled(BackendKind::Wgpu))
    }

    /// The first CUDA device (CubeCL opens it lazily: [`probe`] finds a missing driver). Not
    /// compiled in this project's environment (README, *GPU*: the feature's build
    /// downloads LLVM).
    #[cfg(feature = "cuda")]
    pub fn cuda() -> Result<Device, BackendError> {
        static DEVICE: std::sync::OnceLock<Result<Device, String>> = std::sync::OnceLock::new();
        once(&DEVICE, BackendKind::Cuda, || Ok(Device::cuda(0)))
    }

    #[cfg(not(feature = "cuda"))]
    pub fn cuda() -> Result<Device, BackendError> {
        Err(BackendError::NotCompiled(BackendKind::Cuda))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cpu_backends_always_start() {
        for b in [BackendKind::Ndarray, BackendKind::Flex] {
            assert!(b.is_compiled() && !b.is_gpu());
            let d = b.device().expect("CPU backend");
            assert!(is_cpu(&d) && is_cpu(&b.autodiff_device().expect("autodiff")));
        }
    }

    #[test]
    fn a_backend_left_out_of_the_build_names_its_feature() {
        for b in BackendKind::ALL.into_iter().filter(|b| !b.is_compiled()) {
            let e = b.device().expect_err("not compiled").to_string();
            assert!(e.contains(&format!("--features {b}")), "{e}");
        }
    }

    #[test]
    fn training_runs_where_it_was_checked() {
        for b in BackendKind::ALL {
            for network in ["SDFCNN", "FPFDCNN"] {
                let ok = b.check_training(network).is_ok();
                assert_eq!(
                    ok,
                    b.is_compiled() && b != BackendKind::Cuda,
                    "{b} {network}"
                );
            }
        }
        let e = BackendKind::Cuda.check_training("FPFDCNN").unwrap_err();
        let want = if BackendKind::Cuda.is_compiled() {
            "FPFDCNN training on `cuda` is refused"
        } else {
            "backend `cuda` is not compiled"
        };
        assert!(e.to_string().starts_with(want), "{e}");
    }

    #[test]
    fn names_round_trip_through_configs() {
        for b in BackendKind::ALL {
            let text =
                toml::to_string(&std::collections::BTreeMap::from([("backend", b)])).expect("toml");
            assert_eq!(text.trim(), format!("backend = \"{b}\""));
        }
    }
}
