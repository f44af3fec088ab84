//! Which relative motion do the colour images support: the ground truth's or the depth
//! alignment's? For every frame pair `(i, i + GAP)` in `FIRST..LAST`, the second frame's depth
//! is aligned to the first's (`slam::keyframe_alignment::PairAlignment`: the keyframe
//! alignments' settings and gates, started from the ground truth), and:
//!
//! * the ground truth's step is compared with the depth-refined step per camera axis
//!   ([`AxisScale`]: translation and rotation-vector slopes, every refined pair);
//! * where the ground truth moves at least 3 cm, ORB + BF matches give the translation
//!   direction under each pose's rotation (the epipolar constraint is linear in `t`;
//!   reweighted least squares started from no direction, 1.5 px), and each pose's own
//!   direction is scored by its angle to that one and by the matches within 1.5 px.
//!
//! The colour images take no part in either pose (lab/notes/slam-results.md, *Repeated images and
//! jumps in 7-Scenes' ground truth*). With `--each`, every pair's figures too.
//!
//! cargo run --release --example epipolar_check -- SEQUENCE CAMERA FIRST LAST [GAP] [--each]

use anyhow::{Context, bail};
use nalgebra::{Matrix3, Vector3};
use sdf_slam::camera::Camera;
use sdf_slam::dataset::TumSequence;
use sdf_slam::features::bf_matcher::matched_pixels;
use sdf_slam::features::orb::{OrbConfig, detect_and_compute};
use sdf_slam::geometry::Pose;
use sdf_slam::metrics::{AxisScale, Stats};
use sdf_slam::raster::rgb_to_gray;
use sdf_slam::slam::SlamConfig;
use sdf_slam::slam::backend::keyframe_alignment::PairAlignment;

/// Inlier gate on the epipolar distance, pixels.
const GATE_PX: f64 = 1.5;
/// Pairs whose ground truth moves less than this (metres) leave the direction uncertain.
const MIN_STEP: f64 = 0.03;

/// Epipolar (Sampson) distance, normalised units, of a ray pair under `E = [t]x R`.
fn sampson(e: &Matrix3<f64>, fa: &Vector3<f64>, fb: &Vector3<f64>) -> f64 {
    let (eb, ea) = (e * fb, e.transpose() * fa);
    let den = eb.x * eb.x + eb.y * eb.y + ea.x * ea.x + ea.y * ea.y;
    if den > 0.0 {
        fa.dot(&eb).abs() / den.sqrt()
    } else {
        f64::INFINITY
    }
}

/// The translation direction the ray pairs support under `pose`'s rotation, and the pairs
/// within `gate` of it. Each pair gives `t · (f_a × R f_b) = 0`; the first round weighs every
/// pair alike, so no pose's own direction is favoured.
fn direction(
    rays: &[(Vector3<f64>, Vector3<f64>)],
    pose: &Pose,
    gate: f64,
) -> (Vector3<f64>, usize) {
    let rot = pose.rotation.to_rotation_matrix().into_inner();
    let mut t: Option<Vector3<f64>> = None;
    let mut inliers = 0;
    for _ in 0..10 {
        let mut m = Matrix3::zeros();
        inliers = 0;
        for (ra, rb) in rays {
            let d = t.map_or(0.0, |t| sampson(&(t.cross_matrix() * rot), ra, rb));
            if d < 3.0 * gate {
                let n = ra.cross(&(rot * rb));
                m += n * n.transpose() / (1.0 + (d / gate).powi(2)) / n.norm_squared().max(1e-12);
                inliers += (d < gate) as usize;
            }
        }
        let eig = m.symmetric_eigen();
        let found = eig.eigenvectors.column(eig.eigenvalues.imin()).into_owned();
        t = Some(if found.dot(&pose.translation.vector) < 0.0 {
            -found
        } else {
            found
        });
    }
    (t.unwrap_or_default(), inliers)
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let each = args.iter().any(|a| a == "--each");
    let args: Vec<&String> = args.iter().filter(|a| *a != "--each").collect();
    if args.len() < 4 {
        bail!("usage: epipolar_check SEQUENCE CAMERA FIRST LAST [GAP] [--each]");
    }
    let seq = TumSequence::open(args[0])?;
    let camera = Camera::load(args[1])?;
    let (first, last): (usize, usize) = (
        args[2].parse().context("FIRST")?,
        args[3].parse().context("LAST")?,
    );
    let gap: usize = args.get(4).map_or(Ok(10), |s| s.parse()).context("GAP")?;
    if gap == 0 {
        bail!("GAP must be at least 1");
    }
    let last = last.min(seq.len());
    let aligner = PairAlignment::new(&camera, &SlamConfig::default());
    let orb = OrbConfig::default();
    let gate = GATE_PX / camera.fx;

    let mut scale = AxisScale::new();
    // Per pair moving at least MIN_STEP: angles to the colour direction (degrees) and
    // inliers, under the ground truth and under the refined pose.
    let (mut angles, mut inliers): ([Vec<f64>; 2], [usize; 2]) = Default::default();
    let mut gt_closer = 0;
    for i in first..last.saturating_sub(gap) {
        let (a, b) = (seq.load_frame(i)?, seq.load_frame(i + gap)?);
        let (Some(depth_a), Some(depth_b), Some(pa), Some(pb)) =
            (a.depth.as_ref(), b.depth.as_ref(), a.gt_pose, b.gt_pose)
        else {
            continue;
        };
        let gt = pa.inverse() * pb;
        let Some(refined) = aligner
            .refine(depth_a, depth_b, &gt)
            .with_context(|| format!("frames {i} and {}", i + gap))?
        else {
            continue;
        };
        scale.add(&gt, &refined);
        if gt.translation.vector.norm() < MIN_STEP {
            continue;
        }
        let fa = detect_and_compute(&rgb_to_gray(&a.rgb), &orb)?;
        let fb = detect_and_compute(&rgb_to_gray(&b.rgb), &orb)?;
        let pair_rays: Vec<(Vector3<f64>, Vector3<f64>)> = matched_pixels(&fa, &fb)
            .iter()
            .map(|(x, y)| {
                (
                    camera.normalized(x).push(1.0),
                    camera.normalized(y).push(1.0),
                )
            })
            .collect();
        let mut pair = [(0.0, 0); 2];
        for (k, pose) in [gt, refined].iter().enumerate() {
            let (colour, n) = direction(&pair_rays, pose, gate);
            let angle = colour.angle(&pose.translation.vector).to_degrees();
            angles[k].push(angle);
            inliers[k] += n;
            pair[k] = (angle, n);
        }
        gt_closer += (pair[0].0 < pair[1].0) as usize;
        if each {
            println!(
                "{i} {}: {} matches; angle to the colour direction {:.2} / {:.2} deg, inliers {} / {} (ground truth / refined)",
                i + gap,
                pair_rays.len(),
                pair[0].0,
                pair[1].0,
                pair[0].1,
                pair[1].1
            );
        }
    }
    let fmt = |v: Option<Vector3<f64>>| {
        v.map_or("-".into(), |v| {
            format!("{:.3} / {:.3} / {:.3}", v.x, v.y, v.z)
        })
    };
    println!(
        "{} frames {first}..{last}, pairs {gap} apart refined by depth: {}; the ground truth's step on the refined one, per camera axis (x / y / z): translation {}, rotation {}",
        args[0],
        scale.pairs,
        fmt(scale.translation()),
        fmt(scale.rotation())
    );
    let n = angles[0].len();
    let [g, r] = angles.map(|a| Stats::of(&a).map_or(f64::NAN, |s| s.median));
    println!(
        "pairs moving at least {MIN_STEP} m: {n}; median angle to the colour images' direction: ground truth {g:.1} deg, refined {r:.1} deg; matches within {GATE_PX} px: {:.0} / {:.0} per pair; the ground truth closer in {gt_closer} ({:.0} %)",
        inliers[0] as f64 / n.max(1) as f64,
        inliers[1] as f64 / n.max(1) as f64,
        100.0 * gt_closer as f64 / n.max(1) as f64
    );
    Ok(())
}
