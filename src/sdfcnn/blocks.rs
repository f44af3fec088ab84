//! SDFCNN building blocks (Fig. 6, Table 13): convbnrelu, the MobileNetV2 inverted-residual
//! block and Light-Weight RefineNet's chained residual pooling (CRP).

use crate::nn::relu6;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::pool::{MaxPool2d, MaxPool2dConfig};
use burn::nn::{BatchNorm, BatchNormConfig, PaddingConfig2d};
use burn::prelude::*;

use crate::nn::{ShapeTrace, batch_norm, conv2d, max_pool2d};

/// Bias-free convolution with `padding = kernel / 2` (Table 13's 0 for 1×1, 1 for 3×3).
pub(crate) fn conv(
    channels: [usize; 2],
    kernel: usize,
    stride: usize,
    groups: usize,
    bias: bool,
    device: &Device,
) -> Conv2d {
    let p = kernel / 2;
    Conv2dConfig::new(channels, [kernel, kernel])
        .with_stride([stride, stride])
        .with_groups(groups)
        .with_padding(PaddingConfig2d::Explicit(p, p, p, p))
        .with_bias(bias)
        .init(device)
}

/// `method` text of a convolution for the shape summary.
pub(crate) fn describe(conv: &Conv2d) -> String {
    let [out, per_group, k, _] = conv.weight.dims();
    let [s, _] = conv.stride;
    let dw = if conv.groups > 1 { " dw" } else { "" };
    format!("conv {k}x{k}{dw} s{s} {}->{out}", per_group * conv.groups)
}

/// "convbnrelu" (Fig. 6 left): bias-free conv, batch norm, ReLU6 — or no activation for the
/// linear projection of an inverted-residual block.
#[derive(Module, Debug)]
pub struct ConvBn {
    pub(crate) conv: Conv2d,
    pub(super) bn: BatchNorm,
    pub(super) relu6: bool,
}

impl ConvBn {
    /// Conv `kernel`×`kernel` / `stride` / `groups`, BN, optionally ReLU6.
    pub fn new(
        channels: [usize; 2],
        kernel: usize,
        stride: usize,
        groups: usize,
        relu6: bool,
        device: &Device,
    ) -> Self {
        Self {
            conv: conv(channels, kernel, stride, groups, false, device),
            bn: BatchNormConfig::new(channels[1]).init(device),
            relu6,
        }
    }

    /// Applies conv, BN and the activation.
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let x = batch_norm(&self.bn, conv2d(&self.conv, x));
        if self.relu6 { relu6(x) } else { x }
    }

    /// [`Self::forward`], recording the batch norm's input statistics in `probes`.
    pub fn forward_probe(&self, x: Tensor<4>, name: &str, probes: &mut Vec<BnProbe>) -> Tensor<4> {
        let y = conv2d(&self.conv, x);
        let [n, c, h, w] = y.dims();
        let batch_mean = y
            .clone()
            .swap_dims(0, 1)
            .reshape([c, n * h * w])
            .mean_dim(1)
            .reshape([c]);
        probes.push(BnProbe {
            name: name.to_string(),
            batch_mean: to_vec(batch_mean),
            running_mean: to_vec(self.bn.running_mean.value()),
        });
        let y = batch_norm(&self.bn, y);
        if self.relu6 { relu6(y) } else { y }
    }

    /// The identity: 1×1 identity weights and a fresh batch norm (γ 1, β 0, mean 0, variance 1).
    fn into_identity(self) -> Self {
        let [c, _, _, _] = self.conv.weight.dims();
        let device = self.conv.weight.device();
        let mut conv = self.conv;
        conv.weight = super::imagenet::identity_1x1(conv.weight);
        Self {
            conv,
            bn: BatchNormConfig::new(c).init(&device),
            relu6: self.relu6,
        }
    }

    /// Summary text: the convolution and the activation.
    pub fn describe(&self) -> String {
        let act = if self.relu6 { "BN ReLU6" } else { "BN" };
        format!("{} {act}", describe(&self.conv))
    }
}

/// MobileNetV2 inverted-residual "block" (Fig. 6 middle): 1×1 expansion conv-BN-ReLU6,
/// depthwise 3×3 conv-BN-ReLU6, 1×1 projection conv-BN (linear), plus the input when the stride
/// is 1 and the channel count is unchanged.
#[derive(Module, Debug)]
pub struct InvertedResidual {
    pub(super) expand: ConvBn,
    pub(super) depthwise: ConvBn,
    pub(super) project: ConvBn,
    pub(super) residual: bool,
}

impl InvertedResidual {
    /// Block `in → in·expansion → out` with the depthwise stride `stride`.
    pub fn new(input: usize, output: usize, expansion: usize, stride: usize, d: &Device) -> Self {
        let hidden = input * expansion;
        Self {
            expand: ConvBn::new([input, hidden], 1, 1, 1, true, d),
            depthwise: ConvBn::new([hidden, hidden], 3, stride, hidden, true, d),
            project: ConvBn::new([hidden, output], 1, 1, 1, false, d),
            residual: stride == 1 && input == output,
        }
    }

    /// Runs the block; `names` are the table names of its three convolutions.
    pub fn forward_traced(
        &self,
        x: Tensor<4>,
        trace: &mut ShapeTrace,
        names: [String; 3],
    ) -> Tensor<4> {
        let [n_expand, n_dw, n_project] = names;
        let y = self.expand.forward(x.clone());
        trace.record(n_expand, self.expand.describe(), &y);
        let y = self.depthwise.forward(y);
        trace.record(n_dw, self.depthwise.describe(), &y);
        let y = self.project.forward(y);
        let add = if self.residual { " + residual" } else { "" };
        trace.record(n_project, format!("{}{add}", self.project.describe()), &y);
        if self.residual { y + x } else { y }
    }
}

/// The per-channel mean of a batch norm's input over a batch, beside the running mean it
/// holds: with trained weights in the right layers the two agree (see `imagenet.rs`).
#[derive(Debug, Clone, PartialEq)]
pub struct BnProbe {
    /// Which batch norm (`layer3.blocks.1.depthwise`).
    pub name: String,
    /// Mean of each input channel over the batch and the pixels.
    pub batch_mean: Vec<f32>,
    /// The stored running mean.
    pub running_mean: Vec<f32>,
}

fn to_vec(t: Tensor<1>) -> Vec<f32> {
    t.into_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .unwrap_or_default()
}

impl InvertedResidual {
    /// Runs the block, recording each batch norm's input statistics.
    fn forward_probe(&self, x: Tensor<4>, name: &str, probes: &mut Vec<BnProbe>) -> Tensor<4> {
        let y = self
            .expand
            .forward_probe(x.clone(), &format!("{name}.expand"), probes);
        let y = self
            .depthwise
            .forward_probe(y, &format!("{name}.depthwise"), probes);
        let y = self
            .project
            .forward_probe(y, &format!("{name}.project"), probes);
        if self.residual { y + x } else { y }
    }
}

/// One encoder layer (Fig. 6 right, Table 4): a chain of inverted-residual blocks.
#[derive(Module, Debug)]
pub struct Stage {
    pub(super) blocks: Vec<InvertedResidual>,
}

impl Stage {
    /// `blocks` blocks `in → out`, the first with `stride`, the rest with stride 1.
    pub fn new(
        input: usize,
        output: usize,
        expansion: usize,
        blocks: usize,
        stride: usize,
        d: &Device,
    ) -> Self {
        let blocks = (0..blocks)
            .map(|i| {
                let (cin, s) = if i == 0 { (input, stride) } else { (output, 1) };
                InvertedResidual::new(cin, output, expansion, s, d)
            })
            .collect();
        Self { blocks }
    }

    /// Runs the blocks, naming their convolutions `{prefix}_{first}`, `{prefix}_{first+1}`, …
    pub fn forward_traced(
        &self,
        mut x: Tensor<4>,
        trace: &mut ShapeTrace,
        prefix: &str,
        first: usize,
    ) -> Tensor<4> {
        for (b, block) in self.blocks.iter().enumerate() {
            let names = std::array::from_fn(|k| format!("{prefix}_{}", first + 3 * b + k));
            x = block.forward_traced(x, trace, names);
        }
        x
    }

    /// Runs the blocks, recording every batch norm's input statistics under `name.blocks.B`.
    pub fn forward_probe(
        &self,
        mut x: Tensor<4>,
        name: &str,
        probes: &mut Vec<BnProbe>,
    ) -> Tensor<4> {
        for (b, block) in self.blocks.iter().enumerate() {
            x = block.forward_probe(x, &format!("{name}.blocks.{b}"), probes);
        }
        x
    }

    /// The stage with its first block's expansion made the identity (for a `t = 1` block that
    /// ImageNet weights have no expansion for).
    pub fn with_identity_first_expansion(mut self) -> Self {
        if let Some(first) = self.blocks.first_mut() {
            first.expand = first.expand.clone().into_identity();
        }
        self
    }

    /// Number of blocks.
    pub fn num_blocks(&self) -> usize {
        self.blocks.len()
    }
}

/// How the stages of a [`Crp`] are named in the summary.
pub(crate) enum CrpNames<'a> {
    /// Pool and conv numbered alternately from `first` (`Layer7_16` pool, `Layer7_17` conv…).
    Interleaved(&'a str, usize),
    /// Only convs numbered, pools as `{prefix}_{k}:pool` (`Layer10_1:pool`, `Layer10_1`…).
    ConvsOnly(&'a str),
}

impl CrpNames<'_> {
    fn name(&self, stage: usize, pool: bool) -> String {
        match *self {
            Self::Interleaved(prefix, first) => {
                format!("{prefix}_{}", first + 2 * stage + usize::from(!pool))
            }
            Self::ConvsOnly(prefix) if pool => format!("{prefix}_{}:pool", stage + 1),
            Self::ConvsOnly(prefix) => format!("{prefix}_{}", stage + 1),
        }
    }
}

/// Light-Weight RefineNet chained residual pooling: `top ← conv(maxpool₅ₓ₅(top))` for each
/// stage, `x ← x + top` (Table 13 Layer7_16–7_23, Layer9_1–9_8, Layer10_1–10_4).
#[derive(Module, Debug)]
pub struct Crp {
    pool: MaxPool2d,
    pub(super) convs: Vec<Conv2d>,
}

impl Crp {
    /// `stages` stages of bias-free 1×1 convs on `channels` channels, depthwise when `depthwise`.
    pub fn new(channels: usize, stages: usize, depthwise: bool, d: &Device) -> Self {
        let groups = if depthwise { channels } else { 1 };
        Self {
            pool: MaxPool2dConfig::new([5, 5])
                .with_strides([1, 1])
                .with_padding(PaddingConfig2d::Explicit(2, 2, 2, 2))
                .init(),
            convs: (0..stages)
                .map(|_| conv([channels, channels], 1, 1, groups, false, d))
                .collect(),
        }
    }

    pub(crate) fn forward_traced(
        &self,
        mut x: Tensor<4>,
        trace: &mut ShapeTrace,
        names: CrpNames,
    ) -> Tensor<4> {
        let mut top = x.clone();
        for (i, conv) in self.convs.iter().enumerate() {
            top = max_pool2d(&self.pool, top);
            trace.record(names.name(i, true), "max_pool 5x5 s1 p2", &top);
            top = conv2d(conv, top);
            trace.record(
                names.name(i, false),
                format!("{} (+ sum)", describe(conv)),
                &top,
            );
            x = x + top.clone();
        }
        x
    }
}
