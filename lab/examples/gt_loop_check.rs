//! Whether a sequence's ground truth agrees with its own depth images when the camera comes
//! back: frame pairs taken every `STEP` frames of `FIRST..LAST`, each pair's relative pose
//! refined by the SLAM's depth alignment (`slam::depth_alignment`: point-to-plane ICP of B's
//! depth against A's, the keyframe alignments' settings and gates, on the sensor's depth at
//! every `map.pixel_stride`-th pixel, without the map's depth-edge filter),
//! started from the ground truth. How far the alignment moves the ground truth's relative
//! pose, for pairs `STEP` frames apart (the sensor's and the ground truth's frame-to-frame
//! noise) and for pairs at least `LONG` frames apart that still see the same surfaces (a
//! revisit: a dense tracker that closes no loops, like the KinectFusion that made 7-Scenes'
//! ground truth, carries its drift into them). Each trajectory file given (TUM format,
//! camera-to-world, stamps of the sequence's colour images) is scored on the same pairs
//! against the same alignments (lab/notes/slam-results.md, *Does the ground truth close its own loops*).
//!
//! cargo run --release --example gt_loop_check -- SEQUENCE CAMERA FIRST LAST [TRAJECTORY ...]

use anyhow::{Context, bail};
use sdf_slam::camera::{Camera, RayTable};
use sdf_slam::dataset::{DepthImage, TumSequence};
use sdf_slam::geometry::Pose;
use sdf_slam::slam::SlamConfig;
use sdf_slam::slam::frontend::depth_alignment::{DepthModel, align};
use sdf_slam::trajectory::Trajectory;
use std::sync::Arc;

/// Frames between the samples, and the least gap of a revisit pair.
const STEP: usize = 5;
const LONG: usize = 50;
/// Revisit candidates: the ground truth's relative pose within these before aligning.
const MAX_TURN_DEG: f64 = 30.0;
const MAX_SHIFT_M: f64 = 0.6;
/// The report's rows: pairs whose frame gap lies in `lo..hi`.
const BINS: [(usize, usize); 5] = [
    (STEP, STEP + 1),
    (LONG, 100),
    (100, 200),
    (200, 400),
    (400, usize::MAX),
];

/// A pair's relative pose from depth (`T_a_b`).
struct Pair {
    a: usize,
    b: usize,
    aligned: Pose,
}

/// Translation (m) and rotation (deg) between two relative poses.
fn difference(x: &Pose, y: &Pose) -> (f64, f64) {
    let d = x.inverse() * y;
    (d.translation.vector.norm(), d.rotation.angle().to_degrees())
}

/// Median and root mean square.
fn stats(mut v: Vec<f64>) -> (f64, f64) {
    if v.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    v.sort_by(f64::total_cmp);
    let rms = (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
    (v[v.len() / 2], rms)
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 4 {
        bail!("usage: gt_loop_check SEQUENCE CAMERA FIRST LAST [TRAJECTORY ...]");
    }
    let seq = TumSequence::open(&args[0])?;
    let camera = Camera::load(&args[1])?;
    let (first, last): (usize, usize) = (args[2].parse()?, args[3].parse()?);
    let last = last.min(seq.len());
    let estimates: Vec<(String, Trajectory)> = args[4..]
        .iter()
        .map(|p| {
            Ok((
                p.clone(),
                Trajectory::read_tum(p).with_context(|| p.clone())?,
            ))
        })
        .collect::<anyhow::Result<_>>()?;

    let cfg = SlamConfig::default();
    let dense = &cfg.dense;
    let range = (cfg.tracking.min_depth, cfg.tracking.max_depth);
    let stride = cfg.map.pixel_stride;
    let rays = Arc::new(RayTable::new(&camera, stride));
    struct Sample {
        index: usize,
        stamp: f64,
        gt: Pose,
        depth: DepthImage,
    }
    let mut samples = Vec::new();
    for index in (first..last).step_by(STEP) {
        let frame = seq.load_frame(index)?;
        let (Some(gt), Some(depth)) = (frame.gt_pose, frame.depth) else {
            continue;
        };
        if (depth.width, depth.height) != (camera.width, camera.height) {
            bail!(
                "frame {index}'s depth is {}x{} but the camera is {}x{}",
                depth.width,
                depth.height,
                camera.width,
                camera.height
            );
        }
        samples.push(Sample {
            index,
            stamp: frame.stamp,
            gt,
            depth: depth.subsample(stride),
        });
    }

    let mut pairs = Vec::new();
    let mut candidates = [0usize; 2];
    for (ia, a) in samples.iter().enumerate() {
        let Some(model) = DepthModel::new(&a.depth, &camera, rays.clone(), dense.model_step, range)
        else {
            continue;
        };
        for b in &samples[ia + 1..] {
            let gap = b.index - a.index;
            let gt = a.gt.inverse() * b.gt;
            let long = gap >= LONG;
            if !(gap == STEP
                || long
                    && gt.translation.vector.norm() <= MAX_SHIFT_M
                    && gt.rotation.angle().to_degrees() <= MAX_TURN_DEG)
            {
                continue;
            }
            candidates[long as usize] += 1;
            let Some(found) = align(&model, &b.depth, &gt, range, dense) else {
                continue;
            };
            if !found.passes_edge_gates(&gt, dense) {
                continue;
            }
            pairs.push(Pair {
                a: a.index,
                b: b.index,
                aligned: found.pose,
            });
        }
    }
    let stamp = |i: usize| samples.iter().find(|s| s.index == i).map(|s| s.stamp);
    let gt_of = |i: usize| samples.iter().find(|s| s.index == i).map(|s| s.gt);

    println!(
        "{} frames {first}..{last} every {STEP}; pairs aligned / tried: {STEP} apart {} / {}, at least {LONG} apart {} / {}",
        args[0],
        pairs.iter().filter(|p| p.b - p.a == STEP).count(),
        candidates[0],
        pairs.iter().filter(|p| p.b - p.a >= LONG).count(),
        candidates[1],
    );
    println!(
        "| poses | pairs | translation from depth, median / RMS (mm) | rotation, median / RMS (deg) |"
    );
    println!("|---|---|---|---|");
    let report = |name: &str, pose_of: &dyn Fn(usize) -> Option<Pose>| {
        for (lo, hi) in BINS {
            let label = if hi == STEP + 1 {
                format!("{STEP} apart")
            } else if hi == usize::MAX {
                format!("{lo} or more apart")
            } else {
                format!("{lo}-{} apart", hi - 1)
            };
            let (mut dt, mut dr) = (Vec::new(), Vec::new());
            for p in pairs.iter().filter(|p| (lo..hi).contains(&(p.b - p.a))) {
                let (Some(a), Some(b)) = (pose_of(p.a), pose_of(p.b)) else {
                    continue;
                };
                let (t, r) = difference(&(a.inverse() * b), &p.aligned);
                dt.push(t * 1000.0);
                dr.push(r);
            }
            let n = dt.len();
            let ((tm, tr), (rm, rr)) = (stats(dt), stats(dr));
            if n == 0 && pairs.iter().any(|p| (lo..hi).contains(&(p.b - p.a))) {
                println!("| {name}, {label} | 0 | no pose at these frames' stamps | |");
            } else if n > 0 {
                println!("| {name}, {label} | {n} | {tm:.1} / {tr:.1} | {rm:.2} / {rr:.2} |");
            }
        }
    };
    report("ground truth", &gt_of);
    // The alignments' own consistency: around each triangle of aligned pairs a -> b -> c
    // against a -> c, the composed relative poses should close (their noise, not the ground
    // truth's).
    let find = |a: usize, b: usize| pairs.iter().find(|p| p.a == a && p.b == b);
    let (mut ct, mut cr) = (Vec::new(), Vec::new());
    for ab in &pairs {
        for bc in pairs.iter().filter(|p| p.a == ab.b) {
            if let Some(ac) = find(ab.a, bc.b)
                && ac.b - ac.a >= LONG
            {
                let (t, r) = difference(&(ab.aligned * bc.aligned), &ac.aligned);
                ct.push(t * 1000.0);
                cr.push(r);
            }
        }
    }
    let n = ct.len();
    let ((tm, tr), (rm, rr)) = (stats(ct), stats(cr));
    println!(
        "| alignments around triangles a-b-c (a-c at least {LONG} apart) | {n} | {tm:.1} / {tr:.1} | {rm:.2} / {rr:.2} |"
    );
    for (name, trajectory) in &estimates {
        report(name, &|i| trajectory.pose_at(stamp(i)?, 0.005));
    }
    Ok(())
}
