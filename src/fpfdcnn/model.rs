//! FPFDCNN: feature-point detection and description network (Section IV-B, Fig. 3,
//! Appendix A Table 12).
//!
//! A shared encoder of six convolutions (L1–L6, ELU) reduces a grayscale image 16×. The
//! detector head (L7 3×3 ELU, L8 1×1 sigmoid) gives 256 = 16² per-cell probabilities that the
//! FP layer rearranges by pixel shuffle into a full-resolution probability map. The descriptor
//! head (L9 3×3 ELU, L10 1×1 linear) gives a 256-d coarse descriptor map that the FD layer
//! upsamples bilinearly to full resolution; [`Fpfdcnn::forward`] stops before FD so that the
//! descriptors can be sampled at the N keypoints only ([`crate::nn::sample_bilinear_at`]).
//!
//! Parameters (weights + biases): 3,025,248 with the default configuration.

use burn::nn::PaddingConfig2d;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::prelude::*;
use burn::tensor::activation::sigmoid;

use crate::nn::{
    SampleError, ShapeTrace, conv2d, elu, pixel_shuffle, resize_bilinear, sample_bilinear_at,
};

/// ELU slope of the negative part (Table 12, footnote 1: `a(eˣ − 1)`, `a = 1`).
const ELU_ALPHA: f64 = 1.0;

/// Configuration of [`Fpfdcnn`] (Table 12).
#[derive(Config, Debug)]
pub struct FpfdcnnConfig {
    /// Descriptor length (L9/L10 channels).
    #[config(default = 256)]
    pub descriptor_dim: usize,
    /// Encoder cell size: the input is reduced `cell`× and the detector predicts `cell²`
    /// sub-pixel probabilities per cell. Fixed by four stride-2 convolutions.
    #[config(default = 16)]
    pub cell: usize,
    /// Channels of L1–L6.
    #[config(default = "[32, 64, 128, 128, 256, 256]")]
    pub encoder_channels: [usize; 6],
    /// Channels of the detector's hidden layer L7.
    #[config(default = 256)]
    pub detector_dim: usize,
}

/// Errors at the [`Fpfdcnn`] API boundary.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum FpfdcnnError {
    /// The input is not `[N, 1, H, W]`.
    #[error("FPFDCNN expects grayscale [N, 1, H, W] input, got {0} channels")]
    Channels(usize),
    /// `H` or `W` is zero or not divisible by the cell size.
    #[error("FPFDCNN input {height}x{width} must be non-empty and divisible by {cell}")]
    Size {
        /// Input height.
        height: usize,
        /// Input width.
        width: usize,
        /// Cell size.
        cell: usize,
    },
    /// The configuration cannot be built.
    #[error("invalid FPFDCNN config: {0}")]
    Config(String),
    /// Keypoint descriptor sampling failed.
    #[error(transparent)]
    Sample(#[from] SampleError),
    /// The descriptor tensor could not be read back as `f32`.
    #[error("reading descriptors: {0}")]
    Data(String),
}

impl From<FpfdcnnError> for crate::error::Error {
    fn from(e: FpfdcnnError) -> Self {
        crate::error::Error::wrap(e)
    }
}

/// FPFDCNN outputs before the FD layer.
#[derive(Debug, Clone)]
pub struct FpfdcnnOutput {
    /// FP: keypoint probability map, `[N, 1, H, W]`.
    pub prob: Tensor<4>,
    /// L8 before its sigmoid: per-cell logits of the `cell²` sub-pixels, `[N, cell², H/cell,
    /// W/cell]` (the training loss's localisation term reads them).
    pub logits: Tensor<4>,
    /// L10: coarse descriptors, `[N, descriptor_dim, H/cell, W/cell]`.
    pub descriptors: Tensor<4>,
}

/// FPFDCNN model (Table 12).
#[derive(Module, Debug)]
pub struct Fpfdcnn {
    /// L1: conv 4×4 s2 p1, 1→32.
    l1: Conv2d,
    /// L2: conv 4×4 s2 p1, 32→64.
    l2: Conv2d,
    /// L3: conv 3×3 s1 p1, 64→128.
    l3: Conv2d,
    /// L4: conv 4×4 s2 p1, 128→128.
    l4: Conv2d,
    /// L5: conv 3×3 s1 p1, 128→256.
    l5: Conv2d,
    /// L6: conv 4×4 s2 p1, 256→256.
    l6: Conv2d,
    /// L7: detector conv 3×3 s1 p1, 256→256, ELU.
    l7: Conv2d,
    /// L8: detector conv 1×1, 256→cell², sigmoid.
    l8: Conv2d,
    /// L9: descriptor conv 3×3 s1 p1, 256→256, ELU.
    l9: Conv2d,
    /// L10: descriptor conv 1×1, 256→descriptor_dim, no activation.
    l10: Conv2d,
    /// Cell size of the FP pixel shuffle.
    cell: usize,
}

fn conv(channels: [usize; 2], kernel: usize, stride: usize, padding: usize, d: &Device) -> Conv2d {
    Conv2dConfig::new(channels, [kernel, kernel])
        .with_stride([stride, stride])
        .with_padding(PaddingConfig2d::Explicit(
            padding, padding, padding, padding,
        ))
        .init(d)
}

impl FpfdcnnConfig {
    /// Builds the network on `device`.
    ///
    /// Fails if `cell` is not 16 (the encoder has four stride-2 layers) or a size is zero.
    pub fn init(&self, device: &Device) -> Result<Fpfdcnn, FpfdcnnError> {
        if self.cell != 16 {
            return Err(FpfdcnnError::Config(format!(
                "cell must be 16 (four stride-2 convolutions), got {}",
                self.cell
            )));
        }
        let zero = self.descriptor_dim == 0
            || self.detector_dim == 0
            || self.encoder_channels.contains(&0);
        if zero {
            return Err(FpfdcnnError::Config("zero channel count".into()));
        }
        let [c1, c2, c3, c4, c5, c6] = self.encoder_channels;
        Ok(Fpfdcnn {
            l1: conv([1, c1], 4, 2, 1, device),
            l2: conv([c1, c2], 4, 2, 1, device),
            l3: conv([c2, c3], 3, 1, 1, device),
            l4: conv([c3, c4], 4, 2, 1, device),
            l5: conv([c4, c5], 3, 1, 1, device),
            l6: conv([c5, c6], 4, 2, 1, device),
            l7: conv([c6, self.detector_dim], 3, 1, 1, device),
            l8: conv([self.detector_dim, self.cell * self.cell], 1, 1, 0, device),
            l9: conv([c6, self.descriptor_dim], 3, 1, 1, device),
            l10: conv([self.descriptor_dim, self.descriptor_dim], 1, 1, 0, device),
            cell: self.cell,
        })
    }
}

impl Fpfdcnn {
    /// Checks that `input` is `[N, 1, H, W]` with `H`, `W` non-zero multiples of the cell.
    pub fn check_input(&self, input: &Tensor<4>) -> Result<(), FpfdcnnError> {
        let [_, c, h, w] = input.dims();
        if c != 1 {
            return Err(FpfdcnnError::Channels(c));
        }
        if h == 0 || w == 0 || h % self.cell != 0 || w % self.cell != 0 {
            return Err(FpfdcnnError::Size {
                height: h,
                width: w,
                cell: self.cell,
            });
        }
        Ok(())
    }

    /// Runs the encoder, the FP layer and L10: probability map at full resolution and the coarse
    /// descriptor map (Table 12 up to FP and L10).
    pub fn forward(&self, input: Tensor<4>) -> Result<FpfdcnnOutput, FpfdcnnError> {
        self.forward_traced(input, &mut ShapeTrace::disabled())
    }

    /// [`Self::forward`], recording every layer's output shape in `trace`.
    pub fn forward_traced(
        &self,
        input: Tensor<4>,
        trace: &mut ShapeTrace,
    ) -> Result<FpfdcnnOutput, FpfdcnnError> {
        self.check_input(&input)?;
        trace.record("Image", "input", &input);
        let mut x = input;
        let encoder = [
            ("L1", &self.l1),
            ("L2", &self.l2),
            ("L3", &self.l3),
            ("L4", &self.l4),
            ("L5", &self.l5),
            ("L6", &self.l6),
        ];
        for (name, layer) in encoder {
            x = elu(conv2d(layer, x), ELU_ALPHA);
            if trace.is_enabled() {
                trace.record(name, describe(layer, "ELU"), &x);
            }
        }

        let det = elu(conv2d(&self.l7, x.clone()), ELU_ALPHA);
        trace.record("L7", describe(&self.l7, "ELU"), &det);
        let logits = conv2d(&self.l8, det);
        let det = sigmoid(logits.clone());
        trace.record("L8", describe(&self.l8, "sigmoid"), &det);
        let prob = pixel_shuffle(det, self.cell);
        trace.record("FP", format!("pixel shuffle x{}", self.cell), &prob);

        let desc = elu(conv2d(&self.l9, x), ELU_ALPHA);
        trace.record("L9", describe(&self.l9, "ELU"), &desc);
        let descriptors = conv2d(&self.l10, desc);
        trace.record("L10", describe(&self.l10, "linear"), &descriptors);
        Ok(FpfdcnnOutput {
            prob,
            logits,
            descriptors,
        })
    }

    /// FD layer: bilinear upsampling (`align_corners=False`) of the coarse descriptors to the
    /// input resolution `[height, width]`, `[N, D, H, W]`.
    pub fn full_descriptors(
        &self,
        descriptors: Tensor<4>,
        [height, width]: [usize; 2],
    ) -> Tensor<4> {
        resize_bilinear(descriptors, [height, width])
    }

    /// FD_FP layer (Table 12): descriptors of image `batch` at full-resolution keypoints
    /// `(x, y)`, bilinearly sampled from the coarse map `descriptors` (`[N, D, H/cell,
    /// W/cell]`) exactly as [`Self::full_descriptors`] would give them, without upsampling the
    /// whole map. Returns one `D`-vector per point.
    pub fn descriptors_at(
        &self,
        descriptors: &Tensor<4>,
        batch: usize,
        [height, width]: [usize; 2],
        points: &[(usize, usize)],
    ) -> Result<Vec<Vec<f32>>, FpfdcnnError> {
        let [n, d, hc, wc] = descriptors.dims();
        if batch >= n {
            return Err(FpfdcnnError::Data(format!("batch {batch} of {n}")));
        }
        let map = descriptors
            .clone()
            .slice(s![batch..batch + 1])
            .into_data()
            .try_to_vec::<f32>()
            .map_err(|e| FpfdcnnError::Data(format!("{e:?}")))?;
        let flat = sample_bilinear_at(&map, [d, hc, wc], [height, width], points)?;
        Ok(flat.chunks_exact(d).map(<[f32]>::to_vec).collect())
    }

    /// Cell size (16).
    pub fn cell(&self) -> usize {
        self.cell
    }

    /// L1-L10 in table order (for [`super::packed::PackedFpfdcnn`]).
    pub(crate) fn layers(&self) -> [&Conv2d; 10] {
        [
            &self.l1, &self.l2, &self.l3, &self.l4, &self.l5, &self.l6, &self.l7, &self.l8,
            &self.l9, &self.l10,
        ]
    }
}

fn describe(layer: &Conv2d, activation: &str) -> String {
    let [out, input, k, _] = layer.weight.dims();
    let [s, _] = layer.stride;
    format!("conv {k}x{k} s{s} {input}->{out}, {activation}")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::trainable_params;

    #[allow(deprecated)]
    fn ndarray() -> Device {
        Device::ndarray()
    }

    fn model(d: &Device) -> Fpfdcnn {
        FpfdcnnConfig::new()
            .init(d)
            .expect("default config is valid")
    }

    #[test]
    fn parameter_count_matches_table_12() {
        let m = model(&Device::flex());
        assert_eq!(m.num_params(), 3_025_248);
        assert_eq!(trainable_params(&m), 3_025_248);
    }

    #[test]
    fn output_shapes_small_input() {
        let d = ndarray();
        let m = model(&d);
        let out = m
            .forward(Tensor::zeros([2, 1, 64, 96], &d))
            .expect("valid input");
        assert_eq!(out.prob.dims(), [2, 1, 64, 96]);
        assert_eq!(out.descriptors.dims(), [2, 256, 4, 6]);
        let full = m.full_descriptors(out.descriptors, [64, 96]);
        assert_eq!(full.dims(), [2, 256, 64, 96]);
        let p = out.prob.into_data().try_to_vec::<f32>().expect("f32");
        assert!(p.iter().all(|v| (0.0..=1.0).contains(v)));
    }

    #[test]
    fn rejects_bad_inputs() {
        let d = Device::flex();
        let m = model(&d);
        assert_eq!(
            m.forward(Tensor::zeros([1, 1, 40, 48], &d)).err(),
            Some(FpfdcnnError::Size {
                height: 40,
                width: 48,
                cell: 16
            })
        );
        assert_eq!(
            m.forward(Tensor::zeros([1, 3, 32, 48], &d)).err(),
            Some(FpfdcnnError::Channels(3))
        );
        assert!(FpfdcnnConfig::new().with_cell(8).init(&d).is_err());
    }

    #[test]
    fn keypoint_descriptors_equal_full_upsampling() {
        let d = ndarray();
        let m = model(&d);
        let x = Tensor::<4>::random([1, 1, 32, 48], burn::tensor::Distribution::Default, &d);
        let out = m.forward(x).expect("valid input");
        let full = m
            .full_descriptors(out.descriptors.clone(), [32, 48])
            .into_data()
            .try_to_vec::<f32>()
            .expect("f32");
        let points = [(0, 0), (47, 31), (5, 17), (23, 8), (40, 1)];
        let sampled = m
            .descriptors_at(&out.descriptors, 0, [32, 48], &points)
            .expect("valid points");
        for (desc, &(x, y)) in sampled.iter().zip(&points) {
            assert_eq!(desc.len(), 256);
            for (c, v) in desc.iter().enumerate() {
                let want = full[c * 32 * 48 + y * 48 + x];
                assert!((v - want).abs() <= 1e-5);
            }
        }
        assert!(
            m.descriptors_at(&out.descriptors, 1, [32, 48], &points)
                .is_err()
        );
        assert!(matches!(
            m.descriptors_at(&out.descriptors, 0, [32, 48], &[(48, 0)]),
            Err(FpfdcnnError::Sample(_))
        ));
    }

    #[test]
    fn backward_reaches_first_layer() {
        let d = ndarray().autodiff();
        let m = model(&d);
        let x = Tensor::<4>::random([1, 1, 32, 32], burn::tensor::Distribution::Default, &d);
        let out = m.forward(x).expect("valid input");
        let full = m.full_descriptors(out.descriptors, [32, 32]);
        let loss = out.prob.mean() + full.powi_scalar(2).mean();
        let grads = loss.backward();
        let g = m.l1.weight.grad(&grads).expect("gradient of L1 weight");
        assert_eq!(g.dims(), [32, 1, 4, 4]);
        let g = g.into_data().try_to_vec::<f32>().expect("f32");
        assert!(g.iter().all(|v| v.is_finite()) && g.iter().any(|v| *v != 0.0));
    }
}
