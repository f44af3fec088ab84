//! The CPU backends a network can run on. ndarray is the default (the users'
//! requirement); flex is selectable and usually faster.

use burn::prelude::Device;
use serde::{Deserialize, Serialize};

/// A Burn CPU backend.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum BackendKind {
    /// burn-ndarray.
    #[default]
    Ndarray,
    /// burn-flex.
    Flex,
}

impl BackendKind {
    /// The inference device.
    pub fn device(self) -> Device {
        match self {
            #[allow(deprecated)] // ndarray is deprecated upstream but required here.
            BackendKind::Ndarray => Device::ndarray(),
            BackendKind::Flex => Device::flex(),
        }
    }

    /// The training device (with automatic differentiation).
    pub fn autodiff_device(self) -> Device {
        self.device().autodiff()
    }
}

impl std::fmt::Display for BackendKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            BackendKind::Ndarray => "ndarray",
            BackendKind::Flex => "flex",
        })
    }
}
