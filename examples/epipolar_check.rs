//! Which translation direction do the colour images support: the ground truth's or the depth
//! alignment's? For every frame pair `(i, i + GAP)`, ORB + BF matches give the translation
//! direction under a fixed rotation (the epipolar constraint is linear in `t`), fitted by
//! iteratively reweighted least squares; it is compared with the ground truth's and with the
//! depth-refined step's direction. Needs no depth beyond the alignment itself and no scale.
//!
//! cargo run --release --example epipolar_check -- SEQUENCE CAMERA FIRST LAST [GAP]

use anyhow::bail;
use nalgebra::{Matrix3, Vector3};
use sdf_slam::camera::{Camera, RayTable};
use sdf_slam::dataset::{DepthImage, TumSequence};
use sdf_slam::features::bf_matcher::matched_pixels;
use sdf_slam::features::orb::{OrbConfig, detect_and_compute};
use sdf_slam::geometry::Pose;
use sdf_slam::raster::rgb_to_gray;
use sdf_slam::slam::SlamConfig;
use sdf_slam::slam::depth_alignment::{DepthModel, align};
use std::sync::Arc;

/// Epipolar distance (normalised units) of a ray pair under `E = [t]x R`.
fn sampson(e: &Matrix3<f64>, fa: &Vector3<f64>, fb: &Vector3<f64>) -> f64 {
    let eb = e * fb;
    let ea = e.transpose() * fa;
    let num = fa.dot(&eb);
    let den = eb.x * eb.x + eb.y * eb.y + ea.x * ea.x + ea.y * ea.y;
    if den <= 0.0 {
        f64::INFINITY
    } else {
        num.abs() / den.sqrt()
    }
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 4 {
        bail!("usage: epipolar_check SEQUENCE CAMERA FIRST LAST [GAP]");
    }
    let seq = TumSequence::open(&args[0])?;
    let camera = Camera::load(&args[1])?;
    let (first, last): (usize, usize) = (args[2].parse()?, args[3].parse()?);
    let gap: usize = args.get(4).map_or(Ok(10), |s| s.parse())?;
    let last = last.min(seq.len());
    let cfg = SlamConfig::default();
    let dense = &cfg.dense;
    let range = (cfg.tracking.min_depth, cfg.tracking.max_depth);
    let stride = cfg.map.pixel_stride;
    let rays = Arc::new(RayTable::new(&camera, stride));
    let view = |depth: &DepthImage| depth.subsample(stride);
    let orb = OrbConfig::default();
    let tau = 1.5 / camera.fx; // inlier gate, 1.5 px
    for i in first..last.saturating_sub(gap) {
        let (a, b) = (seq.load_frame(i)?, seq.load_frame(i + gap)?);
        let (Some(depth_a), Some(depth_b), Some(pa), Some(pb)) =
            (a.depth.as_ref(), b.depth.as_ref(), a.gt_pose, b.gt_pose)
        else {
            continue;
        };
        let gt = pa.inverse() * pb;
        let Some(refined): Option<Pose> = DepthModel::new(
            &view(depth_a),
            &camera,
            rays.clone(),
            dense.model_step,
            range,
        )
        .and_then(|model| align(&model, &view(depth_b), None, &gt, range, dense))
        .filter(|found| found.passes_edge_gates(&gt, dense))
        .map(|found| found.pose) else {
            continue;
        };
        if gt.translation.vector.norm() < 0.03 {
            continue;
        }
        let fa = detect_and_compute(&rgb_to_gray(&a.rgb), &orb)?;
        let fb = detect_and_compute(&rgb_to_gray(&b.rgb), &orb)?;
        let rays_ab: Vec<(Vector3<f64>, Vector3<f64>)> = matched_pixels(&fa, &fb)
            .iter()
            .map(|(x, y)| {
                let (u, v) = (camera.normalized(x), camera.normalized(y));
                (Vector3::new(u.x, u.y, 1.0), Vector3::new(v.x, v.y, 1.0))
            })
            .collect();
        // IRLS for t given R: each match gives n = f_a x (R f_b), t . n = 0. Started from no
        // direction (every match, equal weights), so neither pose is favoured.
        let direction = |pose: &Pose| -> (Vector3<f64>, usize) {
            let rot = pose.rotation.to_rotation_matrix().into_inner();
            let mut t: Option<Vector3<f64>> = None;
            let mut inliers = 0;
            for _ in 0..10 {
                let mut m = Matrix3::zeros();
                inliers = 0;
                for (ra, rb) in &rays_ab {
                    let d = t.map_or(0.0, |t| sampson(&(t.cross_matrix() * rot), ra, rb));
                    if d < 3.0 * tau {
                        let w = 1.0 / (1.0 + (d / tau).powi(2));
                        let n = ra.cross(&(rot * rb));
                        m += w * n * n.transpose() / n.norm_squared().max(1e-12);
                        inliers += (d < tau) as usize;
                    }
                }
                let eig = m.symmetric_eigen();
                let mut nt = eig.eigenvectors.column(eig.eigenvalues.imin()).into_owned();
                if nt.dot(&pose.translation.vector) < 0.0 {
                    nt = -nt;
                }
                t = Some(nt);
            }
            (t.unwrap_or_default(), inliers)
        };
        let ((cg, ig), (cr, ir)) = (direction(&gt), direction(&refined));
        let (tg, tr) = (gt.translation.vector, refined.translation.vector);
        println!(
            "{i} {}: of {}, inliers {ig} {ir}; colour|gt {:.5} {:.5} {:.5}; colour|refined {:.5} {:.5} {:.5}; gt {:.5} {:.5} {:.5}; refined {:.5} {:.5} {:.5}",
            i + gap,
            rays_ab.len(),
            cg.x,
            cg.y,
            cg.z,
            cr.x,
            cr.y,
            cr.z,
            tg.x,
            tg.y,
            tg.z,
            tr.x,
            tr.y,
            tr.z
        );
    }
    Ok(())
}
