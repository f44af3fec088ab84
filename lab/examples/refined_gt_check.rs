//! Whether a sequence's ground-truth relative poses, refined by aligning the two frames'
//! depth images, fit their colour images better: ORB + BF matches of every frame pair
//! `(i, i + GAP)` in `FIRST..LAST`, scored as `eval matching` scores them (A's depth, the
//! camera with distortion, correct within 5 px) against the ground truth's relative pose and
//! against that pose refined by the SLAM's depth alignment
//! (`slam::keyframe_alignment::PairAlignment`: the keyframe alignments' settings and gates, on
//! the sensor's depth at every `map.pixel_stride`-th pixel, without the map's depth-edge
//! filter; the ground truth where the alignment fails its gates). ORB takes no part in either pose, so the pose its matches fit
//! better is the closer to the colour images' motion (lab/notes/slam-results.md, *Does the ground truth close
//! its own loops*).
//!
//! With `--each`, every pair's two scores and refined relative pose too: a pair the ground
//! truth fits far worse than the refined pose is a jump in the ground truth that the images
//! do not show (lab/notes/slam-results.md, *Repeated images and jumps in 7-Scenes' ground truth*).
//!
//! cargo run --release --example refined_gt_check -- SEQUENCE CAMERA FIRST LAST [GAP] [--each]

use anyhow::{Context, bail};
use sdf_slam::camera::Camera;
use sdf_slam::dataset::TumSequence;
use sdf_slam::features::bf_matcher::matched_pixels;
use sdf_slam::features::orb::{OrbConfig, detect_and_compute};
use sdf_slam::geometry::{Pose, pose_to_tum};
use sdf_slam::metrics::matching::{CORRECT_MATCH_PX, MatchingAccuracy, matching_accuracy};
use sdf_slam::raster::rgb_to_gray;
use sdf_slam::slam::SlamConfig;
use sdf_slam::slam::backend::keyframe_alignment::PairAlignment;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let each = args.iter().any(|a| a == "--each");
    let args: Vec<&String> = args.iter().filter(|a| *a != "--each").collect();
    if args.len() < 4 {
        bail!("usage: refined_gt_check SEQUENCE CAMERA FIRST LAST [GAP] [--each]");
    }
    let seq = TumSequence::open(args[0])?;
    let camera = Camera::load(args[1])?;
    let (first, last): (usize, usize) = (args[2].parse()?, args[3].parse()?);
    let gap: usize = args.get(4).map_or(Ok(5), |s| s.parse())?;
    let last = last.min(seq.len());

    let aligner = PairAlignment::new(&camera, &SlamConfig::default());
    let orb = OrbConfig::default();
    // Under the ground truth's relative pose, and under the refined one.
    let mut scores: [Vec<MatchingAccuracy>; 2] = Default::default();
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
        let refined = aligner
            .refine(depth_a, depth_b, &gt)
            .with_context(|| format!("frames {i} and {}", i + gap))?;
        refined_pairs += refined.is_some() as usize;
        let fa = detect_and_compute(&rgb_to_gray(&a.rgb), &orb)?;
        let fb = detect_and_compute(&rgb_to_gray(&b.rgb), &orb)?;
        let matches = matched_pixels(&fa, &fb);
        // A's camera as the world: B's pose is the relative pose.
        for (score, t_ab) in scores.iter_mut().zip([gt, refined.unwrap_or(gt)]) {
            score.push(matching_accuracy(
                &matches,
                depth_a,
                &camera,
                &Pose::identity(),
                &t_ab,
                CORRECT_MATCH_PX,
            )?);
        }
        if each && let (Some(g), Some(r)) = (scores[0].last(), scores[1].last()) {
            let (t, q) = pose_to_tum(&refined.unwrap_or(gt));
            println!(
                "{i} {}: ground truth {:.1} %, refined {:.1} % of {} matches{}; refined T_a_b {} {} {} {} {} {} {}",
                i + gap,
                100.0 * g.accuracy,
                100.0 * r.accuracy,
                g.matches,
                if refined.is_some() {
                    ""
                } else {
                    " (not refined: gates)"
                },
                t[0],
                t[1],
                t[2],
                q[0],
                q[1],
                q[2],
                q[3]
            );
        }
    }
    let [gt, refined] = scores.map(|s| MatchingAccuracy::pool(&s));
    println!(
        "{} frames {first}..{last}, pairs {gap} apart: {pairs}, refined {refined_pairs}; ORB + BF matches within {CORRECT_MATCH_PX} px: ground truth {:.1} % of {}, refined by depth {:.1} % of {}",
        args[0],
        100.0 * gt.accuracy,
        gt.matches,
        100.0 * refined.accuracy,
        refined.matches
    );
    Ok(())
}
