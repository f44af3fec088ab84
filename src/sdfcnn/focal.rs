//! How SDFCNN's metric depth depends on the camera (Section IV-C; eq. 18-20 are in metres).
//!
//! Depth from one image is only metric for the focal length the network learned: the same
//! picture taken with a lens twice as long shows every object twice as large, as if it were
//! half as far. Cameras differ (7-Scenes' colour camera 527 px, TUM fr1 517 px, NYUv2 519 px
//! at 640 px width), and training crops zoom the image, which lengthens the focal length too.
//!
//! SDFCNN therefore predicts depth for a **canonical camera**: one whose focal length is
//! `depth_focal` image widths (`[network] depth_focal` in the training config; the bundled
//! weights use NYUv2's, 518.86 / 640 = 0.8107). During training every depth target is scaled
//! by `depth_focal / (f / w)`, where `f / w` is the sample's focal length over its width after
//! the augmentation's zoom; at inference the prediction is scaled back by `(f / w) /
//! depth_focal` for the camera that took the image (`eval seg --camera`, `slam`'s camera).
//! This is the canonical-camera transform of Metric3D (Yin et al., ICCV 2023) applied to the
//! labels, and it keeps SDFCNN's architecture (Table 13) unchanged. A network without
//! `depth_focal` (the weights of 2026-11-21) uses its depth as predicted.

/// NYUv2's colour camera focal length in pixels (Silberman et al., ECCV 2012, toolbox
/// calibration `fx_rgb`): the camera of NYU-layout folders without a `camera.toml`.
pub const NYU_FX: f64 = 518.857_901_6;

/// The canonical focal length of the bundled weights, in image widths: NYUv2's camera.
pub const NYU_FOCAL: f64 = NYU_FX / 640.0;

/// NYUv2's focal length holds for images of its 640-px-wide camera and for crops of them
/// (the official crop is 561-625 px wide); other widths need their own camera.
pub(crate) fn nyu_fx_fits(width: u32) -> bool {
    (500..=640).contains(&width)
}

/// The factor that turns metric depth seen by a camera of focal length `fx` pixels, in an image
/// `width` pixels wide zoomed by `zoom` (crop width = width / zoom), into the depth a camera of
/// focal length `canonical` image widths would see: `canonical / (fx · zoom / width)`.
pub(crate) fn to_canonical(canonical: f64, fx: f64, width: f64, zoom: f64) -> f64 {
    canonical * width / (fx * zoom)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_longer_lens_or_a_zoom_makes_things_look_nearer() {
        // The canonical camera itself: depth unchanged.
        assert!((to_canonical(NYU_FOCAL, NYU_FX, 640.0, 1.0) - 1.0).abs() < 1e-12);
        // Half-resolution images of the same camera: the same focal length in widths.
        assert!((to_canonical(NYU_FOCAL, NYU_FX / 2.0, 320.0, 1.0) - 1.0).abs() < 1e-12);
        // 7-Scenes' 527 px lens is longer than NYU's: its objects look nearer to the network.
        let k = to_canonical(NYU_FOCAL, 527.0, 640.0, 1.0);
        assert!((k - 518.857_901_6 / 527.0).abs() < 1e-12);
        // Zooming by 2 halves the canonical depth.
        assert!((to_canonical(NYU_FOCAL, NYU_FX, 640.0, 2.0) - 0.5).abs() < 1e-12);
    }
}
