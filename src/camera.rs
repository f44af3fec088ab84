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
pub const MAX_SIDE: u32 = 16384;

/// Brown-Conrady lens distortion coefficients (OpenCV order k1, k2, p1, p2, k3).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Distortion {
    #[serde(default)]
    pub k1: f64,
    #[serde(default)]
    pub k2: f64,
    #[serde(default)]
    pub p1: f64,
    #[serde(default)]
    pub p2: f64,
    #[serde(default)]
    pub k3: f64,
}

impl Distortion {
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
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
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
        cam.validate().map_err(|m| Error::invalid(path, m))?;
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
            None if file.is_file() => Self::from_file(&file),
            None => Ok(Self::tum_fr1()),
        }
    }

    /// Writes the camera as TOML (atomically).
    pub fn save(&self, path: impl AsRef<Path>) -> Result<()> {
        let text = toml::to_string_pretty(self)?;
        crate::io::write_atomic(path, text.as_bytes())
    }

    /// Checks the intrinsics and size (what reading a camera file checks).
    pub(crate) fn validate(&self) -> std::result::Result<(), String> {
        let vals = [self.fx, self.fy, self.cx, self.cy];
        if vals.iter().any(|v| !v.is_finite()) {
            return Err("camera intrinsics must be finite numbers".into());
        }
        if self.fx <= 0.0 || self.fy <= 0.0 {
            return Err(format!(
                "focal lengths must be positive (fx {}, fy {})",
                self.fx, self.fy
            ));
        }
        if self.width == 0 || self.height == 0 {
            return Err("image width and height must be positive".into());
        }
        if self.width > MAX_SIDE || self.height > MAX_SIDE {
            return Err(format!(
                "image size {}x{} is larger than {MAX_SIDE} pixels a side (a typo?)",
                self.width, self.height
            ));
        }
        let d = &self.distortion;
        if [d.k1, d.k2, d.p1, d.p2, d.k3]
            .iter()
            .any(|v| !v.is_finite())
        {
            return Err("distortion coefficients must be finite numbers".into());
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
    pub stride: u32,
    /// Samples per row and per column: the image size divided by `stride`, rounded up.
    pub width: u32,
    pub height: u32,
    pub rays: Vec<[f64; 2]>,
}

impl RayTable {
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
}
