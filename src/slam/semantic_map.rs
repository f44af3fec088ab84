//! The three-dimensional semantic map (section IV-C steps 2-3): each keyframe's
//! pixels with depth are back-projected (eq 9 inverted) to camera points, moved
//! to the world by the keyframe's pose, and fused as `(X, Y, Z, R, G, B, label)`
//! in a voxel grid (hash map of voxel indices): positions and colours are
//! averaged, labels voted. Written as PLY (binary little-endian or ASCII, real
//! colour as `red green blue`, semantic colour as `sem_red sem_green sem_blue`,
//! and `label`), and drawn from above with a class legend.

use super::config::{LabelVoteConfig, MapConfig};
use super::map::KeyFrame;
use crate::camera::Camera;
use crate::classes;
use crate::error::{Error, Result};
use crate::geometry::Pose;
use nalgebra::{Point2, Point3, Vector3};
use rustc_hash::{FxHashMap, FxHashSet};
use std::collections::HashMap;
use std::io::{BufRead, Read, Write};
use std::path::Path;

/// The accumulated observations of one voxel.
#[derive(Debug, Clone)]
pub struct Voxel {
    pub sum: [f64; 3],
    pub rgb: [u32; 3],
    pub count: u32,
    /// Votes per class (0-39).
    pub votes: [u16; classes::NUM_CLASSES],
    /// Void observations.
    pub void: u16,
    /// Keyframes with at least one observation in the voxel.
    pub views: u16,
}

impl Default for Voxel {
    fn default() -> Self {
        Voxel {
            sum: [0.0; 3],
            rgb: [0; 3],
            count: 0,
            votes: [0; classes::NUM_CLASSES],
            void: 0,
            views: 0,
        }
    }
}

impl Voxel {
    /// The voted label: the most voted class (lowest index on ties) if it has
    /// `min_votes` votes and `min_share` of the votes, else void.
    pub fn label(&self, rules: &LabelVoteConfig) -> u8 {
        let (best, &n) = self
            .votes
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.cmp(b.1).then(b.0.cmp(&a.0)))
            .unwrap_or((0, &0));
        let total: u32 = self.votes.iter().map(|&v| v as u32).sum::<u32>()
            + if rules.void_votes {
                self.void as u32
            } else {
                0
            };
        if n == 0 || (n as u32) < rules.min_votes || (n as f64) < rules.min_share * total as f64 {
            classes::VOID
        } else {
            best as u8
        }
    }
}

/// A fused map point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapPoint {
    pub position: Point3<f32>,
    pub rgb: [u8; 3],
    pub label: u8,
}

/// Normalised image coordinates of every `stride`-th pixel (undistortion done once).
#[derive(Debug, Clone)]
struct RayTable {
    stride: u32,
    width: u32,
    height: u32,
    rays: Vec<[f64; 2]>,
}

impl RayTable {
    fn new(camera: &Camera, stride: u32) -> Self {
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
}

/// The voxel grid.
#[derive(Debug, Clone)]
pub struct SemanticMap {
    pub voxel_size: f64,
    pub voxels: FxHashMap<[i32; 3], Voxel>,
    rays: Option<RayTable>,
}

impl SemanticMap {
    pub fn new(voxel_size: f64) -> Self {
        SemanticMap {
            voxel_size,
            voxels: FxHashMap::default(),
            rays: None,
        }
    }

    /// Number of occupied voxels (map points).
    pub fn len(&self) -> usize {
        self.voxels.len()
    }

    pub fn is_empty(&self) -> bool {
        self.voxels.is_empty()
    }

    pub fn clear(&mut self) {
        self.voxels.clear();
    }

    /// Voxel index of a world point.
    pub fn key(&self, p: &Point3<f64>) -> [i32; 3] {
        let f = |v: f64| (v / self.voxel_size).floor() as i32;
        [f(p.x), f(p.y), f(p.z)]
    }

    /// Adds one observation.
    pub fn insert(&mut self, p: &Point3<f64>, rgb: [u8; 3], label: u8) {
        if !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()) {
            return;
        }
        let key = self.key(p);
        let v = self.voxels.entry(key).or_default();
        for a in 0..3 {
            v.sum[a] += p[a];
            v.rgb[a] += rgb[a] as u32;
        }
        v.count += 1;
        match label as usize {
            l if l < classes::NUM_CLASSES => v.votes[l] = v.votes[l].saturating_add(1),
            _ => v.void = v.void.saturating_add(1),
        }
    }

    /// Takes back one observation made by [`Self::insert`] with the same arguments; a voxel
    /// left without observations is removed.
    pub fn remove(&mut self, p: &Point3<f64>, rgb: [u8; 3], label: u8) {
        if !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()) {
            return;
        }
        let key = self.key(p);
        let Some(v) = self.voxels.get_mut(&key) else {
            return;
        };
        if v.count <= 1 {
            self.voxels.remove(&key);
            return;
        }
        for a in 0..3 {
            v.sum[a] -= p[a];
            v.rgb[a] = v.rgb[a].saturating_sub(rgb[a] as u32);
        }
        v.count -= 1;
        match label as usize {
            l if l < classes::NUM_CLASSES => v.votes[l] = v.votes[l].saturating_sub(1),
            _ => v.void = v.void.saturating_sub(1),
        }
    }

    /// Fuses a keyframe's view at `pose`, its depth multiplied by `depth_scale`.
    pub fn fuse(
        &mut self,
        kf: &KeyFrame,
        pose: &Pose,
        depth_scale: f64,
        camera: &Camera,
        cfg: &MapConfig,
    ) {
        let keys = self.integrate(kf, pose, depth_scale, camera, cfg, Self::insert);
        for key in keys {
            if let Some(v) = self.voxels.get_mut(&key) {
                v.views = v.views.saturating_add(1);
            }
        }
    }

    /// Takes back what [`Self::fuse`] added with the same pose and depth scale (voxel
    /// de-integration, as BundleFusion re-integrates frames whose poses changed).
    pub fn unfuse(
        &mut self,
        kf: &KeyFrame,
        pose: &Pose,
        depth_scale: f64,
        camera: &Camera,
        cfg: &MapConfig,
    ) {
        let keys = self.integrate(kf, pose, depth_scale, camera, cfg, Self::remove);
        for key in keys {
            if let Some(v) = self.voxels.get_mut(&key) {
                v.views = v.views.saturating_sub(1);
            }
        }
    }

    /// Applies `op` to every fused pixel of the keyframe; returns the voxels it touched.
    fn integrate(
        &mut self,
        kf: &KeyFrame,
        pose: &Pose,
        depth_scale: f64,
        camera: &Camera,
        cfg: &MapConfig,
        mut op: impl FnMut(&mut Self, &Point3<f64>, [u8; 3], u8),
    ) -> FxHashSet<[i32; 3]> {
        let mut touched = FxHashSet::default();
        let view = &kf.view;
        let stale = self.rays.as_ref().is_none_or(|r| {
            r.stride != view.stride || (r.width, r.height) != (view.depth.width, view.depth.height)
        });
        if stale {
            self.rays = Some(RayTable::new(camera, view.stride));
        }
        let Some(rays) = self.rays.take() else {
            return touched;
        };
        if (rays.width, rays.height) == (view.depth.width, view.depth.height) {
            for (i, ray) in rays.rays.iter().enumerate() {
                let d = view.depth.data[i] as f64 * depth_scale;
                if !(d >= cfg.min_depth && d <= cfg.max_depth) || d <= 0.0 {
                    continue;
                }
                let p = pose * Point3::new(ray[0] * d, ray[1] * d, d);
                if !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()) {
                    continue;
                }
                let (x, y) = (i as u32 % rays.width, i as u32 / rays.width);
                let c = view.rgb.get_pixel(x, y).0;
                op(self, &p, c, view.labels.data[i]);
                touched.insert(self.key(&p));
            }
        }
        self.rays = Some(rays);
        touched
    }

    /// Map points (voxel means) of the voxels seen by at least `min_views` keyframes
    /// (a multi-view consistency check: predicted depth that disagrees across keyframes
    /// scatters over voxels only one keyframe sees), ordered by voxel index so output is
    /// deterministic. Voxels filled by [`Self::insert`] alone count as seen once.
    pub fn points(&self, rules: &LabelVoteConfig, min_views: u16) -> Vec<MapPoint> {
        let mut keys: Vec<&[i32; 3]> = self
            .voxels
            .iter()
            .filter(|(_, v)| v.views.max(1) >= min_views)
            .map(|(k, _)| k)
            .collect();
        keys.sort_unstable();
        keys.into_iter()
            .map(|k| {
                let v = &self.voxels[k];
                let n = v.count.max(1) as f64;
                MapPoint {
                    position: Point3::new(
                        (v.sum[0] / n) as f32,
                        (v.sum[1] / n) as f32,
                        (v.sum[2] / n) as f32,
                    ),
                    rgb: [0, 1, 2].map(|a| (v.rgb[a] as f64 / n).round().min(255.0) as u8),
                    label: v.label(rules),
                }
            })
            .collect()
    }
}

/// Points per label (index 40 counts void).
pub fn label_histogram(points: &[MapPoint]) -> [usize; classes::NUM_CLASSES + 1] {
    let mut h = [0usize; classes::NUM_CLASSES + 1];
    for p in points {
        h[(p.label as usize).min(classes::NUM_CLASSES)] += 1;
    }
    h
}

const PLY_PROPS: [(&str, &str); 10] = [
    ("float", "x"),
    ("float", "y"),
    ("float", "z"),
    ("uchar", "red"),
    ("uchar", "green"),
    ("uchar", "blue"),
    ("uchar", "sem_red"),
    ("uchar", "sem_green"),
    ("uchar", "sem_blue"),
    ("uchar", "label"),
];

/// Writes map points as PLY, atomically: binary little-endian, or ASCII.
pub fn write_ply(path: impl AsRef<Path>, points: &[MapPoint], ascii: bool) -> Result<()> {
    crate::io::write_atomic_with(path, |w| {
        let format = if ascii {
            "ascii"
        } else {
            "binary_little_endian"
        };
        writeln!(w, "ply\nformat {format} 1.0")?;
        writeln!(
            w,
            "comment sdf-slam semantic map: real colour red/green/blue, NYU40 class colour sem_*, label 0-39 (255 = none)"
        )?;
        writeln!(w, "element vertex {}", points.len())?;
        for (t, n) in PLY_PROPS {
            writeln!(w, "property {t} {n}")?;
        }
        writeln!(w, "end_header")?;
        for p in points {
            let s = classes::colorize(p.label);
            if ascii {
                writeln!(
                    w,
                    "{} {} {} {} {} {} {} {} {} {}",
                    p.position.x,
                    p.position.y,
                    p.position.z,
                    p.rgb[0],
                    p.rgb[1],
                    p.rgb[2],
                    s[0],
                    s[1],
                    s[2],
                    p.label
                )?;
            } else {
                for v in [p.position.x, p.position.y, p.position.z] {
                    w.write_all(&v.to_le_bytes())?;
                }
                w.write_all(&p.rgb)?;
                w.write_all(&s)?;
                w.write_all(&[p.label])?;
            }
        }
        Ok(())
    })
}

/// Reads a PLY vertex list with (at least) `x y z` and optionally `red green
/// blue` and `label` properties, binary little-endian or ASCII.
pub fn read_ply(path: impl AsRef<Path>) -> Result<Vec<MapPoint>> {
    let path = path.as_ref();
    let bad = |m: String| Error::invalid(path, m);
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut r = std::io::BufReader::new(file);
    let mut line = String::new();
    let mut next = |r: &mut std::io::BufReader<std::fs::File>| -> Result<String> {
        line.clear();
        let n = r.read_line(&mut line).map_err(|e| Error::io(path, e))?;
        if n == 0 {
            return Err(Error::invalid(path, "PLY header ends early"));
        }
        Ok(line.trim().to_string())
    };
    if next(&mut r)? != "ply" {
        return Err(bad("not a PLY file".into()));
    }
    let (mut binary, mut count, mut props) = (None, None, Vec::<(String, String)>::new());
    let mut in_vertex = false;
    loop {
        let l = next(&mut r)?;
        let f: Vec<&str> = l.split_whitespace().collect();
        match f.as_slice() {
            ["end_header"] => break,
            ["format", "binary_little_endian", _] => binary = Some(true),
            ["format", "ascii", _] => binary = Some(false),
            ["format", other, _] => return Err(bad(format!("unsupported PLY format {other}"))),
            ["element", "vertex", n] => {
                count = Some(
                    n.parse::<usize>()
                        .map_err(|_| bad(format!("bad vertex count '{n}'")))?,
                );
                in_vertex = true;
            }
            ["element", ..] => in_vertex = false,
            ["property", t, n] if in_vertex => props.push((t.to_string(), n.to_string())),
            _ => {}
        }
    }
    let binary = binary.ok_or_else(|| bad("PLY header has no format line".into()))?;
    let count = count.ok_or_else(|| bad("PLY has no vertex element".into()))?;
    let size = |t: &str| -> Result<usize> {
        match t {
            "char" | "uchar" | "int8" | "uint8" => Ok(1),
            "short" | "ushort" | "int16" | "uint16" => Ok(2),
            "int" | "uint" | "float" | "int32" | "uint32" | "float32" => Ok(4),
            "double" | "float64" => Ok(8),
            _ => Err(Error::invalid(
                path,
                format!("unsupported PLY property type {t}"),
            )),
        }
    };
    let sizes: Vec<usize> = props.iter().map(|p| size(&p.0)).collect::<Result<_>>()?;
    let find = |name: &str| props.iter().position(|p| p.1 == name);
    let (Some(ix), Some(iy), Some(iz)) = (find("x"), find("y"), find("z")) else {
        return Err(bad("PLY vertices have no x y z".into()));
    };
    let colour = [find("red"), find("green"), find("blue")];
    let label = find("label");
    let mut values = vec![0f64; props.len()];
    let mut out = Vec::with_capacity(count.min(1 << 24));
    let mut text = String::new();
    if !binary {
        r.read_to_string(&mut text)
            .map_err(|e| Error::io(path, e))?;
    }
    let mut tokens = text.split_whitespace();
    let record = sizes.iter().sum::<usize>();
    let mut buf = vec![0u8; record];
    for k in 0..count {
        if binary {
            r.read_exact(&mut buf)
                .map_err(|_| bad(format!("PLY body ends at vertex {k} of {count}")))?;
            let mut o = 0;
            for (v, (p, s)) in values.iter_mut().zip(props.iter().zip(&sizes)) {
                let b = &buf[o..o + s];
                *v = match p.0.as_str() {
                    "float" | "float32" => f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
                    "double" | "float64" => {
                        f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]])
                    }
                    "uchar" | "uint8" => b[0] as f64,
                    "char" | "int8" => b[0] as i8 as f64,
                    "short" | "int16" => i16::from_le_bytes([b[0], b[1]]) as f64,
                    "ushort" | "uint16" => u16::from_le_bytes([b[0], b[1]]) as f64,
                    "int" | "int32" => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
                    _ => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
                };
                o += s;
            }
        } else {
            for v in values.iter_mut() {
                let t = tokens
                    .next()
                    .ok_or_else(|| bad(format!("PLY body ends at vertex {k} of {count}")))?;
                *v = t
                    .parse()
                    .map_err(|_| bad(format!("vertex {k}: '{t}' is not a number")))?;
            }
        }
        let byte = |i: Option<usize>| i.map_or(0, |i| values[i].clamp(0.0, 255.0) as u8);
        out.push(MapPoint {
            position: Point3::new(values[ix] as f32, values[iy] as f32, values[iz] as f32),
            rgb: colour.map(byte),
            label: label.map_or(classes::VOID, |i| values[i].clamp(0.0, 255.0) as u8),
        });
    }
    Ok(out)
}

/// The "up" direction of a set of camera poses: the mean of the cameras' `−y`
/// axes (image up), which is vertical for a hand-held or robot camera.
pub fn up_direction(poses: &[Pose]) -> Vector3<f64> {
    let s: Vector3<f64> = poses.iter().map(|p| p.rotation * -Vector3::y()).sum();
    if s.norm() > 1e-9 {
        s.normalize()
    } else {
        Vector3::z()
    }
}

/// Refines an up direction on the map itself: within 20° of `up`, the
/// direction along which point heights are most concentrated (floors, table
/// tops and ceilings are horizontal), so that a camera pitched down on average
/// does not tilt the top-down view.
pub fn level_up_direction(up: Vector3<f64>, points: &[MapPoint]) -> Vector3<f64> {
    let step = (points.len() / 8_000).max(1);
    let sample: Vec<Vector3<f64>> = points
        .iter()
        .step_by(step)
        .map(|p| p.position.coords.cast::<f64>())
        .collect();
    if sample.len() < 100 {
        return up;
    }
    let helper = if up.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let e1 = up.cross(&helper).normalize();
    let e2 = up.cross(&e1);
    let entropy = |u: &Vector3<f64>| -> f64 {
        let mut bins: HashMap<i64, usize> = HashMap::new();
        for p in &sample {
            *bins.entry((p.dot(u) / 0.02).floor() as i64).or_default() += 1;
        }
        let n = sample.len() as f64;
        bins.values()
            .map(|&c| {
                let q = c as f64 / n;
                -q * q.ln()
            })
            .sum()
    };
    // A 2° grid, then 0.5° around its best.
    let mut best = (entropy(&up), 0.0, 0.0);
    for (range, step, centre) in [(10, 2.0, (0.0, 0.0)), (4, 0.5, (0.0, 0.0))] {
        let c = if step < 1.0 { (best.1, best.2) } else { centre };
        for a in -range..=range {
            for b in -range..=range {
                let (da, db) = (c.0 + a as f64 * step, c.1 + b as f64 * step);
                let u = (up + e1 * da.to_radians().tan() + e2 * db.to_radians().tan()).normalize();
                let h = entropy(&u);
                if h < best.0 - 1e-9 {
                    best = (h, da, db);
                }
            }
        }
    }
    (up + e1 * best.1.to_radians().tan() + e2 * best.2.to_radians().tan()).normalize()
}

/// Draws the map from above (along `up`), each pixel the highest point below
/// the ceiling in its class colour (its real colour when unlabelled), with the
/// keyframe path, a 1 m scale bar and a legend of the classes present.
pub fn render_topdown(
    path: impl AsRef<Path>,
    title: &str,
    points: &[MapPoint],
    keyframe_poses: &[Pose],
    voxel_size: f64,
    size: u32,
) -> Result<()> {
    use plotters::prelude::*;
    const CEILING: u8 = 21;
    let up = level_up_direction(up_direction(keyframe_poses), points);
    // Horizontal axes: principal directions of the points in the plane.
    let helper = if up.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let e1 = up.cross(&helper).normalize();
    let e2 = up.cross(&e1);
    let flat: Vec<(f64, f64, f64, usize)> = points
        .iter()
        .enumerate()
        .filter(|(_, p)| p.label != CEILING)
        .map(|(i, p)| {
            let v = p.position.coords.cast::<f64>();
            (v.dot(&e1), v.dot(&e2), v.dot(&up), i)
        })
        .collect();
    let cams: Vec<(f64, f64)> = keyframe_poses
        .iter()
        .map(|p| (p.translation.vector.dot(&e1), p.translation.vector.dot(&e2)))
        .collect();
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for (a, b) in flat.iter().map(|f| (f.0, f.1)).chain(cams.iter().copied()) {
        lo = [lo[0].min(a), lo[1].min(b)];
        hi = [hi[0].max(a), hi[1].max(b)];
    }
    if !lo[0].is_finite() {
        lo = [-1.0, -1.0];
        hi = [1.0, 1.0];
    }
    let margin = 30.0;
    let extent = (hi[0] - lo[0]).max(hi[1] - lo[1]).max(0.1) * 1.02;
    let scale = (size as f64 - 2.0 * margin) / extent;
    let legend_w = 300u32;
    let (w, h) = (size + legend_w, size + 40);
    let centre = [(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0];
    let to_px = |a: f64, b: f64| -> (i32, i32) {
        (
            (size as f64 / 2.0 + (a - centre[0]) * scale) as i32,
            (40.0 + size as f64 / 2.0 - (b - centre[1]) * scale) as i32,
        )
    };
    let mut buf = vec![255u8; (w * h * 3) as usize];
    let mut zbuf = vec![f64::NEG_INFINITY; (w * h) as usize];
    let splat = (voxel_size * scale).ceil().clamp(1.0, 8.0) as i32;
    let labelled = points.iter().any(|p| p.label != classes::VOID);
    for &(a, b, z, i) in &flat {
        let (x, y) = to_px(a, b);
        let p = &points[i];
        let c = if p.label != classes::VOID {
            classes::colorize(p.label)
        } else {
            p.rgb
        };
        for dy in 0..splat {
            for dx in 0..splat {
                let (xx, yy) = (x + dx, y + dy);
                if xx < 0 || yy < 40 || xx >= size as i32 || yy >= h as i32 {
                    continue;
                }
                let k = (yy as u32 * w + xx as u32) as usize;
                if z > zbuf[k] {
                    zbuf[k] = z;
                    buf[3 * k..3 * k + 3].copy_from_slice(&c);
                }
            }
        }
    }
    crate::plot::register_fonts();
    let mut hist = label_histogram(points);
    hist[classes::NUM_CLASSES] = 0;
    let mut present: Vec<(usize, usize)> = hist
        .iter()
        .enumerate()
        .filter(|(_, n)| **n > 0)
        .map(|(l, n)| (l, *n))
        .collect();
    present.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
    let err = |e: String| Error::msg(format!("drawing the top-down map failed: {e}"));
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        let font = ("sans-serif", 16).into_font();
        root.draw_text(
            title,
            &("sans-serif", 22).into_font().color(&BLACK),
            (10, 8),
        )
        .map_err(|e| err(e.to_string()))?;
        let path_px: Vec<(i32, i32)> = cams.iter().map(|&(a, b)| to_px(a, b)).collect();
        root.draw(&PathElement::new(path_px.clone(), BLACK.stroke_width(2)))
            .map_err(|e| err(e.to_string()))?;
        if let Some(&s) = path_px.first() {
            root.draw(&Circle::new(s, 5, BLACK.filled()))
                .map_err(|e| err(e.to_string()))?;
        }
        // 1 m scale bar.
        let bar = scale.round() as i32;
        let (bx, by) = (20, h as i32 - 20);
        if bar > 4 && bar < size as i32 {
            root.draw(&PathElement::new(
                vec![(bx, by), (bx + bar, by)],
                BLACK.stroke_width(3),
            ))
            .map_err(|e| err(e.to_string()))?;
            root.draw_text("1 m", &font.color(&BLACK), (bx, by - 20))
                .map_err(|e| err(e.to_string()))?;
        }
        let x0 = size as i32 + 10;
        let mut y = 50;
        let heading = if labelled {
            "classes (points)"
        } else {
            "RGB colours (no labels)"
        };
        root.draw_text(heading, &font.color(&BLACK), (x0, y))
            .map_err(|e| err(e.to_string()))?;
        y += 26;
        for (l, n) in present {
            if y > h as i32 - 24 {
                break;
            }
            let c = classes::colorize(l as u8);
            root.draw(&Rectangle::new(
                [(x0, y), (x0 + 18, y + 16)],
                RGBColor(c[0], c[1], c[2]).filled(),
            ))
            .map_err(|e| err(e.to_string()))?;
            root.draw_text(
                &format!("{} ({n})", classes::display_name(l as u8)),
                &font.color(&BLACK),
                (x0 + 26, y),
            )
            .map_err(|e| err(e.to_string()))?;
            y += 22;
        }
        root.present().map_err(|e| err(e.to_string()))?;
    }
    let img =
        image::RgbImage::from_raw(w, h, buf).ok_or_else(|| Error::msg("top-down buffer size"))?;
    crate::imageio::write_png_atomic(path, &image::DynamicImage::ImageRgb8(img))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn voxel_label_voting_and_colour_averaging() {
        let mut m = SemanticMap::new(0.1);
        let p = Point3::new(0.01, 0.02, 0.03);
        m.insert(&p, [10, 20, 30], 1);
        m.insert(&Point3::new(0.05, 0.05, 0.05), [30, 40, 50], 1);
        m.insert(&Point3::new(0.09, 0.01, 0.02), [20, 30, 40], 4);
        m.insert(&Point3::new(0.02, 0.02, 0.02), [20, 30, 40], classes::VOID);
        m.insert(&Point3::new(0.02, 0.02, 0.02), [20, 30, 40], classes::VOID);
        m.insert(&Point3::new(0.5, 0.5, 0.5), [0, 0, 0], 7);
        assert_eq!(m.len(), 2);
        let rules = LabelVoteConfig::default();
        let pts = m.points(&rules, 1);
        assert_eq!(pts[0].label, 1, "majority of class votes, void ignored");
        assert_eq!(pts[0].rgb, [20, 30, 40]);
        assert!((pts[0].position.x - 0.038).abs() < 1e-6);
        assert_eq!(pts[1].label, 7);
        // Void votes counted: 2 of 5 for class 1 is below a 50 % share.
        let strict = LabelVoteConfig {
            void_votes: true,
            min_share: 0.5,
            ..rules.clone()
        };
        assert_eq!(m.points(&strict, 1)[0].label, classes::VOID);
        let min2 = LabelVoteConfig {
            min_votes: 2,
            ..rules
        };
        assert_eq!(m.points(&min2, 1)[1].label, classes::VOID);
        // Ties go to the lower class.
        let mut t = SemanticMap::new(1.0);
        t.insert(&p, [0; 3], 5);
        t.insert(&p, [0; 3], 3);
        assert_eq!(t.points(&LabelVoteConfig::default(), 1)[0].label, 3);
        let h = label_histogram(&pts);
        assert_eq!((h[1], h[7], h[40]), (1, 1, 0));
    }

    #[test]
    fn removing_observations_gives_the_map_without_them() {
        let obs: Vec<(Point3<f64>, [u8; 3], u8)> = (0..200)
            .map(|i| {
                let t = i as f64 * 0.013;
                (
                    Point3::new(t.sin(), (2.0 * t).cos(), 0.3 * t),
                    [(i % 256) as u8, (3 * i % 256) as u8, 7],
                    if i % 9 == 0 {
                        classes::VOID
                    } else {
                        (i % 5) as u8
                    },
                )
            })
            .collect();
        let mut all = SemanticMap::new(0.05);
        let mut kept = SemanticMap::new(0.05);
        for (k, (p, c, l)) in obs.iter().enumerate() {
            all.insert(p, *c, *l);
            if k % 3 != 0 {
                kept.insert(p, *c, *l);
            }
        }
        for (p, c, l) in obs.iter().step_by(3) {
            all.remove(p, *c, *l);
        }
        let rules = LabelVoteConfig::default();
        let (a, b) = (all.points(&rules, 1), kept.points(&rules, 1));
        assert_eq!(a.len(), b.len(), "emptied voxels are removed");
        for (x, y) in a.iter().zip(&b) {
            assert_eq!((x.rgb, x.label), (y.rgb, y.label));
            assert!((x.position - y.position).norm() < 1e-5);
        }
        // Taking back an observation that was never made changes nothing.
        all.remove(&Point3::new(50.0, 50.0, 50.0), [1, 2, 3], 4);
        assert_eq!(all.len(), b.len());
    }

    /// A keyframe looking down +z at a wall `depth` metres away.
    fn wall_keyframe(id: usize, depth: f32) -> KeyFrame {
        use crate::dataset::{DepthImage, LabelImage};
        use crate::slam::map::{KeyframeFeatures, KeyframeView};
        let (w, h) = (32, 24);
        let mut d = DepthImage::new(w, h);
        d.data.iter_mut().for_each(|v| *v = depth);
        let view = KeyframeView::new(
            1,
            &image::RgbImage::new(w, h),
            &d,
            &LabelImage::new(w, h, 3),
        );
        KeyFrame {
            id,
            frame_index: id,
            stamp: id as f64,
            odom_pose: Pose::identity(),
            pose: Pose::identity(),
            gt_pose: None,
            track: std::sync::Arc::new(KeyframeFeatures::default()),
            view,
            depth_scale: 1.0,
        }
    }

    #[test]
    fn map_points_need_min_views_keyframes_and_unfuse_takes_a_view_back() {
        let camera = Camera::pinhole(32, 24, 30.0, 30.0, 15.5, 11.5);
        let cfg = MapConfig::default();
        let rules = LabelVoteConfig::default();
        let (near, far) = (wall_keyframe(0, 1.0), wall_keyframe(1, 1.5));
        let mut m = SemanticMap::new(0.02);
        for k in [&near, &near, &far] {
            m.fuse(k, &k.pose, 1.0, &camera, &cfg);
        }
        let all = m.points(&rules, 1).len();
        let agreed = m.points(&rules, 2);
        assert!(!agreed.is_empty() && agreed.len() < all);
        assert!(
            agreed.iter().all(|p| (p.position.z - 1.0).abs() < 0.02),
            "only the wall both views saw"
        );
        assert!(m.points(&rules, 3).is_empty());
        m.unfuse(&near, &near.pose, 1.0, &camera, &cfg);
        assert!(m.points(&rules, 2).is_empty());
        assert_eq!(m.points(&rules, 1).len(), all);
        assert!(m.voxels.values().all(|v| v.views == 1));
    }

    #[test]
    fn ply_round_trip_binary_and_ascii() {
        let dir = std::env::temp_dir().join(format!("sdf_ply_{}", std::process::id()));
        let pts: Vec<MapPoint> = (0..37)
            .map(|i| MapPoint {
                position: Point3::new(i as f32 * 0.5, -1.25, 3.0 + i as f32),
                rgb: [i as u8, 200, 7],
                label: if i % 5 == 0 {
                    classes::VOID
                } else {
                    (i % 40) as u8
                },
            })
            .collect();
        for ascii in [false, true] {
            let p = dir.join(if ascii { "a.ply" } else { "b.ply" });
            write_ply(&p, &pts, ascii).unwrap();
            let bytes = std::fs::read(&p).unwrap();
            let header_end = bytes
                .windows(11)
                .position(|w| w == b"end_header\n")
                .unwrap()
                + 11;
            let header = std::str::from_utf8(&bytes[..header_end]).unwrap();
            assert!(header.contains("element vertex 37"));
            assert!(
                header.contains("property uchar sem_red")
                    && header.contains("property uchar label")
            );
            if !ascii {
                assert!(header.contains("binary_little_endian"));
                assert_eq!(bytes.len() - header_end, 37 * 19);
                // First vertex, by hand: x = 0.0, y = -1.25, z = 3.0, void label black.
                let body = &bytes[header_end..];
                assert_eq!(f32::from_le_bytes(body[4..8].try_into().unwrap()), -1.25);
                assert_eq!(&body[12..19], &[0, 200, 7, 0, 0, 0, 255]);
            }
            assert_eq!(read_ply(&p).unwrap(), pts);
        }
        let p = dir.join("trunc.ply");
        let mut bytes = std::fs::read(dir.join("b.ply")).unwrap();
        bytes.truncate(bytes.len() - 5);
        std::fs::write(&p, bytes).unwrap();
        assert!(read_ply(&p).unwrap_err().to_string().contains("vertex 36"));
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn topdown_png_is_written() {
        let dir = std::env::temp_dir().join(format!("sdf_top_{}", std::process::id()));
        let pts: Vec<MapPoint> = (0..400)
            .map(|i| MapPoint {
                position: Point3::new((i % 20) as f32 * 0.05, 1.0, (i / 20) as f32 * 0.05),
                rgb: [100, 100, 100],
                label: if i < 200 { 1 } else { 0 },
            })
            .collect();
        // Cameras looking along +z with image-down = +y (world up = -y).
        let poses = vec![
            Pose::translation(0.0, 0.0, -1.0),
            Pose::translation(0.5, 0.0, -1.0),
        ];
        assert!((up_direction(&poses) + Vector3::y()).norm() < 1e-12);
        let p = dir.join("top.png");
        render_topdown(&p, "test", &pts, &poses, 0.05, 300).unwrap();
        let img = image::open(&p).unwrap();
        assert_eq!(img.width(), 600);
        std::fs::remove_dir_all(dir).unwrap();
    }
}
