//! Outputs of a run, all written atomically: `trajectory.txt` (every frame, TUM),
//! `keyframes.txt`, `map.ply`, `map_topdown.png`, `trajectory.png`, and `report.md` /
//! `report.json` ([`report`]), the report last: a folder holds a finished run exactly when it
//! has one. [`evaluation`] measures the run against the sequence's ground truth, [`ply`]
//! writes (and reads) the map, [`topdown`] draws it.

pub mod evaluation;
pub mod ply;
pub mod report;
pub mod topdown;

use crate::camera::Camera;
use crate::dataset::TumSequence;
use crate::error::{Error, Result};
use crate::slam::config::SlamConfig;
use crate::slam::system::SlamOutput;
use evaluation::{evaluate_map_accuracy, evaluate_trajectory, keyframe_ates};
use ply::write_ply;
use report::Report;
use std::path::{Path, PathBuf};
use topdown::render_topdown;

/// Writes only `trajectory.txt` (e.g. as soon as a run is interrupted).
pub fn write_trajectory(out: &SlamOutput, dir: &Path) -> Result<PathBuf> {
    retire_manifest(dir)?;
    let p = dir.join("trajectory.txt");
    out.trajectory().write_tum(&p)?;
    Ok(p)
}

/// `report.json` is written last and lists the run's files: a folder holds a finished run
/// exactly when it has one. Before a run writes over an earlier one, the earlier report
/// goes first, so that a run killed half-way never leaves old and new files looking like
/// one run.
fn retire_manifest(dir: &Path) -> Result<()> {
    for name in ["report.json", "report.md"] {
        let p = dir.join(name);
        match std::fs::remove_file(&p) {
            Ok(()) => crate::io::sync_parent(&p).map_err(|e| Error::io(&p, e))?,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => return Err(Error::io(&p, e)),
        }
    }
    Ok(())
}

/// Writes every output into `dir` (the report last, see `retire_manifest`) and returns
/// the report.
pub fn write_outputs(
    out: &SlamOutput,
    seq: &TumSequence,
    camera: &Camera,
    cfg: &SlamConfig,
    dir: &Path,
) -> Result<Report> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let mut outputs = vec![write_trajectory(out, dir)?];
    let kf_path = dir.join("keyframes.txt");
    out.keyframe_trajectory().write_tum(&kf_path)?;
    outputs.push(kf_path);
    let points = out.semantic_map.points(&cfg.labels, cfg.map.min_views);
    let ply = dir.join("map.ply");
    write_ply(&ply, &points, cfg.map.ply_ascii)?;
    outputs.push(ply);
    let top = dir.join("map_topdown.png");
    let kf_poses: Vec<_> = out.map.keyframes.iter().map(|k| k.pose).collect();
    render_topdown(
        &top,
        &format!(
            "{}: semantic map from above ({} points)",
            seq.name(),
            points.len()
        ),
        &points,
        &kf_poses,
        // The map's own (a monocular map scaled by the camera height scales its voxels).
        out.semantic_map.voxel_size,
        cfg.map.topdown_size,
    )?;
    outputs.push(top);
    let estimate = out.trajectory();
    let trajectory = evaluate_trajectory(seq.groundtruth.as_ref(), &estimate, out.depth);
    let traj_png = dir.join("trajectory.png");
    match (&seq.groundtruth, estimate.len() >= 3, &trajectory.drawn) {
        (Some(_), true, Some((a, how))) => {
            let times: Vec<f64> = a
                .estimate
                .stamps
                .iter()
                .map(|t| t - a.estimate.stamps[0])
                .collect();
            crate::plot::trajectory_figure(
                &traj_png,
                &format!(
                    "{}: SLAM ({how:?}-aligned) vs ground truth, ATE RMSE {:.4} m",
                    seq.name(),
                    a.stats.rmse
                ),
                &[
                    ("ground truth", &a.reference.positions()),
                    ("SLAM", &a.estimate.positions()),
                ],
                Some(("ATE (m)", &times, &a.errors)),
            )?;
            outputs.push(traj_png);
        }
        (Some(_), true, None) => {}
        _ => {
            crate::plot::trajectory_figure(
                &traj_png,
                &format!("{}: SLAM trajectory (no ground truth)", seq.name()),
                &[("SLAM", &estimate.positions())],
                None,
            )?;
            outputs.push(traj_png);
        }
    }
    let map_accuracy = evaluate_map_accuracy(out, seq, camera, cfg, &points)?;
    let mut report = Report::new(out, seq, &points, trajectory, map_accuracy);
    report.keyframe_ate = keyframe_ates(seq.groundtruth.as_ref(), out);
    let json_path = dir.join("report.json");
    let md_path = dir.join("report.md");
    outputs.push(json_path.clone());
    outputs.push(md_path.clone());
    report.outputs = outputs;
    let mut json = serde_json::to_vec_pretty(&report)?;
    json.push(b'\n');
    crate::io::write_atomic(&json_path, &json)?;
    crate::io::write_atomic(&md_path, report.markdown().as_bytes())?;
    Ok(report)
}
