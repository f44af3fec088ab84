//! Scale anchors of a monocular map beyond the network (issue 70).
//!
//! A monocular map's scale comes from SDFCNN's depth, which in a room unlike its training rooms
//! keeps their size. Two measurements check it, and one fixes it:
//!
//! * **The floor and the camera height.** A robot knows how high its camera is. The map's points
//!   labelled `floor` give a plane (the lowest well-filled level along up, then least squares on
//!   its points), the keyframes' camera centres give the camera's height above it in map units,
//!   and a known
//!   height `H` gives the scale `H / height` ([`FloorFit::scale_for`]). The height is reported
//!   even when `H` is not given, so a user can check the map against a tape measure.
//!   Labels on real frames are noisy (table tops and cabinet fronts called floor), so the
//!   floor is the lowest well-supported level of floor points along the up direction the
//!   cameras' horizontal axes give (`fit_floor`).
//! * **Multi-view against single-view depth.** Where the plane sweep
//!   ([`super::multiview_depth`]) measured a keyframe's depth, the median ratio measured /
//!   predicted is that keyframe's scale against the map's geometry. `fuse_ratios` fuses them
//!   over the whole run (median in log space, with its standard error), not per frame. It shows
//!   whether the network's scale is consistent from view to view; a bias every view shares
//!   (a room-size prior) moves the map's geometry with it and only the floor can show that.

use crate::classes::label;
use crate::geometry::Pose;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::semantic_map::MapPoint;

/// The highest camera height `--camera-height` accepts (metres).
pub(crate) const MAX_CAMERA_HEIGHT: f64 = 10.0;

/// Floor points fewer than this: the floor is not seen.
pub(crate) const MIN_FLOOR_POINTS: usize = 200;
/// Share of the floor points within [`INLIER_DISTANCE`] of the floor's level for it to count
/// (monocular depth smears the floor over tens of centimetres).
const MIN_INLIER_SHARE: f64 = 0.1;
/// Distance to the plane within which a floor point is an inlier, as a share of the median
/// distance from the cameras to the floor points' centroid (the map's unit is not known yet).
const INLIER_DISTANCE: f64 = 0.03;
/// Largest angle between the least-squares floor normal and up, degrees.
pub(crate) const MAX_TILT_DEG: f64 = 30.0;

/// Keyframes with a multi-view ratio fewer than this, or a relative standard error above
/// [`MAX_SCALE_ERROR`]: the map-level scale is poorly determined.
pub(crate) const MIN_SCALE_KEYFRAMES: usize = 5;
/// Largest relative standard error of the fused multi-view scale for it to be trusted.
pub(crate) const MAX_SCALE_ERROR: f64 = 0.05;

/// The floor plane of a map and the camera height it implies.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FloorFit {
    /// Unit normal, pointing from the floor towards the cameras.
    pub normal: [f64; 3],
    /// The plane is `normal · x = offset`.
    pub offset: f64,
    /// Points labelled floor.
    pub floor_points: usize,
    /// Of them, those on the floor's level (within the inlier distance of it along up).
    pub inliers: usize,
    /// Median height of the keyframes' camera centres above the plane (map units).
    pub camera_height: f64,
    /// Median absolute deviation of those heights (map units): a hand-held camera moves up and
    /// down, a robot's camera should not.
    pub height_spread: f64,
    /// Keyframes below the floor (a wrong plane when many).
    pub cameras_below: usize,
}

/// Why the floor could not anchor the scale.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub(crate) enum FloorError {
    /// Fewer than [`MIN_FLOOR_POINTS`] map points are labelled floor (the count).
    #[error(
        "the floor is not seen: {0} map points are labelled floor (at least {MIN_FLOOR_POINTS} needed)"
    )]
    TooFewPoints(usize),
    /// No keyframes to measure the camera height from.
    #[error("no keyframes to measure the camera height from")]
    NoCameras,
    /// The floor points lie on no well-supported level below the cameras, or that level tilts
    /// more than [`MAX_TILT_DEG`] from up.
    #[error(
        "the floor points do not lie on one level below the cameras ({inliers} of {points} within reach at most)"
    )]
    NotPlanar {
        /// The most floor points within reach of one level (or of the fitted plane).
        inliers: usize,
        /// Points labelled floor.
        points: usize,
    },
    /// The cameras are not above the floor plane (their median height above it, map units).
    #[error("the cameras are not above the floor plane (median height {0:.3} map units)")]
    CamerasNotAbove(f64),
}

/// Checks a user's camera height (metres): a positive finite number under
/// `MAX_CAMERA_HEIGHT`.
pub fn check_camera_height(h: f64) -> Result<f64, String> {
    if h.is_finite() && h > 0.0 && h < MAX_CAMERA_HEIGHT {
        Ok(h)
    } else {
        Err(format!(
            "camera height {h}: must be a positive number of metres under {MAX_CAMERA_HEIGHT}"
        ))
    }
}

/// Fits the floor of `points` (those labelled floor) and measures the height of the
/// `cameras` (camera-to-world poses, image `x` right and `y` down) above it.
///
/// 1. **Up.** A camera is held or mounted without much roll, so its `x` axis is horizontal:
///    up is the direction the keyframes' `x` axes avoid (the least-variance direction of
///    their sum of outer products), signed towards the images' up. When the `x` axes barely
///    turn, that direction is not determined and the images' mean up direction, made
///    perpendicular to their mean `x`, stands in.
/// 2. **The floor level.** The heights along up of the floor-labelled points below the
///    cameras are counted in bands (a `INLIER_DISTANCE` share of the scene's size either
///    side); the floor is the lowest peak of those counts holding a third as many points as
///    the fullest and a tenth of all floor points (and at least half of [`MIN_FLOOR_POINTS`]):
///    mislabelled table tops and seats lie
///    higher, and a peak (not the lowest point) stays put when monocular depth smears it.
/// 3. **The plane.** Least squares on the level's points gives the normal, which must be
///    within [`MAX_TILT_DEG`] of up; the cameras' median height above the plane is the camera
///    height.
pub(crate) fn fit_floor(points: &[MapPoint], cameras: &[Pose]) -> Result<FloorFit, FloorError> {
    let floor: Vec<Vector3<f64>> = points
        .iter()
        .filter(|p| p.label == label::FLOOR)
        .map(|p| p.position.cast::<f64>().coords)
        .filter(|p| p.iter().all(|v| v.is_finite()))
        .collect();
    if floor.len() < MIN_FLOOR_POINTS {
        return Err(FloorError::TooFewPoints(floor.len()));
    }
    if cameras.is_empty() {
        return Err(FloorError::NoCameras);
    }
    let centres: Vec<Vector3<f64>> = cameras.iter().map(|p| p.translation.vector).collect();
    let up = up_direction(cameras);
    let centre = centres.iter().sum::<Vector3<f64>>() / centres.len() as f64;
    let centroid = floor.iter().sum::<Vector3<f64>>() / floor.len() as f64;
    let reach =
        INLIER_DISTANCE * median(centres.iter().map(|c| (c - centroid).norm()).collect()).max(1e-9);
    // Heights of the floor points below the cameras, lowest first.
    let mut heights: Vec<(f64, usize)> = floor
        .iter()
        .enumerate()
        .map(|(i, p)| (up.dot(&(p - centre)), i))
        .filter(|(h, _)| *h < 0.0)
        .collect();
    heights.sort_by(|a, b| a.0.total_cmp(&b.0));
    let not_planar = |inliers: usize| FloorError::NotPlanar {
        inliers,
        points: floor.len(),
    };
    // A histogram of the heights in bins of half the reach, each bin's count summed over
    // the reach either side; its peaks (fullest within twice the reach) are the levels.
    let (Some(&(low, _)), Some(&(high, _))) = (heights.first(), heights.last()) else {
        return Err(not_planar(0));
    };
    let bin = reach / 2.0;
    let bins = ((high - low) / bin).min((MAX_BINS - 1) as f64) as usize + 1;
    let mut counts = vec![0usize; bins];
    for &(h, _) in &heights {
        counts[(((h - low) / bin) as usize).min(bins - 1)] += 1;
    }
    fn window(c: &[usize], i: usize, r: usize) -> &[usize] {
        &c[i.saturating_sub(r)..(i + r + 1).min(c.len())]
    }
    let smooth: Vec<usize> = (0..bins)
        .map(|i| window(&counts, i, 2).iter().sum())
        .collect();
    let fullest = smooth.iter().copied().max().unwrap_or(0);
    let enough = (MIN_INLIER_SHARE * floor.len() as f64).max(MIN_FLOOR_POINTS as f64 / 2.0);
    // The lowest level holding a third of the fullest's points (and enough of all): higher
    // levels are table tops and seats.
    let Some(peak) = (0..bins).find(|&i| {
        let n = smooth[i];
        3 * n >= fullest && n as f64 >= enough && window(&smooth, i, 4).iter().all(|&m| m <= n)
    }) else {
        return Err(not_planar(fullest));
    };
    let level = low + (peak as f64 + 0.5) * bin;
    let inliers: Vec<Vector3<f64>> = heights
        .iter()
        .filter(|(h, _)| (h - level).abs() <= reach)
        .map(|&(_, i)| floor[i])
        .collect();
    if inliers.len() < 3 {
        return Err(not_planar(inliers.len()));
    }
    let mean = inliers.iter().sum::<Vector3<f64>>() / inliers.len() as f64;
    let cov = inliers.iter().fold(nalgebra::Matrix3::zeros(), |m, p| {
        m + (p - mean) * (p - mean).transpose()
    });
    let eig = cov.symmetric_eigen();
    let mut normal: Vector3<f64> = eig.eigenvectors.column(eig.eigenvalues.imin()).into_owned();
    if normal.dot(&up) < 0.0 {
        normal = -normal;
    }
    // A level of a wall (floor labels on a wall, spread over its height) is thin along the
    // wall's normal, not along up.
    let faces_up = normal.dot(&up) >= MAX_TILT_DEG.to_radians().cos();
    if !faces_up {
        return Err(not_planar(inliers.len()));
    }
    let h: Vec<f64> = centres.iter().map(|c| normal.dot(&(c - mean))).collect();
    let camera_height = median(h.clone());
    // A camera within the floor's level is on the floor, not above it.
    if !(camera_height.is_finite() && camera_height > reach) {
        return Err(FloorError::CamerasNotAbove(camera_height));
    }
    Ok(FloorFit {
        normal: [normal.x, normal.y, normal.z],
        offset: normal.dot(&mean),
        floor_points: floor.len(),
        inliers: inliers.len(),
        camera_height,
        height_spread: median(h.iter().map(|x| (x - camera_height).abs()).collect()),
        cameras_below: h.iter().filter(|x| **x < 0.0).count(),
    })
}

/// The world's up direction from camera poses (see [`fit_floor`], step 1).
pub(crate) fn up_direction(cameras: &[Pose]) -> Vector3<f64> {
    let n = cameras.len().max(1) as f64;
    let image_up = cameras
        .iter()
        .map(|p| -(p.rotation * Vector3::y()))
        .sum::<Vector3<f64>>()
        / n;
    let xs: Vec<Vector3<f64>> = cameras.iter().map(|p| p.rotation * Vector3::x()).collect();
    let spread = xs
        .iter()
        .fold(nalgebra::Matrix3::zeros(), |m, x| m + x * x.transpose())
        / n;
    let eig = spread.symmetric_eigen();
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    // The x axes turned by more than about 10 degrees: the least-variance direction is up.
    let up = if eig.eigenvalues[order[1]] > MIN_YAW_SPREAD {
        eig.eigenvectors.column(order[0]).into_owned()
    } else {
        let mean_x = xs.iter().sum::<Vector3<f64>>() / n;
        let mean_x = mean_x.try_normalize(1e-9).unwrap_or_else(Vector3::x);
        image_up - mean_x * mean_x.dot(&image_up)
    };
    let up = up.try_normalize(1e-9).unwrap_or_else(|| -Vector3::y());
    if up.dot(&image_up) < 0.0 { -up } else { up }
}

/// Most height bins of the floor histogram (a map kilometres tall is not a room).
const MAX_BINS: usize = 100_000;

/// Second eigenvalue of the camera `x` axes' mean outer product above which they turned
/// enough to fix up (about 14 degrees between two groups of cameras, 24 for an even sweep).
const MIN_YAW_SPREAD: f64 = 0.015;

impl FloorFit {
    /// The scale that puts the camera `height` metres above the floor.
    pub fn scale_for(&self, height: f64) -> f64 {
        height / self.camera_height
    }
}

/// The map-level scale of a monocular run: its keyframes' multi-view / predicted depth
/// ratios, fused.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MultiviewScale {
    /// Keyframes with a measured ratio.
    pub keyframes: usize,
    /// The fused ratio (geometric median): 1 when the map's geometry agrees with SDFCNN.
    pub scale: f64,
    /// Its relative standard error (of the median in log space, from the MAD).
    pub relative_error: f64,
    /// 10th percentile of the keyframes' ratios.
    pub p10: f64,
    /// 90th percentile of the keyframes' ratios.
    pub p90: f64,
    /// Too few keyframes or too large an error for the scale to be trusted.
    pub poorly_determined: bool,
}

/// Fuses per-keyframe ratios (non-positive and non-finite ones are ignored); `None` without
/// any. The median's standard error is `1.253 · 1.4826 · MAD / √n` in log space (the MAD as a
/// robust standard deviation, the median's efficiency against the mean).
pub(crate) fn fuse_ratios(ratios: &[f64]) -> Option<MultiviewScale> {
    let mut logs: Vec<f64> = ratios
        .iter()
        .filter(|r| r.is_finite() && **r > 0.0)
        .map(|r| r.ln())
        .collect();
    if logs.is_empty() {
        return None;
    }
    logs.sort_by(f64::total_cmp);
    let n = logs.len();
    let m = median(logs.clone());
    let mad = median(logs.iter().map(|l| (l - m).abs()).collect());
    let relative_error = if n > 1 {
        1.253 * 1.4826 * mad / (n as f64).sqrt()
    } else {
        f64::INFINITY
    };
    let at = |q: f64| logs[((n - 1) as f64 * q).round() as usize].exp();
    Some(MultiviewScale {
        keyframes: n,
        scale: m.exp(),
        relative_error,
        p10: at(0.1),
        p90: at(0.9),
        poorly_determined: n < MIN_SCALE_KEYFRAMES || relative_error > MAX_SCALE_ERROR,
    })
}

/// The median of the finite values (NaN without any).
fn median(mut v: Vec<f64>) -> f64 {
    v.retain(|x| x.is_finite());
    crate::metrics::stats::median(&v)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    fn point(x: f64, y: f64, z: f64, l: u8) -> MapPoint {
        MapPoint {
            position: Point3::new(x as f32, y as f32, z as f32),
            rgb: [0; 3],
            label: l,
        }
    }

    /// A floor 1.5 m below cameras at y = 0 (camera convention: y down), a wall, and a few
    /// floor-labelled outliers, everything scaled by `scale`.
    fn room(scale: f64) -> (Vec<MapPoint>, Vec<Pose>) {
        let mut pts = Vec::new();
        for i in 0..40 {
            for j in 0..20 {
                let (x, z) = (i as f64 * 0.1 - 2.0, j as f64 * 0.1 + 1.0);
                pts.push(point(x * scale, 1.5 * scale, z * scale, label::FLOOR));
                let y = j as f64 * 0.1 - 0.5;
                pts.push(point(x * scale, y * scale, 3.0 * scale, label::WALL));
            }
        }
        for i in 0..50 {
            let x = i as f64 * 0.01 * scale;
            pts.push(point(x, 0.7 * scale, 2.0 * scale, label::FLOOR));
        }
        let cams = (0..10)
            .map(|i| camera_at(i as f64 * 0.05 * scale, 0.0, 0.0))
            .collect();
        (pts, cams)
    }

    /// A camera at `(x, y, z)` looking along `+z`, its image `y` along world `+y` (down: the
    /// floor of [`room`] is at `y = 1.5`).
    fn camera_at(x: f64, y: f64, z: f64) -> Pose {
        Pose::translation(x, y, z)
    }

    #[test]
    fn a_shrunk_room_gives_the_scale_back() {
        for s in [0.5, 1.0, 1.7] {
            let (pts, cams) = room(s);
            let fit = fit_floor(&pts, &cams).unwrap();
            assert!((fit.camera_height - 1.5 * s).abs() < 1e-5 * s, "{fit:?}");
            assert!((fit.scale_for(1.5) - 1.0 / s).abs() < 1e-5 / s);
            assert!(
                fit.normal[1] < -0.999,
                "normal points to the cameras: {fit:?}"
            );
            assert_eq!(fit.floor_points, 850);
            assert_eq!(fit.inliers, 800);
            assert_eq!(fit.cameras_below, 0);
            assert!(fit.height_spread < 1e-5);
        }
    }

    #[test]
    fn a_floor_not_seen_is_an_error() {
        let (pts, cams) = room(1.0);
        let walls: Vec<MapPoint> = pts
            .iter()
            .copied()
            .filter(|p| p.label != label::FLOOR)
            .collect();
        assert_eq!(fit_floor(&walls, &cams), Err(FloorError::TooFewPoints(0)));
        assert_eq!(fit_floor(&pts, &[]), Err(FloorError::NoCameras));
        let e = fit_floor(&walls, &cams).unwrap_err().to_string();
        assert!(e.contains("floor is not seen"), "{e}");
    }

    #[test]
    fn scattered_floor_labels_are_not_a_plane() {
        let pts: Vec<MapPoint> = (0..400)
            .map(|i| {
                let t = i as f64;
                let (x, y, z) = ((t * 0.37).sin(), (t * 0.71).cos(), (t * 0.13).sin());
                point(2.0 * x, 2.0 * y, 2.0 * z, label::FLOOR)
            })
            .collect();
        let cams = [camera_at(0.0, 0.0, 0.0)];
        let got = fit_floor(&pts, &cams);
        assert!(matches!(got, Err(FloorError::NotPlanar { .. })), "{got:?}");
    }

    #[test]
    fn cameras_on_the_floor_have_no_floor_below_them() {
        let (pts, _) = room(1.0);
        let cams = [camera_at(0.0, 1.5, 0.0), camera_at(1.0, 1.5, 0.0)];
        let got = fit_floor(&pts, &cams);
        assert!(got.is_err(), "{got:?}");
    }

    #[test]
    fn the_lowest_level_is_the_floor_and_turning_cameras_give_up() {
        // A table top 0.8 m below the cameras with as many floor labels as the floor itself
        // 1.5 m below; the cameras pitched 40 degrees down and turning 60 degrees: their image
        // up is far from the world's, their x axes are not.
        let (mut pts, _) = room(1.0);
        for i in 0..30 {
            for j in 0..30 {
                let (x, z) = (i as f64 * 0.03 - 0.5, j as f64 * 0.03 + 1.2);
                pts.push(point(x, 0.7, z, label::FLOOR));
            }
        }
        let cams: Vec<Pose> = (0..12)
            .map(|i| {
                let yaw = nalgebra::UnitQuaternion::from_axis_angle(
                    &Vector3::y_axis(),
                    (i as f64 * 5.0 - 30.0).to_radians(),
                );
                let pitch = nalgebra::UnitQuaternion::from_axis_angle(&Vector3::x_axis(), -0.7);
                Pose::from_parts(nalgebra::Translation3::identity(), yaw * pitch)
            })
            .collect();
        let up = up_direction(&cams);
        assert!((up - Vector3::new(0.0, -1.0, 0.0)).norm() < 1e-6, "{up:?}");
        let fit = fit_floor(&pts, &cams).unwrap();
        assert!((fit.camera_height - 1.5).abs() < 1e-3, "{fit:?}");
    }

    #[test]
    fn a_floor_labelled_wall_is_not_the_floor() {
        // Every floor label on the wall: no level below the cameras holds enough of them.
        let (pts, cams) = room(1.0);
        let wall: Vec<MapPoint> = pts
            .iter()
            .filter(|p| p.label == label::WALL)
            .map(|p| MapPoint {
                label: label::FLOOR,
                ..*p
            })
            .collect();
        let got = fit_floor(&wall, &cams);
        assert!(matches!(got, Err(FloorError::NotPlanar { .. })), "{got:?}");
    }

    #[test]
    fn camera_heights_out_of_range_are_refused() {
        for h in [0.0, -1.0, f64::NAN, f64::INFINITY, 10.0, 1e9] {
            assert!(check_camera_height(h).is_err(), "{h}");
        }
        assert_eq!(check_camera_height(1.2), Ok(1.2));
    }

    #[test]
    fn ratios_fuse_to_their_geometric_median_with_an_error() {
        let r: Vec<f64> = (0..40)
            .map(|i| 1.2 * (1.0 + 0.01 * (i % 5) as f64 - 0.02))
            .collect();
        let m = fuse_ratios(&r).unwrap();
        assert!((m.scale - 1.2).abs() < 1e-9, "{m:?}");
        assert_eq!(m.keyframes, 40);
        assert!(m.relative_error > 0.0 && m.relative_error < 0.01, "{m:?}");
        assert!(!m.poorly_determined);
        assert!(m.p10 < m.scale && m.scale < m.p90);
        // Three keyframes, or wildly spread ratios: poorly determined.
        assert!(fuse_ratios(&[1.0, 1.1, 0.9]).unwrap().poorly_determined);
        let wild: Vec<f64> = (0..20)
            .map(|i| if i % 2 == 0 { 0.5 } else { 2.0 })
            .collect();
        assert!(fuse_ratios(&wild).unwrap().poorly_determined);
        assert_eq!(fuse_ratios(&[0.0, -1.0, f64::NAN]), None);
    }
}
