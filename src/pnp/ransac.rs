//! RANSAC over P3P, with the input checks and the final refinement.

use super::{PnpConfig, PnpResult, p3p, refine_pose, squared_error};
use crate::camera::Camera;
use crate::error::{Error, Result};
use nalgebra::{Isometry3, Point2, Point3, Vector2, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn check_inputs(points: &[Point3<f64>], pixels: &[Point2<f64>], cfg: &PnpConfig) -> Result<()> {
    if points.len() != pixels.len() {
        return Err(Error::msg(format!(
            "PnP: {} 3D points but {} pixels",
            points.len(),
            pixels.len()
        )));
    }
    if points.len() < 4 {
        return Err(Error::msg(format!(
            "PnP needs at least 4 correspondences, got {}",
            points.len()
        )));
    }
    if let Some(k) = points
        .iter()
        .position(|p| !p.coords.iter().all(|v| v.is_finite()))
    {
        return Err(Error::msg(format!("PnP: 3D point {k} is not finite")));
    }
    if let Some(k) = pixels
        .iter()
        .position(|p| !(p.x.is_finite() && p.y.is_finite()))
    {
        return Err(Error::msg(format!("PnP: pixel {k} is not finite")));
    }
    if !(cfg.threshold_px.is_finite() && cfg.threshold_px > 0.0) {
        return Err(Error::msg(format!(
            "PnP: inlier threshold must be a positive number of pixels, got {}",
            cfg.threshold_px
        )));
    }
    if !(cfg.confidence > 0.0 && cfg.confidence < 1.0) {
        return Err(Error::msg(format!(
            "PnP: RANSAC confidence must be in (0, 1), got {}",
            cfg.confidence
        )));
    }
    Ok(())
}

/// Estimates the motion from the reference camera (where `points` are expressed)
/// to the current camera (where `pixels`, distorted, are observed), with RANSAC
/// over Lambda Twist P3P and Levenberg-Marquardt refinement. `prior` (e.g. a
/// constant-velocity guess) is scored first. Errors when there are fewer than 4
/// correspondences, on non-finite input, or when no model reaches
/// `cfg.min_inliers` (at least 4).
pub fn solve_pnp_ransac(
    points: &[Point3<f64>],
    pixels: &[Point2<f64>],
    camera: &Camera,
    prior: Option<&Isometry3<f64>>,
    cfg: &PnpConfig,
) -> Result<PnpResult> {
    check_inputs(points, pixels, cfg)?;
    let n = points.len();
    let normalized: Vec<Vector2<f64>> = pixels.iter().map(|p| camera.normalized(p)).collect();
    let bearings: Vec<Vector3<f64>> = normalized
        .iter()
        .map(|v| Vector3::new(v.x, v.y, 1.0))
        .collect();
    let focal = (camera.fx, camera.fy);
    let thr2 = cfg.threshold_px * cfg.threshold_px;
    let count = |pose: &Isometry3<f64>| -> (usize, f64) {
        let mut inl = 0;
        let mut err = 0.0;
        for (p, nv) in points.iter().zip(&normalized) {
            let e = squared_error(pose, p, nv, focal);
            if e <= thr2 {
                inl += 1;
                err += e;
            }
        }
        (inl, err)
    };
    // Best model so far: (inliers, sum of inlier squared errors, pose).
    let mut best: Option<(usize, f64, Isometry3<f64>)> = None;
    let consider = |pose: Isometry3<f64>, best: &mut Option<(usize, f64, Isometry3<f64>)>| {
        let (inl, err) = count(&pose);
        let better = match best {
            None => inl > 0,
            Some((bi, be, _)) => inl > *bi || (inl == *bi && err < *be),
        };
        if better {
            *best = Some((inl, err, pose));
        }
    };
    if let Some(p) = prior {
        consider(crate::geometry::renormalized(p), &mut best);
    }
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    let mut needed = cfg.max_iterations;
    let mut iterations = 0;
    while iterations < needed.min(cfg.max_iterations) {
        iterations += 1;
        let i = rng.random_range(0..n);
        let mut j = rng.random_range(0..n - 1);
        if j >= i {
            j += 1;
        }
        let mut k = rng.random_range(0..n - 2);
        for m in [i.min(j), i.max(j)] {
            if k >= m {
                k += 1;
            }
        }
        let sample = [points[i], points[j], points[k]];
        if (sample[1] - sample[0])
            .cross(&(sample[2] - sample[0]))
            .norm_squared()
            < 1e-18
        {
            continue;
        }
        for pose in p3p(&[bearings[i], bearings[j], bearings[k]], &sample) {
            consider(pose, &mut best);
        }
        if let Some((inl, _, _)) = best {
            let w = inl as f64 / n as f64;
            let p_fail = 1.0 - w * w * w;
            needed = if p_fail <= f64::EPSILON {
                iterations
            } else {
                let k = ((1.0 - cfg.confidence).ln() / p_fail.ln()).ceil();
                if k.is_finite() {
                    k.max(1.0) as usize
                } else {
                    usize::MAX
                }
            };
        }
    }
    let min_inliers = cfg.min_inliers.max(4);
    let Some((inl, _, mut pose)) = best.filter(|b| b.0 >= min_inliers) else {
        return Err(Error::msg(format!(
            "PnP failed: no pose explains at least {min_inliers} of {n} correspondences within {} px (best: {})",
            cfg.threshold_px,
            best.map_or(0, |b| b.0)
        )));
    };
    let inlier_mask = |pose: &Isometry3<f64>| -> Vec<bool> {
        points
            .iter()
            .zip(&normalized)
            .map(|(p, nv)| squared_error(pose, p, nv, focal) <= thr2)
            .collect()
    };
    // Refine on the inliers, re-select them, refine again.
    for _ in 0..2 {
        let (sel_p, sel_n): (Vec<Point3<f64>>, Vec<Vector2<f64>>) = inlier_mask(&pose)
            .iter()
            .enumerate()
            .filter(|&(_, &m)| m)
            .map(|(k, _)| (points[k], normalized[k]))
            .unzip();
        if sel_p.len() < 4 {
            break;
        }
        pose = refine_pose(&sel_p, &sel_n, focal, &pose, cfg.refine_iterations);
    }
    let mask = inlier_mask(&pose);
    let n_inliers = mask.iter().filter(|&&m| m).count();
    if n_inliers < min_inliers {
        return Err(Error::msg(format!(
            "PnP failed: refinement left {n_inliers} inliers (RANSAC had {inl})"
        )));
    }
    let sq: f64 = mask
        .iter()
        .enumerate()
        .filter(|&(_, &m)| m)
        .map(|(k, _)| squared_error(&pose, &points[k], &normalized[k], focal))
        .sum();
    Ok(PnpResult {
        pose: crate::geometry::renormalized(&pose),
        inliers: mask,
        n_inliers,
        rms_px: (sq / n_inliers as f64).sqrt(),
        iterations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::TumSequence;
    use crate::features::bf_matcher::bf_match;
    use crate::features::orb::{OrbConfig, detect_and_compute};
    use crate::metrics::PoseErrorSegment;
    use crate::pnp::test_util::{errors, random_pose};
    use crate::raster::rgb_to_gray;
    use nalgebra::UnitQuaternion;

    struct Synthetic {
        pts: Vec<Point3<f64>>,
        px: Vec<Point2<f64>>,
        good: Vec<bool>,
        truth: Isometry3<f64>,
        cam: Camera,
    }

    /// Points 2-3 m in front of the reference camera, seen by the current one with
    /// the fr1 distortion, 0.5 px noise and 40 % gross outliers.
    fn synthetic(seed: u64) -> Synthetic {
        let cam = Camera::tum_fr1();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let truth = random_pose(&mut rng, 0.15, 0.15);
        let (mut pts, mut px, mut good) = (Vec::new(), Vec::new(), Vec::new());
        while pts.len() < 300 {
            let u = Point2::new(rng.random_range(0.0..640.0), rng.random_range(0.0..480.0));
            let p = cam.back_project(&u, rng.random_range(2.0..3.0));
            let Some(q) = cam.project(&(truth * p)) else {
                continue;
            };
            if !cam.contains(&q, 0.0) {
                continue;
            }
            let outlier = rng.random::<f64>() < 0.4;
            let obs = if outlier {
                Point2::new(rng.random_range(0.0..640.0), rng.random_range(0.0..480.0))
            } else {
                let n = |r: &mut ChaCha8Rng| {
                    let (a, b): (f64, f64) = (1.0 - r.random::<f64>(), r.random());
                    0.5 * (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
                };
                Point2::new(q.x + n(&mut rng), q.y + n(&mut rng))
            };
            pts.push(p);
            px.push(obs);
            good.push(!outlier);
        }
        Synthetic {
            pts,
            px,
            good,
            truth,
            cam,
        }
    }

    #[test]
    fn ransac_recovers_a_pose_through_noise_and_40_percent_outliers() {
        for seed in 0..5 {
            let Synthetic {
                pts,
                px,
                good,
                truth,
                cam,
            } = synthetic(seed);
            let res = solve_pnp_ransac(&pts, &px, &cam, None, &PnpConfig::default()).unwrap();
            let (r, t) = errors(&res.pose, &truth);
            let agree = res
                .inliers
                .iter()
                .zip(&good)
                .filter(|(a, b)| a == b)
                .count();
            eprintln!(
                "seed {seed}: rot {r:.4} deg, trans {:.2} mm, {} inliers ({} true), rms {:.2} px, {} iterations",
                t * 1e3,
                res.n_inliers,
                good.iter().filter(|&&g| g).count(),
                res.rms_px,
                res.iterations
            );
            assert!(r < 0.1 && t < 0.01, "seed {seed}: {r} deg {t} m");
            assert!(agree as f64 >= 0.97 * pts.len() as f64);
            assert!(res.rms_px < 1.0);
            // Deterministic for a seed.
            let again = solve_pnp_ransac(&pts, &px, &cam, None, &PnpConfig::default()).unwrap();
            assert_eq!(again, res);
        }
    }

    #[test]
    fn prior_is_tried_first_and_bad_input_is_an_error() {
        let Synthetic {
            pts,
            px,
            truth,
            cam,
            ..
        } = synthetic(9);
        let prior_only = PnpConfig {
            max_iterations: 0,
            ..PnpConfig::default()
        };
        let res = solve_pnp_ransac(&pts, &px, &cam, Some(&truth), &prior_only).unwrap();
        let (r, t) = errors(&res.pose, &truth);
        assert!(r < 0.1 && t < 0.01 && res.iterations == 0);
        assert!(solve_pnp_ransac(&pts, &px, &cam, None, &prior_only).is_err());
        let cfg = PnpConfig::default();
        assert!(solve_pnp_ransac(&pts[..3], &px[..3], &cam, None, &cfg).is_err());
        assert!(solve_pnp_ransac(&pts[..10], &px[..9], &cam, None, &cfg).is_err());
        let mut nan = px.clone();
        nan[2].x = f64::NAN;
        assert!(solve_pnp_ransac(&pts, &nan, &cam, None, &cfg).is_err());
        // All 3D points identical: degenerate, no model.
        let same = vec![Point3::new(0.1, 0.2, 2.0); 20];
        assert!(solve_pnp_ransac(&same, &px[..20], &cam, None, &cfg).is_err());
        let bad = PnpConfig {
            confidence: 1.0,
            ..cfg
        };
        assert!(solve_pnp_ransac(&pts, &px, &cam, None, &bad).is_err());
    }

    #[test]
    fn a_prior_with_a_non_unit_quaternion_gives_a_unit_result() {
        // Tracking chains priors (constant velocity): a result that kept the
        // prior's norm error would feed it back, growing each frame.
        let Synthetic {
            pts,
            px,
            truth,
            cam,
            ..
        } = synthetic(9);
        let off = Isometry3::from_parts(
            truth.translation,
            UnitQuaternion::new_unchecked(truth.rotation.into_inner() * (1.0 + 1e-6)),
        );
        for iterations in [0, 500] {
            let cfg = PnpConfig {
                max_iterations: iterations,
                ..PnpConfig::default()
            };
            let res = solve_pnp_ransac(&pts, &px, &cam, Some(&off), &cfg).unwrap();
            let norm = res.pose.rotation.quaternion().norm();
            assert!((norm - 1.0).abs() < 1e-12, "{iterations}: {norm}");
            let (r, t) = errors(&res.pose, &truth);
            assert!(r < 0.1 && t < 0.01, "{r} {t}");
        }
    }

    #[test]
    fn orb_pnp_on_real_frames_follows_ground_truth() {
        let seq = TumSequence::open(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/datasets/fixtures/tum_fr1_rpy_head10"
        ))
        .unwrap();
        let cam = Camera::tum_fr1();
        let (a, b) = (seq.load_frame(0).unwrap(), seq.load_frame(3).unwrap());
        let cfg = OrbConfig::default();
        let fa = detect_and_compute(&rgb_to_gray(&a.rgb), &cfg).unwrap();
        let fb = detect_and_compute(&rgb_to_gray(&b.rgb), &cfg).unwrap();
        let depth = a.depth.as_ref().unwrap();
        let (mut pts, mut px) = (Vec::new(), Vec::new());
        for m in bf_match(&fa.descriptors, &fb.descriptors, true) {
            let (ka, kb) = (fa.keypoints[m.query], fb.keypoints[m.train]);
            if let Some(z) = depth.at(ka.x as f64, ka.y as f64) {
                pts.push(cam.back_project(&Point2::new(ka.x as f64, ka.y as f64), z as f64));
                px.push(Point2::new(kb.x as f64, kb.y as f64));
            }
        }
        let res = solve_pnp_ransac(&pts, &px, &cam, None, &PnpConfig::default()).unwrap();
        let (pose_a, pose_b) = (a.gt_pose.unwrap(), b.gt_pose.unwrap());
        let gt = pose_b.inverse() * pose_a;
        let (r, t) = errors(&res.pose, &gt);
        // errT/errR of the frame pair (eqs 11-14) on the camera motion T_a⁻¹ T_b.
        let seg = PoseErrorSegment::new(&gt.inverse(), &res.pose.inverse(), None);
        eprintln!(
            "ORB+PnP 0-3: {} correspondences, {} inliers, rms {:.2} px; rotation error {r:.3} deg, translation error {:.1} mm; GT motion {:.3} deg / {:.1} mm; errT {:.1} %, errR {:.3} deg/m",
            pts.len(),
            res.n_inliers,
            res.rms_px,
            t * 1e3,
            gt.rotation.angle().to_degrees(),
            gt.translation.vector.norm() * 1e3,
            100.0 * seg.trans_error / seg.length,
            seg.rot_error_deg / seg.length
        );
        // Measured: 196 inliers, 0.49 deg and 7.4 mm; OpenCV 4.14's ORB + solvePnPRansac
        // on this pair: 0.42 deg and 5.9 mm. The floor is the ground truth's own
        // accuracy on this fast rotation (8.5 deg in 0.1 s).
        assert!(res.n_inliers >= 150);
        assert!(r < 0.8 && t < 0.015, "{r} deg {t} m");
    }
}
