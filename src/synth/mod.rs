//! Synthetic indoor RGB-D sequences with exact depth, NYU40 labels and camera
//! poses, standing in for TUM RGB-D and NYUv2 where they cannot be downloaded.
//!
//! Procedural rooms ([`scene`], `furniture`, `texture`) are ray cast
//! ([`render`]) along planned camera motions ([`trajectory`]), turned into
//! sensor-like images ([`sensor`]) and written ([`writer`]). The same seed and
//! configuration give byte-identical files on every machine: all randomness is
//! ChaCha8 or integer hashing, and trigonometry is done with basic IEEE
//! operations (`detmath`).
//!
//! # Output layout (`OUT/`)
//!
//! ```text
//! OUT/scene.json            seed, full configuration, camera, per-scene room and
//!                           label histograms (pixels per class over each sequence)
//! OUT/config.toml           the configuration used (regenerate with --config)
//! OUT/seq_000/              one TUM RGB-D sequence per scene (seq_001, ...):
//!   rgb/<t>.png             8-bit colour, <t> = timestamp with 6 decimals
//!   depth/<t>.png           16-bit sensor depth, metres x 5000, 0 = no reading
//!   depth_gt/<t>.png        16-bit exact depth (output.gt_depth)
//!   labels/<t>.png          8-bit NYU40 labels, 0-based, 255 = void
//!   labels_color/<t>.png    labels in the NYU40 palette (output.color_labels)
//!   rgb.txt depth.txt labels.txt depth_gt.txt   `timestamp filename` lists
//!   associations.txt        `t rgb/t.png t depth/t.png`
//!   groundtruth.txt         `t tx ty tz qx qy qz qw`, camera-to-world, at each frame
//!   camera.toml             intrinsics and distortion used to render
//!   scene.json              this scene's part of OUT/scene.json
//! OUT/nyu/                  segmentation / depth training set, NYU PNG layout:
//!   rgb/NNNNNN.png          8-bit colour (with sensor noise), NNNNNN 1-based
//!   depth/NNNNNN.png        16-bit exact depth, metres x 5000 (like NYU's filled depth)
//!   labels/NNNNNN.png       8-bit NYU40 labels, 0-based, 255 = void
//!   train.txt test.txt      image names (NNNNNN), one per line; whole scenes
//!                           go to test when there are several scenes
//!   camera.toml
//! ```
//!
//! The NYU-layout images are independent random views of each room (not
//! sequence frames), `output.nyu_views_per_scene` per scene.

pub mod config;
pub(crate) mod detmath;
pub(crate) mod furniture;
pub(crate) mod geom;
pub mod render;
pub mod scene;
pub mod sensor;
pub(crate) mod shadow;
pub(crate) mod texture;
pub mod trajectory;
pub mod writer;

#[cfg(test)]
mod checks;

pub use config::{SynthConfig, TrajectoryKind};
pub use render::{Render, Renderer};
pub use scene::Scene;
pub use trajectory::Motion;

use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::geometry::Pose;
use crate::trajectory::Trajectory;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde_json::{Value, json};
use std::path::Path;
use writer::{FrameFiles, Histogram};

/// Seed of scene `index` derived from the master seed (SplitMix64).
pub fn scene_seed(seed: u64, index: usize) -> u64 {
    let mut z = seed
        ^ (index as u64)
            .wrapping_add(1)
            .wrapping_mul(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Number of work units (frames and views) [`generate`] reports progress in.
pub fn work_units(cfg: &SynthConfig) -> u64 {
    let per_scene = if cfg.output.sequence { cfg.frames } else { 0 }
        + if cfg.output.nyu {
            cfg.output.nyu_views_per_scene
        } else {
            0
        };
    (cfg.scenes * per_scene) as u64
}

/// What [`generate`] wrote.
#[derive(Debug, Clone)]
pub struct Summary {
    /// Sequence frames written, over all scenes.
    pub frames: usize,
    /// NYU-layout views listed in `train.txt`.
    pub nyu_train: usize,
    /// NYU-layout views listed in `test.txt`.
    pub nyu_test: usize,
    /// Label pixels per class over the sequences and the NYU-layout views.
    pub histogram: Histogram,
}

/// Frame timestamps as written (6 decimals) and as numbers.
pub(crate) fn frame_stamps(cfg: &SynthConfig) -> (Vec<String>, Vec<f64>) {
    let names: Vec<String> = (0..cfg.frames)
        .map(|k| format!("{:.6}", cfg.start_time + k as f64 / cfg.fps))
        .collect();
    let values = names.iter().map(|s| s.parse().unwrap_or(0.0)).collect();
    (names, values)
}

/// Times (seconds from the first frame) of the renders averaged into frame `k`.
pub(crate) fn blur_offsets(cfg: &SynthConfig) -> Vec<f64> {
    let b = &cfg.blur;
    if !b.enabled || b.samples <= 1 {
        return vec![0.0];
    }
    let n = b.samples | 1;
    let e = b.exposure_ms / 1000.0;
    (0..n)
        .map(|j| (j as f64 / (n - 1) as f64 - 0.5) * e)
        .collect()
}

/// Renders frame images at time `t`: colour averaged over the exposure, depth
/// and labels of the centre pose. `ae` is the auto-exposure gain of the
/// previous frame (the camera adapts over a few frames); returns the new one.
pub fn render_frame(
    renderer: &Renderer,
    motion: &Motion,
    cfg: &SynthConfig,
    t: f64,
    noise_seed: u32,
    ae: Option<f32>,
) -> (FrameFiles, Pose, f32) {
    let offsets = blur_offsets(cfg);
    let pose = motion.pose(t);
    let centre = renderer.render(&pose);
    let mut acc: Vec<[f32; 3]> = centre.px.iter().map(|p| p.rgb).collect();
    if offsets.len() > 1 {
        for &o in offsets.iter().filter(|&&o| o != 0.0) {
            let sub = renderer.render(&motion.pose(t + o));
            for (a, p) in acc.iter_mut().zip(&sub.px) {
                for (v, c) in a.iter_mut().zip(p.rgb) {
                    *v += c;
                }
            }
        }
        let k = 1.0 / offsets.len() as f32;
        acc.iter_mut()
            .for_each(|a| a.iter_mut().for_each(|v| *v *= k));
    }
    let target = sensor::auto_exposure(&acc);
    let ae = ae.map_or(target, |g| 0.75 * g + 0.25 * target);
    let gain = ae * sensor::exposure_gain(&cfg.sensor, noise_seed, t);
    let files = finish(&centre, &acc, gain, cfg, &renderer.camera, noise_seed);
    (files, pose, ae)
}

fn finish(
    centre: &Render,
    rgb: &[[f32; 3]],
    gain: f32,
    cfg: &SynthConfig,
    cam: &Camera,
    seed: u32,
) -> FrameFiles {
    let depth_gt = sensor::exact_depth(centre);
    let sensor_on = cfg.sensor.depth_noise || cfg.sensor.depth_holes || cfg.sensor.min_depth > 0.0;
    FrameFiles {
        rgb: sensor::color_image(
            rgb,
            centre.width,
            centre.height,
            gain,
            &cfg.render,
            &cfg.sensor,
            seed,
        ),
        depth: if sensor_on {
            sensor::sensor_depth(centre, cam, &cfg.sensor, seed)
        } else {
            depth_gt.clone()
        },
        depth_gt: cfg.output.gt_depth.then_some(depth_gt),
        labels: sensor::label_image(centre),
        color_labels: cfg.output.color_labels,
    }
}

/// Generates everything the configuration asks for into `out`, calling
/// `progress` with the number of frames / views just finished.
pub fn generate(cfg: &SynthConfig, out: &Path, progress: &(dyn Fn(u64) + Sync)) -> Result<Summary> {
    cfg.validate()?;
    let camera = cfg.camera()?;
    writer::prepare_out(out)?;
    crate::io::write_atomic(out.join("config.toml"), cfg.to_toml()?.as_bytes())?;
    let views = if cfg.output.nyu {
        cfg.output.nyu_views_per_scene
    } else {
        0
    };
    let mut scenes_json = Vec::new();
    let mut totals = Histogram::default();
    let mut nyu_totals = Histogram::default();
    let (mut train, mut test) = (Vec::new(), Vec::new());
    let mut frames_written = 0;
    let frac = cfg.output.nyu_test_fraction;
    let is_test =
        |i: usize, n: usize| ((i + 1) as f64 * frac).floor() > (i as f64 * frac).floor() && n > 0;
    for s in 0..cfg.scenes {
        let seed = scene_seed(cfg.seed, s);
        let scene = Scene::generate(&cfg.room, seed)?;
        let renderer = Renderer::new(&scene, &camera, &cfg.render);
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x7a11_ec70_9e5e_ed00);
        let job = SceneJob {
            cfg,
            scene: &scene,
            renderer: &renderer,
            camera: &camera,
            index: s,
            seed,
            out,
            progress,
        };
        let mut info = json!({
            "index": s,
            "seed": seed,
            "room": {
                "kind": scene.room.kind,
                "width": scene.room.width,
                "depth": scene.room.depth,
                "height": scene.room.height,
                "l_shaped": scene.room.notch.is_some(),
                "notch": scene.room.notch,
            },
            "solids": scene.solids.len(),
            "lights": scene.lights.len(),
            "classes_in_scene": scene.labels().iter().filter_map(|&l| crate::classes::name(l)).collect::<Vec<_>>(),
        });
        if cfg.output.sequence {
            let hist = write_sequence(&job, &mut rng, &mut info)?;
            totals.add(&hist);
            frames_written += cfg.frames;
        }
        if views > 0 {
            let hist = write_nyu_views(&job, views, &mut rng)?;
            for v in 0..views {
                let name = format!("{:06}", s * views + v + 1);
                let test_item = if cfg.scenes > 1 {
                    is_test(s, cfg.scenes)
                } else {
                    is_test(v, views)
                };
                if test_item {
                    test.push(name)
                } else {
                    train.push(name)
                }
            }
            info["nyu_label_histogram"] = hist.to_json();
            info["nyu_classes_in_view"] = json!(hist.classes_present());
            nyu_totals.add(&hist);
        }
        scenes_json.push(info);
    }
    let nyu = if views > 0 {
        let dir = out.join("nyu");
        writer::write_split(&dir.join("train.txt"), &train)?;
        writer::write_split(&dir.join("test.txt"), &test)?;
        camera.save(dir.join("camera.toml"))?;
        json!({
            "folder": "nyu",
            "train": train.len(),
            "test": test.len(),
            "depth": "exact",
            "label_histogram": nyu_totals.to_json(),
            "classes_in_view": nyu_totals.classes_present(),
        })
    } else {
        Value::Null
    };
    let bytes = writer::scene_json(cfg, &camera, scenes_json, &totals, nyu)?;
    crate::io::write_atomic(out.join("scene.json"), &bytes)?;
    totals.add(&nyu_totals);
    Ok(Summary {
        frames: frames_written,
        nyu_train: train.len(),
        nyu_test: test.len(),
        histogram: totals,
    })
}

/// One room of a run, as the writers of its outputs see it.
struct SceneJob<'a> {
    cfg: &'a SynthConfig,
    scene: &'a Scene,
    renderer: &'a Renderer<'a>,
    camera: &'a Camera,
    /// The room's index in the run.
    index: usize,
    seed: u64,
    out: &'a Path,
    progress: &'a (dyn Fn(u64) + Sync),
}

/// A training view as the NYU layout holds it: colour with the sensor's colour model, exact
/// depth (no sensor simulation) and labels. `time` varies the exposure.
fn view_files(
    renderer: &Renderer,
    cfg: &SynthConfig,
    pose: &Pose,
    nseed: u32,
    time: f64,
) -> FrameFiles {
    let r = renderer.render(pose);
    let rgb: Vec<[f32; 3]> = r.px.iter().map(|p| p.rgb).collect();
    let gain = sensor::auto_exposure(&rgb) * sensor::exposure_gain(&cfg.sensor, nseed, time);
    FrameFiles {
        rgb: sensor::color_image(
            &rgb,
            r.width,
            r.height,
            gain,
            &cfg.render,
            &cfg.sensor,
            nseed,
        ),
        depth: sensor::exact_depth(&r),
        depth_gt: None,
        labels: sensor::label_image(&r),
        color_labels: false,
    }
}

/// Attempts at a room with a valid random view before [`stream_view`] gives up.
const STREAM_ATTEMPTS: usize = 8;

/// One training view without the disk (training streams them: a synth config as a `[data]
/// train` source's `path`): a fresh room from `seed` seen by `camera` (e.g. with a random
/// focal length), one random view of it, rendered as [`generate`]'s NYU-layout views are. A
/// room without a valid view is replaced by the next seed's.
pub(crate) fn stream_view(cfg: &SynthConfig, camera: &Camera, seed: u64) -> Result<FrameFiles> {
    let mut last = None;
    for attempt in 0..STREAM_ATTEMPTS {
        let seed = scene_seed(seed, attempt);
        let scene = Scene::generate(&cfg.room, seed)?;
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x7a11_ec70_9e5e_ed00);
        match trajectory::random_view(&scene, camera, &cfg.motion, &mut rng) {
            Ok(pose) => {
                let renderer = Renderer::new(&scene, camera, &cfg.render);
                let time = (seed % 1000) as f64;
                return Ok(view_files(&renderer, cfg, &pose, seed as u32, time));
            }
            Err(e) => last = Some(e),
        }
    }
    Err(last.unwrap_or_else(|| Error::msg("no room with a valid view")))
}

/// The room's TUM-layout sequence `seq_NNN/` (frames, lists, ground truth, camera,
/// `scene.json`); its facts go into `info`. Returns the label histogram of its frames.
fn write_sequence(job: &SceneJob, rng: &mut ChaCha8Rng, info: &mut Value) -> Result<Histogram> {
    let SceneJob {
        cfg,
        scene,
        renderer,
        camera,
        index: s,
        seed,
        out,
        progress,
    } = *job;
    let folder = format!("seq_{s:03}");
    let dir = out.join(&folder);
    let (names, stamps) = frame_stamps(cfg);
    let times: Vec<f64> = (0..cfg.frames).map(|k| k as f64 / cfg.fps).collect();
    let offsets = blur_offsets(cfg);
    let check: Vec<f64> = times
        .iter()
        .flat_map(|&t| offsets.iter().map(move |o| t + o))
        .collect();
    let duration = times.last().copied().unwrap_or(0.0) + offsets.last().copied().unwrap_or(0.0);
    let motion = Motion::plan(
        cfg.trajectory,
        scene,
        camera,
        &cfg.motion,
        duration,
        &check,
        rng,
    )
    .map_err(|e| Error::msg(format!("scene {s}: {e}")))?;
    let mut poses = Vec::with_capacity(cfg.frames);
    let mut hist = Histogram::default();
    let noise_base = (seed as u32) ^ 0x5e05;
    let mut ae = None;
    for chunk in (0..cfg.frames).collect::<Vec<_>>().chunks(8) {
        let rendered: Vec<(usize, FrameFiles)> = chunk
            .iter()
            .map(|&k| {
                let noise = noise_base.wrapping_add((k as u32).wrapping_mul(7919));
                let (files, pose, gain) = render_frame(renderer, &motion, cfg, times[k], noise, ae);
                ae = Some(gain);
                poses.push(pose);
                (k, files)
            })
            .collect();
        for (_, f) in &rendered {
            hist.add_image(&f.labels);
        }
        rendered
            .par_iter()
            .map(|(k, f)| f.write(&dir, &names[*k]))
            .collect::<Result<Vec<()>>>()?;
        progress(chunk.len() as u64);
    }
    writer::write_lists(&dir, &names, cfg.output.gt_depth)?;
    let traj = Trajectory::from_parts(stamps, poses)?;
    traj.write_tum(dir.join("groundtruth.txt"))?;
    camera.save(dir.join("camera.toml"))?;
    info["folder"] = json!(folder);
    info["trajectory"] = json!(cfg.trajectory);
    info["frames"] = json!(cfg.frames);
    info["path_length_m"] = json!(traj.path_length());
    info["label_histogram"] = hist.to_json();
    info["classes_in_view"] = json!(hist.classes_present());
    let one = writer::scene_json(cfg, camera, vec![info.clone()], &hist, Value::Null)?;
    crate::io::write_atomic(dir.join("scene.json"), &one)?;
    Ok(hist)
}

/// The room's NYU-layout training views in `nyu/` (exact depth, no sensor simulation).
/// Returns their label histogram.
fn write_nyu_views(job: &SceneJob, views: usize, rng: &mut ChaCha8Rng) -> Result<Histogram> {
    let SceneJob {
        cfg,
        scene,
        renderer,
        camera,
        index: s,
        seed,
        out,
        progress,
    } = *job;
    let dir = out.join("nyu");
    let mut hist = Histogram::default();
    let poses: Vec<Pose> = (0..views)
        .map(|_| trajectory::random_view(scene, camera, &cfg.motion, rng))
        .collect::<Result<_>>()
        .map_err(|e| Error::msg(format!("scene {s}: {e}")))?;
    for chunk in (0..views).collect::<Vec<_>>().chunks(8) {
        let rendered: Vec<(usize, FrameFiles)> = chunk
            .iter()
            .map(|&v| {
                let nseed = (seed as u32) ^ 0x0e1a_0000 ^ (v as u32).wrapping_mul(7919);
                (
                    v,
                    view_files(renderer, cfg, &poses[v], nseed, v as f64 * 3.7),
                )
            })
            .collect();
        for (_, f) in &rendered {
            hist.add_image(&f.labels);
        }
        rendered
            .par_iter()
            .map(|(v, f)| f.write(&dir, &format!("{:06}", s * views + v + 1)))
            .collect::<Result<Vec<()>>>()?;
        progress(chunk.len() as u64);
    }
    Ok(hist)
}
