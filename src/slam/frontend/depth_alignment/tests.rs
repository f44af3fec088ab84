use super::*;
use crate::slam::config::DenseConfig;
use nalgebra::{Point2, Translation3, UnitQuaternion};

/// Depth of a box room seen from `pose` (world from camera): floor, walls, and a block,
/// so that every direction is constrained.
pub(crate) fn render(camera: &Camera, pose: &Pose) -> DepthImage {
    let (w, h) = (camera.width, camera.height);
    let mut depth = DepthImage::new(w, h);
    // Planes n·x = d in the world frame.
    let planes = [
        (Vector3::new(0.0, 0.0, -1.0), -3.0), // back wall z = 3
        (Vector3::new(0.0, -1.0, 0.0), -1.0), // floor y = 1
        (Vector3::new(1.0, 0.0, 0.0), -1.5),  // left wall x = -1.5
        (Vector3::new(-1.0, 0.0, 0.0), -1.2), // right wall x = 1.2
    ];
    let origin = pose.translation.vector;
    for v in 0..h {
        for u in 0..w {
            let n = camera.normalized(&Point2::new(u as f64, v as f64));
            let ray_cam = Vector3::new(n.x, n.y, 1.0);
            let ray = pose.rotation * ray_cam;
            let mut best = f64::INFINITY;
            for (n, d) in &planes {
                let den = n.dot(&ray);
                if den.abs() > 1e-9 {
                    let t = (d - n.dot(&origin)) / den;
                    if t > 0.0 && t < best {
                        best = t;
                    }
                }
            }
            // A block in front of the back wall: z = 2.2 for |x| < 0.4, y in [0.2, 1].
            let t = (2.2 - origin.z) / ray.z;
            let hit = origin + t * ray;
            if t > 0.0 && t < best && hit.x.abs() < 0.4 && hit.y > 0.2 && hit.y < 1.0 {
                best = t;
            }
            if best.is_finite() {
                // Depth is the z of the hit in the camera frame: t · ray_cam.z = t.
                depth.data[(v * w + u) as usize] = best as f32;
            }
        }
    }
    depth
}

#[test]
fn recovers_a_small_motion_from_a_perturbed_start() {
    let camera = Camera::tum_fr1().resized(160, 120);
    let kf_pose = Pose::identity();
    let frame_pose = Pose::from_parts(
        Translation3::new(0.03, -0.02, 0.05),
        UnitQuaternion::from_euler_angles(0.02, -0.03, 0.01),
    );
    let kf_depth = render(&camera, &kf_pose);
    let frame_depth = render(&camera, &frame_pose);
    let range = (0.1, 6.0);
    // A 160x120 image has 300 points at the coarsest level; a third, finer level (every
    // 2nd pixel) for precision.
    let mut levels = DenseConfig::default().levels;
    levels.push(crate::slam::config::DenseLevel {
        step: 2,
        max_distance: 0.02,
    });
    let cfg = DenseConfig {
        min_pairs: 100,
        levels,
        ..DenseConfig::default()
    };
    let rays = Arc::new(RayTable::new(&camera, 1));
    let model = DepthModel::new(&kf_depth, &camera, rays, 1, range).unwrap();
    let truth = kf_pose.inverse() * frame_pose;
    let start = Pose::from_parts(
        Translation3::new(0.01, -0.01, 0.03),
        UnitQuaternion::from_euler_angles(0.01, -0.015, 0.0),
    );
    let a = align(&model, &frame_depth, &start, range, &cfg).expect("aligned");
    let err = truth.inverse() * a.pose;
    assert!(
        err.translation.vector.norm() < 2e-3 && err.rotation.angle() < 1e-3,
        "error {:?} after {} pairs",
        err,
        a.inliers
    );
    assert!(a.inliers > a.points / 2, "{} of {}", a.inliers, a.points);
}

#[test]
fn a_non_finite_start_is_refused_without_a_panic() {
    let camera = Camera::tum_fr1().resized(160, 120);
    let depth = render(&camera, &Pose::identity());
    let range = (0.1, 6.0);
    let rays = Arc::new(RayTable::new(&camera, 1));
    let model = DepthModel::new(&depth, &camera, rays, 1, range).unwrap();
    let cfg = DenseConfig {
        min_pairs: 100,
        ..DenseConfig::default()
    };
    let nan = Pose::from_parts(
        Translation3::new(f64::NAN, 0.0, 0.0),
        UnitQuaternion::identity(),
    );
    assert!(align(&model, &depth, &nan, range, &cfg).is_none());
}

#[test]
fn noise_weights_follow_the_kinect_model() {
    assert!((noise_weight(1.0) - 1.0).abs() < 1e-12);
    assert!(
        (noise_weight(2.0) - 0.0963).abs() < 1e-3,
        "{}",
        noise_weight(2.0)
    );
    assert!(
        (noise_weight(3.0) - 0.0179).abs() < 1e-3,
        "{}",
        noise_weight(3.0)
    );
    assert!(noise_weight(0.5) > 1.0);
    assert!((axial_noise(3.0) - 0.014044).abs() < 1e-6);
}

#[test]
fn noise_weighting_scales_each_pair_by_its_depth() {
    // A wall facing the camera, the frame nearer by `offset`: every pair has the same
    // residual, so weighting scales the whole system by one factor. 4 mm is within Huber's
    // 1 cm either way: the weight at the wall's depth (1 at 1 m, about a tenth at 2 m). 2 cm
    // is beyond it unweighted (Huber's weight 1/2); whitened at 2 m it is 6 mm, within.
    let camera = Camera::tum_fr1().resized(80, 60);
    let rays = Arc::new(RayTable::new(&camera, 1));
    let wall = |z: f32| {
        let mut d = DepthImage::new(camera.width, camera.height);
        d.data.fill(z);
        d
    };
    let w2 = noise_weight(2.0);
    for (z, offset, factor) in [
        (1.0f32, 0.004, 1.0),
        (2.0, 0.004, w2),
        (1.0, 0.02, 1.0),
        (2.0, 0.02, w2 / 0.5),
    ] {
        let model = DepthModel::new(&wall(z), &camera, rays.clone(), 1, (0.1, 6.0)).unwrap();
        let source: Vec<Vector3<f64>> = (0..60)
            .flat_map(|v| (0..80).map(move |u| (u, v)))
            .map(|(u, v)| rays.point(u, v, f64::from(z) - offset).coords)
            .collect();
        let pose = Pose::identity();
        let weights = |noise_weighting| Weights {
            max_sq: 0.01,
            huber: 0.01,
            noise_weighting,
        };
        let e0 = normal_equations(&model, &source, &pose, &weights(false));
        let e1 = normal_equations(&model, &source, &pose, &weights(true));
        let (h0, g0, n0, h1, g1, n1) = (e0.h, e0.g, e0.pairs, e1.h, e1.g, e1.pairs);
        assert_eq!(n0, n1);
        assert!(n0 > 3000, "{n0} pairs");
        let case = format!("wall at {z} m, {offset} m nearer");
        assert!(
            (h1 - h0 * factor).norm() < 1e-6 * h0.norm(),
            "{case}: {h1} vs {factor} x {h0}"
        );
        assert!((g1 - g0 * factor).norm() < 1e-6 * g0.norm(), "{case}");
    }
}

#[test]
fn aligns_depth_sampled_every_second_pixel() {
    // A keyframe's depth at the fusion resolution: the camera's image every 2nd pixel,
    // with a ray table of the same stride; levels keep counting full-image pixels.
    let camera = Camera::tum_fr1().resized(320, 240);
    let frame_pose = Pose::from_parts(
        Translation3::new(-0.02, 0.01, 0.04),
        UnitQuaternion::from_euler_angles(-0.01, 0.02, 0.015),
    );
    let sub = |d: &DepthImage| {
        crate::slam::map::KeyframeView::new(
            2,
            &image::RgbImage::new(d.width, d.height),
            d,
            &crate::dataset::LabelImage::new(d.width, d.height, 0),
        )
        .depth
    };
    let kf_depth = sub(&render(&camera, &Pose::identity()));
    let frame_depth = sub(&render(&camera, &frame_pose));
    let range = (0.1, 6.0);
    let cfg = DenseConfig {
        min_pairs: 100,
        ..DenseConfig::default()
    };
    let rays = Arc::new(RayTable::new(&camera, 2));
    let model = DepthModel::new(&kf_depth, &camera, rays, 1, range).expect("stride 2");
    let a = align(&model, &frame_depth, &Pose::identity(), range, &cfg).expect("aligned");
    let err = frame_pose.inverse() * a.pose;
    assert!(
        err.translation.vector.norm() < 3e-3 && err.rotation.angle() < 2e-3,
        "error {err:?}"
    );
    // Full-resolution depth against the stride-2 model is not the same sampling.
    let full = render(&camera, &frame_pose);
    assert!(align(&model, &full, &Pose::identity(), range, &cfg).is_none());
}

#[test]
fn a_single_plane_is_refused() {
    let camera = Camera::tum_fr1().resized(160, 120);
    let mut depth = DepthImage::new(camera.width, camera.height);
    depth.data.fill(2.0);
    let range = (0.1, 6.0);
    let model = DepthModel::new(
        &depth,
        &camera,
        Arc::new(RayTable::new(&camera, 1)),
        1,
        range,
    )
    .expect("the camera's size");
    let cfg = DenseConfig {
        min_pairs: 100,
        ..DenseConfig::default()
    };
    // Enough pairs (every frame point lands on the plane), but sliding along the plane
    // and turning about its normal are unconstrained.
    let a = align(&model, &depth, &Pose::identity(), range, &cfg);
    assert!(a.is_none(), "{a:?}");
    // A depth image of another size than the camera's: no model, no alignment.
    let small = DepthImage::new(80, 60);
    let rays = Arc::new(RayTable::new(&camera, 1));
    assert!(DepthModel::new(&small, &camera, rays, 1, range).is_none());
    assert!(align(&model, &small, &Pose::identity(), range, &cfg).is_none());
}

#[test]
fn edge_gates_bound_the_inliers_and_the_change() {
    let cfg = DenseConfig {
        edge_min_inlier_fraction: 0.5,
        edge_agree_translation: 0.1,
        edge_agree_rotation_deg: 6.0,
        ..DenseConfig::default()
    };
    let initial = Pose::from_parts(
        Translation3::new(0.3, 0.0, 0.1),
        UnitQuaternion::from_euler_angles(0.0, 0.2, 0.0),
    );
    let found = |dx: f64, turn_deg: f64, inliers: usize| Alignment {
        pose: initial
            * Pose::from_parts(
                Translation3::new(dx, 0.0, 0.0),
                UnitQuaternion::from_euler_angles(turn_deg.to_radians(), 0.0, 0.0),
            ),
        inliers,
        points: 1000,
        rms: 0.01,
    };
    assert!(found(0.09, 5.0, 500).passes_edge_gates(&initial, &cfg));
    assert!(!found(0.09, 5.0, 499).passes_edge_gates(&initial, &cfg));
    assert!(!found(0.11, 0.0, 1000).passes_edge_gates(&initial, &cfg));
    assert!(!found(0.0, 6.5, 1000).passes_edge_gates(&initial, &cfg));
    assert!(!found(f64::NAN, 0.0, 1000).passes_edge_gates(&initial, &cfg));
}
