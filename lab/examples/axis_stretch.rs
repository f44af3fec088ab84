//! How much of a trajectory's ATE an uneven per-axis stretch of the reference makes: the
//! reference's `GAP`-frame steps against the estimate's, per camera axis ([`AxisScale`]; pairs
//! where the reference moves at least 3 cm), then the estimate re-chained from its own
//! consecutive steps with each step's translation stretched per axis (by `SX SY SZ` when
//! given, else by the slopes just measured) and scored by ATE after SE(3) alignment, as run
//! and stretched (lab/notes/slam-results.md, *Repeated images and jumps in 7-Scenes' ground truth*).
//!
//! cargo run --release --example axis_stretch -- GROUNDTRUTH ESTIMATE [GAP] [SX SY SZ]

use anyhow::{Context, bail};
use nalgebra::{Translation3, Vector3};
use sdf_slam::metrics::{Alignment, AxisScale, ape, associate};
use sdf_slam::trajectory::Trajectory;

/// evo's default association window, seconds.
const T_MAX_DIFF: f64 = 0.01;
/// Reference steps shorter than this (metres) are left out of the slopes.
const MIN_STEP: f64 = 0.03;

/// `estimate` rebuilt from its first pose and its consecutive steps, each step's translation
/// (in the earlier camera's frame) multiplied per axis by `stretch`.
fn rechain(estimate: &Trajectory, stretch: &Vector3<f64>) -> anyhow::Result<Trajectory> {
    let mut poses = Vec::with_capacity(estimate.len());
    for (i, pose) in estimate.poses.iter().enumerate() {
        poses.push(match i {
            0 => *pose,
            _ => {
                let mut step = estimate.poses[i - 1].inverse() * pose;
                step.translation =
                    Translation3::from(step.translation.vector.component_mul(stretch));
                poses[i - 1] * step
            }
        });
    }
    Ok(Trajectory::from_parts(estimate.stamps.clone(), poses)?)
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if !matches!(args.len(), 2 | 3 | 6) {
        bail!("usage: axis_stretch GROUNDTRUTH ESTIMATE [GAP] [SX SY SZ]");
    }
    let (reference, estimate) = (
        Trajectory::read_tum(&args[0])?,
        Trajectory::read_tum(&args[1])?,
    );
    let gap: usize = args.get(2).map_or(Ok(10), |s| s.parse()).context("GAP")?;
    if gap == 0 {
        bail!("GAP must be at least 1");
    }
    let (reference, estimate) = associate(&reference, &estimate, T_MAX_DIFF)?;
    let mut scale = AxisScale::new();
    let (r, e) = (&reference.poses, &estimate.poses);
    for i in 0..r.len().saturating_sub(gap) {
        let step = r[i].inverse() * r[i + gap];
        if step.translation.vector.norm() >= MIN_STEP {
            scale.add(&step, &(e[i].inverse() * e[i + gap]));
        }
    }
    let measured = scale.translation();
    let fmt = |v: &Vector3<f64>| format!("{:.3} / {:.3} / {:.3}", v.x, v.y, v.z);
    println!(
        "{} pairs {gap} poses apart moving at least {MIN_STEP} m: {}; the reference's step on the estimate's, per camera axis (x / y / z): translation {}, rotation {}",
        args[1],
        scale.pairs,
        measured.as_ref().map_or("-".into(), fmt),
        scale.rotation().as_ref().map_or("-".into(), fmt)
    );
    let stretch = if args.len() == 6 {
        let v: Vec<f64> = args[3..6]
            .iter()
            .map(|s| s.parse())
            .collect::<Result<_, _>>()
            .context("SX SY SZ")?;
        Vector3::new(v[0], v[1], v[2])
    } else if let Some(m) = measured {
        m
    } else {
        bail!("the estimate does not move along every axis: give SX SY SZ");
    };
    if !stretch.iter().all(|s| s.is_finite() && *s > 0.0) {
        bail!("the stretch must be positive and finite: {}", fmt(&stretch));
    }
    let as_run = ape(&reference, &estimate, Alignment::Se3, T_MAX_DIFF)?;
    let stretched = ape(
        &reference,
        &rechain(&estimate, &stretch)?,
        Alignment::Se3,
        T_MAX_DIFF,
    )?;
    println!(
        "ATE (SE(3)) {:.4} m as run, {:.4} m with each step stretched by {}",
        as_run.stats.rmse,
        stretched.stats.rmse,
        fmt(&stretch)
    );
    Ok(())
}
