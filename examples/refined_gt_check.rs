//! Whether a sequence's ground-truth relative poses, refined by aligning the two frames'
//! depth images, fit their colour images better: ORB + BF matches of every frame pair
//! `(i, i + GAP)` in `FIRST..LAST`, scored as `eval matching` scores them (A's depth, the
//! camera with distortion, correct within 5 px) against the ground truth's relative pose and
//! against that pose refined by the SLAM's depth alignment (`slam::depth_alignment`, the
//! keyframe alignments' settings and gates at half resolution; the ground truth where the
//! alignment fails its gates). ORB takes no part in either pose, so the pose its matches fit
//! better is the closer to the colour images' motion (README, *Does the ground truth close
//! its own loops*).
//!
//! cargo run --release --example refined_gt_check -- SEQUENCE CAMERA FIRST LAST [GAP]

use anyhow::bail;
use sdf_slam::camera::{Camera, RayTable};
use sdf_slam::dataset::TumSequence;
use sdf_slam::features::bf_matcher::matched_pixels;
use sdf_slam::features::orb::{OrbConfig, detect_and_compute};
use sdf_slam::geometry::Pose;
use sdf_slam::raster::rgb_to_gray;
use sdf_slam::slam::SlamConfig;
use sdf_slam::slam::depth_alignment::{DepthModel, align};
use std::sync::Arc;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 4 {
        bail!("usage: refined_gt_check SEQUENCE CAMERA FIRST LAST [GAP]");
    }
    let seq = TumSequence::open(&args[0])?;
    let camera = Camera::load(&args[1])?;
    let (first, last): (usize, usize) = (args[2].parse()?, args[3].parse()?);
    let gap: usize = args.get(4).map_or(Ok(5), |s| s.parse())?;
    let last = last.min(seq.len());

    let cfg = SlamConfig::default();
    let dense = &cfg.dense;
    let range = (cfg.tracking.min_depth, cfg.tracking.max_depth);
    let stride = cfg.map.pixel_stride;
    let rays = Arc::new(RayTable::new(&camera, stride));
    let orb = OrbConfig::default();
    // [ground truth, refined]: correct, judged.
    let mut counts = [[0usize; 2]; 2];
    let (mut refined_pairs, mut pairs) = (0, 0);
    for i in first..last.saturating_sub(gap) {
        let (a, b) = (seq.load_frame(i)?, seq.load_frame(i + gap)?);
        let (Some(depth_a), Some(depth_b), Some(pa), Some(pb)) =
            (a.depth.as_ref(), b.depth.as_ref(), a.gt_pose, b.gt_pose)
        else {
            continue;
        };
        pairs += 1;
        let gt = pa.inverse() * pb;
        let refined = DepthModel::new(
            &depth_a.subsample(stride),
            &camera,
            rays.clone(),
            dense.model_step,
            range,
        )
        .and_then(|model| align(&model, &depth_b.subsample(stride), None, &gt, range, dense))
        .filter(|found| found.passes_edge_gates(&gt, dense))
        .map(|found| found.pose);
        refined_pairs += refined.is_some() as usize;
        let poses: [Pose; 2] = [gt, refined.unwrap_or(gt)];
        let fa = detect_and_compute(&rgb_to_gray(&a.rgb), &orb)?;
        let fb = detect_and_compute(&rgb_to_gray(&b.rgb), &orb)?;
        for (xa, xb) in matched_pixels(&fa, &fb) {
            let Some(z) = depth_a.at(xa.x, xa.y) else {
                continue;
            };
            let p = camera.back_project(&xa, z as f64);
            for (k, t_ab) in poses.iter().enumerate() {
                if let Some(x) = camera.project(&(t_ab.inverse() * p)) {
                    counts[k][1] += 1;
                    counts[k][0] += ((x - xb).norm() <= 5.0) as usize;
                }
            }
        }
    }
    let share = |k: usize| 100.0 * counts[k][0] as f64 / counts[k][1].max(1) as f64;
    println!(
        "{} frames {first}..{last}, pairs {gap} apart: {pairs}, refined {refined_pairs}; ORB + BF matches within 5 px: ground truth {:.1} % of {}, refined by depth {:.1} % of {}",
        args[0],
        share(0),
        counts[0][1],
        share(1),
        counts[1][1]
    );
    Ok(())
}
