//! TUM RGB-D benchmark sequences in their own layout: `rgb.txt`, `depth.txt`,
//! `groundtruth.txt`, optional `associations.txt`, `rgb/`, `depth/`.
//!
//! Opening a sequence reads only the text files; images are decoded lazily, one
//! frame at a time, so sequences of thousands of 640x480 frames cost nothing to open.

use super::depth::DepthImage;
use super::frame_check::FrameSpec;
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::geometry::Pose;
use crate::io::{parse_f64, read_text, records};
use crate::trajectory::Trajectory;
use image::{GrayImage, RgbImage};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// How a sequence is read.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TumConfig {
    /// Maximum RGB-depth timestamp difference for association, seconds.
    pub max_assoc_diff: f64,
    /// Use `associations.txt` when the folder has one.
    pub use_associations_file: bool,
    /// Depth PNG value per metre.
    pub depth_scale: f64,
    /// Ground truth is `None` where its nearest sample is farther than this, seconds.
    pub max_gt_gap: f64,
    /// Frames take the ground truth this many seconds after their colour stamps (negative:
    /// before). 0, as the benchmark's tools read it; fr1_rpy's colour images fit the ground
    /// truth best about 8 ms before their stamps (lab/notes/slam-results.md, *Depth taken after the colour*).
    pub gt_time_offset: f64,
}

impl Default for TumConfig {
    fn default() -> Self {
        TumConfig {
            max_assoc_diff: 0.02,
            use_associations_file: true,
            depth_scale: 5000.0,
            max_gt_gap: 0.02,
            gt_time_offset: 0.0,
        }
    }
}

/// One entry of a sequence: an RGB image and, when associated, a depth image.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameInfo {
    /// Timestamp of the RGB image, seconds.
    pub rgb_stamp: f64,
    /// Path of the RGB image (under the sequence folder).
    pub rgb_path: PathBuf,
    /// Timestamp of the associated depth image, seconds (`None` without one).
    pub depth_stamp: Option<f64>,
    /// Path of the associated depth image (`None` without one).
    pub depth_path: Option<PathBuf>,
}

impl FrameInfo {
    /// The depth image's stamp minus the colour image's, seconds (0 without a depth image).
    pub fn depth_offset(&self) -> f64 {
        self.depth_stamp.map_or(0.0, |t| t - self.rgb_stamp)
    }
}

/// A loaded frame.
#[derive(Debug, Clone)]
pub struct Frame {
    /// Position of the frame in the sequence, from 0.
    pub index: usize,
    /// Timestamp of the RGB image, seconds.
    pub stamp: f64,
    /// The decoded colour image.
    pub rgb: RgbImage,
    /// The depth image in metres (`None` when the frame has no depth image).
    pub depth: Option<DepthImage>,
    /// Ground-truth camera-to-world pose interpolated at `stamp`.
    pub gt_pose: Option<Pose>,
}

/// A TUM RGB-D sequence folder.
#[derive(Debug, Clone)]
pub struct TumSequence {
    /// The sequence folder.
    pub root: PathBuf,
    /// How the sequence was read.
    pub config: TumConfig,
    /// Every frame, in `rgb.txt` (or `associations.txt`) order.
    pub frames: Vec<FrameInfo>,
    /// `groundtruth.txt`, with the file's own stamps (`None` without one).
    pub groundtruth: Option<Trajectory>,
    /// What every frame's images must be (the camera's size: [`TumSequence::expect_camera`]);
    /// `None`: images are read as they are, a depth image only checked against its colour
    /// image.
    pub frame_spec: Option<FrameSpec>,
}

/// Most frames a sequence's tables may list: a million, 9 hours at 30 Hz (TUM RGB-D's longest
/// sequences have a few thousand, 7-Scenes' 1000; `synth` writes at most this many). Opening a
/// sequence costs a few hundred bytes a frame before any image is read, so a table of
/// millions of lines is refused rather than read.
pub(crate) const MAX_SEQUENCE_FRAMES: usize = 1_000_000;

/// Longest file name a table may give, bytes (Linux's PATH_MAX: no longer path can be opened).
pub(crate) const MAX_PATH_BYTES: usize = 4096;

/// A file name field of a table, checked to be a name a file can have.
fn file_field<'a>(path: &Path, line: usize, field: &'a str) -> Result<&'a str> {
    if field.len() > MAX_PATH_BYTES {
        return Err(Error::parse(
            path,
            line,
            format!(
                "file name '{}' is {} bytes long, longer than any path can be ({MAX_PATH_BYTES})",
                crate::io::short(field),
                field.len()
            ),
        ));
    }
    Ok(field)
}

/// An error once a table lists more than [`MAX_SEQUENCE_FRAMES`] entries.
fn check_count(path: &Path, line: usize, count: usize) -> Result<()> {
    if count >= MAX_SEQUENCE_FRAMES {
        return Err(Error::parse(
            path,
            line,
            format!(
                "more than {MAX_SEQUENCE_FRAMES} entries: longer than any sequence this reads (9 \
                 hours at 30 Hz)"
            ),
        ));
    }
    Ok(())
}

/// A `timestamp filename` list (`rgb.txt`, `depth.txt`).
fn read_file_list(path: &Path) -> Result<Vec<(f64, String, usize)>> {
    let text = read_text(path)?;
    let mut out: Vec<(f64, String, usize)> = Vec::new();
    for rec in records(&text) {
        check_count(path, rec.line, out.len())?;
        if rec.fields.len() < 2 {
            return Err(Error::parse(
                path,
                rec.line,
                format!(
                    "expected 'timestamp filename', found {} field(s)",
                    rec.fields.len()
                ),
            ));
        }
        let t = parse_f64(path, rec.line, "timestamp", rec.fields[0])?;
        if let Some((last, _, _)) = out.last()
            && t <= *last
        {
            return Err(Error::parse(
                path,
                rec.line,
                format!(
                    "timestamp {} is not after the previous one ({last})",
                    rec.fields[0]
                ),
            ));
        }
        let name = file_field(path, rec.line, rec.fields[1])?;
        out.push((t, name.to_string(), rec.line));
    }
    Ok(out)
}

/// Associates two sorted timestamp lists as the benchmark's `associate.py` does:
/// every pair closer than `max_diff` is a candidate, candidates are taken in order
/// of increasing time difference, each stamp used at most once. Returns index
/// pairs sorted by the first list.
pub fn associate(a: &[f64], b: &[f64], max_diff: f64) -> Vec<(usize, usize)> {
    let mut candidates: Vec<(f64, usize, usize)> = Vec::new();
    let mut lo = 0;
    for (i, &ta) in a.iter().enumerate() {
        while lo < b.len() && b[lo] <= ta - max_diff {
            lo += 1;
        }
        let mut j = lo;
        while j < b.len() && b[j] < ta + max_diff {
            let d = (ta - b[j]).abs();
            if d < max_diff {
                candidates.push((d, i, j));
            }
            j += 1;
        }
    }
    candidates.sort_by(|x, y| x.partial_cmp(y).unwrap_or(std::cmp::Ordering::Equal));
    let (mut used_a, mut used_b) = (vec![false; a.len()], vec![false; b.len()]);
    let mut pairs = Vec::new();
    for (_, i, j) in candidates {
        if !used_a[i] && !used_b[j] {
            used_a[i] = true;
            used_b[j] = true;
            pairs.push((i, j));
        }
    }
    pairs.sort_unstable();
    pairs
}

impl TumSequence {
    /// Opens a sequence folder with the default configuration.
    pub fn open(root: impl AsRef<Path>) -> Result<Self> {
        Self::open_with(root, TumConfig::default())
    }

    /// Opens a sequence folder: reads the text files, associates RGB and depth,
    /// loads the ground truth. No image is decoded.
    pub fn open_with(root: impl AsRef<Path>, config: TumConfig) -> Result<Self> {
        let root = root.as_ref().to_path_buf();
        if !root.is_dir() {
            return Err(Error::invalid(&root, "sequence folder does not exist"));
        }
        let rgb_txt = root.join("rgb.txt");
        let assoc_txt = root.join("associations.txt");
        let depth_txt = root.join("depth.txt");
        // `exists`, not `is_file`: a table that is a FIFO or a folder is refused by name when
        // read, not passed over.
        let frames = if config.use_associations_file && assoc_txt.exists() {
            Self::read_associations(&root, &assoc_txt)?
        } else {
            if !rgb_txt.exists() && super::seven_scenes::list_frames(&root).is_ok() {
                return Err(Error::invalid(
                    &root,
                    format!(
                        "a 7-Scenes sequence folder, not a TUM RGB-D one: convert it first \
                         (`dataset seven-scenes {} --out DIR`)",
                        root.display()
                    ),
                ));
            }
            if !rgb_txt.exists() {
                return Err(Error::invalid(
                    &root,
                    "no rgb.txt (nor associations.txt): not a TUM RGB-D sequence folder",
                ));
            }
            let rgb = read_file_list(&rgb_txt)?;
            if depth_txt.exists() {
                let depth = read_file_list(&depth_txt)?;
                let ta: Vec<f64> = rgb.iter().map(|r| r.0).collect();
                let tb: Vec<f64> = depth.iter().map(|d| d.0).collect();
                associate(&ta, &tb, config.max_assoc_diff)
                    .into_iter()
                    .map(|(i, j)| FrameInfo {
                        rgb_stamp: rgb[i].0,
                        rgb_path: root.join(&rgb[i].1),
                        depth_stamp: Some(depth[j].0),
                        depth_path: Some(root.join(&depth[j].1)),
                    })
                    .collect()
            } else {
                rgb.into_iter()
                    .map(|(t, f, _)| FrameInfo {
                        rgb_stamp: t,
                        rgb_path: root.join(f),
                        depth_stamp: None,
                        depth_path: None,
                    })
                    .collect()
            }
        };
        if frames.is_empty() {
            return Err(Error::invalid(
                &root,
                format!(
                    "sequence has no frames (no RGB images, or none with a depth image within {} s)",
                    config.max_assoc_diff
                ),
            ));
        }
        let gt_path = root.join("groundtruth.txt");
        let groundtruth = if gt_path.exists() {
            Some(Trajectory::read_tum(&gt_path)?)
        } else {
            None
        };
        Ok(TumSequence {
            root,
            config,
            frames,
            groundtruth,
            frame_spec: None,
        })
    }

    fn read_associations(root: &Path, path: &Path) -> Result<Vec<FrameInfo>> {
        let text = read_text(path)?;
        let mut frames: Vec<FrameInfo> = Vec::new();
        for rec in records(&text) {
            check_count(path, rec.line, frames.len())?;
            let f = &rec.fields;
            if f.len() < 4 {
                return Err(Error::parse(
                    path,
                    rec.line,
                    format!(
                        "expected 't_rgb rgb/file t_depth depth/file', found {} field(s)",
                        f.len()
                    ),
                ));
            }
            let t_rgb = parse_f64(path, rec.line, "RGB timestamp", f[0])?;
            let t_depth = parse_f64(path, rec.line, "depth timestamp", f[2])?;
            if let Some(last) = frames.last()
                && t_rgb <= last.rgb_stamp
            {
                return Err(Error::parse(
                    path,
                    rec.line,
                    format!("RGB timestamp {} is not after the previous one", f[0]),
                ));
            }
            frames.push(FrameInfo {
                rgb_stamp: t_rgb,
                rgb_path: root.join(file_field(path, rec.line, f[1])?),
                depth_stamp: Some(t_depth),
                depth_path: Some(root.join(file_field(path, rec.line, f[3])?)),
            });
        }
        Ok(frames)
    }

    /// From now on every frame's images are checked against `camera` where they are read
    /// ([`FrameSpec`]: size, channels, bit depth): a frame that does not fit is an error
    /// naming the file, what it is and what the camera expects. `slam`, training and `eval`
    /// call this once they know the camera.
    pub fn expect_camera(&mut self, camera: &Camera) {
        self.frame_spec = Some(FrameSpec::of(camera));
    }

    /// [`TumSequence::expect_camera`], by value.
    pub fn with_camera(mut self, camera: &Camera) -> Self {
        self.expect_camera(camera);
        self
    }

    /// Number of frames.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// Whether the sequence has no frames.
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// Whether frames carry depth images.
    pub fn has_depth(&self) -> bool {
        self.frames.iter().any(|f| f.depth_path.is_some())
    }

    /// The sequence's name (its folder name).
    pub fn name(&self) -> String {
        self.root
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| self.root.display().to_string())
    }

    fn info(&self, index: usize) -> Result<&FrameInfo> {
        self.frames.get(index).ok_or_else(|| {
            Error::msg(format!(
                "frame {index} out of range: {} has {} frames",
                self.root.display(),
                self.frames.len()
            ))
        })
    }

    /// Ground-truth pose at a timestamp, read `gt_time_offset` after it (see
    /// [`Trajectory::pose_at`]). `groundtruth` itself keeps the file's stamps: code that
    /// reads it directly (the SLAM's ATE) does not see the offset.
    pub fn gt_pose_at(&self, stamp: f64) -> Option<Pose> {
        self.groundtruth
            .as_ref()
            .and_then(|gt| gt.pose_at(stamp + self.config.gt_time_offset, self.config.max_gt_gap))
    }

    /// Decodes frame `index`'s RGB image (checked against the camera when one is expected:
    /// [`TumSequence::expect_camera`]).
    pub fn load_rgb(&self, index: usize) -> Result<RgbImage> {
        let path = &self.info(index)?.rgb_path;
        match &self.frame_spec {
            Some(spec) => spec.read_colour(path),
            None => crate::imageio::read_rgb(path),
        }
    }

    /// Decodes frame `index`'s RGB image as grayscale (checked as [`TumSequence::load_rgb`]).
    pub fn load_gray(&self, index: usize) -> Result<GrayImage> {
        let path = &self.info(index)?.rgb_path;
        match &self.frame_spec {
            Some(spec) => spec.read_gray(path),
            None => crate::imageio::read_gray(path),
        }
    }

    /// Decodes frame `index`'s depth image in metres (`None` without depth; checked as
    /// [`TumSequence::load_rgb`]).
    pub fn load_depth(&self, index: usize) -> Result<Option<DepthImage>> {
        let Some(path) = &self.info(index)?.depth_path else {
            return Ok(None);
        };
        match &self.frame_spec {
            Some(spec) => spec.read_depth(path, self.config.depth_scale).map(Some),
            None => DepthImage::read_png(path, self.config.depth_scale).map(Some),
        }
    }

    /// Loads frame `index`: RGB, depth (checked to have the RGB image's size) and
    /// interpolated ground truth.
    pub fn load_frame(&self, index: usize) -> Result<Frame> {
        let info = self.info(index)?;
        let rgb = self.load_rgb(index)?;
        let depth = self.load_depth(index)?;
        if let (Some(d), Some(p)) = (&depth, &info.depth_path)
            && (d.width, d.height) != rgb.dimensions()
        {
            return Err(Error::invalid(
                p,
                format!(
                    "depth image is {}x{} but its RGB image {} is {}x{}",
                    d.width,
                    d.height,
                    info.rgb_path.display(),
                    rgb.width(),
                    rgb.height()
                ),
            ));
        }
        Ok(Frame {
            index,
            stamp: info.rgb_stamp,
            rgb,
            depth,
            gt_pose: self.gt_pose_at(info.rgb_stamp),
        })
    }

    /// Iterates over frames, decoding each one only when it is reached.
    pub fn iter(&self) -> impl Iterator<Item = Result<Frame>> + '_ {
        (0..self.len()).map(move |i| self.load_frame(i))
    }
}

impl Trajectory {
    /// Pose at time `t`: linear interpolation of the translation and SLERP of the
    /// rotation between the two samples around `t`. `None` when the nearest
    /// sample is farther than `max_gap` seconds. Outside the trajectory's time
    /// span, the end pose is returned if it is within `max_gap` (no extrapolation).
    pub fn pose_at(&self, t: f64, max_gap: f64) -> Option<Pose> {
        if self.is_empty() || !t.is_finite() {
            return None;
        }
        let k = self.stamps.partition_point(|&s| s <= t);
        if k == 0 {
            return (self.stamps[0] - t <= max_gap).then(|| self.poses[0]);
        }
        if k == self.len() {
            let last = self.len() - 1;
            return (t - self.stamps[last] <= max_gap).then(|| self.poses[last]);
        }
        let (t0, t1) = (self.stamps[k - 1], self.stamps[k]);
        if (t - t0).min(t1 - t) > max_gap {
            return None;
        }
        let s = (t - t0) / (t1 - t0);
        Some(crate::geometry::interpolate(
            &self.poses[k - 1],
            &self.poses[k],
            s,
        ))
    }

    /// The trajectory read at `stamps` by [`Trajectory::pose_at`]: stamps it cannot give a
    /// pose for (farther than `max_gap` from every sample) are left out, and so are stamps
    /// that are not strictly increasing.
    pub fn resampled_at(&self, stamps: &[f64], max_gap: f64) -> Trajectory {
        let mut out = Trajectory::new();
        for &t in stamps {
            if let Some(pose) = self.pose_at(t, max_gap) {
                // Not after the last stamp: left out, as documented.
                let _ = out.push(t, pose);
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resampling_interpolates_and_leaves_out_what_it_cannot_read() {
        // 100 Hz, moving 1 m/s along x and turning 1 rad/s about y.
        let at = |t: f64| {
            Pose::from_parts(
                nalgebra::Translation3::new(t, 0.0, 0.0),
                nalgebra::UnitQuaternion::from_scaled_axis(nalgebra::Vector3::y() * t),
            )
        };
        let mut gt = Trajectory::new();
        for k in 0..=100 {
            gt.push(k as f64 / 100.0, at(k as f64 / 100.0)).unwrap();
        }
        let r = gt.resampled_at(&[0.0123, 0.5, 0.5, 0.4, 0.777, 1.2, 2.0], 0.01);
        assert_eq!(r.stamps, vec![0.0123, 0.5, 0.777]);
        for (t, p) in r.stamps.iter().zip(&r.poses) {
            let e = at(*t).inverse() * p;
            assert!(e.translation.vector.norm() < 1e-12, "{t}");
            assert!(e.rotation.angle() < 1e-9, "{t}");
        }
    }

    #[test]
    fn association_is_greedy_and_unique() {
        let a = [1.00, 1.03, 1.06, 2.0];
        let b = [1.005, 1.012, 1.061, 3.0];
        let pairs = associate(&a, &b, 0.02);
        // 1.00-1.005 (5 ms) wins over 1.00-1.012; 1.03 has nothing within 20 ms
        // except 1.012 (18 ms), 1.06-1.061.
        assert_eq!(pairs, vec![(0, 0), (1, 1), (2, 2)]);
        assert_eq!(associate(&a, &b, 0.002), vec![(2, 2)]);
    }

    #[test]
    fn pose_at_interpolates_and_respects_gaps() {
        use crate::geometry::pose_from_tum;
        let p = |x: f64| pose_from_tum([x, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]).unwrap();
        let t = Trajectory::from_parts(vec![0.0, 0.01, 1.0], vec![p(0.0), p(1.0), p(2.0)]).unwrap();
        assert!((t.pose_at(0.005, 0.02).unwrap().translation.x - 0.5).abs() < 1e-12);
        assert!(t.pose_at(0.5, 0.02).is_none());
        assert!((t.pose_at(0.995, 0.02).unwrap().translation.x - 1.0 - 0.985 / 0.99).abs() < 1e-12);
        assert!(t.pose_at(-0.01, 0.02).is_some());
        assert!(t.pose_at(-0.05, 0.02).is_none());
        assert!(t.pose_at(1.03, 0.02).is_none());
    }
}
