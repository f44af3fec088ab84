//! The semantic map drawn from above with the keyframe path, a scale bar and a class
//! legend (`topdown.png` of a run).

use crate::classes;
use crate::error::{Error, Result};
use crate::geometry::Pose;
use crate::slam::mapping::semantic_map::{MapPoint, label_histogram};
use nalgebra::Vector3;
use std::collections::HashMap;
use std::path::Path;

/// The "up" direction of a set of camera poses: the mean of the cameras' `−y`
/// axes (image up), which is vertical for a hand-held or robot camera.
pub(crate) fn up_direction(poses: &[Pose]) -> Vector3<f64> {
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
pub(crate) fn level_up_direction(up: Vector3<f64>, points: &[MapPoint]) -> Vector3<f64> {
    let step = (points.len() / 8_000).max(1);
    let sample: Vec<Vector3<f64>> = points
        .iter()
        .step_by(step)
        .map(|p| p.position.coords.cast::<f64>())
        .collect();
    if sample.len() < 100 {
        return up;
    }
    let (e1, e2) = crate::geometry::orthonormal_basis(&up);
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
pub(crate) fn render_topdown(
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
    let (e1, e2) = crate::geometry::orthonormal_basis(&up);
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
        draw_legend(&root, size as i32 + 10, h, points)?;
        root.present().map_err(|e| err(e.to_string()))?;
    }
    let img =
        image::RgbImage::from_raw(w, h, buf).ok_or_else(|| Error::msg("top-down buffer size"))?;
    crate::imageio::write_png_atomic(path, &image::DynamicImage::ImageRgb8(img))
}

/// The legend right of the map: the classes present, most points first (or a note that
/// the colours are the points' own).
fn draw_legend(
    root: &plotters::drawing::DrawingArea<
        plotters::prelude::BitMapBackend<'_>,
        plotters::coord::Shift,
    >,
    x0: i32,
    h: u32,
    points: &[MapPoint],
) -> Result<()> {
    use plotters::prelude::*;
    let err = |e: String| Error::msg(format!("drawing the top-down map failed: {e}"));
    let font = ("sans-serif", 16).into_font();
    let labelled = points.iter().any(|p| p.label != classes::VOID);
    let mut hist = label_histogram(points);
    hist[classes::NUM_CLASSES] = 0;
    let mut present: Vec<(usize, usize)> = hist
        .iter()
        .enumerate()
        .filter(|(_, n)| **n > 0)
        .map(|(l, n)| (l, *n))
        .collect();
    present.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
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
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

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
