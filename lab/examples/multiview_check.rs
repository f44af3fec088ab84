//! The multi-view depth sweep (`src/slam/multiview_depth.rs`) on real frames with their
//! ground-truth poses, apart from tracking: the "prediction" is the target's sensor depth
//! times FACTOR, and the measured pixels are compared with sensor depth.
//!
//! cargo run --release --example multiview_check -- SEQUENCE TARGET GAPS FACTOR [MIN_PARALLAX_PX]
//! e.g. `../shared/data/7scenes_redkitchen_0_799 650 10,20,30 1.15`: frame 650 against
//! frames 640, 630 and 620 (the sequence's camera.toml, the default settings of
//! `configs/slam/default.toml`'s `[multiview]`).

use sdf_slam::camera::Camera;
use sdf_slam::dataset::{LabelImage, TumSequence};
use sdf_slam::slam::SlamConfig;
use sdf_slam::slam::map::KeyframeView;
use sdf_slam::slam::mapping::multiview_depth::{GrayView, SweepReference, sweep_depth};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (root, target, gaps, factor, parallax) = match args.as_slice() {
        [r, t, g, f] => (r, t, g, f, None),
        [r, t, g, f, p] => (r, t, g, f, Some(p.parse::<f64>()?)),
        _ => {
            return Err(
                "usage: multiview_check SEQUENCE TARGET GAPS(comma-separated) FACTOR [MIN_PARALLAX_PX]"
                    .into(),
            );
        }
    };
    let target: usize = target.parse()?;
    let factor: f32 = factor.parse()?;
    let gaps = gaps
        .split(',')
        .map(|g| g.parse::<usize>())
        .collect::<Result<Vec<_>, _>>()?;
    let seq = TumSequence::open(root)?;
    let camera = Camera::load(&format!("{root}/camera.toml"))?;
    let mut mv = SlamConfig::default().multiview;
    if let Some(p) = parallax {
        mv.min_parallax_px = p;
    }
    let stride = SlamConfig::default().map.pixel_stride;
    // The map's grid of a frame (every `stride`-th pixel of its sensor depth), its grey
    // image at full resolution and its ground-truth pose.
    let frame = |i: usize| -> Result<_, Box<dyn std::error::Error>> {
        let rgb = seq.load_rgb(i)?;
        let depth = seq.load_depth(i)?.ok_or("the sequence has no depth")?;
        let labels = LabelImage::new(rgb.width(), rgb.height(), 255);
        let stamp = seq.frames.get(i).ok_or("frame out of range")?.rgb_stamp;
        let pose = seq.gt_pose_at(stamp).ok_or("no ground-truth pose")?;
        let grid = KeyframeView::new(stride, &rgb, &depth, &labels).depth;
        Ok((grid, GrayView::from_rgb(&rgb), pose))
    };
    let (truth, gray, pose) = frame(target)?;
    let mut predicted = truth.clone();
    predicted.data.iter_mut().for_each(|d| *d *= factor);
    let mut refs = Vec::new();
    for g in &gaps {
        let i = target.checked_sub(*g).ok_or("gap before the first frame")?;
        let (_, image, p) = frame(i)?;
        let baseline = (p.translation.vector - pose.translation.vector).norm();
        println!("reference {i}: baseline {baseline:.3} m");
        refs.push((image, p));
    }
    let refs: Vec<SweepReference> = refs
        .iter()
        .map(|(image, pose)| SweepReference { image, pose: *pose })
        .collect();
    let (measured, sum) = sweep_depth(&gray, &pose, &predicted, &refs, &camera, stride, &mv);
    let pairs: Vec<(f32, f32)> = measured
        .data
        .iter()
        .zip(&truth.data)
        .filter(|(m, t)| **m > 0.0 && **t > 0.0)
        .map(|(m, t)| (*m, *t))
        .collect();
    if pairs.is_empty() {
        println!("{sum:?}: no pixel measured");
        return Ok(());
    }
    let mut rel: Vec<f32> = pairs.iter().map(|(m, t)| (m - t) / t).collect();
    rel.sort_by(f32::total_cmp);
    let n = rel.len();
    let within = pairs.iter().filter(|(m, t)| (m - t).abs() <= 0.05).count();
    println!(
        "{} of {} candidate pixels measured; signed relative error p10 {:.3} p50 {:.3} p90 {:.3}; within 5 cm {:.1} %",
        sum.confirmed,
        sum.candidates,
        rel[n / 10],
        rel[n / 2],
        rel[9 * n / 10],
        100.0 * within as f64 / n as f64
    );
    Ok(())
}
