//! Inference-only depthwise convolutions on channels-last images (MobileNetV2's 3×3 layers,
//! SDFCNN's depthwise 1×1 judge and CRP layers): each output pixel is a sum of `k²` input
//! pixels weighted channel by channel, a loop over contiguous channels that vectorises.

use super::nhwc::{Activation, Nhwc, NhwcView, activate, simd_fn};
use super::packed_conv::{ConvGeometry, PackError};
use rayon::prelude::*;

/// A depthwise convolution (one filter per channel) with its bias and activation.
#[derive(Debug, Clone)]
pub(crate) struct PackedDepthwise {
    c: usize,
    k: usize,
    stride: usize,
    padding: usize,
    /// `[k, k, c]`: tap `(ky, kx)` of every channel, contiguous.
    weight: Vec<f32>,
    bias: Vec<f32>,
    activation: Activation,
}

simd_fn! {
    /// `acc[i] += x[i]·w[i]`.
    fn multiply_add(acc: &mut [f32], x: &[f32], w: &[f32]) {
        for ((a, &p), &q) in acc.iter_mut().zip(x).zip(w) {
            *a += p * q;
        }
    }
}

impl PackedDepthwise {
    /// Packs row-major `[c, 1, k, k]` weights and a bias.
    pub fn from_weights(
        w: &[f32],
        bias: &[f32],
        g: ConvGeometry,
        activation: Activation,
    ) -> Result<Self, PackError> {
        let (c, k) = (g.cout, g.kernel);
        if g.groups != c || g.cin != 1 || w.len() != c * k * k || bias.len() != c || g.stride == 0 {
            return Err(PackError::Unsupported(format!("depthwise {g:?}")));
        }
        let mut weight = vec![0.0; k * k * c];
        for ch in 0..c {
            for t in 0..k * k {
                weight[t * c + ch] = w[ch * k * k + t];
            }
        }
        Ok(Self {
            c,
            k,
            stride: g.stride,
            padding: g.padding,
            weight,
            bias: bias.to_vec(),
            activation,
        })
    }

    /// The convolution of `x`, bias and activation included.
    pub fn forward(&self, x: &NhwcView) -> Result<Nhwc, PackError> {
        if x.c != self.c {
            return Err(PackError::Channels {
                got: x.c,
                expected: self.c,
            });
        }
        let (k, s, p) = (self.k, self.stride, self.padding);
        if x.h + 2 * p < k || x.w + 2 * p < k {
            return Err(PackError::Size { h: x.h, w: x.w });
        }
        let (oh, ow) = ((x.h + 2 * p - k) / s + 1, (x.w + 2 * p - k) / s + 1);
        let mut out = Nhwc::zeros(oh, ow, self.c);
        let c = self.c;
        out.data
            .par_chunks_mut(ow * c)
            .enumerate()
            .for_each(|(y, row)| {
                for (ox, acc) in row.chunks_exact_mut(c).enumerate() {
                    acc.copy_from_slice(&self.bias);
                    for ky in 0..k {
                        let Some(iy) = (y * s + ky).checked_sub(p).filter(|&i| i < x.h) else {
                            continue;
                        };
                        for kx in 0..k {
                            let Some(ix) = (ox * s + kx).checked_sub(p).filter(|&i| i < x.w) else {
                                continue;
                            };
                            let w = &self.weight[(ky * k + kx) * c..(ky * k + kx + 1) * c];
                            multiply_add(acc, x.pixel(iy, ix), w);
                        }
                    }
                }
                activate(row, self.activation);
            });
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::nhwc::{from_nchw, to_nchw};
    use crate::nn::packed_conv::read_conv;
    use burn::nn::PaddingConfig2d;
    use burn::nn::conv::Conv2dConfig;
    use burn::prelude::*;
    use rand::{RngExt, SeedableRng};

    #[test]
    fn matches_burn_depthwise_convolutions() {
        let d = Device::flex();
        for (c, k, s, [h, w]) in [(8, 3, 1, [7, 9]), (8, 3, 2, [7, 10]), (5, 1, 1, [3, 4])] {
            let p = k / 2;
            let conv = Conv2dConfig::new([c, c], [k, k])
                .with_groups(c)
                .with_stride([s, s])
                .with_padding(PaddingConfig2d::Explicit(p, p, p, p))
                .init(&d);
            let (wt, bias, g) = read_conv(&conv).unwrap();
            let packed = PackedDepthwise::from_weights(&wt, &bias, g, Activation::Relu6).unwrap();
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
            let x: Vec<f32> = (0..c * h * w)
                .map(|_| rng.random_range(-4.0..4.0))
                .collect();
            let got = packed.forward(&from_nchw(&x, [c, h, w]).view()).unwrap();
            let input = Tensor::<4>::from_data(TensorData::new(x, [1, c, h, w]), &d);
            let want = burn::tensor::activation::relu6(conv.forward(input));
            let [_, _, oh, ow] = want.dims();
            assert_eq!([got.h, got.w], [oh, ow]);
            let want = want.into_data().try_into_vec::<f32>().unwrap();
            for (a, b) in to_nchw(&got.view()).iter().zip(&want) {
                assert!((a - b).abs() < 1e-5, "{a} vs {b} (k {k}, stride {s})");
            }
        }
    }
}
