//! Pixel shuffle (sub-pixel rearrangement), FPFDCNN's FP layer (Table 12).

use burn::prelude::*;

/// Rearranges `[N, C·r², H, W]` into `[N, C, H·r, W·r]` with PyTorch's `pixel_shuffle`
/// channel order: `out[c, h·r + i, w·r + j] = in[c·r² + i·r + j, h, w]`.
///
/// # Panics
/// If `r` is zero or the channel count is not a multiple of `r²`.
pub fn pixel_shuffle(x: Tensor<4>, r: usize) -> Tensor<4> {
    let [n, c, h, w] = x.dims();
    assert!(
        r > 0 && c % (r * r) == 0,
        "pixel_shuffle: {c} channels are not a multiple of {r}²"
    );
    let oc = c / (r * r);
    x.reshape([n, oc, r, r, h, w])
        .permute([0, 1, 4, 2, 5, 3])
        .reshape([n, oc, h * r, w * r])
}

/// The inverse of [`pixel_shuffle`]: `[N, C, H·r, W·r]` into `[N, C·r², H, W]` with
/// `out[c·r² + i·r + j, h, w] = in[c, h·r + i, w·r + j]` (PyTorch's `pixel_unshuffle`).
///
/// # Panics
/// If `r` is zero or the height or width is not a multiple of `r`.
pub fn pixel_unshuffle(x: Tensor<4>, r: usize) -> Tensor<4> {
    let [n, c, hr, wr] = x.dims();
    assert!(
        r > 0 && hr % r == 0 && wr % r == 0,
        "pixel_unshuffle: {hr}x{wr} is not a multiple of {r}"
    );
    let (h, w) = (hr / r, wr / r);
    x.reshape([n, c, h, r, w, r])
        .permute([0, 1, 3, 5, 2, 4])
        .reshape([n, c * r * r, h, w])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pixel_shuffle_matches_hand_example() {
        #[allow(deprecated)]
        let d = Device::ndarray();
        // in: 2 output channels × r² = 4 sub-pixels, on a 1×2 grid; value = 10·channel + w.
        let v: Vec<f32> = (0..8)
            .flat_map(|ch| [10.0 * ch as f32, 10.0 * ch as f32 + 1.0])
            .collect();
        let x = Tensor::<4>::from_data(TensorData::new(v, [1, 8, 1, 2]), &d);
        let y = pixel_shuffle(x, 2);
        assert_eq!(y.dims(), [1, 2, 2, 4]);
        // out[c, i, 2w + j] = in[4c + 2i + j, 0, w]
        let want = [
            0., 10., 1., 11., // c0 row0: ch0 w0, ch1 w0, ch0 w1, ch1 w1
            20., 30., 21., 31., // c0 row1: ch2, ch3
            40., 50., 41., 51., // c1 row0: ch4, ch5
            60., 70., 61., 71., // c1 row1: ch6, ch7
        ];
        assert_eq!(y.into_data().try_to_vec::<f32>().expect("f32"), want);
    }

    #[test]
    fn pixel_unshuffle_inverts_pixel_shuffle() {
        let d = Device::flex();
        let x = Tensor::<4>::random([2, 2 * 9, 3, 5], burn::tensor::Distribution::Default, &d);
        let back = pixel_unshuffle(pixel_shuffle(x.clone(), 3), 3);
        assert_eq!(back.into_data(), x.into_data());
    }

    #[test]
    fn pixel_shuffle_matches_burn_module() {
        let d = Device::flex();
        let x = Tensor::<4>::random([2, 3 * 16, 3, 5], burn::tensor::Distribution::Default, &d);
        let ours = pixel_shuffle(x.clone(), 4);
        let theirs = burn::nn::PixelShuffleConfig::new(4).init().forward(x);
        assert_eq!(ours.into_data(), theirs.into_data());
    }
}
