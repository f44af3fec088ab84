//! The bundled networks' time on real frames as `slam` runs them: SDFCNN's labels and depth
//! (`predict_for_camera`) and FPFDCNN's keypoints (`detect` with the SLAM's detector
//! settings), each on one thread and on the global pool, medians over the frames
//! (lab/notes/cpu-speed.md). Usage: `cargo run --release --example network_timing --
//! SEQUENCE [CAMERA] [FRAMES]` (CAMERA as `slam --camera`; default 10 frames).
use sdf_slam::bundled::{BUNDLED_FPFDCNN, BUNDLED_SDFCNN, bundled_weights};
use sdf_slam::camera::Camera;
use sdf_slam::dataset::TumSequence;
use sdf_slam::fpfdcnn::inference::FpfdcnnDetector;
use sdf_slam::nn::BackendKind;
use sdf_slam::sdfcnn::SdfcnnPredictor;
use sdf_slam::slam::SlamConfig;
use std::time::Instant;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let usage = "usage: network_timing SEQUENCE [CAMERA] [FRAMES]";
    let root = args.next().ok_or_else(|| anyhow::anyhow!(usage))?;
    let seq = TumSequence::open(&root)?;
    let cam = Camera::load(&args.next().unwrap_or_else(|| "fr1".into()))?;
    let n: usize = args.next().map(|s| s.parse()).transpose()?.unwrap_or(10);
    let sd = bundled_weights(BUNDLED_SDFCNN).ok_or_else(|| anyhow::anyhow!("no SDFCNN"))?;
    let fp = bundled_weights(BUNDLED_FPFDCNN).ok_or_else(|| anyhow::anyhow!("no FPFDCNN"))?;
    let sdfcnn = SdfcnnPredictor::load(&sd, BackendKind::Ndarray)?;
    let detector_cfg = SlamConfig::default().features.detector();
    let fpfdcnn = FpfdcnnDetector::load(&fp, BackendKind::Ndarray, detector_cfg)?;
    let frames: Vec<_> = (0..n.min(seq.frames.len()))
        .map(|i| seq.load_frame(i))
        .collect::<Result<_, _>>()?;
    anyhow::ensure!(!frames.is_empty(), "no frames to time ({usage})");
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    for (name, single) in [("global pool", false), ("one thread", true)] {
        let (mut s, mut f) = (Vec::new(), Vec::new());
        for frame in &frames {
            let gray = image::imageops::grayscale(&frame.rgb);
            let run = || -> anyhow::Result<(f64, f64)> {
                let t = Instant::now();
                sdfcnn.predict_for_camera(&frame.rgb, Some(cam.fx))?;
                let a = t.elapsed().as_secs_f64();
                let t = Instant::now();
                fpfdcnn.detect(&gray)?;
                Ok((a, t.elapsed().as_secs_f64()))
            };
            let (a, b) = if single { one.install(run)? } else { run()? };
            s.push(a * 1e3);
            f.push(b * 1e3);
        }
        println!(
            "{name}: SDFCNN {:.1} ms, FPFDCNN {:.1} ms (medians of {} frames)",
            median(s),
            median(f),
            frames.len()
        );
    }
    Ok(())
}
