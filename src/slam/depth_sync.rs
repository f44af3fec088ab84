//! Depth re-registered to its colour image's instant.
//!
//! A Kinect's colour and depth streams are not synchronised: TUM RGB-D pairs each colour
//! image with the depth image nearest in time (`associate.py`, up to 20 ms apart). On
//! fr1_rpy the depth comes 3-11 ms after the colour on most frames from frame 24 on, while
//! the camera turns at 1-2.4 rad/s: 0.5-1.3 degrees, 4-12 pixels, between the two. Tracking's
//! pose is the colour image's, and every use of the depth (the dense refinement, the
//! keyframes' 3D points, the map, the keyframe alignments) takes the depth as seen from that
//! pose. [`register`] moves each depth pixel by the camera's motion between the two instants;
//! [`motion_over`] takes that motion from the frame's own velocity (constant velocity).
//! 7-Scenes' frames, registered offline with equal stamps, are left as they are.

use crate::camera::{Camera, RayTable};
use crate::dataset::DepthImage;
use crate::geometry::Pose;
use nalgebra::{Translation3, UnitQuaternion};

/// Offsets shorter than this (seconds) are treated as none.
pub const MIN_OFFSET_S: f64 = 0.5e-3;

/// Depth assumed for a pixel without a reading when looking up where its ray lands: the
/// motion over a few milliseconds is mostly a turn, which moves pixels whatever their depth.
const NOMINAL_DEPTH_M: f64 = 2.0;

/// The camera's motion over `offset_s` seconds after an instant, at the velocity of `step`
/// (`T_prev⁻¹ T_now`, camera frame, taken over `step_s` seconds), to first order: the
/// step's rotation vector and translation scaled by `offset_s / step_s`. That is
/// `T_now⁻¹ T(now + offset)`, the depth camera's pose in the colour camera's frame when the
/// depth comes `offset_s` after the colour. `None` when the offset is shorter than
/// [`MIN_OFFSET_S`], longer than the step, or any input is not finite.
pub fn motion_over(step: &Pose, step_s: f64, offset_s: f64) -> Option<Pose> {
    if !(step_s.is_finite() && step_s > 1e-6 && offset_s.is_finite())
        || offset_s.abs() < MIN_OFFSET_S
        || offset_s.abs() > step_s
    {
        return None;
    }
    let s = offset_s / step_s;
    let rotation = step.rotation.scaled_axis() * s;
    let translation = step.translation.vector * s;
    (rotation
        .iter()
        .chain(translation.iter())
        .all(|v| v.is_finite()))
    .then(|| {
        Pose::from_parts(
            Translation3::from(translation),
            UnitQuaternion::from_scaled_axis(rotation),
        )
    })
}

/// `depth`, seen from the depth camera at `colour_from_depth` (its pose in the colour
/// camera's frame), as the colour camera sees it: each pixel's ray (at its own depth, or a
/// nominal one without a reading) is followed into the depth image, the nearest depth pixel
/// there read (depths are not blended across edges; once more from that depth when it differs
/// by more than 2 %) and its point's depth in the colour camera's frame kept. Pixels whose ray
/// leaves the depth image or lands on no reading are 0. `rays` is `camera`'s full-resolution
/// [`RayTable`]; `None` when it or the image's data do not match the camera's size.
pub fn register(
    depth: &DepthImage,
    camera: &Camera,
    rays: &RayTable,
    colour_from_depth: &Pose,
) -> Option<DepthImage> {
    let (w, h) = (depth.width, depth.height);
    if (camera.width, camera.height) != (w, h)
        || rays.stride != 1
        || (rays.width, rays.height) != (w, h)
        || depth.data.len() != w as usize * h as usize
    {
        return None;
    }
    let depth_from_colour = colour_from_depth.inverse();
    // The depth pixel the ray of colour pixel (x, y) at z-depth `z` lands on, and its reading.
    let lookup = |x: usize, y: usize, z: f64| -> Option<(usize, usize, f32)> {
        let p = camera.project(&(depth_from_colour * rays.point(x, y, z)))?;
        let (sx, sy) = (p.x.round(), p.y.round());
        if !(sx >= 0.0 && sy >= 0.0 && sx < w as f64 && sy < h as f64) {
            return None;
        }
        let (sx, sy) = (sx as usize, sy as usize);
        let d = depth.data[sy * w as usize + sx];
        (d > 0.0 && d.is_finite()).then_some((sx, sy, d))
    };
    let mut out = DepthImage::new(w, h);
    for y in 0..h as usize {
        for x in 0..w as usize {
            let own = depth.data[y * w as usize + x];
            let guess = if own > 0.0 && own.is_finite() {
                own as f64
            } else {
                NOMINAL_DEPTH_M
            };
            let Some(mut hit) = lookup(x, y, guess) else {
                continue;
            };
            if (hit.2 as f64 - guess).abs() > 0.02 * guess {
                match lookup(x, y, hit.2 as f64) {
                    Some(again) => hit = again,
                    None => continue,
                }
            }
            let (sx, sy, d) = hit;
            let z = (colour_from_depth * rays.point(sx, sy, d as f64)).z;
            if z > 0.0 {
                out.data[y * w as usize + x] = z as f32;
            }
        }
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point2, Vector3};

    fn camera() -> Camera {
        Camera::tum_fr1()
    }

    /// A depth image of a slanted plane with a box in front, seen from `pose` (world from
    /// camera): the plane z = 2.5 + 0.5 x and a box face at z = 1.5 over |x|, |y| < 0.3.
    fn scene(cam: &Camera, pose: &Pose) -> DepthImage {
        let mut d = DepthImage::new(cam.width, cam.height);
        for y in 0..cam.height {
            for x in 0..cam.width {
                let n = cam.normalized(&Point2::new(x as f64, y as f64));
                let o = pose.translation.vector;
                let r = pose.rotation * Vector3::new(n.x, n.y, 1.0);
                // Ray o + t r against the box face z = 1.5, then the plane z - 0.5 x = 2.5.
                let mut best = f64::INFINITY;
                let t = (1.5 - o.z) / r.z;
                let p = o + r * t;
                if t > 0.0 && p.x.abs() < 0.3 && p.y.abs() < 0.3 {
                    best = t;
                }
                let t = (2.5 - o.z + 0.5 * o.x) / (r.z - 0.5 * r.x);
                if t > 0.0 && t < best {
                    best = t;
                }
                if best.is_finite() {
                    d.data[(y * cam.width + x) as usize] = best as f32; // r has unit z in camera
                }
            }
        }
        d
    }

    #[test]
    fn registered_depth_is_what_the_colour_camera_sees() {
        let cam = camera();
        let rays = RayTable::new(&cam, 1);
        let colour = Pose::identity();
        // The depth camera about 10 ms later: turned by 0.8 degrees, moved by 4 mm.
        let motion = Pose::from_parts(
            Translation3::new(0.003, -0.002, 0.001),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.004, 0.012, 0.006)),
        );
        let seen_by_depth = scene(&cam, &(colour * motion));
        let truth = scene(&cam, &colour);
        let registered = register(&seen_by_depth, &cam, &rays, &motion).unwrap();
        let (mut close_before, mut close_after, mut n) = (0, 0, 0);
        for i in 0..truth.data.len() {
            let t = truth.data[i];
            if t <= 0.0 {
                continue;
            }
            n += 1;
            close_before += ((seen_by_depth.data[i] - t).abs() < 0.005) as usize;
            close_after += ((registered.data[i] - t).abs() < 0.005) as usize;
        }
        let (before, after) = (
            close_before as f64 / n as f64,
            close_after as f64 / n as f64,
        );
        // Unregistered, the slanted plane and the box's edges are off; registered, all but
        // the strip the motion brings into view and a pixel at the box's edges agree.
        assert!(before < 0.5, "before {before}");
        assert!(after > 0.97, "after {after}");
    }

    #[test]
    fn no_motion_changes_nothing_and_bad_sizes_are_refused() {
        let cam = camera();
        let rays = RayTable::new(&cam, 1);
        let d = scene(&cam, &Pose::identity());
        assert_eq!(register(&d, &cam, &rays, &Pose::identity()).unwrap(), d);
        let small = DepthImage::new(320, 240);
        assert!(register(&small, &cam, &rays, &Pose::identity()).is_none());
        let mut short = d.clone();
        short.data.truncate(10);
        assert!(register(&short, &cam, &rays, &Pose::identity()).is_none());
        assert!(register(&d, &cam, &RayTable::new(&cam, 2), &Pose::identity()).is_none());
    }

    #[test]
    fn motion_over_scales_the_step_and_refuses_what_it_cannot_extrapolate() {
        let step = Pose::from_parts(
            Translation3::new(0.03, 0.0, 0.0),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.06, 0.0)),
        );
        let m = motion_over(&step, 1.0 / 30.0, 0.01).unwrap();
        assert!((m.translation.vector.x - 0.009).abs() < 1e-12);
        assert!((m.rotation.scaled_axis().y - 0.018).abs() < 1e-12);
        let back = motion_over(&step, 1.0 / 30.0, -0.01).unwrap();
        assert!((back * m).rotation.angle() < 1e-12);
        assert!((back.translation.vector + m.translation.vector).norm() < 1e-12);
        assert!(motion_over(&step, 1.0 / 30.0, 0.0001).is_none());
        assert!(motion_over(&step, 1.0 / 30.0, 0.05).is_none());
        assert!(motion_over(&step, 0.0, 0.01).is_none());
        assert!(motion_over(&step, f64::NAN, 0.01).is_none());
        assert!(motion_over(&step, 1.0 / 30.0, f64::INFINITY).is_none());
    }
}
