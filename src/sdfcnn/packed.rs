//! SDFCNN inference on the CPU with packed channels-last layers: the network of
//! [`Sdfcnn::forward`] (Table 13) with every batch normalisation folded into the convolution
//! before it, dense convolutions as matrix products (`crate::nn::packed_conv`), depthwise
//! ones channel-vectorised (`crate::nn::packed_depthwise`), and the labels taken by an argmax
//! fused with the output's bilinear upsampling (the 40 full-resolution logit maps are never
//! stored). [`super::SdfcnnPredictor`] uses it on the CPU backends; GPUs keep Burn's kernels.

use super::blocks::{ConvBn, Crp, InvertedResidual, Stage};
use super::model::Sdfcnn;
use crate::nn::nhwc::{self, Activation, Nhwc, NhwcView};
use crate::nn::packed_conv::{PackError, PackedConv, fold_batch_norm, read_conv};
use crate::nn::packed_depthwise::PackedDepthwise;
use burn::nn::conv::Conv2d;
use rayon::prelude::*;

/// A dense or depthwise convolution with its bias and activation.
#[derive(Debug, Clone)]
enum Layer {
    Dense(PackedConv),
    Depthwise(PackedDepthwise),
}

impl Layer {
    fn from_parts(
        weight: &[f32],
        bias: &[f32],
        g: crate::nn::packed_conv::ConvGeometry,
        act: Activation,
    ) -> Result<Self, PackError> {
        if g.groups == 1 {
            Ok(Self::Dense(PackedConv::from_weights(weight, bias, g, act)?))
        } else {
            Ok(Self::Depthwise(PackedDepthwise::from_weights(
                weight, bias, g, act,
            )?))
        }
    }

    fn conv(conv: &Conv2d, act: Activation) -> Result<Self, PackError> {
        let (w, b, g) = read_conv(conv)?;
        Self::from_parts(&w, &b, g, act)
    }

    fn conv_bn(layer: &ConvBn) -> Result<Self, PackError> {
        let (mut w, mut b, g) = read_conv(&layer.conv)?;
        fold_batch_norm(&mut w, &mut b, &layer.bn)?;
        let act = if layer.relu6 {
            Activation::Relu6
        } else {
            Activation::Identity
        };
        Self::from_parts(&w, &b, g, act)
    }

    fn forward(&self, x: &NhwcView) -> Result<Nhwc, PackError> {
        match self {
            Self::Dense(c) => c.forward(x),
            Self::Depthwise(c) => c.forward(x),
        }
    }
}

#[derive(Debug, Clone)]
struct Block {
    expand: Layer,
    depthwise: Layer,
    project: Layer,
    residual: bool,
}

impl Block {
    fn new(b: &InvertedResidual) -> Result<Self, PackError> {
        Ok(Self {
            expand: Layer::conv_bn(&b.expand)?,
            depthwise: Layer::conv_bn(&b.depthwise)?,
            project: Layer::conv_bn(&b.project)?,
            residual: b.residual,
        })
    }

    fn forward(&self, x: &Nhwc) -> Result<Nhwc, PackError> {
        let y = self.expand.forward(&x.view())?;
        let y = self.depthwise.forward(&y.view())?;
        let mut y = self.project.forward(&y.view())?;
        if self.residual {
            nhwc::add(&mut y, &x.view());
        }
        Ok(y)
    }
}

fn stage(s: &Stage) -> Result<Vec<Block>, PackError> {
    s.blocks.iter().map(Block::new).collect()
}

/// Chained residual pooling: `x += conv(pool(top))`, four times.
#[derive(Debug, Clone)]
struct PackedCrp {
    convs: Vec<Layer>,
}

impl PackedCrp {
    fn new(c: &Crp) -> Result<Self, PackError> {
        let convs = c
            .convs
            .iter()
            .map(|conv| Layer::conv(conv, Activation::Identity))
            .collect::<Result<_, _>>()?;
        Ok(Self { convs })
    }

    fn forward(&self, mut x: Nhwc) -> Result<Nhwc, PackError> {
        // The first pool reads `x` itself, each later one the previous convolution's output.
        let mut top: Option<Nhwc> = None;
        for conv in &self.convs {
            let t = conv.forward(&nhwc::max_pool(&top.as_ref().unwrap_or(&x).view(), 5).view())?;
            nhwc::add(&mut x, &t.view());
            top = Some(t);
        }
        Ok(x)
    }
}

/// SDFCNN's layers packed for the CPU.
#[derive(Debug, Clone)]
pub struct PackedSdfcnn {
    layer1: Layer,
    /// Layer2 … Layer7 (the 320-channel block last).
    stages: Vec<Vec<Block>>,
    /// conv8, conv7, conv6, conv5, conv4, conv3.
    lateral: Vec<Layer>,
    /// crp4, crp3, crp2, crp1.
    crp: Vec<PackedCrp>,
    /// adapt4, adapt3, adapt2.
    adapt: Vec<Layer>,
    pre_seg: Layer,
    seg: Layer,
    pre_depth: Layer,
    depth: Layer,
    inner_size: [usize; 2],
    mean: [f32; 3],
    std: [f32; 3],
}

/// The judge layer's outputs at 1/4 of the inner size, channels last.
#[derive(Debug, Clone)]
pub struct QuarterOutput {
    /// `[h, w, classes]` logits.
    pub seg: Nhwc,
    /// `[h, w, 1]` depth.
    pub depth: Nhwc,
}

impl PackedSdfcnn {
    /// Packs a model's weights, or says why it cannot (e.g. an odd inner size).
    pub fn new(m: &Sdfcnn) -> Result<Self, PackError> {
        let [ih, iw] = m.inner_size;
        if ih % 2 != 0 || iw % 2 != 0 {
            return Err(PackError::Size { h: ih, w: iw });
        }
        let relu = |c: &Conv2d| Layer::conv(c, Activation::Relu);
        let plain = |c: &Conv2d| Layer::conv(c, Activation::Identity);
        Ok(Self {
            layer1: Layer::conv_bn(&m.layer1)?,
            stages: [
                &m.layer2,
                &m.layer3,
                &m.layer4,
                &m.layer5,
                &m.layer6,
                &m.layer7,
                &m.layer7_320,
            ]
            .into_iter()
            .map(stage)
            .collect::<Result<_, _>>()?,
            lateral: [&m.conv8, &m.conv7, &m.conv6, &m.conv5, &m.conv4, &m.conv3]
                .into_iter()
                .map(plain)
                .collect::<Result<_, _>>()?,
            crp: [&m.crp4, &m.crp3, &m.crp2, &m.crp1]
                .into_iter()
                .map(PackedCrp::new)
                .collect::<Result<_, _>>()?,
            adapt: [&m.adapt4, &m.adapt3, &m.adapt2]
                .into_iter()
                .map(plain)
                .collect::<Result<_, _>>()?,
            pre_seg: relu(&m.pre_seg)?,
            seg: plain(&m.seg)?,
            pre_depth: relu(&m.pre_depth)?,
            depth: plain(&m.depth)?,
            inner_size: m.inner_size,
            mean: m.mean,
            std: m.std,
        })
    }

    /// The network up to the judge layer (as [`Sdfcnn::forward_quarter`]) on one RGB image in
    /// `[0, 1]`, channels last (`rgb[(y·w + x)·3 + c]`).
    pub fn forward_quarter(
        &self,
        rgb: &[f32],
        [h, w]: [usize; 2],
    ) -> Result<QuarterOutput, PackError> {
        if h == 0 || w == 0 || rgb.len() != h * w * 3 {
            return Err(PackError::Size { h, w });
        }
        let image = NhwcView {
            h,
            w,
            c: 3,
            stride: w,
            data: rgb,
        };
        // Layer0: resize, then eq. 15.
        let mut x = nhwc::resize_bilinear(&image, self.inner_size);
        let inv = self.std.map(|s| 1.0 / s);
        x.data.par_chunks_mut(3).for_each(|px| {
            for c in 0..3 {
                px[c] = (px[c] - self.mean[c]) * inv[c];
            }
        });
        let layer1 = self.layer1.forward(&x.view())?;
        // Each stage's output is kept (the decoder reads them all) and read by the next stage.
        let mut features: Vec<Nhwc> = Vec::with_capacity(self.stages.len());
        for blocks in &self.stages {
            let mut x: Option<Nhwc> = None;
            for b in blocks {
                let input = x.as_ref().or(features.last()).unwrap_or(&layer1);
                x = Some(b.forward(input)?);
            }
            let Some(x) = x else {
                return Err(PackError::Unsupported(
                    "an encoder stage without blocks".into(),
                ));
            };
            features.push(x);
        }
        let [_, l24, l32, l64, l96, l160, l320] = &features[..] else {
            unreachable!("seven encoder stages")
        };
        let lat = |i: usize, f: &Nhwc| self.lateral[i].forward(&f.view());
        let resize_to = |x: &Nhwc, like: &Nhwc| nhwc::resize_bilinear(&x.view(), [like.h, like.w]);
        let relu = |mut x: Nhwc| {
            x.data
                .par_chunks_mut(4096)
                .for_each(|c| nhwc::activate(c, Activation::Relu));
            x
        };
        // Layer8.
        let mut x = lat(0, l320)?;
        nhwc::add(&mut x, &lat(1, l160)?.view());
        let x = self.crp[0].forward(relu(x))?;
        let x = resize_to(&self.adapt[0].forward(&x.view())?, l96);
        // Layer9.
        let mut y = lat(2, l96)?;
        nhwc::add(&mut y, &lat(3, l64)?.view());
        nhwc::add(&mut y, &x.view());
        let x = self.crp[1].forward(relu(y))?;
        let x = resize_to(&self.adapt[1].forward(&x.view())?, l32);
        // Layer10.
        let mut y = lat(4, l32)?;
        nhwc::add(&mut y, &x.view());
        let x = self.crp[2].forward(relu(y))?;
        let x = resize_to(&self.adapt[2].forward(&x.view())?, l24);
        // Layer11.
        let mut y = lat(5, l24)?;
        nhwc::add(&mut y, &x.view());
        let x = self.crp[3].forward(relu(y))?;
        // Judge.
        let seg = self.seg.forward(&self.pre_seg.forward(&x.view())?.view())?;
        let depth = self
            .depth
            .forward(&self.pre_depth.forward(&x.view())?.view())?;
        Ok(QuarterOutput { seg, depth })
    }

    /// Labels (the argmax of the bilinearly upsampled logits, computed pixel by pixel) and
    /// depth (bilinearly upsampled) at the input resolution, row-major.
    pub fn predict(
        &self,
        rgb: &[f32],
        [h, w]: [usize; 2],
    ) -> Result<(Vec<u8>, Vec<f32>), PackError> {
        let q = self.forward_quarter(rgb, [h, w])?;
        let depth = nhwc::resize_bilinear(&q.depth.view(), [h, w]).data;
        Ok((upsampled_argmax(&q.seg.view(), [h, w]), depth))
    }
}

/// For every pixel of an `[h, w]` image: the channel with the largest value in the bilinear
/// upsampling of `logits` (the first on ties, as Burn's argmax), without storing the
/// upsampled maps. Columns first, then rows, as [`nhwc::resize_bilinear`]: each band of
/// [`ARGMAX_BAND`] output rows blends the columns of the logit rows it reads once, into rows
/// of one channel each (so that [`argmax_row`] compares [`LANES`] pixels at once), then each
/// pixel's two rows.
fn upsampled_argmax(logits: &NhwcView, [h, w]: [usize; 2]) -> Vec<u8> {
    use crate::nn::resize::taps;
    let c = logits.c;
    let tx: Vec<_> = (0..w).map(|x| taps(x, logits.w, w)).collect();
    // A blended logit row: c channel rows of `wp` values (the pixels past w are zeros).
    let wp = w.div_ceil(LANES) * LANES;
    let row = c * wp;
    let mut labels = vec![0u8; h * w];
    if row == 0 || h == 0 || logits.h == 0 || logits.w == 0 {
        return labels;
    }
    labels
        .par_chunks_mut(ARGMAX_BAND * w)
        .enumerate()
        .for_each(|(b, band)| {
            let y0 = b * ARGMAX_BAND;
            let ty: Vec<_> = (y0..y0 + band.len() / w)
                .map(|y| taps(y, logits.h, h))
                .collect();
            // Logit rows lo..=hi, their columns blended to the output's width.
            let (lo, hi) = (ty[0].i0, ty[ty.len() - 1].i1);
            ARGMAX_SCRATCH.with(|cell| {
                let (cols, best) = &mut *cell.borrow_mut();
                // Every value is written before it is read: no zeroing on reuse.
                cols.resize((hi - lo + 1) * row, 0.0);
                best.resize(2 * wp, 0.0);
                for (k, out) in cols.chunks_exact_mut(row).enumerate() {
                    for (x, t) in tx.iter().enumerate() {
                        let (p, q) = (logits.pixel(lo + k, t.i0), logits.pixel(lo + k, t.i1));
                        for (i, (&p, &q)) in p.iter().zip(q).enumerate() {
                            out[i * wp + x] = t.w0 * p + t.w1 * q;
                        }
                    }
                    for channel in out.chunks_exact_mut(wp) {
                        channel[w..].fill(0.0);
                    }
                }
                for (out, t) in band.chunks_mut(w).zip(&ty) {
                    let r0 = &cols[(t.i0 - lo) * row..][..row];
                    let r1 = &cols[(t.i1 - lo) * row..][..row];
                    argmax_row(out, r0, t.w0, r1, t.w1, wp, best);
                }
            })
        });
    labels
}

/// Output rows a task of [`upsampled_argmax`] labels.
const ARGMAX_BAND: usize = 16;

/// Pixels [`argmax_row`] compares at once.
const LANES: usize = 16;

thread_local! {
    /// A band's column-blended logit rows and a row's running maxima and labels, kept per
    /// thread.
    static ARGMAX_SCRATCH: std::cell::RefCell<(Vec<f32>, Vec<f32>)> =
        const { std::cell::RefCell::new((Vec::new(), Vec::new())) };
}

nhwc::simd_fn! {
    /// One row of labels: pixel `x`'s is the first channel `i` with the largest
    /// `a0·r0[i·wp + x] + a1·r1[i·wp + x]` (`r0`, `r1`: channel rows of `wp` values, a
    /// multiple of [`LANES`]; `scratch` holds `2·wp` values).
    fn argmax_row(
        out: &mut [u8],
        r0: &[f32],
        a0: f32,
        r1: &[f32],
        a1: f32,
        wp: usize,
        scratch: &mut [f32],
    ) {
        let (best, label) = scratch[..2 * wp].split_at_mut(wp);
        for ((b, &p), &q) in best.iter_mut().zip(&r0[..wp]).zip(&r1[..wp]) {
            *b = a0 * p + a1 * q;
        }
        label.fill(0.0);
        let channels = r0.len() / wp;
        for x in (0..wp).step_by(LANES) {
            let mut b: [f32; LANES] = best[x..x + LANES].try_into().expect("LANES values");
            let mut l = [0.0f32; LANES];
            for i in 1..channels {
                let p: &[f32; LANES] = r0[i * wp + x..][..LANES].try_into().expect("LANES");
                let q: &[f32; LANES] = r1[i * wp + x..][..LANES].try_into().expect("LANES");
                let fi = i as f32;
                for k in 0..LANES {
                    let v = a0 * p[k] + a1 * q[k];
                    let more = v > b[k];
                    b[k] = if more { v } else { b[k] };
                    l[k] = if more { fi } else { l[k] };
                }
            }
            label[x..x + LANES].copy_from_slice(&l);
        }
        for (o, &l) in out.iter_mut().zip(label.iter()) {
            *o = (l as usize).min(254) as u8;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sdfcnn::SdfcnnConfig;
    use burn::prelude::*;
    use rand::{RngExt, SeedableRng};

    /// A network whose batch norms have non-trivial statistics (a fresh one has mean 0,
    /// variance 1), so that folding is tested.
    fn model(device: &Device) -> Sdfcnn {
        let m = SdfcnnConfig::new()
            .with_inner_size([64, 96])
            .init(device)
            .unwrap();
        let m = crate::nn::seeded_init(m, 21);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        let mut tweak = |bn: &mut burn::nn::BatchNorm| {
            let n = bn.gamma.dims()[0];
            let mut vec = |lo: f32, hi: f32| {
                let v: Vec<f32> = (0..n).map(|_| rng.random_range(lo..hi)).collect();
                Tensor::<1>::from_data(TensorData::new(v, [n]), device)
            };
            bn.running_mean = burn::module::RunningState::new(vec(-0.2, 0.2));
            bn.running_var = burn::module::RunningState::new(vec(0.5, 2.0));
            bn.gamma = burn::module::Param::from_tensor(vec(0.5, 1.5));
            bn.beta = burn::module::Param::from_tensor(vec(-0.1, 0.1));
        };
        let mut m = m;
        tweak(&mut m.layer1.bn);
        for s in [&mut m.layer2, &mut m.layer5, &mut m.layer7_320] {
            for b in &mut s.blocks {
                tweak(&mut b.expand.bn);
                tweak(&mut b.depthwise.bn);
                tweak(&mut b.project.bn);
            }
        }
        m
    }

    #[test]
    fn matches_the_burn_network_on_both_cpu_backends() {
        #[allow(deprecated)]
        for device in [Device::ndarray(), Device::flex()] {
            let m = model(&device);
            let packed = PackedSdfcnn::new(&m).unwrap();
            let (h, w) = (45, 70);
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(8);
            let hwc: Vec<f32> = (0..h * w * 3).map(|_| rng.random_range(0.0..1.0)).collect();
            let q = packed.forward_quarter(&hwc, [h, w]).unwrap();
            let nchw = crate::nn::nhwc::to_nchw(&NhwcView {
                h,
                w,
                c: 3,
                stride: w,
                data: &hwc,
            });
            let input = Tensor::<4>::from_data(TensorData::new(nchw, [1, 3, h, w]), &device);
            let want = m.forward_quarter(input.clone()).unwrap();
            let close = |got: &Nhwc, want: Tensor<4>, what: &str| {
                let [_, c, qh, qw] = want.dims();
                assert_eq!([got.c, got.h, got.w], [c, qh, qw], "{what}");
                let want = want.into_data().try_into_vec::<f32>().unwrap();
                let peak = want.iter().fold(0.0f32, |a, v| a.max(v.abs())).max(1e-6);
                let got = crate::nn::nhwc::to_nchw(&got.view());
                let worst = got
                    .iter()
                    .zip(&want)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f32::max);
                assert!(worst <= 1e-4 * peak, "{what}: {worst} of {peak}");
            };
            close(&q.seg, want.seg, "logits");
            close(&q.depth, want.depth, "depth");
            // Full resolution: depth, and labels wherever the top two logits are apart.
            let (labels, depth) = packed.predict(&hwc, [h, w]).unwrap();
            let full = m.forward(input).unwrap();
            let want_depth = full.depth.into_data().try_into_vec::<f32>().unwrap();
            let peak = want_depth.iter().fold(0.0f32, |a, v| a.max(v.abs()));
            for (a, b) in depth.iter().zip(&want_depth) {
                assert!((a - b).abs() <= 1e-4 * peak);
            }
            let logits = full.seg.clone().into_data().try_into_vec::<f32>().unwrap();
            let want_labels = full
                .seg
                .argmax(1)
                .into_data()
                .convert::<i64>()
                .to_vec::<i64>()
                .unwrap();
            let plane = h * w;
            let mut compared = 0;
            for (i, (&l, &want)) in labels.iter().zip(&want_labels).enumerate() {
                let mut v: Vec<f32> = (0..40).map(|c| logits[c * plane + i]).collect();
                v.sort_by(|a, b| b.total_cmp(a));
                if v[0] - v[1] > 1e-3 * v[0].abs().max(1.0) {
                    assert_eq!(l as i64, want, "pixel {i}");
                    compared += 1;
                }
            }
            assert!(
                compared > plane / 2,
                "{compared} of {plane} pixels compared"
            );
        }
    }

    /// The upsampled argmax computed the plain way: every pixel's column blends, then its
    /// row blend, then the first largest channel.
    fn argmax_reference(logits: &NhwcView, [h, w]: [usize; 2]) -> Vec<u8> {
        use crate::nn::resize::taps;
        let c = logits.c;
        let mut labels = vec![0u8; h * w];
        for y in 0..h {
            let ty = taps(y, logits.h, h);
            for x in 0..w {
                let t = taps(x, logits.w, w);
                let v: Vec<f32> = (0..c)
                    .map(|i| {
                        let r0 = t.w0 * logits.pixel(ty.i0, t.i0)[i]
                            + t.w1 * logits.pixel(ty.i0, t.i1)[i];
                        let r1 = t.w0 * logits.pixel(ty.i1, t.i0)[i]
                            + t.w1 * logits.pixel(ty.i1, t.i1)[i];
                        ty.w0 * r0 + ty.w1 * r1
                    })
                    .collect();
                let best = (1..c).fold(0, |b, i| if v[i] > v[b] { i } else { b });
                labels[y * w + x] = best.min(254) as u8;
            }
        }
        labels
    }

    #[test]
    fn the_banded_argmax_equals_the_plain_one_bit_for_bit() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        // Sizes off the band and scale grids; logits on a coarse grid of values make ties.
        for ([lh, lw, c], [h, w], levels) in [
            ([30, 40, 40], [120, 160], 0),
            ([7, 5, 40], [29, 21], 4),
            ([3, 4, 3], [37, 11], 2),
            ([1, 1, 2], [5, 3], 0),
        ] {
            let data: Vec<f32> = (0..lh * lw * c)
                .map(|_| {
                    let v: f32 = rng.random_range(-4.0..4.0);
                    if levels > 0 {
                        (v * levels as f32).round() / levels as f32
                    } else {
                        v
                    }
                })
                .collect();
            let logits = NhwcView {
                h: lh,
                w: lw,
                c,
                stride: lw,
                data: &data,
            };
            assert_eq!(
                upsampled_argmax(&logits, [h, w]),
                argmax_reference(&logits, [h, w]),
                "{lh}x{lw}x{c} -> {h}x{w}"
            );
        }
    }

    #[test]
    fn refuses_odd_inner_sizes_and_wrong_inputs() {
        let d = Device::flex();
        let odd = SdfcnnConfig::new()
            .with_inner_size([63, 96])
            .init(&d)
            .unwrap();
        assert!(PackedSdfcnn::new(&odd).is_err());
        let packed = PackedSdfcnn::new(&model(&d)).unwrap();
        assert!(packed.forward_quarter(&[0.5; 10], [4, 4]).is_err());
    }
}
