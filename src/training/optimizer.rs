//! `[optimizer]` of every training config: the Burn optimizer (SGD with momentum or Adam),
//! its learning-rate schedule and gradient clipping. The keys are the same for both
//! networks (so sweeps vary `optimizer.lr` whichever they train); the defaults are each
//! network's own: a key a config leaves out takes the value of the network's recipe
//! (`deserialize_over`), never another network's.

use burn::optim::decay::WeightDecayConfig;
use burn::optim::momentum::MomentumConfig;
use burn::optim::{AdamConfig, ModuleOptimizer, SgdConfig};
use serde::{Deserialize, Deserializer, Serialize};

/// Optimizer family.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum OptimizerKind {
    /// SGD with momentum (SDFCNN's recipe, Section V-C).
    #[default]
    Sgd,
    /// Adam.
    Adam,
}

/// `[optimizer]`, every field filled in.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OptimizerConfig {
    /// `sgd` or `adam`.
    pub kind: OptimizerKind,
    /// Initial learning rate.
    pub lr: f64,
    /// `[epoch, lr]` pairs: from that many completed epochs on, use `lr`.
    pub lr_steps: Vec<(usize, f64)>,
    /// SGD momentum (0 = plain SGD).
    pub momentum: f64,
    /// SGD momentum dampening.
    pub dampening: f64,
    /// Nesterov momentum.
    pub nesterov: bool,
    /// L2 weight decay added to the gradient (0 = none).
    pub weight_decay: f64,
    /// Adam β1.
    pub beta1: f64,
    /// Adam β2.
    pub beta2: f64,
    /// Adam ε.
    pub epsilon: f64,
    /// Clip the gradient norm of each parameter tensor to this value (0 = no clipping).
    pub grad_clip_norm: f64,
}

impl OptimizerConfig {
    /// SGD with momentum 0.9 (PyTorch semantics: dampening 0), weight decay 1e-4, learning
    /// rate 0.1 for the first 20 epochs, then 0.01: SDFCNN's recipe (Section V-C).
    pub fn sgd_paper() -> Self {
        OptimizerConfig {
            kind: OptimizerKind::Sgd,
            lr: 0.1,
            lr_steps: vec![(20, 0.01)],
            momentum: 0.9,
            dampening: 0.0,
            nesterov: false,
            weight_decay: 1e-4,
            beta1: 0.9,
            beta2: 0.999,
            epsilon: 1e-8,
            grad_clip_norm: 0.0,
        }
    }

    /// Adam at `lr` with Burn's `AdamConfig` defaults (ε = 1e-5), no schedule, no weight
    /// decay, gradient norm clipped at 1.
    pub fn adam(lr: f64) -> Self {
        OptimizerConfig {
            kind: OptimizerKind::Adam,
            lr,
            lr_steps: Vec::new(),
            weight_decay: 0.0,
            epsilon: 1e-5,
            grad_clip_norm: 1.0,
            ..Self::sgd_paper()
        }
    }

    /// Learning rate of epoch `epoch` (0-based).
    pub fn lr_at(&self, epoch: usize) -> f64 {
        self.lr_steps
            .iter()
            .filter(|(e, _)| *e <= epoch)
            .max_by_key(|(e, _)| *e)
            .map_or(self.lr, |(_, lr)| *lr)
    }

    /// The Burn optimizer.
    pub fn init(&self) -> ModuleOptimizer {
        let decay =
            (self.weight_decay > 0.0).then(|| WeightDecayConfig::new(self.weight_decay as f32));
        let clip = (self.grad_clip_norm > 0.0).then_some(
            burn::grad_clipping::GradientClippingConfig::Norm(self.grad_clip_norm as f32),
        );
        match self.kind {
            OptimizerKind::Sgd => {
                let momentum = (self.momentum > 0.0).then(|| {
                    MomentumConfig::new()
                        .with_momentum(self.momentum)
                        .with_dampening(self.dampening)
                        .with_nesterov(self.nesterov)
                });
                SgdConfig::new()
                    .with_momentum(momentum)
                    .with_weight_decay(decay)
                    .with_gradient_clipping(clip)
                    .init()
            }
            OptimizerKind::Adam => AdamConfig::new()
                .with_beta_1(self.beta1 as f32)
                .with_beta_2(self.beta2 as f32)
                .with_epsilon(self.epsilon as f32)
                .with_weight_decay(decay)
                .with_grad_clipping(clip)
                .init(),
        }
    }

    /// Checks the values; the message names the `optimizer.` key.
    pub fn validate(&self) -> std::result::Result<(), String> {
        let lrs = std::iter::once(self.lr).chain(self.lr_steps.iter().map(|s| s.1));
        if lrs.clone().any(|lr| !(lr > 0.0 && lr.is_finite())) {
            return Err("optimizer learning rates must be positive".into());
        }
        // A schedule out of epoch order (or with one epoch twice) is a typo whose intent
        // cannot be read back.
        if let Some(w) = self.lr_steps.windows(2).find(|w| w[1].0 <= w[0].0) {
            return Err(format!(
                "optimizer.lr_steps must list epochs in increasing order: [{}, {}] comes after \
                 [{}, {}]",
                w[1].0, w[1].1, w[0].0, w[0].1
            ));
        }
        if !(0.0..1.0).contains(&self.momentum) || !(0.0..=1.0).contains(&self.dampening) {
            return Err("optimizer.momentum must be in [0, 1), dampening in [0, 1]".into());
        }
        let betas = (0.0..1.0).contains(&self.beta1) && (0.0..1.0).contains(&self.beta2);
        if !(betas && self.epsilon > 0.0 && self.epsilon.is_finite()) {
            return Err("optimizer.beta1 and beta2 must be in [0, 1), epsilon positive".into());
        }
        let non_negative = |v: f64| v >= 0.0 && v.is_finite();
        if !non_negative(self.weight_decay) || !non_negative(self.grad_clip_norm) {
            return Err(
                "optimizer.weight_decay and grad_clip_norm must be non-negative (0: off)".into(),
            );
        }
        Ok(())
    }
}

/// `[optimizer]` as written: what is left out takes the network's default.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Written {
    kind: Option<OptimizerKind>,
    lr: Option<f64>,
    lr_steps: Option<Vec<(usize, f64)>>,
    momentum: Option<f64>,
    dampening: Option<f64>,
    nesterov: Option<bool>,
    weight_decay: Option<f64>,
    beta1: Option<f64>,
    beta2: Option<f64>,
    epsilon: Option<f64>,
    grad_clip_norm: Option<f64>,
}

/// Reads `[optimizer]` over `defaults` (the network's recipe): for
/// `#[serde(deserialize_with = ...)]` in a network's training config.
pub(crate) fn deserialize_over<'de, D: Deserializer<'de>>(
    deserializer: D,
    defaults: OptimizerConfig,
) -> Result<OptimizerConfig, D::Error> {
    let w = Written::deserialize(deserializer)?;
    let d = defaults;
    Ok(OptimizerConfig {
        kind: w.kind.unwrap_or(d.kind),
        lr: w.lr.unwrap_or(d.lr),
        lr_steps: w.lr_steps.unwrap_or(d.lr_steps),
        momentum: w.momentum.unwrap_or(d.momentum),
        dampening: w.dampening.unwrap_or(d.dampening),
        nesterov: w.nesterov.unwrap_or(d.nesterov),
        weight_decay: w.weight_decay.unwrap_or(d.weight_decay),
        beta1: w.beta1.unwrap_or(d.beta1),
        beta2: w.beta2.unwrap_or(d.beta2),
        epsilon: w.epsilon.unwrap_or(d.epsilon),
        grad_clip_norm: w.grad_clip_norm.unwrap_or(d.grad_clip_norm),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Deserialize)]
    struct Adam {
        #[serde(default = "adam", deserialize_with = "adam_over")]
        optimizer: OptimizerConfig,
    }
    fn adam() -> OptimizerConfig {
        OptimizerConfig::adam(1e-3)
    }
    fn adam_over<'de, D: Deserializer<'de>>(d: D) -> Result<OptimizerConfig, D::Error> {
        deserialize_over(d, adam())
    }

    #[test]
    fn left_out_keys_take_the_networks_defaults() {
        let a: Adam = toml::from_str("").unwrap();
        assert_eq!(a.optimizer, adam());
        let a: Adam =
            toml::from_str("[optimizer]\nlr = 0.0002\nlr_steps = [[14, 0.00007]]\n").unwrap();
        assert_eq!(a.optimizer.kind, OptimizerKind::Adam);
        assert_eq!(
            (a.optimizer.grad_clip_norm, a.optimizer.weight_decay),
            (1.0, 0.0)
        );
        assert_eq!(
            (a.optimizer.lr_at(13), a.optimizer.lr_at(14)),
            (0.0002, 0.00007)
        );
        let e = toml::from_str::<Adam>("[optimizer]\nlearning_rate = 3\n")
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(e.contains("learning_rate"), "{e}");
        let p = OptimizerConfig::sgd_paper();
        assert_eq!(
            (p.lr_at(0), p.lr_at(19), p.lr_at(20), p.lr_at(500)),
            (0.1, 0.1, 0.01, 0.01)
        );
        assert!(
            OptimizerConfig {
                grad_clip_norm: f64::NAN,
                ..p
            }
            .validate()
            .is_err()
        );
    }
}
