//! The devices of a data-parallel training run (`devices = [...]` in a training config,
//! `train --devices`): one entry per GPU, all on the run's backend.
//!
//! An entry names its backend and which of its devices: `wgpu:N` (the N-th discrete GPU, as
//! wgpu counts them), `wgpu:integrated:N`, `wgpu:virtual:N`, `wgpu:cpu` (a software adapter
//! such as Mesa's lavapipe), `wgpu` (the adapter a plain `--backend wgpu` takes) and `cuda:N`.
//! The CPU backends have one device each, so a list is refused for them, as are lists that
//! mix backends, repeat an entry, or name a device the machine lacks: all before any data is
//! read ([`training_devices`]).

use super::backend::{BackendError, BackendKind};
use burn::prelude::Device;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// Which of a GPU backend's devices an entry names.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Selector {
    /// The backend's own choice (what `--backend` alone takes).
    Default,
    /// The N-th discrete GPU (`wgpu:N`, `cuda:N`).
    Discrete(usize),
    /// The N-th integrated GPU (`wgpu:integrated:N`).
    Integrated(usize),
    /// The N-th virtual GPU (`wgpu:virtual:N`).
    Virtual(usize),
    /// A CPU adapter of a GPU API (`wgpu:cpu`).
    Cpu,
}

/// One entry of a device list, e.g. `wgpu:0`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct DeviceSpec {
    /// The backend the device belongs to.
    pub backend: BackendKind,
    /// Which of its devices.
    pub selector: Selector,
}

/// Largest device index accepted (cubecl's own bound on adapter indices is far above any
/// machine's GPU count).
const MAX_INDEX: usize = 255;

impl std::str::FromStr for DeviceSpec {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        let bad = || {
            format!(
                "device `{text}`: expected `wgpu:N`, `wgpu:integrated:N`, `wgpu:virtual:N`, \
                 `wgpu:cpu`, `wgpu`, `cuda:N`, `ndarray` or `flex` (N a device index)"
            )
        };
        let index = |s: &str| match s.parse::<usize>() {
            Ok(i) if i <= MAX_INDEX => Ok(i),
            _ => Err(bad()),
        };
        let parts: Vec<&str> = text.trim().split(':').collect();
        let backend = match parts[0] {
            "ndarray" => BackendKind::Ndarray,
            "flex" => BackendKind::Flex,
            "wgpu" => BackendKind::Wgpu,
            "cuda" => BackendKind::Cuda,
            _ => return Err(bad()),
        };
        let selector = match (backend, &parts[1..]) {
            (_, []) => Selector::Default,
            (BackendKind::Ndarray | BackendKind::Flex, ["0"]) => Selector::Default,
            (BackendKind::Wgpu, ["cpu"]) => Selector::Cpu,
            (BackendKind::Wgpu | BackendKind::Cuda, [n]) => Selector::Discrete(index(n)?),
            (BackendKind::Wgpu, ["integrated", n]) => Selector::Integrated(index(n)?),
            (BackendKind::Wgpu, ["virtual", n]) => Selector::Virtual(index(n)?),
            _ => return Err(bad()),
        };
        Ok(DeviceSpec { backend, selector })
    }
}

impl std::fmt::Display for DeviceSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let b = self.backend;
        match self.selector {
            Selector::Default => write!(f, "{b}"),
            Selector::Discrete(n) => write!(f, "{b}:{n}"),
            Selector::Integrated(n) => write!(f, "{b}:integrated:{n}"),
            Selector::Virtual(n) => write!(f, "{b}:virtual:{n}"),
            Selector::Cpu => write!(f, "{b}:cpu"),
        }
    }
}

impl Serialize for DeviceSpec {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

impl<'de> Deserialize<'de> for DeviceSpec {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        String::deserialize(d)?
            .parse()
            .map_err(serde::de::Error::custom)
    }
}

/// Why a device list cannot train.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DeviceListError {
    /// Entries on different backends.
    #[error("the devices {0} and {1} are on different backends: a device list cannot mix backends")]
    Mixed(DeviceSpec, DeviceSpec),
    /// Entries on another backend than the run's.
    #[error(
        "the devices are on `{devices}` but the run's backend is `{backend}`: set \
         `backend = \"{devices}\"` (or `--backend {devices}`)"
    )]
    OtherBackend {
        /// The run's backend.
        backend: BackendKind,
        /// The devices' backend.
        devices: BackendKind,
    },
    /// A device list for a backend with one device.
    #[error(
        "backend `{0}` has one device: a device list (`devices`, `--devices`) is for GPU \
         backends; leave it out to train on `{0}`"
    )]
    OneDevice(BackendKind),
    /// An entry listed twice.
    #[error("device {0} is listed twice")]
    Repeated(DeviceSpec),
    /// A device the backend cannot open.
    #[error("device {spec}: {reason}")]
    Missing {
        /// The entry.
        spec: DeviceSpec,
        /// The backend's answer.
        reason: String,
    },
}

impl From<DeviceListError> for crate::error::Error {
    fn from(e: DeviceListError) -> Self {
        crate::error::Error::wrap(e)
    }
}

/// Checks what a device list shows by itself (a config is checked with it when read): one
/// backend, no entry twice.
pub fn check_entries(specs: &[DeviceSpec]) -> Result<(), DeviceListError> {
    let Some(first) = specs.first() else {
        return Ok(());
    };
    if let Some(other) = specs.iter().find(|s| s.backend != first.backend) {
        return Err(DeviceListError::Mixed(*first, *other));
    }
    for (i, s) in specs.iter().enumerate() {
        if specs[..i].contains(s) {
            return Err(DeviceListError::Repeated(*s));
        }
    }
    Ok(())
}

/// Checks a device list against the run's `backend` (after the command line's overrides)
/// without opening a device: [`check_entries`], then the run's backend, a GPU backend.
pub fn check_device_list(
    backend: BackendKind,
    specs: &[DeviceSpec],
) -> Result<(), DeviceListError> {
    check_entries(specs)?;
    let Some(first) = specs.first() else {
        return Ok(());
    };
    if first.backend != backend {
        return Err(DeviceListError::OtherBackend {
            backend,
            devices: first.backend,
        });
    }
    if !backend.is_gpu() {
        return Err(DeviceListError::OneDevice(backend));
    }
    Ok(())
}

/// The training devices (with automatic differentiation) of a run on `backend` with the
/// device list `specs`, the first the main one (it holds the model and the optimizer): the
/// backend's device alone for an empty list. Every device is opened and probed here, so a
/// missing one is an error before any data is read.
pub fn training_devices(
    backend: BackendKind,
    specs: &[DeviceSpec],
) -> Result<Vec<Device>, crate::error::Error> {
    check_device_list(backend, specs)?;
    if specs.is_empty() {
        return Ok(vec![backend.autodiff_device()?]);
    }
    specs
        .iter()
        .map(|s| {
            open(*s)
                .map(Device::autodiff)
                .map_err(crate::error::Error::from)
        })
        .collect()
}

/// Opens one GPU device (each once per process).
fn open(spec: DeviceSpec) -> Result<Device, DeviceListError> {
    let missing = |e: BackendError| DeviceListError::Missing {
        spec,
        reason: match e {
            BackendError::NoDevice { reason, .. } => reason,
            other => other.to_string(),
        },
    };
    match (spec.backend, spec.selector) {
        (_, Selector::Default) => spec.backend.device().map_err(missing),
        (BackendKind::Wgpu, selector) => super::backend::wgpu_at(selector).map_err(missing),
        (BackendKind::Cuda, Selector::Discrete(n)) => super::backend::cuda_at(n).map_err(missing),
        _ => unreachable!("checked by the parser"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(s: &str) -> DeviceSpec {
        s.parse().unwrap_or_else(|e| panic!("{e}"))
    }

    #[test]
    fn entries_round_trip_through_their_names() {
        for s in [
            "wgpu",
            "wgpu:0",
            "wgpu:3",
            "wgpu:integrated:1",
            "wgpu:virtual:0",
            "wgpu:cpu",
            "cuda:1",
            "ndarray",
            "flex",
        ] {
            assert_eq!(spec(s).to_string(), s);
            let text = toml::to_string(&std::collections::BTreeMap::from([("d", vec![spec(s)])]))
                .expect("toml");
            assert_eq!(text.trim(), format!("d = [\"{s}\"]"));
        }
        assert_eq!(spec("flex:0"), spec("flex"));
    }

    #[test]
    fn malformed_entries_say_what_is_expected() {
        for s in [
            "", "gpu:0", "wgpu:-1", "wgpu:x", "flex:1", "cuda:cpu", "wgpu:0:1", "wgpu:999",
        ] {
            let e = s.parse::<DeviceSpec>().expect_err(s);
            assert!(
                e.contains(&format!("device `{s}`")) && e.contains("wgpu:N"),
                "{e}"
            );
        }
    }

    #[test]
    fn lists_that_cannot_train_are_refused_before_any_device_opens() {
        use BackendKind::*;
        let list = |v: &[&str]| v.iter().map(|s| spec(s)).collect::<Vec<_>>();
        let mixed = check_device_list(Wgpu, &list(&["wgpu:0", "cuda:0"])).unwrap_err();
        assert!(mixed.to_string().contains("cannot mix backends"), "{mixed}");
        let other = check_device_list(Flex, &list(&["wgpu:0", "wgpu:1"])).unwrap_err();
        assert!(other.to_string().contains("backend = \"wgpu\""), "{other}");
        for b in [Ndarray, Flex] {
            let one = check_device_list(b, &list(&[&b.to_string()])).unwrap_err();
            assert_eq!(one, DeviceListError::OneDevice(b));
            assert!(one.to_string().contains("has one device"), "{one}");
        }
        let twice = check_device_list(Wgpu, &list(&["wgpu:0", "wgpu:0"])).unwrap_err();
        assert_eq!(twice, DeviceListError::Repeated(spec("wgpu:0")));
        assert!(check_device_list(Wgpu, &list(&["wgpu:0", "wgpu:1"])).is_ok());
        assert!(check_device_list(Flex, &[]).is_ok());
    }

    #[test]
    fn an_empty_list_trains_on_the_backends_own_device() {
        let d = training_devices(BackendKind::Flex, &[]).expect("flex");
        assert_eq!(d, vec![BackendKind::Flex.autodiff_device().expect("flex")]);
    }

    #[test]
    fn a_device_the_machine_lacks_is_an_error_naming_it() {
        // Never this many discrete GPUs; without the feature, the build's own refusal.
        let e = training_devices(BackendKind::Wgpu, &[spec("wgpu:200"), spec("wgpu:201")])
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("device wgpu:200: "), "{e}");
    }
}
