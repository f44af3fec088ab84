//! FPFDCNN inference on the CPU with packed NHWC convolutions (`crate::nn::packed_conv`):
//! the same network as [`Fpfdcnn::forward`] (Table 12), weights packed once when the detector
//! is built, no autodiff graph and no layout change between layers. `slam`, `eval matching`
//! and the detector use it on the CPU backends; GPUs keep Burn's kernels.

use super::model::{Fpfdcnn, FpfdcnnError};
use crate::nn::packed_conv::{Activation, NhwcView, PackError, PackedConv, Scratch};
use std::sync::Mutex;

/// The output of one image.
#[derive(Debug, Clone)]
pub struct PackedOutput {
    /// The FP probability map, row-major `[h, w]` (after the pixel shuffle).
    pub prob: Vec<f32>,
    /// The coarse descriptor map (before FD), row-major and channels last:
    /// `[h / cell, w / cell, dim]`, as [`crate::nn::sample_bilinear_at_nhwc`] reads it.
    pub descriptors: Vec<f32>,
    /// `[dim, h / cell, w / cell]`.
    pub descriptor_dims: [usize; 3],
}

/// FPFDCNN's ten convolutions packed for `PackedConv::forward_view`, with their buffers
/// (kept between calls: no allocation per image once the size is known, also when several
/// threads run the network at once: each call takes a set of buffers from a pool and puts it
/// back).
#[derive(Debug)]
pub struct PackedFpfdcnn {
    encoder: Vec<PackedConv>,
    detector: Vec<PackedConv>,
    descriptor: Vec<PackedConv>,
    cell: usize,
    /// Free sets of buffers, one buffer per convolution in the order encoder, detector,
    /// descriptor.
    scratch: Mutex<Vec<Vec<Scratch>>>,
}

/// Runs `convs` one after the other, each in its own `scratch`.
fn chain<'s>(
    convs: &[PackedConv],
    x: NhwcView<'_>,
    scratch: &'s mut [Scratch],
) -> Result<NhwcView<'s>, PackError> {
    let ([first, rest_scratch @ ..], [conv, rest @ ..]) = (scratch, convs) else {
        unreachable!("chain of at least one convolution with one scratch each")
    };
    let y = conv.forward_view(x, first)?;
    if rest.is_empty() {
        Ok(y)
    } else {
        chain(rest, y, rest_scratch)
    }
}

impl PackedFpfdcnn {
    /// Packs a model's weights (read once from its device).
    pub fn new(model: &Fpfdcnn) -> Result<Self, PackError> {
        let l = model.layers();
        let elu = |i: usize| PackedConv::new(l[i], Activation::Elu);
        Ok(Self {
            encoder: (0..6).map(elu).collect::<Result<_, _>>()?,
            detector: vec![elu(6)?, PackedConv::new(l[7], Activation::Sigmoid)?],
            descriptor: vec![elu(8)?, PackedConv::new(l[9], Activation::Identity)?],
            cell: model.cell(),
            scratch: Mutex::new(Vec::new()),
        })
    }

    fn layers(&self) -> usize {
        self.encoder.len() + self.detector.len() + self.descriptor.len()
    }

    /// The network on one grey image in `[0, 1]`, row-major `[h, w]`, both sides multiples
    /// of the cell (16).
    pub fn forward(&self, image: &[f32], [h, w]: [usize; 2]) -> Result<PackedOutput, FpfdcnnError> {
        let cell = self.cell;
        if h == 0 || w == 0 || h % cell != 0 || w % cell != 0 || image.len() != h * w {
            return Err(FpfdcnnError::Size {
                height: h,
                width: w,
                cell,
            });
        }
        let x = NhwcView {
            h,
            w,
            c: 1,
            stride: w,
            data: image,
        };
        // A free set of buffers, or a new one when every set is in use: the pool keeps one
        // set per thread that ran the network at once (the lock is held only to take and
        // return a set; a call that panics drops its set).
        let pool = || self.scratch.lock().unwrap_or_else(|e| e.into_inner());
        let mut buffers = pool().pop().unwrap_or_default();
        buffers.resize_with(self.layers(), Scratch::default);
        let result = self.forward_in(x, [h, w], &mut buffers);
        pool().push(buffers);
        result
    }

    fn forward_in(
        &self,
        x: NhwcView<'_>,
        [h, w]: [usize; 2],
        buffers: &mut [Scratch],
    ) -> Result<PackedOutput, FpfdcnnError> {
        let (cell, err) = (self.cell, |e: PackError| FpfdcnnError::Data(e.to_string()));
        let (encoder, heads) = buffers.split_at_mut(self.encoder.len());
        let (detector, descriptor) = heads.split_at_mut(self.detector.len());
        let x = chain(&self.encoder, x, encoder).map_err(err)?;
        let det = chain(&self.detector, x, detector).map_err(err)?;
        let desc = chain(&self.descriptor, x, descriptor).map_err(err)?;
        // Pixel shuffle: cell pixel (dy, dx) is channel dy·cell + dx (PyTorch's order).
        let mut prob = vec![0.0f32; h * w];
        for cy in 0..det.h {
            for cx in 0..det.w {
                let px = det.pixel(cy, cx);
                for dy in 0..cell {
                    let row = (cy * cell + dy) * w + cx * cell;
                    prob[row..row + cell].copy_from_slice(&px[dy * cell..(dy + 1) * cell]);
                }
            }
        }
        Ok(PackedOutput {
            prob,
            descriptor_dims: [desc.c, desc.h, desc.w],
            descriptors: desc.to_owned().data,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fpfdcnn::FpfdcnnConfig;
    use burn::prelude::*;
    use rand::{RngExt, SeedableRng};

    fn close(a: &[f32], b: &[f32], what: &str) {
        assert_eq!(a.len(), b.len(), "{what}");
        let peak = b.iter().fold(0.0f32, |m, v| m.max(v.abs())).max(1e-6);
        let worst = a
            .iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f32::max);
        assert!(worst <= 1e-4 * peak, "{what}: {worst} of {peak}");
    }

    #[test]
    fn matches_the_burn_network_on_both_cpu_backends() {
        #[allow(deprecated)]
        for device in [Device::ndarray(), Device::flex()] {
            let model = FpfdcnnConfig::new().init(&device).unwrap();
            let packed = PackedFpfdcnn::new(&model).unwrap();
            let (h, w) = (48, 64);
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
            let img: Vec<f32> = (0..h * w).map(|_| rng.random_range(0.0..1.0)).collect();
            let got = packed.forward(&img, [h, w]).unwrap();
            let input = Tensor::<4>::from_data(TensorData::new(img, [1, 1, h, w]), &device);
            let want = model.forward(input).unwrap();
            let vec = |t: Tensor<4>| t.into_data().try_into_vec::<f32>().unwrap();
            close(&got.prob, &vec(want.prob), "probability map");
            assert_eq!(got.descriptor_dims, [256, 3, 4]);
            let nhwc = NhwcView {
                h: 3,
                w: 4,
                c: 256,
                stride: 4,
                data: &got.descriptors,
            };
            let nchw = crate::nn::nhwc::to_nchw(&nhwc);
            close(&nchw, &vec(want.descriptors), "descriptors");
        }
    }

    #[test]
    fn reused_buffers_give_the_same_result_across_sizes() {
        let model = FpfdcnnConfig::new().init(&Device::flex()).unwrap();
        let packed = PackedFpfdcnn::new(&model).unwrap();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let mut image =
            |n: usize| -> Vec<f32> { (0..n).map(|_| rng.random_range(0.0..1.0)).collect() };
        let (a, b) = (image(32 * 48), image(64 * 32));
        let first = packed.forward(&a, [32, 48]).unwrap();
        let other = packed.forward(&b, [64, 32]).unwrap();
        let again = packed.forward(&a, [32, 48]).unwrap();
        assert_eq!(first.prob, again.prob);
        assert_eq!(first.descriptors, again.descriptors);
        let fresh = PackedFpfdcnn::new(&model)
            .unwrap()
            .forward(&b, [64, 32])
            .unwrap();
        assert_eq!(other.prob, fresh.prob);
    }

    #[test]
    fn refuses_sizes_off_the_cell_grid() {
        let model = FpfdcnnConfig::new().init(&Device::flex()).unwrap();
        let packed = PackedFpfdcnn::new(&model).unwrap();
        assert!(packed.forward(&vec![0.0; 40 * 64], [40, 64]).is_err());
        assert!(packed.forward(&[0.0; 10], [16, 16]).is_err());
    }
}
