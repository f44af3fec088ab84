//! The ORB baseline of the paper's Tables 6 and 7 on a TUM RGB-D sequence: for
//! every frame pair `(i, i + gap)`, ORB (500) + brute-force Hamming matching with
//! cross-check, matching accuracy against ground truth (correct within 5 px), and
//! PnP-RANSAC on the matches with frame i's depth, compared with the ground-truth
//! relative pose. Also counts the FP-dataset pairs (Harris corners mapped by
//! depth and ground truth) of the same frame pairs.
//!
//! cargo run --release --example orb_baseline -- SEQUENCE [GAP] [DEGRADATION]
//! e.g. `... -- /data/rgbd_dataset_freiburg1_desk2 3 motion:9` blurs frame i + gap.

use rand::SeedableRng;
use sdf_slam::camera::Camera;
use sdf_slam::dataset::photometric::Degradation;
use sdf_slam::dataset::{FpConfig, TumSequence, fp_pair};
use sdf_slam::features::bf_matcher::matched_pixels;
use sdf_slam::features::orb::{OrbConfig, detect_and_compute};
use sdf_slam::metrics::PoseErrorSegment;
use sdf_slam::metrics::matching::{CORRECT_MATCH_PX, MatchingAccuracy, matching_accuracy};
use sdf_slam::pnp::{PnpConfig, solve_pnp_ransac};
use sdf_slam::raster::GrayF32;
use sdf_slam::raster::{gray_from_f32, rgb_to_gray};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let Some(root) = args.get(1) else {
        anyhow::bail!("usage: orb_baseline SEQUENCE [GAP] [DEGRADATION]");
    };
    let gap: usize = args.get(2).map_or(Ok(1), |s| s.parse())?;
    let degrade = args.get(3).map(|s| Degradation::parse(s)).transpose()?;
    let seq = TumSequence::open(root)?;
    let cam = Camera::tum_fr1();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0);
    let (mut accs, mut rot, mut trans, mut segs) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let (mut fp_matches, mut fp_pairs, mut keypoints, mut failures) = (0, 0, 0, 0);
    let fp_cfg = FpConfig::default();
    let orb = OrbConfig::default();
    let start = std::time::Instant::now();
    for i in 0..seq.len().saturating_sub(gap) {
        let (a, b) = (seq.load_frame(i)?, seq.load_frame(i + gap)?);
        let (Some(pose_a), Some(pose_b), Some(depth)) = (a.gt_pose, b.gt_pose, a.depth.as_ref())
        else {
            continue;
        };
        let gray_b = match &degrade {
            Some(d) => gray_from_f32(&d.apply(&GrayF32::from_rgb(&b.rgb), &mut rng)),
            None => rgb_to_gray(&b.rgb),
        };
        let fa = detect_and_compute(&rgb_to_gray(&a.rgb), &orb)?;
        let fb = detect_and_compute(&gray_b, &orb)?;
        keypoints += fa.len();
        let pairs: Vec<_> = matched_pixels(&fa, &fb);
        accs.push(matching_accuracy(
            &pairs,
            depth,
            &cam,
            &pose_a,
            &pose_b,
            CORRECT_MATCH_PX,
        )?);
        let (mut pts, mut px) = (Vec::new(), Vec::new());
        for (pa, pb) in &pairs {
            if let Some(z) = depth.at(pa.x, pa.y) {
                pts.push(cam.back_project(pa, z as f64));
                px.push(*pb);
            }
        }
        let gt = pose_b.inverse() * pose_a;
        match solve_pnp_ransac(&pts, &px, &cam, None, &PnpConfig::default()) {
            Ok(r) => {
                let d = r.pose.inverse() * gt;
                rot.push(d.rotation.angle().to_degrees());
                trans.push((r.pose.translation.vector - gt.translation.vector).norm());
                segs.push(PoseErrorSegment::new(
                    &gt.inverse(),
                    &r.pose.inverse(),
                    None,
                ));
            }
            Err(_) => failures += 1,
        }
        let fp = fp_pair(&cam, &a, &b, &fp_cfg)?;
        fp_matches += fp.matches.len();
        fp_pairs += 1;
    }
    let n = accs.len();
    anyhow::ensure!(n > 0, "no frame pair with depth and ground truth");
    let acc = MatchingAccuracy::pool(&accs);
    let median = |v: &[f64]| {
        let mut v = v.to_vec();
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
    };
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    println!(
        "{} pairs (gap {gap}{}), {:.1} ms per pair",
        n,
        degrade.map_or(String::new(), |d| format!(", {d:?} on the second image")),
        start.elapsed().as_secs_f64() * 1e3 / n as f64
    );
    println!(
        "ORB keypoints per image: {:.1}",
        keypoints as f64 / n as f64
    );
    println!(
        "ORB + BF matching accuracy: {}/{} = {:.1} %",
        acc.correct,
        acc.matches,
        100.0 * acc.accuracy
    );
    println!(
        "PnP: {} failures; rotation error mean {:.3} / median {:.3} deg; translation error mean {:.1} / median {:.1} mm",
        failures,
        mean(&rot),
        median(&rot),
        1e3 * mean(&trans),
        1e3 * median(&trans)
    );
    if let Ok(e) = sdf_slam::metrics::PoseError::pool(&segs) {
        println!(
            "errT {:.2} %, errR {:.4} deg/m (pooled over pairs)",
            e.err_t_percent, e.err_r_deg_per_m
        );
    }
    println!(
        "FP pairs: {:.1} matches per pair",
        fp_matches as f64 / fp_pairs.max(1) as f64
    );
    Ok(())
}
