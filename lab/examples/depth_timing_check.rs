//! Which instant a TUM depth image was taken at: ICP between consecutive depth images
//! compared with the ground truth's motion between their colour stamps and between their
//! depth stamps, on the pairs whose two offsets differ (lab/notes/slam-results.md, *Depth taken after the
//! colour*). Usage: `cargo run --release --example depth_timing_check -- SEQUENCE [CAMERA]`
//! (CAMERA as `slam --camera`: a preset name or a camera.toml; default `fr1`).
use sdf_slam::camera::{Camera, RayTable};
use sdf_slam::dataset::TumSequence;
use sdf_slam::geometry::rotation_angle;
use sdf_slam::slam::config::DenseConfig;
use sdf_slam::slam::frontend::depth_alignment::{DepthModel, align};
use std::sync::Arc;

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let root = args
        .next()
        .ok_or_else(|| anyhow::anyhow!("usage: depth_timing_check SEQUENCE [CAMERA]"))?;
    let seq = TumSequence::open(&root)?;
    let cam = Camera::load(&args.next().unwrap_or_else(|| "fr1".into()))?;
    let rays = Arc::new(RayTable::new(&cam, 1));
    let cfg = DenseConfig::default();
    let range = (0.1, 6.0);
    let (mut sum_rgb, mut sum_depth, mut n) = (0.0, 0.0, 0);
    for i in 0..seq.frames.len().saturating_sub(1) {
        let (a, b) = (&seq.frames[i], &seq.frames[i + 1]);
        let (Some(ta), Some(tb)) = (a.depth_stamp, b.depth_stamp) else {
            continue;
        };
        let (Some(ra), Some(rb), Some(da), Some(db)) = (
            seq.gt_pose_at(a.rgb_stamp),
            seq.gt_pose_at(b.rgb_stamp),
            seq.gt_pose_at(ta),
            seq.gt_pose_at(tb),
        ) else {
            continue;
        };
        let (fa, fb) = (seq.load_frame(i)?, seq.load_frame(i + 1)?);
        let (Some(depth_a), Some(depth_b)) = (fa.depth.as_ref(), fb.depth.as_ref()) else {
            continue;
        };
        let Some(model) = DepthModel::new(depth_a, &cam, rays.clone(), 2, range) else {
            anyhow::bail!("the camera does not fit the depth images of {root}");
        };
        let by_rgb = ra.inverse() * rb;
        let by_depth = da.inverse() * db;
        let Some(icp) = align(&model, depth_b, &by_rgb, range, &cfg) else {
            continue;
        };
        let e_rgb = rotation_angle(&(icp.pose.rotation.inverse() * by_rgb.rotation)).to_degrees();
        let e_depth =
            rotation_angle(&(icp.pose.rotation.inverse() * by_depth.rotation)).to_degrees();
        let offs = ((ta - a.rgb_stamp) * 1e3, (tb - b.rgb_stamp) * 1e3);
        println!(
            "{i:3} offsets {:6.2} {:6.2} ms  ICP vs GT(rgb) {e_rgb:.3} deg  vs GT(depth) {e_depth:.3} deg  turn {:.2} deg",
            offs.0,
            offs.1,
            rotation_angle(&by_rgb.rotation).to_degrees()
        );
        if (offs.0 - offs.1).abs() > 2.0 {
            sum_rgb += e_rgb;
            sum_depth += e_depth;
            n += 1;
        }
    }
    println!(
        "pairs whose offsets differ by > 2 ms: {n}; mean ICP rotation error against GT at colour stamps {:.3} deg, at depth stamps {:.3} deg",
        sum_rgb / n.max(1) as f64,
        sum_depth / n.max(1) as f64
    );
    Ok(())
}
