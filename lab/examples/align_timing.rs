//! The dense alignment's time on real frames as tracking runs it: each frame's depth aligned
//! to the depth of the frame `gap` before it (the reference keyframe's model at full
//! resolution, the default `[dense]` levels and iterations), from the identity; prints the
//! median milliseconds and a checksum of the poses, so that a faster build can be checked to
//! give the same poses (lab/notes/cpu-speed.md). Usage: `cargo run --release --example
//! align_timing -- SEQUENCE [CAMERA] [FRAMES] [GAP]`.
use sdf_slam::camera::{Camera, RayTable};
use sdf_slam::dataset::TumSequence;
use sdf_slam::geometry::Pose;
use sdf_slam::slam::config::DenseConfig;
use sdf_slam::slam::frontend::depth_alignment::{DepthModel, align};
use std::sync::Arc;
use std::time::Instant;

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let usage = "usage: align_timing SEQUENCE [CAMERA] [FRAMES] [GAP]";
    let seq = TumSequence::open(args.next().ok_or_else(|| anyhow::anyhow!(usage))?)?;
    let cam = Camera::load(&args.next().unwrap_or_else(|| "fr1".into()))?;
    let n: usize = args.next().map(|s| s.parse()).transpose()?.unwrap_or(40);
    let gap: usize = args.next().map(|s| s.parse()).transpose()?.unwrap_or(2);
    let rays = Arc::new(RayTable::new(&cam, 1));
    let cfg = DenseConfig::default();
    let range = (0.1, 6.0);
    let depths: Vec<_> = (0..n.min(seq.frames.len()))
        .map(|i| seq.load_frame(i).map(|f| f.depth))
        .collect::<Result<_, _>>()?;
    let (mut times, mut model_times, mut checksum) = (Vec::new(), Vec::new(), 0.0f64);
    for i in gap..depths.len() {
        let (Some(a), Some(b)) = (&depths[i - gap], &depths[i]) else {
            continue;
        };
        let t = Instant::now();
        let model = DepthModel::new(a, &cam, rays.clone(), cfg.model_step, range)
            .ok_or_else(|| anyhow::anyhow!("depth not at the camera's size"))?;
        model_times.push(t.elapsed().as_secs_f64() * 1e3);
        let t = Instant::now();
        let got = align(&model, b, &Pose::identity(), range, &cfg);
        times.push(t.elapsed().as_secs_f64() * 1e3);
        if let Some(a) = got {
            checksum += a.pose.translation.vector.sum() + a.pose.rotation.coords.sum();
            checksum += a.inliers as f64 + a.rms;
        }
    }
    anyhow::ensure!(
        !times.is_empty(),
        "no frame pair {gap} apart with depth among the first {n} frames"
    );
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    println!(
        "{} alignments: median {:.2} ms (model {:.2} ms); checksum {checksum:.15e}",
        times.len(),
        median(times),
        median(model_times)
    );
    Ok(())
}
