//! How well a TUM sequence's ground truth fits its colour images in time: ORB + BF matches
//! of every frame pair `(i, i + GAP)` scored against the ground truth's projection (A's
//! depth, the camera with distortion, correct within 5 px, as `eval matching` scores them),
//! with the ground truth read `shift` milliseconds from each colour stamp and each keypoint's
//! bearing turned back to its image's middle row at the ground truth's angular velocity for
//! a rolling-shutter readout of `readout` frame times (0: a global shutter). The matches are
//! the same in every cell; only the ground truth's reading of them changes (lab/notes/slam-results.md,
//! *Depth taken after the colour*).
//!
//! cargo run --release --example gt_timing_check -- SEQUENCE [GAP] [CAMERA]

use nalgebra::{Point2, UnitQuaternion, Vector3};
use sdf_slam::camera::Camera;
use sdf_slam::dataset::TumSequence;
use sdf_slam::features::bf_matcher::matched_pixels;
use sdf_slam::features::orb::{OrbConfig, detect_and_compute};
use sdf_slam::raster::rgb_to_gray;

const SHIFTS_MS: [f64; 9] = [-20.0, -15.0, -10.0, -8.0, -5.0, 0.0, 5.0, 10.0, 20.0];
const READOUTS: [f64; 3] = [0.0, 0.5, 1.0];

/// One match: A's keypoint with its depth, B's keypoint, both colour stamps.
struct Match {
    a: Point2<f64>,
    z: f64,
    b: Point2<f64>,
    t_a: f64,
    t_b: f64,
}

/// The ground truth's rotation over one frame time about `t` (rotation vector, camera frame).
fn angular_velocity(seq: &TumSequence, t: f64) -> Option<Vector3<f64>> {
    let half = 0.5 / 30.0;
    let (a, b) = (seq.gt_pose_at(t - half)?, seq.gt_pose_at(t + half)?);
    Some((a.inverse() * b).rotation.scaled_axis())
}

/// `p`'s bearing at its row's instant turned to the image's middle row's.
fn to_middle_row(
    cam: &Camera,
    p: &Point2<f64>,
    w: &Vector3<f64>,
    readout: f64,
) -> Option<Point2<f64>> {
    let frames = readout * (p.y - cam.cy) / cam.height as f64;
    cam.project(&(UnitQuaternion::from_scaled_axis(w * frames) * cam.back_project(p, 1.0)))
}

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let root = args
        .next()
        .ok_or_else(|| anyhow::anyhow!("usage: gt_timing_check SEQUENCE [GAP] [CAMERA]"))?;
    let gap: usize = args.next().map_or(Ok(5), |s| s.parse())?;
    let cam = Camera::load(&args.next().unwrap_or_else(|| "fr1".into()))?;
    let seq = TumSequence::open(&root)?;
    let orb = OrbConfig::default();
    let mut matches = Vec::new();
    for i in 0..seq.len().saturating_sub(gap) {
        let (a, b) = (seq.load_frame(i)?, seq.load_frame(i + gap)?);
        let Some(depth) = a.depth.as_ref() else {
            continue;
        };
        let fa = detect_and_compute(&rgb_to_gray(&a.rgb), &orb)?;
        let fb = detect_and_compute(&rgb_to_gray(&b.rgb), &orb)?;
        for (pa, pb) in matched_pixels(&fa, &fb) {
            if let Some(z) = depth.at(pa.x, pa.y) {
                let (t_a, t_b) = (a.stamp, b.stamp);
                matches.push(Match {
                    a: pa,
                    z: z as f64,
                    b: pb,
                    t_a,
                    t_b,
                });
            }
        }
    }
    println!(
        "{} ORB + BF matches with depth, pairs {gap} frames apart; share within 5 px of the ground truth's projection:",
        matches.len()
    );
    println!("| ground truth read at | global shutter | readout 0.5 frame | readout 1 frame |");
    println!("|---|---|---|---|");
    for shift_ms in SHIFTS_MS {
        let shift = shift_ms / 1000.0;
        let mut row = format!("| colour stamp {shift_ms:+} ms |");
        for readout in READOUTS {
            let (mut correct, mut judged) = (0usize, 0usize);
            for m in &matches {
                let poses = (seq.gt_pose_at(m.t_a + shift), seq.gt_pose_at(m.t_b + shift));
                let speeds = (
                    angular_velocity(&seq, m.t_a + shift),
                    angular_velocity(&seq, m.t_b + shift),
                );
                let (Some(pa), Some(pb), Some(wa), Some(wb)) =
                    (poses.0, poses.1, speeds.0, speeds.1)
                else {
                    continue;
                };
                let (Some(ca), Some(cb)) = (
                    to_middle_row(&cam, &m.a, &wa, readout),
                    to_middle_row(&cam, &m.b, &wb, readout),
                ) else {
                    continue;
                };
                let Some(gt) = cam.project(&(pb.inverse() * (pa * cam.back_project(&ca, m.z))))
                else {
                    continue;
                };
                judged += 1;
                correct += ((gt - cb).norm() <= 5.0) as usize;
            }
            row += &format!(" {:.1} % |", 100.0 * correct as f64 / judged.max(1) as f64);
        }
        println!("{row}");
    }
    Ok(())
}
