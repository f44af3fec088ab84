//! Microsoft 7-Scenes (Shotton et al., "Scene Coordinate Regression Forests for Camera
//! Relocalization in RGB-D Images", CVPR 2013) in its own layout, converted to the TUM
//! RGB-D layout every tool of this crate reads.
//!
//! A 7-Scenes sequence folder (`redkitchen/seq-01`) holds, per frame,
//! `frame-NNNNNN.color.png` (640x480 colour), `frame-NNNNNN.depth.png` (16-bit, millimetres,
//! 65535 = no reading) and `frame-NNNNNN.pose.txt` (the 4x4 camera-to-world matrix of the
//! *depth* camera, from KinectFusion). Colour and depth come from the Kinect's two cameras
//! and are not registered, and 7-Scenes publishes only the depth camera's intrinsics
//! (585, 585, 320, 240). [`convert`] forward-warps each depth image into the colour camera
//! (nearest surface wins; colour pixels no depth pixel lands on have no reading), moves each
//! pose to the colour camera, and writes `rgb/`, `depth/` (metres x 5000), `rgb.txt`,
//! `depth.txt`, `associations.txt`, `groundtruth.txt` and the colour camera as `camera.toml`.
//! Frame `n` gets the made-up time stamp `1000 + n / 30` s (7-Scenes has none; the Kinect
//! runs at 30 Hz), so a converted sub-range keeps the stamps of the whole sequence.
//!
//! The default [`Registration`] is the one of the converted `redkitchen` frames this project
//! trains and evaluates on: a colour camera (527, 527, 323, 236) and a depth-to-colour
//! offset of (-3.5, +0.5, 0) cm, both fitted by aligning depth discontinuities with colour
//! edges (good to about 3 px at depth edges). Its convention is DSAC*'s `d_to_rgb`:
//! `X_colour = X_depth + offset`, so the colour camera's centre sits at `-offset` in the
//! depth camera's coordinates.

use super::depth::DepthImage;
use super::frame_check::{FrameImage, FrameSpec};
use crate::camera::{Camera, toml_error};
use crate::error::{Error, Result};
use crate::geometry::Pose;
use crate::io::{read_text, records, write_atomic_with};
use nalgebra::{Matrix3, Point2, Rotation3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::{Path, PathBuf};

/// A depth PNG value that means "no reading" in 7-Scenes.
pub const NO_READING: u16 = u16::MAX;

/// Depth PNG value per metre in 7-Scenes (millimetres).
pub(crate) const DEPTH_SCALE: f64 = 1000.0;

/// Depth PNG value per metre written by [`convert`] (TUM RGB-D's).
pub(crate) const TUM_DEPTH_SCALE: f64 = 5000.0;

/// Frames a second of the made-up time stamps.
pub(crate) const FRAME_RATE: f64 = 30.0;

/// Time stamp of frame 0, seconds.
pub(crate) const FIRST_STAMP: f64 = 1000.0;

/// How a 7-Scenes depth image is registered to its colour image. Loaded from TOML:
///
/// ```toml
/// offset = [-0.035, 0.005, 0.0]   # X_colour = X_depth + offset, metres
/// [depth]                         # the depth camera
/// width = 640
/// height = 480
/// fx = 585.0
/// fy = 585.0
/// cx = 320.0
/// cy = 240.0
/// [colour]                        # the colour camera: the converted sequence's camera.toml
/// name = "7scenes_colour"
/// width = 640
/// height = 480
/// fx = 527.0
/// fy = 527.0
/// cx = 323.0
/// cy = 236.0
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Registration {
    /// Translation from depth- to colour-camera coordinates, metres.
    pub offset: [f64; 3],
    /// The depth camera (7-Scenes publishes fx = fy = 585, cx = 320, cy = 240).
    pub depth: Camera,
    /// The colour camera the depth is warped into.
    pub colour: Camera,
}

impl Default for Registration {
    /// The registration of this project's converted `redkitchen` frames (module docs).
    fn default() -> Self {
        let mut colour = Camera::pinhole(640, 480, 527.0, 527.0, 323.0, 236.0);
        colour.name = "7scenes_colour".into();
        let mut depth = Camera::pinhole(640, 480, 585.0, 585.0, 320.0, 240.0);
        depth.name = "7scenes_depth".into();
        Registration {
            offset: [-0.035, 0.005, 0.0],
            depth,
            colour,
        }
    }
}

/// Largest offset accepted, metres: the Kinect's cameras are a few centimetres apart.
const MAX_OFFSET: f64 = 0.5;

impl Registration {
    /// Reads a registration TOML file (the struct's docs show one).
    pub fn from_file(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let text = read_text(path)?;
        let reg: Registration = toml::from_str(&text).map_err(|e| toml_error(path, &text, e))?;
        reg.validate().map_err(|m| Error::invalid(path, m))?;
        Ok(reg)
    }

    fn validate(&self) -> std::result::Result<(), String> {
        if self
            .offset
            .iter()
            .any(|v| !v.is_finite() || v.abs() > MAX_OFFSET)
        {
            return Err(format!(
                "offset {:?} must be finite and within {MAX_OFFSET} m on each axis",
                self.offset
            ));
        }
        for (what, cam) in [("depth", &self.depth), ("colour", &self.colour)] {
            cam.validate().map_err(|m| format!("{what} camera: {m}"))?;
        }
        Ok(())
    }

    fn offset(&self) -> Vector3<f64> {
        Vector3::from(self.offset)
    }

    /// The colour camera's pose given the depth camera's (both camera-to-world):
    /// `T_wc = T_wd T_dc` with `T_dc` the translation by `-offset`.
    pub fn colour_pose(&self, depth_pose: &Pose) -> Pose {
        depth_pose * Translation3::from(-self.offset())
    }

    /// Forward-warps a 7-Scenes depth image (millimetres, row-major, the depth camera's
    /// size; 0 and [`NO_READING`] are no reading) into the colour camera: each reading is
    /// back-projected, moved by the offset, projected and written to the nearest pixel, the
    /// nearest surface winning where several land on one pixel. Pixels no reading lands on
    /// have none. Depth in metres. A registration that fails its checks or an image of
    /// another size than the depth camera's is an error.
    pub fn register(&self, depth_mm: &[u16]) -> Result<DepthImage> {
        self.validate().map_err(Error::msg)?;
        let want = self.depth.width as usize * self.depth.height as usize;
        if depth_mm.len() != want {
            return Err(Error::msg(format!(
                "a depth image of {} values for a {}x{} depth camera",
                depth_mm.len(),
                self.depth.width,
                self.depth.height
            )));
        }
        let (dw, dh) = (self.depth.width as usize, self.depth.height as usize);
        let (cw, ch) = (self.colour.width as i64, self.colour.height as i64);
        let mut out = DepthImage::new(self.colour.width, self.colour.height);
        let offset = self.offset();
        for (v, row) in depth_mm.chunks_exact(dw).take(dh).enumerate() {
            for (u, &raw) in row.iter().enumerate() {
                if raw == 0 || raw == NO_READING {
                    continue;
                }
                let z = raw as f64 / DEPTH_SCALE;
                let p = self.depth.back_project(&Point2::new(u as f64, v as f64), z) + offset;
                let Some(px) = self.colour.project(&p) else {
                    continue;
                };
                let (x, y) = (px.x.round() as i64, px.y.round() as i64);
                if x < 0 || y < 0 || x >= cw || y >= ch {
                    continue;
                }
                let cell = &mut out.data[(y * cw + x) as usize];
                let zc = p.z as f32;
                if *cell == 0.0 || zc < *cell {
                    *cell = zc;
                }
            }
        }
        Ok(out)
    }
}

/// Largest frame number accepted (7-Scenes sequences have 500-1000 frames).
pub(crate) const MAX_FRAME_NUMBER: usize = 99_999_999;

/// One frame of a 7-Scenes sequence folder.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct SevenScenesFrame {
    /// The frame number `NNNNNN` of its file names.
    pub number: usize,
    /// Path of its `frame-NNNNNN.color.png` colour image.
    pub colour: PathBuf,
    /// Path of its `frame-NNNNNN.depth.png` depth image (millimetres, depth camera).
    pub depth: PathBuf,
    /// Path of its `frame-NNNNNN.pose.txt` camera-to-world pose (depth camera).
    pub pose: PathBuf,
}

impl SevenScenesFrame {
    /// The made-up time stamp of this frame (module docs).
    pub fn stamp(&self) -> f64 {
        FIRST_STAMP + self.number as f64 / FRAME_RATE
    }
}

/// Lists a 7-Scenes sequence folder's frames in frame order: every
/// `frame-NNNNNN.color.png` with its `.depth.png` and `.pose.txt` (a missing one is an
/// error naming it).
pub(crate) fn list_frames(dir: impl AsRef<Path>) -> Result<Vec<SevenScenesFrame>> {
    let dir = dir.as_ref();
    if !dir.is_dir() {
        return Err(Error::invalid(
            dir,
            "7-Scenes sequence folder does not exist",
        ));
    }
    let entries = std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))?;
    let mut frames = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|e| Error::io(dir, e))?;
        let name = entry.file_name();
        let Some(digits) = name
            .to_str()
            .and_then(|n| n.strip_prefix("frame-"))
            .and_then(|n| n.strip_suffix(".color.png"))
            .filter(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()))
        else {
            continue;
        };
        let number = digits
            .parse::<usize>()
            .ok()
            .filter(|&n| n <= MAX_FRAME_NUMBER)
            .ok_or_else(|| {
                Error::invalid(
                    entry.path(),
                    format!("frame number {digits} is larger than {MAX_FRAME_NUMBER}"),
                )
            })?;
        let frame = SevenScenesFrame {
            number,
            colour: entry.path(),
            depth: dir.join(format!("frame-{digits}.depth.png")),
            pose: dir.join(format!("frame-{digits}.pose.txt")),
        };
        for p in [&frame.depth, &frame.pose] {
            // `exists`: a FIFO or folder of that name is refused by name when read.
            if !p.exists() {
                return Err(Error::invalid(
                    p,
                    format!(
                        "missing: 7-Scenes frame {} has a colour image but not this file",
                        frame.number
                    ),
                ));
            }
        }
        frames.push(frame);
    }
    if frames.is_empty() {
        return Err(Error::invalid(
            dir,
            "no frame-NNNNNN.color.png here: not a 7-Scenes sequence folder (e.g. redkitchen/seq-01)",
        ));
    }
    frames.sort_by_key(|f| f.number);
    if let Some(w) = frames.windows(2).find(|w| w[0].number == w[1].number) {
        return Err(Error::invalid(
            &w[1].colour,
            format!(
                "frame number {} also names {}",
                w[1].number,
                w[0].colour.display()
            ),
        ));
    }
    Ok(frames)
}

/// Largest camera position accepted, metres from the origin: 7-Scenes' rooms are a few
/// metres across; a kilometre is beyond any indoor RGB-D recording.
pub(crate) const MAX_POSITION: f64 = 1000.0;

/// An error listing the frame numbers missing between the first and the last of `frames`
/// (sorted): 7-Scenes numbers a sequence's frames without gaps, so a gap is an incomplete
/// copy, and converting across it would make the frames on either side look consecutive to
/// whatever tracks them. The frames on either side of a gap convert separately (`--first`,
/// `--count`).
fn check_numbering(src: &Path, frames: &[SevenScenesFrame]) -> Result<()> {
    let gaps: Vec<(usize, usize)> = frames
        .windows(2)
        .filter(|w| w[1].number > w[0].number + 1)
        .map(|w| (w[0].number + 1, w[1].number - 1))
        .collect();
    if gaps.is_empty() {
        return Ok(());
    }
    let missing: usize = gaps.iter().map(|(a, b)| b - a + 1).sum();
    let listed: Vec<String> = gaps
        .iter()
        .take(10)
        .map(|&(a, b)| {
            if a == b {
                format!("{a}")
            } else {
                format!("{a}-{b}")
            }
        })
        .collect();
    Err(Error::invalid(
        src,
        format!(
            "{missing} frame(s) missing from the numbering between frames {} and {}: {}{} (an \
             incomplete copy? convert the frames on either side of a gap separately with \
             --first and --count)",
            frames[0].number,
            frames[frames.len() - 1].number,
            listed.join(", "),
            if gaps.len() > 10 { ", ..." } else { "" }
        ),
    ))
}

/// Reads a 7-Scenes `pose.txt`: four rows of four numbers, a rigid camera-to-world
/// transform (last row 0 0 0 1, an orthonormal rotation, a position within
/// [`MAX_POSITION`] of the origin). Anything else is an error naming the file, and the line
/// where one line is at fault.
pub(crate) fn read_pose(path: impl AsRef<Path>) -> Result<Pose> {
    let path = path.as_ref();
    let text = read_text(path)?;
    let mut rows: Vec<[f64; 4]> = Vec::new();
    let mut lines: Vec<usize> = Vec::new();
    let mut last_line = 0;
    for rec in records(&text) {
        last_line = rec.line;
        lines.push(rec.line);
        if rows.len() == 4 {
            return Err(Error::parse(path, rec.line, "more than four rows"));
        }
        if rec.fields.len() != 4 {
            return Err(Error::parse(
                path,
                rec.line,
                format!("expected 4 numbers, found {} field(s)", rec.fields.len()),
            ));
        }
        let mut row = [0.0; 4];
        for (v, f) in row.iter_mut().zip(&rec.fields) {
            *v = f
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| {
                    Error::parse(path, rec.line, format!("'{f}' is not a finite number"))
                })?;
        }
        rows.push(row);
    }
    if rows.len() != 4 {
        return Err(Error::invalid(
            path,
            format!("expected a 4x4 matrix, found {} row(s)", rows.len()),
        ));
    }
    let last = rows[3];
    if (last[0].abs() + last[1].abs() + last[2].abs() + (last[3] - 1.0).abs()) > 1e-6 {
        return Err(Error::parse(
            path,
            last_line,
            format!("last row is {last:?}, not 0 0 0 1: not a rigid transform"),
        ));
    }
    let r = Matrix3::from_fn(|i, j| rows[i][j]);
    let err = (r.transpose() * r - Matrix3::identity()).abs().max();
    if err > 1e-3 || r.determinant() <= 0.0 {
        return Err(Error::invalid(
            path,
            format!(
                "the upper-left 3x3 block is not a rotation (|R^T R - I| = {err:.2e}, det {:.4})",
                r.determinant()
            ),
        ));
    }
    if let Some(k) = (0..3).find(|&k| rows[k][3].abs() > MAX_POSITION) {
        return Err(Error::parse(
            path,
            lines[k],
            format!(
                "translation {:e} m is not a camera position in a room (at most \
                 {MAX_POSITION} m from the origin)",
                rows[k][3]
            ),
        ));
    }
    let t_norm = (0..3).map(|k| rows[k][3].powi(2)).sum::<f64>().sqrt();
    if t_norm > MAX_POSITION {
        return Err(Error::invalid(
            path,
            format!(
                "the camera is {t_norm:.1} m from the origin: not a camera position in a room \
                 (at most {MAX_POSITION} m)"
            ),
        ));
    }
    // Closed form (the matrix is a rotation to 1e-3, checked above), renormalised.
    let rotation = UnitQuaternion::new_normalize(
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r)).into_inner(),
    );
    let t = Translation3::new(rows[0][3], rows[1][3], rows[2][3]);
    Ok(Pose::from_parts(t, rotation))
}

/// Reads a 7-Scenes depth image: 16-bit single-channel PNG of the depth camera's size
/// (checked as every frame is: [`FrameSpec`]).
pub fn read_depth_mm(path: impl AsRef<Path>, camera: &Camera) -> Result<Vec<u16>> {
    let path = path.as_ref();
    let spec = FrameSpec::of(camera);
    let check = |h: &crate::imageio::ImageHeader| spec.check(path, FrameImage::Depth, h);
    let buf = super::depth::read_png_u16_with(path, spec.max_file_bytes(), &check)?;
    Ok(buf.into_raw())
}

/// What [`convert`] does (default: every frame, the default registration).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ConvertOptions {
    /// Frames numbered below this are skipped.
    pub first: usize,
    /// This many frames from `first` on (`None`: all); more than the folder has from `first`
    /// on is an error.
    pub count: Option<usize>,
    /// The depth-to-colour registration used to warp depth and poses.
    pub registration: Registration,
}

/// What [`convert`] wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct ConvertSummary {
    /// Number of frames converted.
    pub frames: usize,
    /// Frame number of the first converted frame.
    pub first: usize,
    /// Frame number of the last converted frame.
    pub last: usize,
    /// Mean share of colour pixels with a registered depth reading.
    pub depth_coverage: f64,
}

/// Converts the frames of a 7-Scenes sequence folder `src` into a TUM-layout sequence in
/// `out` (module docs). `out` must not already hold a sequence; colour PNGs are checked by
/// decoding them and copied as they are; registered depth beyond the 13.1 m a TUM depth PNG
/// holds becomes no reading; every file is written atomically and the lists last, so an interrupted
/// conversion leaves no list naming a missing image. `progress` is called after each frame
/// with the number done and the total.
pub fn convert(
    src: impl AsRef<Path>,
    out: impl AsRef<Path>,
    options: &ConvertOptions,
    mut progress: impl FnMut(usize, usize),
) -> Result<ConvertSummary> {
    let (src, out) = (src.as_ref(), out.as_ref());
    let reg = &options.registration;
    reg.validate().map_err(Error::msg)?;
    if options.count == Some(0) {
        return Err(Error::msg("a count of 0 frames converts nothing"));
    }
    let mut frames: Vec<SevenScenesFrame> = list_frames(src)?
        .into_iter()
        .filter(|f| f.number >= options.first)
        .collect();
    if frames.is_empty() {
        return Err(Error::invalid(
            src,
            format!("no frame numbered {} or later", options.first),
        ));
    }
    if let Some(count) = options.count {
        if count > frames.len() {
            return Err(Error::invalid(
                src,
                format!(
                    "{count} frames asked for (--count) but the folder has {} from frame {} on \
                     ({}..{})",
                    frames.len(),
                    options.first,
                    frames[0].number,
                    frames[frames.len() - 1].number
                ),
            ));
        }
        frames.truncate(count);
    }
    check_numbering(src, &frames)?;
    for list in [
        "rgb.txt",
        "depth.txt",
        "associations.txt",
        "groundtruth.txt",
    ] {
        if out.join(list).exists() {
            return Err(Error::invalid(
                out.join(list),
                "the output folder already holds a sequence: choose another folder",
            ));
        }
    }
    // One line whatever the folder's name holds.
    let source = src.display().to_string().replace(['\n', '\r'], " ");
    let header = format!(
        "# converted from Microsoft 7-Scenes {source} (frames {}..{}) by sdf-slam; depth \
         registered to colour, colour-camera poses",
        frames[0].number,
        frames[frames.len() - 1].number
    );
    let mut coverage = 0.0;
    /// One converted frame: its stamp, file names and colour-camera pose.
    struct Row {
        stamp: String,
        rgb: String,
        depth: String,
        pose: Pose,
    }
    // Every pose first (small files): one that cannot be right stops the conversion before
    // anything is written.
    let poses = frames
        .iter()
        .map(|f| read_pose(&f.pose))
        .collect::<Result<Vec<Pose>>>()?;
    let mut rows = Vec::with_capacity(frames.len());
    let colour = FrameSpec::of(&reg.colour);
    for (i, (f, depth_pose)) in frames.iter().zip(poses).enumerate() {
        // Decoded once, so that a truncated or unreadable image, or one that does not fit
        // the registration's colour camera, is named here.
        colour.read_colour(&f.colour)?;
        let mut depth = reg
            .register(&read_depth_mm(&f.depth, &reg.depth)?)
            .map_err(|e| Error::invalid(&f.depth, e.to_string()))?;
        // Beyond what TUM's 16-bit PNGs hold (13.1 m): no reading.
        for z in depth.data.iter_mut() {
            if *z as f64 * TUM_DEPTH_SCALE > u16::MAX as f64 {
                *z = 0.0;
            }
        }
        coverage += depth.valid_fraction();
        let stamp = format!("{:.6}", f.stamp());
        let rgb_name = format!("rgb/{stamp}.png");
        let depth_name = format!("depth/{stamp}.png");
        let bytes = crate::io::read_image_bytes(&f.colour, colour.max_file_bytes())?;
        crate::io::write_atomic(out.join(&rgb_name), &bytes)?;
        depth.write_png(out.join(&depth_name), TUM_DEPTH_SCALE)?;
        rows.push(Row {
            stamp,
            rgb: rgb_name,
            depth: depth_name,
            pose: reg.colour_pose(&depth_pose),
        });
        progress(i + 1, frames.len());
    }
    reg.colour.save(out.join("camera.toml"))?;
    let list = |name: &str, pick: &dyn Fn(&Row) -> String| {
        write_atomic_with(out.join(name), |w| {
            writeln!(w, "{header}")?;
            writeln!(w, "# timestamp filename")?;
            for r in &rows {
                writeln!(w, "{}", pick(r))?;
            }
            Ok(())
        })
    };
    list("rgb.txt", &|r| format!("{} {}", r.stamp, r.rgb))?;
    list("depth.txt", &|r| format!("{} {}", r.stamp, r.depth))?;
    write_atomic_with(out.join("groundtruth.txt"), |w| {
        writeln!(w, "{header}")?;
        writeln!(w, "# timestamp tx ty tz qx qy qz qw")?;
        for r in &rows {
            let (t, q) = crate::geometry::pose_to_tum(&r.pose);
            writeln!(
                w,
                "{} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9}",
                r.stamp, t[0], t[1], t[2], q[0], q[1], q[2], q[3]
            )?;
        }
        Ok(())
    })?;
    // Last: readers prefer associations.txt, so its presence marks a finished conversion.
    write_atomic_with(out.join("associations.txt"), |w| {
        for r in &rows {
            writeln!(w, "{} {} {} {}", r.stamp, r.rgb, r.stamp, r.depth)?;
        }
        Ok(())
    })?;
    Ok(ConvertSummary {
        frames: rows.len(),
        first: frames[0].number,
        last: frames[frames.len() - 1].number,
        depth_coverage: coverage / rows.len() as f64,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    fn dir(name: &str) -> crate::io::ScratchDir {
        crate::io::ScratchDir::new(&format!("7scenes_{name}")).unwrap()
    }

    /// Registers a plane `n . X = d` (depth-camera coordinates) seen by `reg.depth` and
    /// checks every colour pixel against the plane's depth along its own ray in the colour
    /// camera (`n . (X - offset) = d`): off by at most half a pixel's depth change along each
    /// axis (the warp rounds to the nearest pixel) plus the input's millimetre. Returns the
    /// number of pixels checked.
    fn check_plane(reg: &Registration, n: Vector3<f64>, d: f64) -> usize {
        let n = n.normalize();
        let (w, h) = (reg.depth.width as usize, reg.depth.height as usize);
        let mut mm = vec![0u16; w * h];
        for v in 0..h {
            for u in 0..w {
                let r = reg
                    .depth
                    .back_project(&Point2::new(u as f64, v as f64), 1.0);
                mm[v * w + u] = (d / n.dot(&r.coords) * DEPTH_SCALE).round() as u16;
            }
        }
        let out = reg.register(&mm).unwrap();
        let dc = d + n.dot(&reg.offset());
        let truth = |x: f64, y: f64| {
            let r = reg.colour.back_project(&Point2::new(x, y), 1.0);
            dc / n.dot(&r.coords)
        };
        let mut checked = 0;
        for y in 1..reg.colour.height as i64 - 1 {
            for x in 1..reg.colour.width as i64 - 1 {
                let Some(z) = out.get(x, y) else { continue };
                let (xf, yf) = (x as f64, y as f64);
                let slope = (truth(xf + 1.0, yf) - truth(xf - 1.0, yf)).abs() / 2.0
                    + (truth(xf, yf + 1.0) - truth(xf, yf - 1.0)).abs() / 2.0;
                let err = (z as f64 - truth(xf, yf)).abs();
                assert!(
                    err <= 0.5 * slope + 0.0006,
                    "pixel ({x}, {y}): {z} m, plane {} m",
                    truth(xf, yf)
                );
                checked += 1;
            }
        }
        checked
    }

    #[test]
    fn registration_puts_a_plane_where_the_colour_camera_sees_it() {
        let reg = Registration::default();
        let checked = check_plane(&reg, Vector3::new(0.5, -0.4, 1.0), 1.6);
        // About four fifths of the colour image lie inside the depth camera's view.
        let all = (reg.colour.width * reg.colour.height) as usize;
        assert!(checked > all * 3 / 4 && checked < all * 9 / 10, "{checked}");
        // Other cameras and an offset along every axis.
        let reg = Registration {
            offset: [-0.05, 0.04, 0.03],
            depth: Camera::pinhole(320, 240, 290.0, 300.0, 158.0, 122.0),
            colour: Camera::pinhole(400, 300, 330.0, 320.0, 205.0, 148.0),
        };
        assert!(check_plane(&reg, Vector3::new(-0.3, 0.6, 1.0), 1.2) > 60_000);
        // The colour camera's edges lie outside the depth camera's view: no reading there.
        let out = Registration::default()
            .register(&vec![1500; 640 * 480])
            .unwrap();
        assert_eq!(out.get(2, 240), None);
        assert_eq!(out.get(320, 2), None);
        assert_eq!(out.get(320, 240), Some(1.5));
    }

    #[test]
    fn no_reading_gives_no_reading_and_bad_input_is_an_error() {
        let reg = Registration::default();
        for raw in [NO_READING, 0] {
            let out = reg.register(&vec![raw; 640 * 480]).unwrap();
            assert!(out.data.iter().all(|&z| z == 0.0));
        }
        let e = reg
            .register(&vec![1000; 640 * 479])
            .unwrap_err()
            .to_string();
        assert!(e.contains("640x480"), "{e}");
        let mut bad = Registration::default();
        bad.depth.width = 0;
        assert!(
            bad.register(&[])
                .unwrap_err()
                .to_string()
                .contains("depth camera")
        );
    }

    /// Nearest surface wins: a near square in front of a far wall hides the wall.
    #[test]
    fn registration_keeps_the_nearest_surface_and_skips_no_readings() {
        let reg = Registration {
            offset: [-0.2, 0.0, 0.0],
            depth: Camera::pinhole(40, 30, 40.0, 40.0, 20.0, 15.0),
            colour: Camera::pinhole(40, 30, 40.0, 40.0, 20.0, 15.0),
        };
        let mut mm = vec![3000u16; 40 * 30];
        for v in 10..20 {
            for u in 15..25 {
                mm[v * 40 + u] = 1000;
            }
        }
        mm[5 * 40 + 5] = NO_READING;
        mm[5 * 40 + 6] = 0;
        let out = reg.register(&mm).unwrap();
        // The near square moves 8 px left (40 px * 0.2 m / 1 m), the wall 2.7 px.
        assert_eq!(out.get(10, 15), Some(1.0));
        assert_eq!(out.get(25, 15), Some(3.0));
        // Where the square now covers the wall, the square wins.
        assert!(out.data.iter().filter(|&&z| z == 1.0).count() >= 95);
        // No reading in, none out: the wall pixels behind them moved 3 px left.
        assert_eq!(out.get(2, 5), None);
        assert_eq!(out.get(3, 5), None);
    }

    #[test]
    fn colour_pose_sits_at_minus_the_offset_in_the_depth_camera() {
        let reg = Registration::default();
        let depth_pose = Pose::from_parts(
            Translation3::new(1.0, 2.0, 3.0),
            UnitQuaternion::from_euler_angles(0.3, -0.2, 0.9),
        );
        let c = reg.colour_pose(&depth_pose);
        let centre = c * Point3::origin();
        let expected = depth_pose * Point3::from(-reg.offset());
        assert!((centre - expected).norm() < 1e-12);
        // A world point: its colour-camera coordinates are its depth-camera ones + offset.
        let x = Point3::new(0.4, -0.3, 2.5);
        let in_depth = depth_pose.inverse() * x;
        let in_colour = c.inverse() * x;
        assert!((in_colour - (in_depth + reg.offset())).norm() < 1e-12);
    }

    #[test]
    fn poses_are_read_and_bad_ones_named() {
        let d = dir("poses");
        let p = d.join("frame-000000.pose.txt");
        let r = Rotation3::from_euler_angles(0.1, 0.2, 0.3);
        let m = r.matrix();
        let text = format!(
            "{:e}\t{:e}\t{:e}\t0.5\n{:e}\t{:e}\t{:e}\t-0.25\n{:e}\t{:e}\t{:e}\t1.5\n0\t0\t0\t1\n",
            m[(0, 0)],
            m[(0, 1)],
            m[(0, 2)],
            m[(1, 0)],
            m[(1, 1)],
            m[(1, 2)],
            m[(2, 0)],
            m[(2, 1)],
            m[(2, 2)]
        );
        std::fs::write(&p, &text).unwrap();
        let pose = read_pose(&p).unwrap();
        assert!((pose.translation.vector - Vector3::new(0.5, -0.25, 1.5)).norm() < 1e-12);
        assert!(
            pose.rotation
                .angle_to(&UnitQuaternion::from_rotation_matrix(&r))
                < 1e-9
        );

        let bad = |text: &str, needle: &str| {
            std::fs::write(&p, text).unwrap();
            let e = read_pose(&p).unwrap_err().to_string();
            assert!(
                e.contains("frame-000000.pose.txt") && e.contains(needle),
                "{e}"
            );
        };
        // A half turn, where iterative conversions are known to fail.
        std::fs::write(&p, "-1 0 0 1\n0 -1 0 2\n0 0 1 3\n0 0 0 1\n").unwrap();
        let half = read_pose(&p).unwrap();
        let x = half * Point3::new(1.0, 1.0, 1.0);
        assert!((x - Point3::new(0.0, 1.0, 4.0)).norm() < 1e-12, "{x}");
        bad("1 0 0 0\n0 1 0 0\n0 0 1 0\n", "found 3 row(s)");
        bad(
            "1 0 0 0\n0 1 0\n0 0 1 0\n0 0 0 1\n",
            ":2: expected 4 numbers",
        );
        bad(
            "1 0 0 0\n0 1 0 0\n0 0 nan 0\n0 0 0 1\n",
            ":3: 'nan' is not a finite",
        );
        bad("2 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n", "not a rotation");
        bad("-1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n", "not a rotation");
        bad("1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 1 1\n", ":4: last row");
        bad(
            "1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n1 0 0 0\n",
            ":5: more than four rows",
        );
        // Positions no room holds.
        bad(
            "1 0 0 0\n0 1 0 1e300\n0 0 1 0\n0 0 0 1\n",
            ":2: translation 1e300 m",
        );
        bad(
            "1 0 0 -1500\n0 1 0 0\n0 0 1 0\n0 0 0 1\n",
            ":1: translation -1.5e3 m",
        );
        bad(
            "1 0 0 600\n0 1 0 600\n0 0 1 600\n0 0 0 1\n",
            "1039.2 m from the origin",
        );
        std::fs::write(&p, "1 0 0 999\n0 1 0 0\n0 0 1 0\n0 0 0 1\n").unwrap();
        assert!(read_pose(&p).is_ok());
    }

    #[test]
    fn registration_files_are_checked() {
        let d = dir("registration");
        let p = d.join("reg.toml");
        let good = toml::to_string(&Registration::default()).unwrap();
        std::fs::write(&p, &good).unwrap();
        assert_eq!(
            Registration::from_file(&p).unwrap(),
            Registration::default()
        );
        std::fs::write(&p, good.replace("-0.035", "3.5")).unwrap();
        let e = Registration::from_file(&p).unwrap_err().to_string();
        assert!(e.contains("reg.toml") && e.contains("offset"), "{e}");
        std::fs::write(&p, good.replace("fx = 585.0", "fx = -585.0")).unwrap();
        let e = Registration::from_file(&p).unwrap_err().to_string();
        assert!(e.contains("depth camera"), "{e}");
        std::fs::write(&p, format!("scale = 2\n{good}")).unwrap();
        let e = Registration::from_file(&p).unwrap_err().to_string();
        assert!(e.contains("reg.toml") && e.contains("scale"), "{e}");
    }
}
