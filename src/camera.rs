//! Pinhole camera with Brown-Conrady distortion (k1, k2, p1, p2, k3), the model of
//! OpenCV and of the TUM RGB-D calibration. Eq 1 and eq 9 of the paper are its
//! undistorted special case: `(u, v, 1)ᵀ = K (X, Y, Z)ᵀ / Z`.
//!
//! Pixel coordinates follow OpenCV: `(0, 0)` is the centre of the top-left pixel.

use crate::error::{Error, Result};
use nalgebra::{Matrix2, Point2, Point3, Vector2};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Largest image side a camera may describe: buffers per pixel are allocated from it.
pub(crate) const MAX_SIDE: u32 = 16384;

/// Focal lengths a camera may have: `fx` in image widths, `fy` in image heights (TUM's
/// cameras: 0.81; 0.1 is a field of view of 157°, 100 one of 0.6°).
pub(crate) const FOCAL_RANGE: (f64, f64) = (0.1, 100.0);

/// Brown-Conrady lens distortion coefficients (OpenCV order k1, k2, p1, p2, k3).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Distortion {
    /// First radial distortion coefficient (r² term).
    #[serde(default)]
    pub k1: f64,
    /// Second radial distortion coefficient (r⁴ term).
    #[serde(default)]
    pub k2: f64,
    /// First tangential distortion coefficient.
    #[serde(default)]
    pub p1: f64,
    /// Second tangential distortion coefficient.
    #[serde(default)]
    pub p2: f64,
    /// Third radial distortion coefficient (r⁶ term).
    #[serde(default)]
    pub k3: f64,
}

impl Distortion {
    /// Whether every coefficient is zero (no distortion: an ideal pinhole).
    pub fn is_zero(&self) -> bool {
        *self == Distortion::default()
    }

    /// Distorts normalised image coordinates.
    pub fn distort(&self, p: Vector2<f64>) -> Vector2<f64> {
        let (x, y) = (p.x, p.y);
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        Vector2::new(
            x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x),
            y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y,
        )
    }

    /// Jacobian of [`Distortion::distort`] at `p`.
    fn jacobian(&self, p: Vector2<f64>) -> Matrix2<f64> {
        let (x, y) = (p.x, p.y);
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        // d(radial)/d(r2)
        let dr = self.k1 + r2 * (2.0 * self.k2 + 3.0 * r2 * self.k3);
        let dxdx = radial + x * dr * 2.0 * x + 2.0 * self.p1 * y + self.p2 * 6.0 * x;
        let dxdy = x * dr * 2.0 * y + 2.0 * self.p1 * x + self.p2 * 2.0 * y;
        let dydx = y * dr * 2.0 * x + self.p1 * 2.0 * x + 2.0 * self.p2 * y;
        let dydy = radial + y * dr * 2.0 * y + self.p1 * 6.0 * y + 2.0 * self.p2 * x;
        Matrix2::new(dxdx, dxdy, dydx, dydy)
    }

    /// Inverts [`Distortion::distort`] by Gauss-Newton (machine precision within
    /// the image for the TUM calibrations).
    pub fn undistort(&self, pd: Vector2<f64>) -> Vector2<f64> {
        if self.is_zero() {
            return pd;
        }
        let mut p = pd;
        for _ in 0..20 {
            let residual = self.distort(p) - pd;
            if residual.norm_squared() < 1e-26 {
                break;
            }
            match self.jacobian(p).try_inverse() {
                Some(inv) => p -= inv * residual,
                None => break,
            }
        }
        p
    }
}

/// Camera intrinsics, image size and distortion.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Camera {
    /// Optional human-readable name (e.g. "freiburg1").
    #[serde(default)]
    pub name: String,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Horizontal focal length, pixels.
    pub fx: f64,
    /// Vertical focal length, pixels.
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
    /// Lens distortion (zero for an ideal pinhole).
    #[serde(default)]
    pub distortion: Distortion,
}

impl Camera {
    /// Ideal pinhole camera.
    pub fn pinhole(width: u32, height: u32, fx: f64, fy: f64, cx: f64, cy: f64) -> Self {
        Camera {
            name: String::new(),
            width,
            height,
            fx,
            fy,
            cx,
            cy,
            distortion: Distortion::default(),
        }
    }

    /// TUM RGB-D freiburg1 colour camera (published calibration).
    pub fn tum_fr1() -> Self {
        Camera {
            name: "freiburg1".into(),
            distortion: Distortion {
                k1: 0.2624,
                k2: -0.9531,
                p1: -0.0054,
                p2: 0.0026,
                k3: 1.1633,
            },
            ..Camera::pinhole(640, 480, 517.3, 516.5, 318.6, 255.3)
        }
    }

    /// TUM RGB-D freiburg2 colour camera.
    pub fn tum_fr2() -> Self {
        Camera {
            name: "freiburg2".into(),
            distortion: Distortion {
                k1: 0.2312,
                k2: -0.7849,
                p1: -0.0033,
                p2: -0.0001,
                k3: 0.9172,
            },
            ..Camera::pinhole(640, 480, 520.9, 521.0, 325.1, 249.7)
        }
    }

    /// TUM RGB-D freiburg3 colour camera (images already undistorted).
    pub fn tum_fr3() -> Self {
        Camera {
            name: "freiburg3".into(),
            ..Camera::pinhole(640, 480, 535.4, 539.2, 320.1, 247.6)
        }
    }

    /// A preset by name (`fr1`, `fr2`, `fr3`, also `freiburg1`...).
    pub fn preset(name: &str) -> Option<Self> {
        match name.to_ascii_lowercase().as_str() {
            "fr1" | "freiburg1" => Some(Self::tum_fr1()),
            "fr2" | "freiburg2" => Some(Self::tum_fr2()),
            "fr3" | "freiburg3" => Some(Self::tum_fr3()),
            _ => None,
        }
    }

    /// Reads a camera TOML file (`width height fx fy cx cy`, optional
    /// `[distortion]` table with `k1 k2 p1 p2 k3`).
    pub fn from_file(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let text = crate::io::read_text(path)?;
        let cam: Camera = toml::from_str(&text).map_err(|e| toml_error(path, &text, e))?;
        cam.validate()
            .map_err(|m| crate::io::config_error(path, &text, m))?;
        Ok(cam)
    }

    /// A preset name or a camera file path.
    pub fn load(spec: &str) -> Result<Self> {
        match Self::preset(spec) {
            Some(c) => Ok(c),
            None if Path::new(spec).exists() => Self::from_file(spec),
            None if spec.contains(['/', '\\']) || spec.ends_with(".toml") => Err(Error::invalid(
                Path::new(spec),
                "camera file does not exist",
            )),
            None => Err(Error::msg(format!(
                "unknown camera '{spec}': use fr1, fr2, fr3 or the path of a camera TOML file"
            ))),
        }
    }

    /// The camera of a TUM-layout sequence: `spec` (a preset or a file) when given, else
    /// the folder's `camera.toml` when it has one (7-Scenes conversions do), else TUM's
    /// freiburg1 camera. `slam`, `eval matching` and FPFDCNN training choose it this way.
    pub fn for_sequence(spec: Option<&str>, sequence: &Path) -> Result<Self> {
        let file = sequence.join("camera.toml");
        match spec {
            Some(s) => Self::load(s),
            // `exists`: a camera.toml that is a FIFO or a folder is refused, not passed over.
            None if file.exists() => Self::from_file(&file),
            None => Ok(Self::tum_fr1()),
        }
    }

    /// Writes the camera as TOML (atomically).
    pub fn save(&self, path: impl AsRef<Path>) -> Result<()> {
        let text = toml::to_string_pretty(self)?;
        crate::io::write_atomic(path, text.as_bytes())
    }

    /// Checks that the camera can be a real one (what reading a camera file or a registration
    /// checks, and what every preset passes); the message names the field:
    ///
    /// * every number finite; `width` and `height` 1 to `MAX_SIDE`;
    /// * `fx` between 0.1 and 100 image widths and `fy` between 0.1 and 100 image heights
    ///   (`FOCAL_RANGE`: fields of view from 157° down to 0.6°; TUM's cameras have 0.81);
    /// * the principal point (`cx`, `cy`) inside the image;
    /// * a distortion that keeps the image in one piece: the radial distortion
    ///   `r_d(r) = r (1 + k1 r² + k2 r⁴ + k3 r⁶)` increasing from the centre until it reaches
    ///   the farthest image corner (sampled every thousandth of the corner's radius), and
    ///   reaching it between a quarter and four times the corner's radius (the field of view
    ///   neither shrunk nor stretched fourfold); the whole distortion, tangential terms
    ///   included, invertible with a positive Jacobian over a 17x17 grid of the image
    ///   ([`Distortion::undistort`] converging at every point).
    pub fn validate(&self) -> std::result::Result<(), String> {
        let d = &self.distortion;
        let numbers = [
            ("fx", self.fx),
            ("fy", self.fy),
            ("cx", self.cx),
            ("cy", self.cy),
            ("distortion.k1", d.k1),
            ("distortion.k2", d.k2),
            ("distortion.p1", d.p1),
            ("distortion.p2", d.p2),
            ("distortion.k3", d.k3),
        ];
        if let Some((name, v)) = numbers.iter().find(|(_, v)| !v.is_finite()) {
            return Err(format!(
                "{name} = {v}: camera intrinsics and distortion coefficients must be finite numbers"
            ));
        }
        if self.width == 0 || self.height == 0 {
            return Err(format!(
                "width and height must be positive, got {}x{}",
                self.width, self.height
            ));
        }
        if self.width > MAX_SIDE || self.height > MAX_SIDE {
            return Err(format!(
                "image size {}x{} is larger than {MAX_SIDE} pixels a side (a typo?)",
                self.width, self.height
            ));
        }
        let (lo, hi) = FOCAL_RANGE;
        for (name, f, side, unit) in [
            ("fx", self.fx, self.width, "image widths"),
            ("fy", self.fy, self.height, "image heights"),
        ] {
            let rel = f / side as f64;
            if !(lo..=hi).contains(&rel) {
                return Err(format!(
                    "{name} = {} px is {} {unit}: a focal length must be between {lo} and {hi} \
                     {unit} (fields of view of 157° to 0.6°; TUM's cameras: 0.81)",
                    num(f),
                    num(rel)
                ));
            }
        }
        for (name, c, side, axis) in [
            ("cx", self.cx, self.width, "wide"),
            ("cy", self.cy, self.height, "high"),
        ] {
            let max = side as f64 - 0.5;
            if !(-0.5..=max).contains(&c) {
                return Err(format!(
                    "{name} = {} puts the principal point outside the image ({side} pixels \
                     {axis}: {name} must be between -0.5 and {max})",
                    num(c)
                ));
            }
        }
        self.check_distortion()
    }

    /// The distortion part of [`Camera::validate`].
    fn check_distortion(&self) -> std::result::Result<(), String> {
        let d = &self.distortion;
        if d.is_zero() {
            return Ok(());
        }
        let (w, h) = (self.width as f64 - 0.5, self.height as f64 - 0.5);
        let normalised =
            |u: f64, v: f64| Vector2::new((u - self.cx) / self.fx, (v - self.cy) / self.fy);
        let corner = [(-0.5, -0.5), (w, -0.5), (-0.5, h), (w, h)]
            .into_iter()
            .map(|(u, v)| normalised(u, v).norm())
            .fold(0.0, f64::max);
        // The coefficient that moves the image corner most, named in the messages.
        let dominant = || {
            let r = corner;
            [
                ("k1", d.k1, d.k1.abs() * r * r),
                ("k2", d.k2, d.k2.abs() * r.powi(4)),
                ("k3", d.k3, d.k3.abs() * r.powi(6)),
                ("p1", d.p1, 3.0 * d.p1.abs() * r),
                ("p2", d.p2, 3.0 * d.p2.abs() * r),
            ]
            .into_iter()
            .max_by(|a, b| a.2.total_cmp(&b.2))
            .map(|(n, v, _)| format!("distortion.{n} = {}", num(v)))
            .unwrap_or_default()
        };
        // Radial: r_d increasing from the centre until it reaches the corner, at an undistorted
        // radius between a quarter and four times the corner's.
        let radial = |r: f64| {
            let r2 = r * r;
            r * (1.0 + r2 * (d.k1 + r2 * (d.k2 + r2 * d.k3)))
        };
        let step = corner / 1000.0;
        let mut previous = 0.0;
        let mut reached = None;
        for i in 1..=4000 {
            let r = i as f64 * step;
            let rd = radial(r);
            if rd <= previous {
                return Err(format!(
                    "{}: the radial distortion folds back {:.0} % of the way to the image \
                     corner (r_d stops increasing at r = {r:.4}), so two points of the scene \
                     would land on one pixel: not a real lens's calibration",
                    dominant(),
                    100.0 * previous / corner
                ));
            }
            if rd >= corner {
                reached = Some(r);
                break;
            }
            previous = rd;
        }
        match reached {
            Some(r) if r >= corner / 4.0 => {}
            Some(r) => {
                return Err(format!(
                    "{}: the image corner would show the ray an undistorted camera sees at \
                     {} of the corner's radius (at least 0.25): the distortion squeezes the \
                     field of view; not a real lens's calibration",
                    dominant(),
                    num(r / corner)
                ));
            }
            None => {
                return Err(format!(
                    "{}: the image corner would show a ray an undistorted camera sees beyond 4 \
                     times the corner's radius: the distortion stretches the field of view; \
                     not a real lens's calibration",
                    dominant()
                ));
            }
        }
        // The whole distortion (tangential terms too): invertible over the image.
        const GRID: usize = 17;
        for j in 0..GRID {
            for i in 0..GRID {
                let u = -0.5 + (w + 0.5) * i as f64 / (GRID - 1) as f64;
                let v = -0.5 + (h + 0.5) * j as f64 / (GRID - 1) as f64;
                let pd = normalised(u, v);
                let pu = d.undistort(pd);
                let back = (d.distort(pu) - pd).norm();
                let det = d.jacobian(pu).determinant();
                let scale_ok = pd.norm() < 0.1 * corner
                    || (pu.norm() >= pd.norm() / 4.0 && pu.norm() <= pd.norm() * 4.0);
                if !(back < 1e-6 * (1.0 + pd.norm()) && det > 0.0 && scale_ok) {
                    return Err(format!(
                        "{}: the distortion cannot be undone at pixel ({u:.0}, {v:.0}) (it \
                         folds or tears the image there): not a real lens's calibration",
                        dominant()
                    ));
                }
            }
        }
        Ok(())
    }

    /// The same camera for images resized to `width x height`.
    pub fn resized(&self, width: u32, height: u32) -> Self {
        let sx = width as f64 / self.width as f64;
        let sy = height as f64 / self.height as f64;
        Camera {
            width,
            height,
            fx: self.fx * sx,
            fy: self.fy * sy,
            cx: (self.cx + 0.5) * sx - 0.5,
            cy: (self.cy + 0.5) * sy - 0.5,
            ..self.clone()
        }
    }

    /// The same intrinsics without lens distortion.
    pub fn undistorted(&self) -> Self {
        Camera {
            distortion: Distortion::default(),
            ..self.clone()
        }
    }

    /// Projects a point in camera coordinates to pixels, with distortion.
    /// `None` behind the camera.
    pub fn project(&self, p: &Point3<f64>) -> Option<Point2<f64>> {
        if p.z <= 1e-9 {
            return None;
        }
        let d = self.distortion.distort(Vector2::new(p.x / p.z, p.y / p.z));
        Some(Point2::new(
            self.fx * d.x + self.cx,
            self.fy * d.y + self.cy,
        ))
    }

    /// Back-projects a (distorted) pixel with its z-depth to camera coordinates.
    pub fn back_project(&self, px: &Point2<f64>, depth: f64) -> Point3<f64> {
        let n = self.normalized(px);
        Point3::new(n.x * depth, n.y * depth, depth)
    }

    /// Undistorted normalised coordinates `(X/Z, Y/Z)` of a pixel.
    pub fn normalized(&self, px: &Point2<f64>) -> Vector2<f64> {
        let pd = Vector2::new((px.x - self.cx) / self.fx, (px.y - self.cy) / self.fy);
        self.distortion.undistort(pd)
    }

    /// Where a distorted pixel would be seen by the ideal pinhole camera.
    pub fn undistort_pixel(&self, px: &Point2<f64>) -> Point2<f64> {
        let n = self.normalized(px);
        Point2::new(self.fx * n.x + self.cx, self.fy * n.y + self.cy)
    }

    /// Whether a pixel position lies inside the image (with a margin in pixels).
    pub fn contains(&self, px: &Point2<f64>, margin: f64) -> bool {
        px.x >= -0.5 + margin
            && px.y >= -0.5 + margin
            && px.x <= self.width as f64 - 0.5 - margin
            && px.y <= self.height as f64 - 0.5 - margin
    }
}

/// Undistorted normalised coordinates `(X/Z, Y/Z)` of every `stride`-th pixel of a camera's
/// images, row by row (undistortion iterates: done once, looked up per frame).
#[derive(Debug, Clone)]
pub struct RayTable {
    /// Pixel step between samples, in both directions (at least 1).
    pub stride: u32,
    /// Samples per row and per column: the image size divided by `stride`, rounded up.
    pub width: u32,
    /// Samples per column: the image height divided by `stride`, rounded up.
    pub height: u32,
    /// Normalised coordinates `[X/Z, Y/Z]` of each sample, row by row (`width * height` of them).
    pub rays: Vec<[f64; 2]>,
}

impl RayTable {
    /// Tabulates the rays of `camera` every `stride` pixels (a `stride` of 0 is taken as 1).
    pub fn new(camera: &Camera, stride: u32) -> Self {
        let stride = stride.max(1);
        let (w, h) = (
            camera.width.div_ceil(stride),
            camera.height.div_ceil(stride),
        );
        let mut rays = Vec::with_capacity((w * h) as usize);
        for y in 0..h {
            for x in 0..w {
                let n = camera.normalized(&Point2::new((x * stride) as f64, (y * stride) as f64));
                rays.push([n.x, n.y]);
            }
        }
        RayTable {
            stride,
            width: w,
            height: h,
            rays,
        }
    }

    /// The camera-frame point of sample `(x, y)` at z-depth `z`.
    pub fn point(&self, x: usize, y: usize, z: f64) -> Point3<f64> {
        let [nx, ny] = self.rays[y * self.width as usize + x];
        Point3::new(nx * z, ny * z, z)
    }
}

/// A number as a message quotes it: as written for everyday magnitudes, in exponent form for
/// the very large and very small (`1e30`, not 31 digits).
fn num(v: f64) -> String {
    if v == 0.0 || (1e-4..1e7).contains(&v.abs()) {
        format!("{}", (v * 1e6).round() / 1e6)
    } else {
        format!("{v:e}")
    }
}

/// A TOML error with the file, and the line when the parser knows it.
///
/// Public so that config readers outside the library (the `train` application's sweeps)
/// report TOML errors exactly as the library's own config readers do.
pub fn toml_error(path: &Path, text: &str, e: toml::de::Error) -> Error {
    match e.span() {
        Some(span) => {
            let line = text[..span.start.min(text.len())].matches('\n').count() + 1;
            Error::parse(path, line, e.message().to_string())
        }
        None => Error::invalid(path, e.message().to_string()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn project_back_project_round_trip_with_distortion() {
        let cam = Camera::tum_fr1();
        for &(u, v, z) in &[
            (0.0, 0.0, 1.0),
            (639.0, 479.0, 2.5),
            (320.0, 240.0, 0.7),
            (10.0, 400.0, 4.0),
        ] {
            let p = cam.back_project(&Point2::new(u, v), z);
            assert!((p.z - z).abs() < 1e-12);
            let q = cam.project(&p).unwrap();
            assert!(
                (q.x - u).abs() < 1e-9 && (q.y - v).abs() < 1e-9,
                "{u},{v} -> {q}"
            );
        }
    }

    #[test]
    fn distortion_moves_corner_pixels_and_not_the_centre() {
        let cam = Camera::tum_fr1();
        let centre = cam.undistort_pixel(&Point2::new(cam.cx, cam.cy));
        assert!((centre - Point2::new(cam.cx, cam.cy)).norm() < 1e-12);
        let corner = cam.undistort_pixel(&Point2::new(0.0, 0.0));
        assert!((corner - Point2::new(0.0, 0.0)).norm() > 1.0);
    }

    #[test]
    fn presets_and_resizing() {
        assert_eq!(Camera::preset("FR2").unwrap().fx, 520.9);
        assert!(Camera::preset("fr4").is_none());
        let c = Camera::tum_fr3().resized(320, 240);
        assert_eq!(c.fx, 535.4 / 2.0);
        assert!((c.cx - (320.1 + 0.5) / 2.0 + 0.5).abs() < 1e-12);
    }

    #[test]
    fn camera_file_errors_name_file_and_field() {
        let dir = std::env::temp_dir().join(format!("sdf_cam_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let good = dir.join("good.toml");
        Camera::tum_fr1().save(&good).unwrap();
        assert_eq!(Camera::from_file(&good).unwrap(), Camera::tum_fr1());
        let bad = dir.join("bad.toml");
        std::fs::write(
            &bad,
            "width = 640\nheight = 480\nfx = 500.0\nfy = 500.0\ncx = 320.0\n",
        )
        .unwrap();
        let e = Camera::from_file(&bad).unwrap_err().to_string();
        assert!(e.contains("bad.toml") && e.contains("cy"), "{e}");
        std::fs::write(
            &bad,
            "width = 640\nheight = 480\nfx = \"x\"\nfy = 1.0\ncx = 1.0\ncy = 1.0\n",
        )
        .unwrap();
        let e = Camera::from_file(&bad).unwrap_err().to_string();
        assert!(e.contains("bad.toml:3"), "{e}");
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn presets_and_shipped_cameras_are_plausible() {
        for name in ["fr1", "fr2", "fr3"] {
            let c = Camera::preset(name).unwrap();
            c.validate().unwrap();
            // Resized as synth and training resize them.
            for (w, h) in [(320, 240), (160, 120), (8, 6), (1280, 960)] {
                c.resized(w, h).validate().unwrap();
            }
        }
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/cameras");
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            Camera::from_file(&p).unwrap_or_else(|e| panic!("{e}"));
        }
        // The 7-Scenes colour and depth cameras.
        Camera::pinhole(640, 480, 527.0, 527.0, 323.0, 236.0)
            .validate()
            .unwrap();
        Camera::pinhole(640, 480, 585.0, 585.0, 320.0, 240.0)
            .validate()
            .unwrap();
    }

    #[test]
    fn implausible_cameras_are_refused_naming_the_field() {
        let base = Camera::tum_fr1();
        let check = |c: Camera, field: &str| {
            let e = c.validate().unwrap_err();
            assert!(e.starts_with(field), "{field}: {e}");
        };
        for (cx, cy, field) in [
            (1e6, 255.3, "cx"),
            (-1.0, 255.3, "cx"),
            (640.0, 255.3, "cx"),
            (318.6, -1e6, "cy"),
            (318.6, 480.0, "cy"),
        ] {
            check(
                Camera {
                    cx,
                    cy,
                    ..base.clone()
                },
                field,
            );
        }
        for (fx, fy, field) in [
            (1e-30, 516.5, "fx"),
            (1e30, 516.5, "fx"),
            (63.0, 516.5, "fx"),
            (64_001.0, 516.5, "fx"),
            (517.3, 1e-30, "fy"),
            (517.3, 1e30, "fy"),
            (517.3, 0.0, "fy"),
            (-517.3, 516.5, "fx"),
        ] {
            check(
                Camera {
                    fx,
                    fy,
                    ..base.clone()
                },
                field,
            );
        }
        let with = |d: Distortion| Camera {
            distortion: d,
            ..base.clone()
        };
        let k = |k1, k2, k3| Distortion {
            k1,
            k2,
            k3,
            ..Distortion::default()
        };
        // Far too strong, either way; folding back inside the image; tangential tearing.
        check(with(k(1e10, 0.0, 0.0)), "distortion.k1");
        check(with(k(-1e10, 0.0, 0.0)), "distortion.k1");
        check(with(k(0.0, -5.0, 0.0)), "distortion.k2");
        check(with(k(0.0, 0.0, 1e10)), "distortion.k3");
        check(with(k(-1.0, 0.0, 0.0)), "distortion.k1");
        let p = |p1, p2| Distortion {
            p1,
            p2,
            ..Distortion::default()
        };
        check(with(p(1e10, 0.0)), "distortion.p1");
        check(with(p(0.0, -2.0)), "distortion.p2");
        check(
            with(Distortion {
                k1: f64::NAN,
                ..Distortion::default()
            }),
            "distortion.k1",
        );
        // Mild real-world distortions pass: barrel and pincushion of a few per cent.
        with(k(-0.3, 0.1, 0.0)).validate().unwrap();
        with(k(0.1, 0.0, 0.0)).validate().unwrap();
        with(p(0.01, -0.01)).validate().unwrap();
        // And a file names itself and the field.
        let dir = crate::io::ScratchDir::new("cam_plausible").unwrap();
        let f = dir.join("far.toml");
        std::fs::write(
            &f,
            "width = 640\nheight = 480\nfx = 500.0\nfy = 500.0\ncx = 1000000.0\ncy = 240.0\n",
        )
        .unwrap();
        let e = Camera::from_file(&f).unwrap_err().to_string();
        assert!(e.contains("far.toml") && e.contains("cx = 1000000"), "{e}");
    }
}
