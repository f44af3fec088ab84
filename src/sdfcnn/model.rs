//! SDFCNN: joint semantic segmentation and depth estimation (Section IV-C, Fig. 5/6, Table 4,
//! Appendix B Table 13).
//!
//! Table 13 is MobileNetV2 + Light-Weight RefineNet as in Nekrasov et al. 2019 ("Real-time
//! joint semantic segmentation and depth estimation using asymmetric annotations"):
//!
//! * Layer0: bilinear resize of the RGB input (in `[0, 1]`) to 300×400, then eq. 15
//!   normalisation with mean (0.485, 0.456, 0.406) and std (0.229, 0.224, 0.225).
//! * Encoder: Layer1 conv 3×3 s2 3→32 BN ReLU6; inverted-residual layers (expansion, out,
//!   blocks, stride) Layer2 (1,16,1,1), Layer3 (6,24,2,2), Layer4 (6,32,3,2), Layer5
//!   (6,64,4,2), Layer6 (6,96,3,1), Layer7 (6,160,3,2) + (6,320,1,1).
//! * Decoder (Light-Weight RefineNet, bias-free 1×1 convs): Layer8 = CRP(relu(conv(l320) +
//!   conv(l160))) → adapt → up to l96 size; Layer9 = relu(conv(l96) + conv(l64) + that) → CRP →
//!   adapt → up to l32 size; Layer10 = relu(conv(l32) + that) → CRP → adapt → up to l24 size;
//!   Layer11 = relu(conv(l24) + that) → depthwise CRP; 256 channels at 1/4 of 300×400.
//! * Judge: seg = depthwise 1×1 + ReLU, seg1 = 1×1 256→classes (bias); depth = depthwise 1×1 +
//!   ReLU, depth1 = 3×3 256→1 (bias). Output: bilinear to the input size.
//!
//! Trainable parameters with the default configuration: 2,988,137 (BN γ/β counted, running
//! statistics not), as a PyTorch build of the same network counts.
//!
//! # Deviations from Table 13
//!
//! The table is garbled in places; where its numbers do not chain, the consistent MobileNetV2 /
//! Light-Weight RefineNet reading is used:
//!
//! 1. Layer3_7 is listed as 1×1×**32**×256; Layer3 has 24 channels, so it is 24→256.
//! 2. Layer4_10 is listed as 1×1×**64**×256; Layer4 has 32 channels, so it is 32→256.
//! 3. Layer5_9 is listed as 1×1×64×384; it is the projection 384→64 (its feature map is
//!    25×19×64).
//! 4. Every encoder row says "convbnrelu", including the 1×1 projections (Layer2_3, Layer3_3, …);
//!    MobileNetV2's projections are linear (conv + BN, no activation), and so are they here.
//! 5. ReLU6 is used in the encoder (MobileNetV2); the table only names the module "convbnrelu".
//! 6. Residual adds follow MobileNetV2 (stride 1 and equal channels); the table's Pre/Post_Layer
//!    sums (e.g. "Layer5_9+ Layer5_6+ Layer5_3") are read as that chain of residual adds.
//! 7. Layer9 (= Layer8 + Layer6_10 + Layer5_13), Layer10 and Layer11 are sums with no
//!    activation in the table; a ReLU follows each sum here, as after Layer7_15.
//! 8. Layer10_1–Layer10_4 are listed as four 1×1 convs without max pooling; the text says Layer10
//!    "has the same design idea as Layer8", so it is a CRP with 5×5 max pooling like Layer8/9.
//! 9. Layer11 has no CRP in the table (seg/depth take Layer11 directly); here Layer11 ends with
//!    Nekrasov et al.'s last CRP, whose four 1×1 convs are depthwise (4×256 parameters).
//! 10. seg1 lists bias 256; it has one bias per class (40).
//! 11. Pre_Layer references that point to the wrong row (Layer7_13 "Layer7_10", Layer9_2
//!     "Layer9_2", …) are read in table order.
//! 12. The text normalises (eq. 15) before the Layer0 resize; here the resize comes first (fewer
//!     pixels). Both orders give the same result: the interpolation weights sum to 1 and the
//!     normalisation is a per-channel affine map.
//! 13. Feature-map sizes are printed W×H in the table except Layer7 (10×13 is H×W). With
//!     padding 1 the sizes for 300×400 are exactly the table's: 150×200, 75×100, 38×50, 19×25,
//!     10×13 (H×W); no deviation.
//!
//! Differences from Nekrasov et al.'s code that follow the table instead: seg1 is 1×1 (theirs
//! 3×3) and the decoder/judge activations are ReLU (theirs ReLU6).

use burn::module::{ModuleVisitor, Param};
use burn::nn::conv::Conv2d;
use burn::optim::GradientsParams;
use burn::prelude::*;
use burn::tensor::activation::relu;

use super::blocks::{BnProbe, ConvBn, Crp, CrpNames, Stage, conv, describe};
use crate::nn::{ShapeTrace, conv2d, resize_bilinear};

/// Inverted-residual layers of the encoder, `(expansion, out_channels, blocks, stride)`:
/// Layer2 … Layer6, then Layer7's 160-channel part and its final 320-channel block.
pub(super) const ENCODER: [(usize, usize, usize, usize); 7] = [
    (1, 16, 1, 1),
    (6, 24, 2, 2),
    (6, 32, 3, 2),
    (6, 64, 4, 2),
    (6, 96, 3, 1),
    (6, 160, 3, 2),
    (6, 320, 1, 1),
];

/// Moves the gradients of the parameters it visits from one set to another.
struct MoveGrads<'a> {
    from: &'a mut GradientsParams,
    to: &'a mut GradientsParams,
}

impl ModuleVisitor for MoveGrads<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if let Some(g) = self.from.remove::<D>(param.id) {
            self.to.register::<D>(param.id, g);
        }
    }
}

/// Configuration of [`Sdfcnn`] (Table 13).
#[derive(Config, Debug)]
pub struct SdfcnnConfig {
    /// Semantic classes (seg1 output channels; NYUv2-40).
    #[config(default = 40)]
    pub num_classes: usize,
    /// Layer0 output size `[height, width]`.
    #[config(default = "[300, 400]")]
    pub inner_size: [usize; 2],
    /// Per-channel RGB mean of eq. 15.
    #[config(default = "[0.485, 0.456, 0.406]")]
    pub mean: [f32; 3],
    /// Per-channel RGB standard deviation of eq. 15.
    #[config(default = "[0.229, 0.224, 0.225]")]
    pub std: [f32; 3],
    /// Decoder width.
    #[config(default = 256)]
    pub decoder_dim: usize,
    /// Stages of each chained residual pooling.
    #[config(default = 4)]
    pub crp_stages: usize,
}

/// Errors at the [`Sdfcnn`] API boundary.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SdfcnnError {
    /// The input is not `[N, 3, H, W]`.
    #[error("SDFCNN expects RGB [N, 3, H, W] input, got {0} channels")]
    Channels(usize),
    /// An empty input.
    #[error("SDFCNN input {height}x{width} is empty")]
    Empty {
        /// Input height.
        height: usize,
        /// Input width.
        width: usize,
    },
    /// The configuration cannot be built.
    #[error("invalid SDFCNN config: {0}")]
    Config(String),
}

impl From<SdfcnnError> for crate::error::Error {
    fn from(e: SdfcnnError) -> Self {
        crate::error::Error::wrap(e)
    }
}

/// SDFCNN predictions.
#[derive(Debug, Clone)]
pub struct SdfcnnOutput {
    /// Segmentation logits, `[N, classes, H, W]`.
    pub seg: Tensor<4>,
    /// Depth, `[N, 1, H, W]`.
    pub depth: Tensor<4>,
}

/// SDFCNN model (Table 13).
#[derive(Module, Debug)]
pub struct Sdfcnn {
    pub(super) layer1: ConvBn,
    pub(super) layer2: Stage,
    pub(super) layer3: Stage,
    pub(super) layer4: Stage,
    pub(super) layer5: Stage,
    pub(super) layer6: Stage,
    /// Layer7's three 160-channel blocks (Layer7_1–7_9).
    pub(super) layer7: Stage,
    /// Layer7's last, 320-channel block (Layer7_10–7_12).
    pub(super) layer7_320: Stage,
    /// Layer7_13: 320→256.
    pub(super) conv8: Conv2d,
    /// Layer7_14: 160→256.
    pub(super) conv7: Conv2d,
    /// Layer6_10: 96→256.
    pub(super) conv6: Conv2d,
    /// Layer5_13: 64→256.
    pub(super) conv5: Conv2d,
    /// Layer4_10: 32→256.
    pub(super) conv4: Conv2d,
    /// Layer3_7: 24→256.
    pub(super) conv3: Conv2d,
    pub(super) crp4: Crp,
    pub(super) crp3: Crp,
    pub(super) crp2: Crp,
    pub(super) crp1: Crp,
    /// Layer7_24.
    pub(super) adapt4: Conv2d,
    /// Layer9_9.
    pub(super) adapt3: Conv2d,
    /// Layer10_5.
    pub(super) adapt2: Conv2d,
    /// seg: depthwise 1×1.
    pub(super) pre_seg: Conv2d,
    /// seg1: 1×1 → classes.
    pub(super) seg: Conv2d,
    /// depth: depthwise 1×1.
    pub(super) pre_depth: Conv2d,
    /// depth1: 3×3 → 1.
    pub(super) depth: Conv2d,
    pub(super) inner_size: [usize; 2],
    pub(super) mean: [f32; 3],
    pub(super) std: [f32; 3],
}

impl SdfcnnConfig {
    /// Builds the network on `device`.
    pub fn init(&self, device: &Device) -> Result<Sdfcnn, SdfcnnError> {
        let d = self.decoder_dim;
        if self.num_classes == 0 || d == 0 || self.inner_size.contains(&0) {
            return Err(SdfcnnError::Config("zero size".into()));
        }
        if self.std.iter().any(|s| !s.is_normal()) {
            return Err(SdfcnnError::Config(format!(
                "std {:?} must be non-zero",
                self.std
            )));
        }
        let mut input = 32;
        let mut stages = ENCODER.iter().map(|&(t, c, n, s)| {
            let stage = Stage::new(input, c, t, n, s, device);
            input = c;
            stage
        });
        let mut next = || stages.next().expect("ENCODER has seven layers");
        let c1x1 = |cin: usize| conv([cin, d], 1, 1, 1, false, device);
        let crp = |depthwise| Crp::new(d, self.crp_stages, depthwise, device);
        Ok(Sdfcnn {
            layer1: ConvBn::new([3, 32], 3, 2, 1, true, device),
            layer2: next(),
            layer3: next(),
            layer4: next(),
            layer5: next(),
            layer6: next(),
            layer7: next(),
            layer7_320: next(),
            conv8: c1x1(320),
            conv7: c1x1(160),
            conv6: c1x1(96),
            conv5: c1x1(64),
            conv4: c1x1(32),
            conv3: c1x1(24),
            crp4: crp(false),
            crp3: crp(false),
            crp2: crp(false),
            crp1: crp(true),
            adapt4: c1x1(d),
            adapt3: c1x1(d),
            adapt2: c1x1(d),
            pre_seg: conv([d, d], 1, 1, d, false, device),
            seg: conv([d, self.num_classes], 1, 1, 1, true, device),
            pre_depth: conv([d, d], 1, 1, d, false, device),
            depth: conv([d, 1], 3, 1, 1, true, device),
            inner_size: self.inner_size,
            mean: self.mean,
            std: self.std,
        })
    }
}

impl Sdfcnn {
    /// Takes the encoder's gradients (Layer1 … Layer7, MobileNetV2's part, which `init` can
    /// take from ImageNet) out of `grads`; the decoder's and the judge layers' stay.
    pub fn take_encoder_grads(&self, grads: &mut GradientsParams) -> GradientsParams {
        let mut encoder = GradientsParams::new();
        let mut mover = MoveGrads {
            from: grads,
            to: &mut encoder,
        };
        self.layer1.visit(&mut mover);
        for stage in [
            &self.layer2,
            &self.layer3,
            &self.layer4,
            &self.layer5,
            &self.layer6,
            &self.layer7,
            &self.layer7_320,
        ] {
            stage.visit(&mut mover);
        }
        encoder
    }

    /// Checks that `input` is a non-empty `[N, 3, H, W]` batch.
    pub fn check_input(&self, input: &Tensor<4>) -> Result<(), SdfcnnError> {
        let [_, c, h, w] = input.dims();
        if c != 3 {
            return Err(SdfcnnError::Channels(c));
        }
        if h == 0 || w == 0 {
            return Err(SdfcnnError::Empty {
                height: h,
                width: w,
            });
        }
        Ok(())
    }

    /// Segmentation logits and depth at the input resolution (Table 13 out_seg, out_depth).
    pub fn forward(&self, input: Tensor<4>) -> Result<SdfcnnOutput, SdfcnnError> {
        self.forward_traced(input, &mut ShapeTrace::disabled())
    }

    /// Segmentation logits and depth at the judge layer's resolution, 1/4 of the inner size
    /// (75×100 by default; Table 13 seg1, depth1).
    pub fn forward_quarter(&self, input: Tensor<4>) -> Result<SdfcnnOutput, SdfcnnError> {
        self.forward_quarter_traced(input, &mut ShapeTrace::disabled())
    }

    /// [`Self::forward`], recording every layer's output shape in `trace`.
    pub fn forward_traced(
        &self,
        input: Tensor<4>,
        trace: &mut ShapeTrace,
    ) -> Result<SdfcnnOutput, SdfcnnError> {
        let [_, _, h, w] = input.dims();
        let out = self.forward_quarter_traced(input, trace)?;
        let seg = resize_bilinear(out.seg, [h, w]);
        trace.record("out_seg", "bilinear", &seg);
        let depth = resize_bilinear(out.depth, [h, w]);
        trace.record("out_depth", "bilinear", &depth);
        Ok(SdfcnnOutput { seg, depth })
    }

    /// [`Self::forward_quarter`], recording every layer's output shape in `trace`.
    pub fn forward_quarter_traced(
        &self,
        input: Tensor<4>,
        trace: &mut ShapeTrace,
    ) -> Result<SdfcnnOutput, SdfcnnError> {
        self.check_input(&input)?;
        trace.record("Image", "input", &input);
        let x = self.layer0(input);
        trace.record("Layer0", "bilinear + normalise (eq. 15)", &x);

        // Encoder (Table 4): Layer1 … Layer7.
        let x = self.layer1.forward(x);
        trace.record("Layer1", self.layer1.describe(), &x);
        let x = self.layer2.forward_traced(x, trace, "Layer2", 1);
        let l24 = self.layer3.forward_traced(x, trace, "Layer3", 1);
        let l32 = self.layer4.forward_traced(l24.clone(), trace, "Layer4", 1);
        let l64 = self.layer5.forward_traced(l32.clone(), trace, "Layer5", 1);
        let l96 = self.layer6.forward_traced(l64.clone(), trace, "Layer6", 1);
        let l160 = self.layer7.forward_traced(l96.clone(), trace, "Layer7", 1);
        let first_320 = 1 + 3 * self.layer7.num_blocks();
        let l320 = self
            .layer7_320
            .forward_traced(l160.clone(), trace, "Layer7", first_320);

        // Layer8: Layer7_13 … Layer7_25.
        let a = self.traced_conv(&self.conv8, l320, trace, "Layer7_13");
        let b = self.traced_conv(&self.conv7, l160, trace, "Layer7_14");
        let x = relu(a + b);
        trace.record("Layer7_15", "ReLU(sum)", &x);
        let x = self
            .crp4
            .forward_traced(x, trace, CrpNames::Interleaved("Layer7", 16));
        let x = self.traced_conv(&self.adapt4, x, trace, "Layer7_24");
        let x = resize_to(x, &l96);
        trace.record("Layer7_25", "bilinear", &x);

        // Layer9.
        let a = self.traced_conv(&self.conv6, l96, trace, "Layer6_10");
        let b = self.traced_conv(&self.conv5, l64, trace, "Layer5_13");
        let x = relu(a + b + x);
        trace.record("Layer9", "ReLU(sum)", &x);
        let x = self
            .crp3
            .forward_traced(x, trace, CrpNames::Interleaved("Layer9", 1));
        let x = self.traced_conv(&self.adapt3, x, trace, "Layer9_9");
        let x = resize_to(x, &l32);
        trace.record("Layer9_10", "bilinear", &x);

        // Layer10.
        let a = self.traced_conv(&self.conv4, l32, trace, "Layer4_10");
        let x = relu(a + x);
        trace.record("Layer10", "ReLU(sum)", &x);
        let x = self
            .crp2
            .forward_traced(x, trace, CrpNames::ConvsOnly("Layer10"));
        let x = self.traced_conv(&self.adapt2, x, trace, "Layer10_5");
        let x = resize_to(x, &l24);
        trace.record("Layer10_6", "bilinear", &x);

        // Layer11.
        let a = self.traced_conv(&self.conv3, l24, trace, "Layer3_7");
        let x = relu(a + x);
        trace.record("Layer11", "ReLU(sum)", &x);
        let x = self
            .crp1
            .forward_traced(x, trace, CrpNames::ConvsOnly("Layer11"));

        // Judge.
        let s = relu(conv2d(&self.pre_seg, x.clone()));
        trace.record("seg", format!("{} ReLU", describe(&self.pre_seg)), &s);
        let seg = self.traced_conv(&self.seg, s, trace, "seg1");
        let dp = relu(conv2d(&self.pre_depth, x));
        trace.record("depth", format!("{} ReLU", describe(&self.pre_depth)), &dp);
        let depth = self.traced_conv(&self.depth, dp, trace, "depth1");
        Ok(SdfcnnOutput { seg, depth })
    }

    /// Layer0: resize to the inner size, then eq. 15 normalisation.
    fn layer0(&self, input: Tensor<4>) -> Tensor<4> {
        let device = input.device();
        let x = resize_bilinear(input, self.inner_size);
        let mean = Tensor::<1>::from_floats(self.mean, &device).reshape([1, 3, 1, 1]);
        let inv_std = self.std.map(|s| 1.0 / s);
        let inv_std = Tensor::<1>::from_floats(inv_std, &device).reshape([1, 3, 1, 1]);
        (x - mean) * inv_std
    }

    fn traced_conv(
        &self,
        conv: &Conv2d,
        x: Tensor<4>,
        trace: &mut ShapeTrace,
        name: &str,
    ) -> Tensor<4> {
        let y = conv2d(conv, x);
        if trace.is_enabled() {
            trace.record(name, describe(conv), &y);
        }
        y
    }

    /// Runs Layer0 … Layer7 on `input` and returns, for each of the encoder's 52 batch norms,
    /// the per-channel mean of its input over the batch beside its stored running mean.
    pub fn encoder_bn_probe(&self, input: Tensor<4>) -> Result<Vec<BnProbe>, SdfcnnError> {
        self.check_input(&input)?;
        let mut probes = Vec::new();
        let x = self.layer0(input);
        let x = self.layer1.forward_probe(x, "layer1", &mut probes);
        let stages = [
            ("layer2", &self.layer2),
            ("layer3", &self.layer3),
            ("layer4", &self.layer4),
            ("layer5", &self.layer5),
            ("layer6", &self.layer6),
            ("layer7", &self.layer7),
            ("layer7_320", &self.layer7_320),
        ];
        stages.iter().fold(x, |x, (name, stage)| {
            stage.forward_probe(x, name, &mut probes)
        });
        Ok(probes)
    }

    /// The model with Layer2's expansion convolution made the identity (see `imagenet.rs`).
    pub(super) fn with_identity_layer2_expansion(mut self) -> Self {
        self.layer2 = self.layer2.with_identity_first_expansion();
        self
    }

    /// Inner (Layer0) size `[height, width]`.
    pub fn inner_size(&self) -> [usize; 2] {
        self.inner_size
    }
}

/// Bilinear resize of `x` to the spatial size of `like`.
fn resize_to(x: Tensor<4>, like: &Tensor<4>) -> Tensor<4> {
    let [_, _, h, w] = like.dims();
    resize_bilinear(x, [h, w])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::trainable_params;

    #[allow(deprecated)]
    fn ndarray() -> Device {
        Device::ndarray()
    }

    /// A small inner size keeps the tests fast.
    fn small(d: &Device) -> Sdfcnn {
        SdfcnnConfig::new()
            .with_inner_size([64, 96])
            .init(d)
            .expect("valid config")
    }

    #[test]
    fn trainable_parameter_count() {
        let m = SdfcnnConfig::new()
            .init(&Device::flex())
            .expect("valid config");
        assert_eq!(trainable_params(&m), 2_988_137);
        // Running mean and variance of the 52 batch norms (15,808 channels).
        assert_eq!(m.num_params() - trainable_params(&m), 2 * 15_808);
    }

    #[test]
    fn output_shapes_small_input() {
        let d = ndarray();
        let m = small(&d);
        let x = Tensor::<4>::random([2, 3, 48, 80], burn::tensor::Distribution::Default, &d);
        let q = m.forward_quarter(x.clone()).expect("valid input");
        assert_eq!(q.seg.dims(), [2, 40, 16, 24]);
        assert_eq!(q.depth.dims(), [2, 1, 16, 24]);
        let out = m.forward(x).expect("valid input");
        assert_eq!(out.seg.dims(), [2, 40, 48, 80]);
        assert_eq!(out.depth.dims(), [2, 1, 48, 80]);
    }

    #[test]
    fn traced_shapes_follow_table_13() {
        let d = Device::flex();
        let m = SdfcnnConfig::new().init(&d).expect("valid config");
        // Layer0 resizes any input to 300×400, so a small input gives the table's sizes.
        let mut trace = ShapeTrace::enabled();
        m.forward_traced(Tensor::zeros([1, 3, 24, 32], &d), &mut trace)
            .expect("valid input");
        let shape = |name: &str| {
            trace
                .layers()
                .iter()
                .find(|l| l.name == name)
                .map(|l| l.shape.clone())
                .unwrap_or_else(|| panic!("{name} not traced"))
        };
        assert_eq!(shape("Layer0"), [1, 3, 300, 400]);
        assert_eq!(shape("Layer1"), [1, 32, 150, 200]);
        assert_eq!(shape("Layer3_6"), [1, 24, 75, 100]);
        assert_eq!(shape("Layer4_9"), [1, 32, 38, 50]);
        assert_eq!(shape("Layer5_9"), [1, 64, 19, 25]);
        assert_eq!(shape("Layer6_9"), [1, 96, 19, 25]);
        assert_eq!(shape("Layer7_12"), [1, 320, 10, 13]);
        assert_eq!(shape("Layer7_25"), [1, 256, 19, 25]);
        assert_eq!(shape("Layer9_10"), [1, 256, 38, 50]);
        assert_eq!(shape("Layer10_6"), [1, 256, 75, 100]);
        assert_eq!(shape("seg1"), [1, 40, 75, 100]);
        assert_eq!(shape("depth1"), [1, 1, 75, 100]);
        assert_eq!(shape("out_seg"), [1, 40, 24, 32]);
    }

    #[test]
    fn rejects_bad_inputs() {
        let d = Device::flex();
        let m = small(&d);
        assert_eq!(
            m.forward(Tensor::zeros([1, 1, 16, 16], &d)).err(),
            Some(SdfcnnError::Channels(1))
        );
        assert!(
            SdfcnnConfig::new()
                .with_std([0.0, 1.0, 1.0])
                .init(&d)
                .is_err()
        );
    }

    #[test]
    fn backward_reaches_first_layer() {
        let d = ndarray().autodiff();
        let m = small(&d);
        let x = Tensor::<4>::random([2, 3, 40, 56], burn::tensor::Distribution::Default, &d);
        let out = m.forward(x).expect("valid input");
        let loss = out.seg.powi_scalar(2).mean() + out.depth.abs().mean();
        let grads = loss.backward();
        let g = m
            .layer1
            .conv
            .weight
            .grad(&grads)
            .expect("gradient of Layer1 weight");
        assert_eq!(g.dims(), [32, 3, 3, 3]);
        let g = g.into_data().try_to_vec::<f32>().expect("f32");
        assert!(g.iter().all(|v| v.is_finite()) && g.iter().any(|v| *v != 0.0));
    }
}
