//! Generator configuration, read from TOML (`configs/synth/default.toml` is the
//! documented reference). Unknown fields are errors with their line number;
//! every field has a default, so a file only lists what it changes.

use crate::camera::{Camera, toml_error};
use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Camera motion of a sequence.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TrajectoryKind {
    /// Hand-held sweep along an arc in front of furniture (like TUM fr1_desk).
    Sweep,
    /// Mostly roll / pitch / yaw about a nearly fixed point (like fr1_rpy).
    Rpy,
    /// Ground robot at 0.4 m: turns in place, then drives (like fr2_pioneer_360).
    Robot,
    /// Smooth random walk through the room looking at random things.
    Walk,
}

impl std::str::FromStr for TrajectoryKind {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s.to_ascii_lowercase().as_str() {
            "sweep" => Ok(Self::Sweep),
            "rpy" => Ok(Self::Rpy),
            "robot" => Ok(Self::Robot),
            "walk" => Ok(Self::Walk),
            _ => Err(Error::msg(format!(
                "unknown trajectory kind '{s}': use sweep, rpy, robot or walk"
            ))),
        }
    }
}

/// The kind of room, which decides its furniture.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RoomKind {
    /// Desks, bookshelves, cabinets and boxes, often a whiteboard.
    Office,
    /// A bed, dresser and wardrobe.
    Bedroom,
    /// A sofa, TV stand, armchair, rug and coffee table.
    Living,
    /// Mostly bookshelves, with a table in the middle.
    Library,
    /// Counters, a fridge and a table in the middle.
    Kitchen,
}

/// Room generation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RoomConfig {
    /// Smallest floor size `[width, depth]`, metres.
    pub min_size: [f64; 2],
    /// Largest floor size `[width, depth]`, metres.
    pub max_size: [f64; 2],
    /// Ceiling height range `[min, max]`, metres.
    pub height: [f64; 2],
    /// Probability that a room is L-shaped.
    pub l_shape_probability: f64,
    /// Room kinds to draw from (uniformly).
    pub kinds: Vec<RoomKind>,
    /// Amount of optional furniture and small props, 0 to 1.
    pub clutter: f64,
}

impl Default for RoomConfig {
    fn default() -> Self {
        RoomConfig {
            min_size: [3.6, 3.4],
            max_size: [6.5, 6.0],
            height: [2.5, 3.0],
            l_shape_probability: 0.3,
            kinds: vec![
                RoomKind::Office,
                RoomKind::Bedroom,
                RoomKind::Living,
                RoomKind::Library,
                RoomKind::Kitchen,
            ],
            clutter: 0.6,
        }
    }
}

impl RoomConfig {
    /// Checks the ranges; the message names the field.
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(Error::msg(m));
        for k in 0..2 {
            let (lo, hi) = (self.min_size[k], self.max_size[k]);
            if !(lo.is_finite() && hi.is_finite()) || lo < 3.0 || hi < lo || hi > 20.0 {
                return bad(format!(
                    "room.min_size and room.max_size must satisfy 3 <= min_size <= max_size <= \
                     20 m, got {lo} and {hi}"
                ));
            }
        }
        let [h0, h1] = self.height;
        if !(h0.is_finite() && h1.is_finite()) || h0 < 2.2 || h1 < h0 || h1 > 6.0 {
            return bad(format!(
                "room.height must satisfy 2.2 <= min <= max <= 6 m, got [{h0}, {h1}]"
            ));
        }
        if !(0.0..=1.0).contains(&self.l_shape_probability) {
            return bad("room.l_shape_probability must be in [0, 1]".into());
        }
        if !(0.0..=1.0).contains(&self.clutter) {
            return bad("room.clutter must be in [0, 1]".into());
        }
        if self.kinds.is_empty() {
            return bad("room.kinds must list at least one room kind".into());
        }
        Ok(())
    }
}

/// Shading.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RenderConfig {
    /// Shadow rays towards the ceiling lights.
    pub shadows: bool,
    /// Brightness multiplier of the whole image.
    pub exposure: f64,
    /// Darkening of the image corners (0 = none).
    pub vignetting: f64,
    /// Light 3x3 blur of the colour image, like a real lens and demosaicing.
    pub soften: bool,
}

impl Default for RenderConfig {
    fn default() -> Self {
        RenderConfig {
            shadows: true,
            exposure: 1.0,
            vignetting: 0.3,
            soften: true,
        }
    }
}

/// Sensor imperfections (off: exact images).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SensorConfig {
    /// Kinect-like depth noise, sigma = 1.2 mm + 1.9 mm (z - 0.4)^2 (Nguyen et
    /// al. 2012), and 1/8-pixel disparity quantisation.
    pub depth_noise: bool,
    /// Holes at depth discontinuities, grazing angles, dark surfaces, glass,
    /// and random blobs.
    pub depth_holes: bool,
    /// Depth readings outside `[min_depth, max_depth]` metres are dropped.
    pub min_depth: f64,
    /// Upper end of the kept depth range, metres.
    pub max_depth: f64,
    /// Colour noise standard deviation (8-bit levels, at mid-grey).
    pub rgb_noise: f64,
    /// Relative amplitude of the slow auto-exposure drift (0 = constant).
    pub exposure_variation: f64,
}

impl Default for SensorConfig {
    fn default() -> Self {
        SensorConfig {
            depth_noise: true,
            depth_holes: true,
            min_depth: 0.45,
            max_depth: 8.0,
            rgb_noise: 2.0,
            exposure_variation: 0.12,
        }
    }
}

impl SensorConfig {
    /// No noise, no holes, constant exposure: images equal the ground truth.
    pub fn exact() -> Self {
        SensorConfig {
            depth_noise: false,
            depth_holes: false,
            min_depth: 0.0,
            max_depth: 1e3,
            rgb_noise: 0.0,
            exposure_variation: 0.0,
        }
    }
}

/// Motion blur: each colour image averages renders along the trajectory.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BlurConfig {
    /// Render motion blur at all.
    pub enabled: bool,
    /// Exposure time, milliseconds.
    pub exposure_ms: f64,
    /// Renders averaged per image (odd, so the middle one is the centre pose).
    pub samples: usize,
}

impl Default for BlurConfig {
    fn default() -> Self {
        BlurConfig {
            enabled: false,
            exposure_ms: 30.0,
            samples: 9,
        }
    }
}

/// Trajectory shape.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MotionConfig {
    /// Scales all speeds (1 = typical TUM hand-held speeds).
    pub speed: f64,
    /// Minimum distance from the camera to any surface, metres.
    pub clearance: f64,
    /// Camera height range `[min, max]` of the NYU-layout still views, metres above the floor.
    pub view_height: [f64; 2],
}

impl Default for MotionConfig {
    fn default() -> Self {
        MotionConfig {
            speed: 1.0,
            clearance: 0.3,
            view_height: [0.8, 1.8],
        }
    }
}

/// What to write.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OutputConfig {
    /// TUM-layout sequence folders.
    pub sequence: bool,
    /// Exact depth (`depth_gt/`) beside the sensor depth in sequences.
    pub gt_depth: bool,
    /// Colourised label images (`labels_color/`) for viewing.
    pub color_labels: bool,
    /// The NYU-layout segmentation / depth training set.
    pub nyu: bool,
    /// Independent random views per scene for the NYU-layout set.
    pub nyu_views_per_scene: usize,
    /// Share of the NYU-layout set in `test.txt` (whole scenes when there are several).
    pub nyu_test_fraction: f64,
}

impl Default for OutputConfig {
    fn default() -> Self {
        OutputConfig {
            sequence: true,
            gt_depth: true,
            color_labels: false,
            nyu: true,
            nyu_views_per_scene: 20,
            nyu_test_fraction: 0.2,
        }
    }
}

/// The whole generator configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SynthConfig {
    /// Master seed: the same seed and configuration give byte-identical output.
    pub seed: u64,
    /// Number of rooms (one sequence folder each).
    pub scenes: usize,
    /// Frames per sequence.
    pub frames: usize,
    /// Frame rate, Hz.
    pub fps: f64,
    /// Timestamp of the first frame, seconds (a TUM-like epoch).
    pub start_time: f64,
    /// Camera motion of each sequence.
    pub trajectory: TrajectoryKind,
    /// `fr1`, `fr2`, `fr3` or the path of a camera TOML file.
    pub camera: String,
    /// `WxH`; empty: the camera's own size. The intrinsics are scaled to it.
    pub resolution: String,
    /// Room generation.
    pub room: RoomConfig,
    /// Trajectory shape.
    pub motion: MotionConfig,
    /// Shading.
    pub render: RenderConfig,
    /// Sensor imperfections.
    pub sensor: SensorConfig,
    /// Motion blur.
    pub blur: BlurConfig,
    /// What to write.
    pub output: OutputConfig,
}

impl Default for SynthConfig {
    fn default() -> Self {
        SynthConfig {
            seed: 1,
            scenes: 1,
            frames: 300,
            fps: 30.0,
            start_time: 1_305_031_100.0,
            trajectory: TrajectoryKind::Sweep,
            camera: "fr1".into(),
            resolution: "640x480".into(),
            room: RoomConfig::default(),
            motion: MotionConfig::default(),
            render: RenderConfig::default(),
            sensor: SensorConfig::default(),
            blur: BlurConfig::default(),
            output: OutputConfig::default(),
        }
    }
}

/// Parses `WxH` (e.g. `640x480`).
pub fn parse_resolution(s: &str) -> Result<(u32, u32)> {
    let err = || {
        Error::msg(format!(
            "resolution '{s}' is not WIDTHxHEIGHT (e.g. 640x480, each 8 to 8192)"
        ))
    };
    let (w, h) = s.trim().split_once(['x', 'X']).ok_or_else(err)?;
    let w: u32 = w.trim().parse().map_err(|_| err())?;
    let h: u32 = h.trim().parse().map_err(|_| err())?;
    if !(8..=8192).contains(&w) || !(8..=8192).contains(&h) {
        return Err(err());
    }
    Ok((w, h))
}

impl SynthConfig {
    /// Reads a TOML file; errors name the file and line.
    pub fn from_file(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let text = crate::io::read_text(path)?;
        let cfg: SynthConfig = toml::from_str(&text).map_err(|e| toml_error(path, &text, e))?;
        cfg.validate()
            .map_err(|e| crate::io::config_error(path, &text, e.to_string()))?;
        Ok(cfg)
    }

    /// The configuration as TOML.
    pub fn to_toml(&self) -> Result<String> {
        Ok(toml::to_string_pretty(self)?)
    }

    /// The camera, resized to the configured resolution.
    pub fn camera(&self) -> Result<Camera> {
        let cam = Camera::load(&self.camera)?;
        if self.resolution.trim().is_empty() {
            return Ok(cam);
        }
        let (w, h) = parse_resolution(&self.resolution)?;
        Ok(cam.resized(w, h))
    }

    /// Checks ranges; the message names the field.
    pub fn validate(&self) -> Result<()> {
        /// Frames of one sequence; the camera path is planned whole before rendering.
        const MAX_FRAMES: usize = crate::dataset::tum::MAX_SEQUENCE_FRAMES;
        /// Independent views of one scene for the NYU-layout set.
        const MAX_VIEWS: usize = 10_000;
        /// Images one run renders, all scenes together: ten million 640x480 renders take
        /// days on a desktop CPU and fill terabytes.
        const MAX_RENDERS: usize = 10_000_000;
        self.room.validate()?;
        let bad = |m: &str| Err(Error::msg(m.to_string()));
        if self.scenes == 0 || self.scenes > 100_000 {
            return Err(Error::msg(format!(
                "scenes must be between 1 and 100000, got {}",
                self.scenes
            )));
        }
        if self.frames > MAX_FRAMES {
            return Err(Error::msg(format!(
                "frames must be at most {MAX_FRAMES} per sequence (about 9 hours at 30 Hz), got {}",
                self.frames
            )));
        }
        if self.frames == 0 && self.output.sequence {
            return bad("frames must be at least 1 when sequences are written");
        }
        if !(self.fps.is_finite() && (1.0..=1000.0).contains(&self.fps)) {
            return bad(
                "fps must be in [1, 1000] (the trajectory is planned for the whole duration)",
            );
        }
        if !(self.start_time.is_finite() && self.start_time >= 0.0) {
            return bad("start_time must be a non-negative number of seconds");
        }
        if !self.resolution.trim().is_empty() {
            parse_resolution(&self.resolution)?;
        }
        let m = &self.motion;
        if !(m.speed.is_finite() && m.speed > 0.0 && m.speed <= 10.0) {
            return bad("motion.speed must be in (0, 10]");
        }
        if !(m.clearance.is_finite() && (0.05..=1.0).contains(&m.clearance)) {
            return bad("motion.clearance must be in [0.05, 1] m");
        }
        let [v0, v1] = m.view_height;
        // The camera keeps its clearance from the floor and from the lowest ceiling.
        let top = self.room.height[0] - m.clearance;
        // And some of the range must leave a still view its margin from floor and ceiling.
        let margin = crate::synth::trajectory::VIEW_MARGIN;
        let reachable = v1 >= m.clearance + margin && v0 <= top - margin;
        if !(v0.is_finite()
            && v1.is_finite()
            && v0 >= m.clearance
            && v1 >= v0
            && v1 <= top
            && reachable)
        {
            return Err(Error::msg(format!(
                "motion.view_height = [{v0}, {v1}] must satisfy motion.clearance ({}) <= min <= \
                 max <= the lowest ceiling (room.height min {}) less the clearance ({top:.2} m), \
                 and reach {margin} m inside that band",
                m.clearance, self.room.height[0]
            )));
        }
        let r = &self.render;
        if !(r.exposure.is_finite() && r.exposure > 0.0 && r.exposure <= 100.0) {
            return bad("render.exposure must be in (0, 100]");
        }
        if !(0.0..=1.0).contains(&r.vignetting) {
            return bad("render.vignetting must be in [0, 1]");
        }
        let s = &self.sensor;
        if !(s.min_depth >= 0.0 && s.max_depth > s.min_depth && s.max_depth.is_finite()) {
            return bad("sensor: need 0 <= min_depth < max_depth");
        }
        if !(0.0..=100.0).contains(&s.rgb_noise) {
            return bad("sensor.rgb_noise must be in [0, 100]");
        }
        if !(0.0..=0.9).contains(&s.exposure_variation) {
            return bad("sensor.exposure_variation must be in [0, 0.9]");
        }
        let b = &self.blur;
        if !(b.exposure_ms.is_finite()
            && b.exposure_ms >= 0.0
            && b.exposure_ms <= 1000.0 / self.fps)
        {
            return bad("blur.exposure_ms must be between 0 and the frame interval");
        }
        if b.samples == 0 || b.samples > 64 {
            return bad("blur.samples must be between 1 and 64");
        }
        let o = &self.output;
        if !o.sequence && !o.nyu {
            return bad("output: nothing to write (sequence and nyu are both false)");
        }
        if !(0.0..=1.0).contains(&o.nyu_test_fraction) {
            return bad("output.nyu_test_fraction must be in [0, 1]");
        }
        if o.nyu && o.nyu_views_per_scene == 0 {
            return bad(
                "output.nyu_views_per_scene must be at least 1 when the NYU set is written",
            );
        }
        if o.nyu_views_per_scene > MAX_VIEWS {
            return Err(Error::msg(format!(
                "output.nyu_views_per_scene must be at most {MAX_VIEWS} (the shipped training \
                 set has 30), got {}",
                o.nyu_views_per_scene
            )));
        }
        // The whole run: every render of every scene (blurred frames average several).
        let per_frame = if b.enabled { b.samples } else { 1 };
        let per_scene = if o.sequence {
            self.frames * per_frame
        } else {
            0
        } + if o.nyu { o.nyu_views_per_scene } else { 0 };
        let renders = self.scenes.saturating_mul(per_scene);
        if renders > MAX_RENDERS {
            return Err(Error::msg(format!(
                "scenes x (frames x blur.samples + output.nyu_views_per_scene) = {renders} \
                 renders, more than the {MAX_RENDERS} one run may make (days of computing and \
                 terabytes of images): split the run (seeds) or lower scenes, frames or \
                 nyu_views_per_scene"
            )));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resolution_parsing() {
        assert_eq!(parse_resolution("640x480").unwrap(), (640, 480));
        assert_eq!(parse_resolution(" 80X60 ").unwrap(), (80, 60));
        for bad in ["640", "640x", "x480", "-1x2", "640*480", "0x0", "99999x10"] {
            let e = parse_resolution(bad).unwrap_err().to_string();
            assert!(e.contains("WIDTHxHEIGHT"), "{bad}: {e}");
        }
    }

    #[test]
    fn unknown_fields_and_bad_values_are_errors_with_lines() {
        let dir = std::env::temp_dir().join(format!("sdf_synth_cfg_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("c.toml");
        std::fs::write(&p, "seed = 3\n[render]\nshadow = true\n").unwrap();
        let e = SynthConfig::from_file(&p).unwrap_err().to_string();
        assert!(e.contains("c.toml:3") && e.contains("shadow"), "{e}");
        std::fs::write(&p, "trajectory = \"zigzag\"\n").unwrap();
        let e = SynthConfig::from_file(&p).unwrap_err().to_string();
        assert!(e.contains("c.toml:1") && e.contains("zigzag"), "{e}");
        std::fs::write(&p, "frames = 10\n[room]\nheight = [2.0, 1.0]\n").unwrap();
        let e = SynthConfig::from_file(&p).unwrap_err().to_string();
        assert!(e.contains("c.toml:3") && e.contains("room.height"), "{e}");
        // Still views that cannot fit under the lowest ceiling.
        std::fs::write(
            &p,
            "[room]\nheight = [2.4, 3]\n[motion]\nview_height = [0.5, 2.5]\n",
        )
        .unwrap();
        let e = SynthConfig::from_file(&p).unwrap_err().to_string();
        assert!(
            e.contains("c.toml:4") && e.contains("lowest ceiling"),
            "{e}"
        );
        std::fs::write(&p, "fps = 0.001\n").unwrap();
        let e = SynthConfig::from_file(&p).unwrap_err().to_string();
        assert!(e.contains("fps"), "{e}");
        for (text, field) in [
            (
                "[output]\nnyu_views_per_scene = 10001\n",
                "nyu_views_per_scene",
            ),
            (
                "[output]\nnyu_views_per_scene = 9223372036854775807\n",
                "nyu_views_per_scene",
            ),
            ("scenes = 100000\nframes = 1000\n", "renders"),
            ("scenes = 20\nframes = 1000000\n", "renders"),
            ("scenes = 1000000\n", "scenes"),
        ] {
            std::fs::write(&p, text).unwrap();
            let e = SynthConfig::from_file(&p).unwrap_err().to_string();
            assert!(e.contains("c.toml") && e.contains(field), "{text}: {e}");
        }
        std::fs::write(&p, "seed = 9\nframes = 12\n").unwrap();
        let c = SynthConfig::from_file(&p).unwrap();
        assert_eq!((c.seed, c.frames, c.scenes), (9, 12, 1));
        std::fs::remove_dir_all(dir).unwrap();
        assert!("robot".parse::<TrajectoryKind>().is_ok());
        assert!(
            "spiral"
                .parse::<TrajectoryKind>()
                .unwrap_err()
                .to_string()
                .contains("sweep")
        );
    }

    #[test]
    fn shipped_configs_are_valid() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/synth");
        let default = SynthConfig::from_file(dir.join("default.toml")).unwrap();
        assert_eq!(default, SynthConfig::default());
        let train = SynthConfig::from_file(dir.join("train.toml")).unwrap();
        assert!(!train.output.sequence && train.scenes >= 100);
        let blur = SynthConfig::from_file(dir.join("blur.toml")).unwrap();
        assert!(blur.blur.enabled && blur.trajectory == TrajectoryKind::Rpy);
    }

    #[test]
    fn round_trips_through_toml() {
        let c = SynthConfig::default();
        let back: SynthConfig = toml::from_str(&c.to_toml().unwrap()).unwrap();
        assert_eq!(back, c);
    }
}
