//! Match two images with FPFDCNN: the bundled network (`weights/fpfdcnn`) detects and
//! describes keypoints in both, the range matcher pairs them with the SLAM's default settings
//! (140-px window, mutual nearest descriptors, the window centred by the global image motion
//! estimated from the descriptors), and a picture shows the pairs.
//!
//! ```text
//! cargo run --release --example match_images -- [IMAGE_A IMAGE_B] [--out PICTURE.png]
//! ```
//!
//! Default images: frames 0 and 4 of the bundled fixture `datasets/fixtures/tum_fr1_rpy_head10`
//! (TUM fr1_rpy); default picture: `runs/examples/matches.png`.

use anyhow::{Context, Result, bail};
use sdf_slam::bundled::{BUNDLED_FPFDCNN, bundled_weights, locate};
use sdf_slam::dataset::TumSequence;
use sdf_slam::fpfdcnn::FpfdcnnDetector;
use sdf_slam::fpfdcnn::evaluate::fpfdcnn_matches;
use sdf_slam::imageio::{read_gray, write_png_atomic};
use sdf_slam::nn::BackendKind;
use sdf_slam::range_matcher::GuideConfig;
use sdf_slam::raster::match_picture;
use sdf_slam::slam::SlamConfig;
use std::path::PathBuf;

const FIXTURE: &str = "datasets/fixtures/tum_fr1_rpy_head10";

fn main() -> Result<()> {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let mut out = PathBuf::from("runs/examples/matches.png");
    if let Some(k) = args.iter().position(|a| a == "--out") {
        let Some(p) = args.get(k + 1) else {
            bail!("--out needs a file name, e.g. --out matches.png");
        };
        out = PathBuf::from(p);
        args.drain(k..k + 2);
    }
    let [a, b] = match args.as_slice() {
        [] => {
            let root = locate(FIXTURE).with_context(|| {
                format!("the default images are frames of {FIXTURE}, which is not here")
            })?;
            let seq = TumSequence::open(&root)?;
            if seq.len() < 5 {
                bail!("{} has {} frames, 5 needed", root.display(), seq.len());
            }
            [
                seq.frames[0].rgb_path.clone(),
                seq.frames[4].rgb_path.clone(),
            ]
        }
        [a, b] => [PathBuf::from(a), PathBuf::from(b)],
        _ => bail!("usage: match_images [IMAGE_A IMAGE_B] [--out PICTURE.png]"),
    };

    // The SLAM's defaults: its detector settings and its range matcher.
    let config = SlamConfig::default();
    let weights = bundled_weights(BUNDLED_FPFDCNN).with_context(|| {
        format!("no bundled FPFDCNN weights ({BUNDLED_FPFDCNN}/model.bpk + config.toml)")
    })?;
    let detector =
        FpfdcnnDetector::load(&weights, BackendKind::Ndarray, config.features.detector())
            .with_context(|| format!("loading FPFDCNN from {}", weights.display()))?;

    let ga = read_gray(&a).with_context(|| format!("reading {}", a.display()))?;
    let gb = read_gray(&b).with_context(|| format!("reading {}", b.display()))?;
    let fa = detector.detect(&ga).context("FPFDCNN on image A")?;
    let fb = detector.detect(&gb).context("FPFDCNN on image B")?;
    let guide = GuideConfig::default();
    let matches = fpfdcnn_matches(&fa, &fb, &config.matcher.range(), Some(&guide))?;

    println!("A: {} ({} keypoints)", a.display(), fa.len());
    println!("B: {} ({} keypoints)", b.display(), fb.len());
    println!(
        "{} matches ({}-dimensional descriptors, {} px window{})",
        matches.len(),
        fa.dim,
        config.matcher.window,
        if config.matcher.mutual {
            ", mutual nearest"
        } else {
            ""
        }
    );
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let picture = match_picture(&ga, &gb, &matches);
    write_png_atomic(&out, &picture.into())?;
    println!("picture: {}", out.display());
    Ok(())
}
