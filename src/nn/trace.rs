//! Layer output shapes recorded while a forward pass runs (for `train summary`), and
//! optionally their values (to find the first layer where two backends part:
//! `tests/gpu_backends.rs`).

use burn::prelude::*;

/// One recorded layer: its table name, what it does, and the shape it produced.
#[derive(Clone, Debug, PartialEq)]
pub struct LayerShape {
    /// Name as in the paper's tables (e.g. `L3`, `Layer5_9`).
    pub name: String,
    /// The operation (e.g. `conv 3x3 s1`, `bilinear`).
    pub method: String,
    /// Output shape, `[N, C, H, W]`.
    pub shape: Vec<usize>,
    /// The output's values, when the trace keeps them ([`ShapeTrace::with_values`]).
    pub values: Option<Vec<f32>>,
}

/// Collects [`LayerShape`]s when enabled; a disabled trace records nothing and allocates
/// nothing, so the plain forward passes share the traced code path.
#[derive(Debug, Default)]
pub struct ShapeTrace {
    enabled: bool,
    values: bool,
    layers: Vec<LayerShape>,
}

impl ShapeTrace {
    /// A trace that records.
    pub fn enabled() -> Self {
        Self {
            enabled: true,
            values: false,
            layers: Vec::new(),
        }
    }

    /// A trace that also keeps every recorded output's values (read back to the host as
    /// they are recorded, which makes a lazy backend compute them there).
    pub fn with_values() -> Self {
        Self {
            enabled: true,
            values: true,
            layers: Vec::new(),
        }
    }

    /// A trace that ignores every record.
    pub fn disabled() -> Self {
        Self::default()
    }

    /// Records the shape of `tensor` under `name` (a no-op when disabled).
    pub fn record<const D: usize>(
        &mut self,
        name: impl Into<String>,
        method: impl Into<String>,
        tensor: &Tensor<D>,
    ) {
        if self.enabled {
            self.layers.push(LayerShape {
                name: name.into(),
                method: method.into(),
                shape: tensor.dims().to_vec(),
                values: self.values.then(|| {
                    let data = tensor.clone().into_data().convert::<f32>();
                    data.try_to_vec::<f32>().unwrap_or_default()
                }),
            });
        }
    }

    /// Whether records are kept.
    pub fn is_enabled(&self) -> bool {
        self.enabled
    }

    /// The recorded layers, in execution order.
    pub fn layers(&self) -> &[LayerShape] {
        &self.layers
    }
}
