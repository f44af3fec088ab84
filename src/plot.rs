//! Plots as PNG (plotters with a bundled DejaVu Sans font, so they render the
//! same on any machine): trajectories seen from above, like the paper's Fig. 9,
//! and line charts (errors over time, loss curves).

use crate::error::{Error, Result};
use nalgebra::Point3;
use plotters::prelude::*;
use std::path::Path;
use std::sync::Once;

static FONT: &[u8] = include_bytes!("../assets/fonts/DejaVuSans.ttf");

/// Registers the bundled font under the generic family names (idempotent).
pub(crate) fn register_fonts() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        for name in ["sans-serif", "serif", "monospace"] {
            // The bundled font is valid, so registration cannot fail.
            let _ = plotters::style::register_font(name, FontStyle::Normal, FONT);
            let _ = plotters::style::register_font(name, FontStyle::Bold, FONT);
        }
    });
}

/// Colours of successive series (reference first).
pub(crate) const PALETTE: [RGBColor; 6] = [
    RGBColor(40, 40, 40),
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
];

/// A named polyline.
pub struct Series<'a> {
    /// Legend entry.
    pub name: &'a str,
    /// `(x, y)` vertices in drawing order.
    pub points: Vec<(f64, f64)>,
}

/// Colour of the `k`-th series: the palette after the reference colour, then hues spaced by
/// the golden angle (so many series stay distinguishable).
fn series_color(k: usize) -> RGBColor {
    if k < PALETTE.len() {
        return PALETTE[(k + 1) % PALETTE.len()];
    }
    let hue = ((k - PALETTE.len()) as f64 * 0.618_033_988_75 + 0.1).fract();
    let (r, g, b) = HSLColor(hue, 0.7, 0.42).rgb();
    RGBColor(r, g, b)
}

/// One chart of a [`line_charts`] figure.
pub struct Chart<'a> {
    /// Title above the chart.
    pub title: &'a str,
    /// Label of the x axis.
    pub x_label: &'a str,
    /// Label of the y axis.
    pub y_label: &'a str,
    /// The lines drawn, in legend order.
    pub series: Vec<Series<'a>>,
    /// Logarithmic y axis.
    pub log_y: bool,
    /// Draw a dot at every point (for curves with few points).
    pub markers: bool,
}

fn plot_err(e: impl std::fmt::Display) -> Error {
    Error::msg(format!("plotting failed: {e}"))
}

/// Renders into an RGB buffer, then writes the PNG atomically.
fn render(
    path: &Path,
    (w, h): (u32, u32),
    draw: impl FnOnce(DrawingArea<BitMapBackend<'_>, plotters::coord::Shift>) -> Result<()>,
) -> Result<()> {
    register_fonts();
    let mut buf = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        draw(root.clone())?;
        root.present().map_err(plot_err)?;
    }
    let img = image::RgbImage::from_raw(w, h, buf).ok_or_else(|| Error::msg("plot buffer size"))?;
    crate::imageio::write_png_atomic(path, &image::DynamicImage::ImageRgb8(img))
}

fn padded_range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    let pad = ((hi - lo) * 0.05).max(1e-3);
    (lo - pad, hi + pad)
}

/// A line chart of several series.
pub(crate) fn line_chart(
    path: impl AsRef<Path>,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series<'_>],
    log_y: bool,
) -> Result<()> {
    render(path.as_ref(), (1000, 640), |root| {
        draw_lines(&root, title, x_label, y_label, series, log_y, false)
    })
}

/// Several line charts in one PNG, `columns` a row.
pub fn line_charts(path: impl AsRef<Path>, charts: &[Chart<'_>], columns: usize) -> Result<()> {
    if charts.is_empty() {
        return Err(Error::msg("a figure needs at least one chart"));
    }
    let columns = columns.clamp(1, charts.len());
    let rows = charts.len().div_ceil(columns);
    let size = (columns as u32 * 900, rows as u32 * 640);
    render(path.as_ref(), size, |root| {
        for (area, c) in root.split_evenly((rows, columns)).iter().zip(charts) {
            draw_lines(
                area, c.title, c.x_label, c.y_label, &c.series, c.log_y, c.markers,
            )?;
        }
        Ok(())
    })
}

fn draw_lines<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series<'_>],
    log_y: bool,
    markers: bool,
) -> Result<()> {
    let (x0, x1) = padded_range(series.iter().flat_map(|s| s.points.iter().map(|p| p.0)));
    let ys = || series.iter().flat_map(|s| s.points.iter().map(|p| p.1));
    let mut builder = ChartBuilder::on(area);
    builder
        .caption(title, ("sans-serif", 24))
        .margin(12)
        .x_label_area_size(44)
        .y_label_area_size(70);
    macro_rules! finish {
        ($chart:expr) => {{
            let mut chart = $chart;
            chart
                .configure_mesh()
                .x_desc(x_label)
                .y_desc(y_label)
                .label_style(("sans-serif", 15))
                .light_line_style(RGBColor(235, 235, 235))
                .draw()
                .map_err(plot_err)?;
            for (k, s) in series.iter().enumerate() {
                let c = series_color(k);
                chart
                    .draw_series(LineSeries::new(s.points.iter().copied(), c.stroke_width(2)))
                    .map_err(plot_err)?
                    .label(s.name)
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(3))
                    });
                if markers {
                    chart
                        .draw_series(s.points.iter().map(|&p| Circle::new(p, 4, c.filled())))
                        .map_err(plot_err)?;
                }
            }
            if series.len() > 1 {
                chart
                    .configure_series_labels()
                    .background_style(WHITE.mix(0.85))
                    .border_style(BLACK)
                    .label_font(("sans-serif", 15))
                    .draw()
                    .map_err(plot_err)?;
            }
        }};
    }
    if log_y {
        let (lo, hi) = ys()
            .filter(|v| *v > 0.0)
            .fold((f64::INFINITY, 0.0f64), |(a, b), v| (a.min(v), b.max(v)));
        let (lo, hi) = if lo.is_finite() {
            (lo * 0.8, hi * 1.25)
        } else {
            (1e-3, 1.0)
        };
        finish!(
            builder
                .build_cartesian_2d(x0..x1, (lo..hi).log_scale())
                .map_err(plot_err)?
        );
    } else {
        let (y0, y1) = padded_range(ys());
        finish!(
            builder
                .build_cartesian_2d(x0..x1, y0..y1)
                .map_err(plot_err)?
        );
    }
    Ok(())
}

/// The two world axes along which a set of trajectories spreads most (a
/// "top view" whatever the world frame's up axis is).
pub(crate) fn dominant_plane(trajectories: &[&[Point3<f64>]]) -> (usize, usize) {
    let mut var = [0.0f64; 3];
    for pts in trajectories {
        if pts.is_empty() {
            continue;
        }
        let n = pts.len() as f64;
        for (a, v) in var.iter_mut().enumerate() {
            let mean = pts.iter().map(|p| p[a]).sum::<f64>() / n;
            *v += pts.iter().map(|p| (p[a] - mean).powi(2)).sum::<f64>() / n;
        }
    }
    let drop = (0..3)
        .min_by(|&a, &b| var[a].total_cmp(&var[b]))
        .unwrap_or(2);
    let mut keep = (0..3).filter(|&a| a != drop);
    (keep.next().unwrap_or(0), keep.next().unwrap_or(1))
}

/// Figure of trajectories seen from above (left, equal axes; start marked) and,
/// when `errors` is given, the per-pose error over time (right).
pub fn trajectory_figure(
    path: impl AsRef<Path>,
    title: &str,
    trajectories: &[(&str, &[Point3<f64>])],
    errors: Option<(&str, &[f64], &[f64])>,
) -> Result<()> {
    let width = if errors.is_some() { 1500 } else { 900 };
    render(path.as_ref(), (width, 800), |root| {
        let root = root.titled(title, ("sans-serif", 26)).map_err(plot_err)?;
        let (left, right) = if errors.is_some() {
            let (l, r) = root.split_horizontally(800);
            (l, Some(r))
        } else {
            (root, None)
        };
        let pts: Vec<&[Point3<f64>]> = trajectories.iter().map(|t| t.1).collect();
        let (a, b) = dominant_plane(&pts);
        let (mut x0, mut x1) = padded_range(pts.iter().flat_map(|p| p.iter().map(|q| q[a])));
        let (mut y0, mut y1) = padded_range(pts.iter().flat_map(|p| p.iter().map(|q| q[b])));
        // Equal metric scale on both axes.
        let half = 0.5 * (x1 - x0).max(y1 - y0);
        let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
        (x0, x1, y0, y1) = (cx - half, cx + half, cy - half, cy + half);
        let axis = ["x", "y", "z"];
        let mut chart = ChartBuilder::on(&left)
            .margin(16)
            .x_label_area_size(44)
            .y_label_area_size(64)
            .build_cartesian_2d(x0..x1, y0..y1)
            .map_err(plot_err)?;
        chart
            .configure_mesh()
            .x_desc(format!("{} (m)", axis[a]))
            .y_desc(format!("{} (m)", axis[b]))
            .label_style(("sans-serif", 15))
            .light_line_style(RGBColor(235, 235, 235))
            .draw()
            .map_err(plot_err)?;
        for (k, (name, p)) in trajectories.iter().enumerate() {
            let c = PALETTE[k % PALETTE.len()];
            let style = if k == 0 {
                c.stroke_width(3)
            } else {
                c.stroke_width(2)
            };
            chart
                .draw_series(LineSeries::new(p.iter().map(|q| (q[a], q[b])), style))
                .map_err(plot_err)?
                .label(*name)
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(3))
                });
            if let Some(s) = p.first() {
                chart
                    .draw_series(std::iter::once(Circle::new((s[a], s[b]), 6, c.filled())))
                    .map_err(plot_err)?;
            }
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 16))
            .draw()
            .map_err(plot_err)?;
        if let (Some(right), Some((label, t, e))) = (right, errors) {
            let series = [Series {
                name: label,
                points: t.iter().copied().zip(e.iter().copied()).collect(),
            }];
            draw_lines(
                &right,
                &format!("{label} over time"),
                "time (s)",
                label,
                &series,
                false,
                false,
            )?;
        }
        Ok(())
    })
}

/// One image of a [`panels_figure`] with its title.
pub(crate) struct Panel<'a> {
    /// Caption drawn above the image.
    pub title: &'a str,
    /// The image shown.
    pub image: &'a image::RgbImage,
}

/// Images side by side (`columns` a row, each under its title) above a colour legend
/// (`(name, rgb)` swatches), like the paper's Fig. 11. Panels of different sizes are placed in
/// cells of the largest size.
pub(crate) fn panels_figure(
    path: impl AsRef<Path>,
    panels: &[Panel<'_>],
    columns: usize,
    legend: &[(String, [u8; 3])],
) -> Result<()> {
    if panels.is_empty() {
        return Err(Error::msg("a figure needs at least one image"));
    }
    let columns = columns.clamp(1, panels.len());
    let rows = panels.len().div_ceil(columns);
    let cw = panels.iter().map(|p| p.image.width()).max().unwrap_or(1);
    let ch = panels.iter().map(|p| p.image.height()).max().unwrap_or(1);
    let (pad, title_h) = (8u32, 26u32);
    let width = columns as u32 * (cw + pad) + pad;
    let legend_cols = (width / 180).max(1) as usize;
    let legend_rows = legend.len().div_ceil(legend_cols) as u32;
    let legend_h = if legend.is_empty() {
        0
    } else {
        legend_rows * 22 + pad
    };
    let height = rows as u32 * (ch + title_h + pad) + pad + legend_h;
    let mut canvas = image::RgbImage::from_pixel(width, height, image::Rgb([255, 255, 255]));
    let origin = |k: usize| {
        let (r, c) = ((k / columns) as u32, (k % columns) as u32);
        (pad + c * (cw + pad), pad + r * (ch + title_h + pad))
    };
    for (k, p) in panels.iter().enumerate() {
        let (x, y) = origin(k);
        image::imageops::replace(&mut canvas, p.image, x as i64, (y + title_h) as i64);
    }
    register_fonts();
    {
        let root = BitMapBackend::with_buffer(canvas.as_mut(), (width, height)).into_drawing_area();
        let font = ("sans-serif", 18).into_font().color(&BLACK);
        for (k, p) in panels.iter().enumerate() {
            let (x, y) = origin(k);
            root.draw_text(p.title, &font, (x as i32, y as i32 + 3))
                .map_err(plot_err)?;
        }
        let small = ("sans-serif", 15).into_font().color(&BLACK);
        let top = (height - legend_h) as i32;
        let cell = (width - pad) / legend_cols as u32;
        for (k, (name, [r, g, b])) in legend.iter().enumerate() {
            let x = (pad + (k % legend_cols) as u32 * cell) as i32;
            let y = top + (k / legend_cols) as i32 * 22;
            root.draw(&Rectangle::new(
                [(x, y + 2), (x + 16, y + 18)],
                RGBColor(*r, *g, *b).filled(),
            ))
            .map_err(plot_err)?;
            root.draw(&Rectangle::new([(x, y + 2), (x + 16, y + 18)], BLACK))
                .map_err(plot_err)?;
            root.draw_text(name, &small, (x + 22, y + 3))
                .map_err(plot_err)?;
        }
        root.present().map_err(plot_err)?;
    }
    crate::imageio::write_png_atomic(path, &image::DynamicImage::ImageRgb8(canvas))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dominant_plane_drops_flat_axis() {
        let pts: Vec<Point3<f64>> = (0..10)
            .map(|i| Point3::new(i as f64, 1.0, 0.5 * i as f64))
            .collect();
        assert_eq!(dominant_plane(&[&pts]), (0, 2));
    }

    #[test]
    fn figures_are_written() {
        let dir = std::env::temp_dir().join(format!("sdf_plot_{}", std::process::id()));
        let pts: Vec<Point3<f64>> = (0..50)
            .map(|i| Point3::new((i as f64 * 0.1).cos(), (i as f64 * 0.1).sin(), 0.0))
            .collect();
        let t: Vec<f64> = (0..50).map(|i| i as f64).collect();
        let e: Vec<f64> = (0..50).map(|i| i as f64 * 0.01).collect();
        let p = dir.join("traj.png");
        trajectory_figure(
            &p,
            "test",
            &[("gt", &pts), ("est", &pts)],
            Some(("ATE (m)", &t, &e)),
        )
        .unwrap();
        let img = image::open(&p).unwrap();
        assert_eq!(img.width(), 1500);
        let p2 = dir.join("lines.png");
        line_chart(
            &p2,
            "loss",
            "epoch",
            "loss",
            &[Series {
                name: "a",
                points: vec![(0.0, 1.0), (1.0, 0.5)],
            }],
            true,
        )
        .unwrap();
        assert!(p2.exists());
        std::fs::remove_dir_all(dir).unwrap();
    }
}
