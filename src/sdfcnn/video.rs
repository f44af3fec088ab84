//! Colour video with a trajectory as SDFCNN training data (`[data] video`): each sample is a
//! target frame with the frames `gap` before and after it and their poses, for the
//! photometric loss of [`super::photometric`]. The recording is a TUM-layout folder (colour
//! only is enough); the trajectory a TUM-format file, usually `slam`'s `trajectory.txt` of the
//! same recording (RGB-D, or monocular with `--camera-height` so that it is metric).

use image::RgbImage;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

use super::data::{resolve, resolve_camera};
use super::focal::to_canonical;
use crate::camera::{Camera, Distortion};
use crate::dataset::augment::{AugmentConfig, augment};
use crate::dataset::labels::VOID;
use crate::dataset::{LabelImage, TumConfig, TumSequence};
use crate::error::{Error, Result};
use crate::geometry::Pose;
use crate::trajectory::Trajectory;
use nalgebra::Vector2;

/// Farthest a frame's stamp may be from the nearest trajectory pose, seconds: well under a
/// frame interval (0.033 s at 30 Hz), so that a frame `slam` did not place takes no
/// neighbour's pose, and enough for 100 Hz ground truth (poses between two are interpolated).
const MAX_POSE_GAP: f64 = 0.01;

/// One recording of a config's `[data] video` list.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VideoSource {
    /// A TUM-layout sequence folder (`rgb.txt` or `associations.txt`); depth is not read.
    pub path: PathBuf,
    /// The camera: `fr1`, `fr2`, `fr3` or a camera TOML file (default: the folder's
    /// `camera.toml`). Distorted frames are undistorted after resizing.
    #[serde(default)]
    pub camera: Option<String>,
    /// The camera's poses, a TUM-format trajectory (`slam`'s `trajectory.txt`), in metres.
    pub trajectory: PathBuf,
    /// Target frames `[first, end)` (0-based, in association order; default all).
    #[serde(default)]
    pub frames: Option<[usize; 2]>,
    /// Every n-th frame of `frames` is a target (default 1).
    #[serde(default)]
    pub every: Option<usize>,
    /// The source frames are this many frames before and after the target (default 1).
    #[serde(default)]
    pub gap: Option<usize>,
}

impl VideoSource {
    /// The source with its relative paths taken from `config_path`'s folder where they do not
    /// exist from the working directory.
    pub fn resolved(&self, config_path: &Path) -> Self {
        let camera = self.camera.as_ref().map(|c| resolve_camera(c, config_path));
        VideoSource {
            path: resolve(&self.path, config_path),
            trajectory: resolve(&self.trajectory, config_path),
            camera,
            ..self.clone()
        }
    }
}

/// A target frame and its two sources, with the target-to-source poses.
#[derive(Debug, Clone)]
struct Triple {
    target: usize,
    sources: [usize; 2],
    poses: [Pose; 2],
}

#[derive(Debug, Clone)]
struct Recording {
    seq: TumSequence,
    camera: Camera,
    triples: Vec<Triple>,
}

/// Every `[data] video` recording, opened and checked.
#[derive(Debug, Clone, Default)]
pub(crate) struct VideoData {
    recordings: Vec<Recording>,
    /// (recording, triple) of every sample.
    index: Vec<(usize, usize)>,
    canonical: Option<f64>,
}

/// One sample on the host: the target and its two sources, `[3, H, W]` RGB in `[0, 1]` each.
#[derive(Debug, Clone)]
pub(crate) struct VideoSample {
    /// Target, previous source, next source.
    pub images: [Vec<f32>; 3],
    /// Target-to-source transforms, rotation row-major then translation (metres).
    pub poses: [[f32; 12]; 2],
    /// `fx, fy, cx, cy` at the sample's size.
    pub k: [f32; 4],
    /// Metres per unit of the network's depth (1 without a canonical focal length).
    pub metric: f32,
    /// `[height, width]`.
    pub size: [usize; 2],
}

impl VideoData {
    /// Opens every recording: its camera must fit the images, and the trajectory must give a
    /// pose near each frame used (targets without one for themselves and both sources are
    /// left out; a recording left with none is an error).
    pub fn open(sources: &[VideoSource]) -> Result<Self> {
        let mut recordings = Vec::new();
        let mut index = Vec::new();
        for (k, s) in sources.iter().enumerate() {
            let rec = open_recording(s)?;
            index.extend((0..rec.triples.len()).map(|t| (k, t)));
            recordings.push(rec);
        }
        Ok(VideoData {
            recordings,
            index,
            canonical: None,
        })
    }

    /// Depth predicted for the canonical camera of focal length `focal` image widths
    /// ([`super::focal`]); `None`: metric as predicted.
    pub fn with_canonical(mut self, focal: Option<f64>) -> Self {
        self.canonical = focal;
        self
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.index.len()
    }

    /// Whether there is no sample.
    pub fn is_empty(&self) -> bool {
        self.index.is_empty()
    }

    /// The median distance between a target camera and its sources, metres (`None` without
    /// samples): the photometric loss learns depth from this translation; a camera turning in
    /// place teaches nothing.
    pub fn median_baseline(&self) -> Option<f64> {
        let baselines: Vec<f64> = self
            .recordings
            .iter()
            .flat_map(|r| &r.triples)
            .flat_map(|t| t.poses.iter().map(|p| p.translation.vector.norm()))
            .collect();
        (!baselines.is_empty()).then(|| crate::metrics::stats::median(&baselines))
    }

    /// Loads sample `i` resized (whole frames, no augmentation) to `[height, width]` and
    /// undistorted to a pinhole image of the same intrinsics.
    pub fn load(&self, i: usize, [height, width]: [usize; 2]) -> Result<VideoSample> {
        let &(r, t) = self
            .index
            .get(i)
            .ok_or_else(|| Error::msg(format!("video sample {i} out of range ({})", self.len())))?;
        let rec = &self.recordings[r];
        let triple = &rec.triples[t];
        let frames = [triple.target, triple.sources[0], triple.sources[1]];
        let mut images: [Vec<f32>; 3] = Default::default();
        let c = &rec.camera;
        let (sx, sy) = (
            width as f64 / c.width as f64,
            height as f64 / c.height as f64,
        );
        let k = [
            c.fx * sx,
            c.fy * sy,
            (c.cx + 0.5) * sx - 0.5,
            (c.cy + 0.5) * sy - 0.5,
        ];
        for (slot, &f) in images.iter_mut().zip(&frames) {
            let small = resized(&rec.seq.load_rgb(f)?, width, height);
            *slot = if c.distortion.is_zero() {
                small
            } else {
                undistorted(&small, [height, width], k, &c.distortion)
            };
        }
        let k = k.map(|v| v as f32);
        let metric = self.canonical.map_or(1.0, |canonical| {
            1.0 / to_canonical(canonical, c.fx, c.width as f64, 1.0) as f32
        });
        Ok(VideoSample {
            images,
            poses: triple.poses.map(|p| flat(&p)),
            k,
            metric,
            size: [height, width],
        })
    }
}

/// A whole frame resampled to `width x height`, `[3, H, W]` in `[0, 1]`.
fn resized(rgb: &RgbImage, width: usize, height: usize) -> Vec<f32> {
    let labels = LabelImage::new(rgb.width(), rgb.height(), VOID);
    let none = AugmentConfig::none();
    let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(0);
    augment(rgb, None, &labels, width, height, &none, &mut rng).rgb
}

/// The pinhole image of intrinsics `k` (`fx, fy, cx, cy`) that a camera with `distortion`
/// saw as `img` (`[3, H, W]`): each pixel bilinearly sampled where the lens put it.
fn undistorted(img: &[f32], [h, w]: [usize; 2], k: [f64; 4], distortion: &Distortion) -> Vec<f32> {
    let [fx, fy, cx, cy] = k;
    let mut out = vec![0f32; img.len()];
    for y in 0..h {
        for x in 0..w {
            let p = Vector2::new((x as f64 - cx) / fx, (y as f64 - cy) / fy);
            let d = distortion.distort(p);
            let u = (fx * d.x + cx).clamp(0.0, (w - 1) as f64);
            let v = (fy * d.y + cy).clamp(0.0, (h - 1) as f64);
            let (u0, v0) = (u.floor() as usize, v.floor() as usize);
            let (u1, v1) = ((u0 + 1).min(w - 1), (v0 + 1).min(h - 1));
            let (a, b) = ((u - u0 as f64) as f32, (v - v0 as f64) as f32);
            for c in 0..3 {
                let at = |yy: usize, xx: usize| img[(c * h + yy) * w + xx];
                let top = at(v0, u0) * (1.0 - a) + at(v0, u1) * a;
                let bottom = at(v1, u0) * (1.0 - a) + at(v1, u1) * a;
                out[(c * h + y) * w + x] = top * (1.0 - b) + bottom * b;
            }
        }
    }
    out
}

/// Rotation row-major, then translation.
fn flat(p: &Pose) -> [f32; 12] {
    let r = p.rotation.to_rotation_matrix();
    let m = r.matrix();
    let t = p.translation.vector;
    let mut out = [0f32; 12];
    for row in 0..3 {
        for col in 0..3 {
            out[3 * row + col] = m[(row, col)] as f32;
        }
        out[9 + row] = t[row] as f32;
    }
    out
}

fn open_recording(s: &VideoSource) -> Result<Recording> {
    let bad = |m: String| Err(Error::invalid(&s.path, m));
    if let Some([a, b]) = s.frames
        && a >= b
    {
        return bad(format!(
            "frames = [{a}, {b}] must be a non-empty range [first, end)"
        ));
    }
    if s.every == Some(0) || s.gap == Some(0) {
        return bad("every and gap must be at least 1".into());
    }
    let mut seq = TumSequence::open_with(&s.path, TumConfig::default())?;
    let camera = match &s.camera {
        Some(spec) => {
            Camera::load(spec).map_err(|e| Error::invalid(&s.path, format!("camera: {e}")))?
        }
        None => {
            let file = s.path.join("camera.toml");
            if !file.is_file() {
                return bad("the recording has no camera.toml: name its camera (camera = \"fr1\" | \"fr2\" | \"fr3\" | FILE)".into());
            }
            Camera::from_file(file)?
        }
    };
    let n = seq.len();
    let [first, end] = s.frames.unwrap_or([0, n]);
    if end > n {
        return bad(format!(
            "frames = [{first}, {end}] but the sequence has {n} frames"
        ));
    }
    let header = crate::imageio::header(&seq.frames[first].rgb_path)?;
    if (header.width, header.height) != (camera.width, camera.height) {
        return Err(Error::invalid(
            &seq.frames[first].rgb_path,
            format!(
                "image is {}x{} but the camera is {}x{}",
                header.width, header.height, camera.width, camera.height
            ),
        ));
    }
    seq.expect_camera(&camera);
    let trajectory = Trajectory::read_tum(&s.trajectory)?;
    let pose = |f: usize| trajectory.pose_at(seq.frames[f].rgb_stamp, MAX_POSE_GAP);
    let gap = s.gap.unwrap_or(1);
    let mut triples = Vec::new();
    for target in (first..end).step_by(s.every.unwrap_or(1)) {
        let Some(before) = target.checked_sub(gap) else {
            continue;
        };
        let after = target + gap;
        if after >= n {
            continue;
        }
        let (Some(t), Some(b), Some(a)) = (pose(target), pose(before), pose(after)) else {
            continue;
        };
        // Poses are camera-to-world: a target point goes to the world, then into the source.
        triples.push(Triple {
            target,
            sources: [before, after],
            poses: [b.inverse() * t, a.inverse() * t],
        });
    }
    if triples.is_empty() {
        return Err(Error::invalid(
            &s.trajectory,
            format!(
                "no frame of {} in [{first}, {end}) has a pose here for itself and the frames \
                 {gap} before and after it (within {MAX_POSE_GAP} s of its stamp)",
                s.path.display()
            ),
        ));
    }
    Ok(Recording {
        seq,
        camera,
        triples,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn undistorting_samples_where_the_lens_put_each_pixel() {
        // No distortion: the image itself.
        let (h, w) = (6, 8);
        let img: Vec<f32> = (0..3 * h * w).map(|i| i as f32 / 144.0).collect();
        let k = [8.0, 8.0, 3.5, 2.5];
        let same = undistorted(&img, [h, w], k, &Distortion::default());
        assert!(same.iter().zip(&img).all(|(a, b)| (a - b).abs() < 1e-6));
        // Barrel distortion (k1 > 0 moves points outwards): the centre pixel stays, a corner
        // pixel samples farther out (clamped to the image), the row through the centre keeps
        // its row.
        let lens = Distortion {
            k1: 0.3,
            ..Distortion::default()
        };
        let ramp: Vec<f32> = (0..3 * h * w).map(|i| (i % w) as f32).collect();
        let out = undistorted(&ramp, [h, w], k, &lens);
        let at = |y: usize, x: usize| out[y * w + x];
        assert!(at(2, 0) < 0.0 + 1e-6 && at(2, 7) > 7.0 - 1e-6);
        assert!((at(2, 5) - 5.0) > 0.0, "{}", at(2, 5));
    }

    #[test]
    fn target_to_source_poses_take_a_target_point_into_the_source_camera() {
        // The source camera is 1 m to the right of the target's (world x), both unrotated: a
        // point 2 m ahead of the target is 1 m to the source's left.
        let t = Pose::identity();
        let s = Pose::translation(1.0, 0.0, 0.0);
        let rel = s.inverse() * t;
        let p = rel * nalgebra::Point3::new(0.0, 0.0, 2.0);
        assert!((p - nalgebra::Point3::new(-1.0, 0.0, 2.0)).norm() < 1e-12);
        let f = flat(&rel);
        assert_eq!(
            f,
            [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, -1.0, 0.0, 0.0]
        );
    }
}
