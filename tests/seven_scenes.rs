//! 7-Scenes sequences in their own layout (`frame-NNNNNN.color.png`, `.depth.png` in
//! millimetres, `.pose.txt` of the depth camera), made here from the 10 real TUM fixture
//! frames, converted by `dataset seven-scenes` and read back as TUM-layout sequences.

mod common;

use common::{fresh_dir, manifest_dir};
use image::{ImageBuffer, Luma};
use nalgebra::{Point2, Point3, Translation3};
use sdf_slam::camera::Camera;
use sdf_slam::dataset::TumSequence;
use sdf_slam::dataset::seven_scenes::{self, ConvertOptions, NO_READING, Registration};
use sdf_slam::geometry::Pose;
use std::path::{Path, PathBuf};
use std::process::Command;

const FIXTURE: &str = "datasets/fixtures/tum_fr1_rpy_head10";

/// Frame numbers given to the fixture's frames (not starting at 0, as a sub-range).
const FIRST_NUMBER: usize = 40;

/// Writes the fixture's frames as a 7-Scenes sequence folder: colour PNG copied, depth in
/// millimetres with no reading as 65535, the ground-truth pose as a 4x4 matrix (standing
/// in for the depth camera's). Returns the folder and the poses written.
fn seven_scenes_folder(dir: &Path) -> (PathBuf, Vec<Pose>) {
    let seq = TumSequence::open(manifest_dir().join(FIXTURE)).unwrap();
    let out = dir.join("seq-01");
    std::fs::create_dir_all(&out).unwrap();
    let mut poses = Vec::new();
    for i in 0..seq.len() {
        let stem = out.join(format!("frame-{:06}", FIRST_NUMBER + i));
        poses.push(common::write_seven_scenes_frame(&seq, i, &stem, NO_READING));
    }
    (out, poses)
}

/// Depth and colour are one pinhole camera, no offset: the conversion must give back the
/// frames as they were (depth to the millimetre, poses, colour bytes, stamps, camera).
#[test]
fn identity_registration_gives_the_frames_back() {
    let dir = fresh_dir("7scenes", "identity");
    let (src, poses) = seven_scenes_folder(&dir);
    let fr1 = Camera::tum_fr1();
    let mut cam = Camera::pinhole(640, 480, fr1.fx, fr1.fy, fr1.cx, fr1.cy);
    cam.name = "pinhole".into();
    let options = ConvertOptions {
        first: FIRST_NUMBER + 2,
        count: Some(6),
        registration: Registration {
            offset: [0.0; 3],
            depth: cam.clone(),
            colour: cam.clone(),
        },
    };
    let out = dir.join("converted");
    let mut calls = 0;
    let summary = seven_scenes::convert(&src, &out, &options, |done, total| {
        calls += 1;
        assert_eq!((done, total), (calls, 6));
    })
    .unwrap();
    assert_eq!((summary.frames, summary.first, summary.last), (6, 42, 47));
    assert_eq!(Camera::from_file(out.join("camera.toml")).unwrap(), cam);

    let fixture = TumSequence::open(manifest_dir().join(FIXTURE)).unwrap();
    let conv = TumSequence::open(&out).unwrap();
    assert_eq!(conv.len(), 6);
    for k in 0..6 {
        let i = k + 2;
        let number = FIRST_NUMBER + i;
        let f = conv.load_frame(k).unwrap();
        assert!((f.stamp - (1000.0 + number as f64 / 30.0)).abs() < 1e-6);
        assert_eq!(
            std::fs::read(&conv.frames[k].rgb_path).unwrap(),
            std::fs::read(&fixture.frames[i].rgb_path).unwrap()
        );
        let want = fixture.load_depth(i).unwrap().unwrap();
        let got = f.depth.unwrap();
        assert_eq!(got.data.len(), want.data.len());
        for (g, w) in got.data.iter().zip(&want.data) {
            assert!((g - w).abs() <= 0.0005 + 1e-6, "{g} vs {w}");
        }
        let gt = f.gt_pose.unwrap();
        assert!((gt.translation.vector - poses[i].translation.vector).norm() < 1e-6);
        assert!(gt.rotation.angle_to(&poses[i].rotation) < 1e-6);
    }
}

/// The default registration: poses move to the colour camera (`-offset` in the depth
/// camera), and every registered depth pixel, taken back into the depth camera, lands on a
/// depth reading at the same depth.
#[test]
fn default_registration_moves_depth_and_poses_to_the_colour_camera() {
    let dir = fresh_dir("7scenes", "default");
    let (src, poses) = seven_scenes_folder(&dir);
    let reg = Registration::default();
    let out = dir.join("converted");
    let options = ConvertOptions::default();
    let summary = seven_scenes::convert(&src, &out, &options, |_, _| {}).unwrap();
    assert_eq!((summary.frames, summary.first, summary.last), (10, 40, 49));
    assert!(
        summary.depth_coverage > 0.5,
        "coverage {}",
        summary.depth_coverage
    );
    let conv = TumSequence::open(&out).unwrap();
    let offset = nalgebra::Vector3::from(reg.offset);
    for (k, pose) in poses.iter().enumerate() {
        let f = conv.load_frame(k).unwrap();
        let gt = f.gt_pose.unwrap();
        let centre = gt * Point3::origin();
        let want = pose * Translation3::from(-offset) * Point3::origin();
        assert!((centre - want).norm() < 1e-6);
        if k % 3 != 0 {
            continue;
        }
        // Back into the depth camera.
        let mm = seven_scenes::read_depth_mm(
            src.join(format!("frame-{:06}.depth.png", FIRST_NUMBER + k)),
            &reg.depth,
        )
        .unwrap();
        let depth = f.depth.unwrap();
        let (mut n, mut agree) = (0, 0);
        for y in (0..480).step_by(5) {
            for x in (0..640).step_by(5) {
                let Some(z) = depth.get(x, y) else { continue };
                let p = reg
                    .colour
                    .back_project(&Point2::new(x as f64, y as f64), z as f64)
                    - offset;
                let q = reg.depth.project(&p).unwrap();
                let (u, v) = (q.x.round() as i64, q.y.round() as i64);
                n += 1;
                // The reading that won this pixel lies within a pixel of there.
                let near = (-1..=1).flat_map(|dv| (-1..=1).map(move |du| (u + du, v + dv)));
                if near
                    .filter(|&(a, b)| (0..640).contains(&a) && (0..480).contains(&b))
                    .map(|(a, b)| mm[(b * 640 + a) as usize])
                    .any(|m| m != NO_READING && (m as f64 / 1000.0 - p.z).abs() < 0.0005)
                {
                    agree += 1;
                }
            }
        }
        assert!(n > 5000, "{n}");
        assert_eq!(agree, n);
    }
}

fn dataset(args: &[&str]) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_dataset"))
        .args(args)
        .env("RUST_BACKTRACE", "0")
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr),
    )
}

#[test]
fn the_command_converts_and_bad_input_is_named() {
    let dir = fresh_dir("7scenes", "cli");
    let (src, _) = seven_scenes_folder(&dir);
    let s = src.to_str().unwrap();
    let out = dir.join("out");
    let o = out.to_str().unwrap();
    let (ok, text) = dataset(&["seven-scenes", s, "--out", o, "--first", "45"]);
    assert!(ok, "{text}");
    assert!(text.contains("5 frames (45..49)"), "{text}");
    assert_eq!(TumSequence::open(&out).unwrap().len(), 5);

    // A second conversion into the same folder is refused and changes nothing.
    let before = std::fs::read(out.join("groundtruth.txt")).unwrap();
    let (ok, text) = dataset(&["seven-scenes", s, "--out", o]);
    assert!(!ok && text.contains("already holds a sequence"), "{text}");
    assert_eq!(std::fs::read(out.join("groundtruth.txt")).unwrap(), before);

    let fresh = |name: &str| dir.join(name).to_str().unwrap().to_string();
    // No frames from --first on.
    let (ok, text) = dataset(&["seven-scenes", s, "--out", &fresh("a"), "--first", "50"]);
    assert!(!ok && text.contains("no frame numbered 50"), "{text}");
    // Not a 7-Scenes folder.
    let (ok, text) = dataset(&["seven-scenes", o, "--out", &fresh("b")]);
    assert!(
        !ok && text.contains("not a 7-Scenes sequence folder"),
        "{text}"
    );
    // An 8-bit depth image is named.
    std::fs::copy(
        src.join("frame-000040.color.png"),
        src.join("frame-000041.depth.png"),
    )
    .unwrap();
    let (ok, text) = dataset(&["seven-scenes", s, "--out", &fresh("d"), "--count", "3"]);
    assert!(
        !ok && text.contains("frame-000041.depth.png") && text.contains("16-bit"),
        "{text}"
    );
    // A registration whose colour camera does not fit the images.
    let reg = dir.join("reg.toml");
    let r = Registration {
        colour: Camera::pinhole(320, 240, 263.5, 263.5, 161.5, 118.0),
        ..Registration::default()
    };
    std::fs::write(&reg, toml::to_string(&r).unwrap()).unwrap();
    let (ok, text) = dataset(&[
        "seven-scenes",
        s,
        "--out",
        &fresh("e"),
        "--registration",
        reg.to_str().unwrap(),
    ]);
    assert!(
        !ok && text.contains("frame-000040.color.png") && text.contains("320x240"),
        "{text}"
    );
    // The other commands point a 7-Scenes folder to the converter.
    let e = TumSequence::open(&src).unwrap_err().to_string();
    assert!(
        e.contains("a 7-Scenes sequence folder") && e.contains("dataset seven-scenes"),
        "{e}"
    );
    // A depth image of another size than the depth camera's.
    let small: ImageBuffer<Luma<u16>, Vec<u16>> = ImageBuffer::new(320, 240);
    small.save(src.join("frame-000040.depth.png")).unwrap();
    let (ok, text) = dataset(&["seven-scenes", s, "--out", &fresh("f")]);
    assert!(
        !ok && text.contains("frame-000040.depth.png") && text.contains("320x240"),
        "{text}"
    );
    let (ok, text) = dataset(&["seven-scenes", s, "--out", &fresh("g"), "--count", "0"]);
    assert!(!ok && text.contains("0 frames"), "{text}");
    // Missing depth and pose files are named.
    std::fs::remove_file(src.join("frame-000043.depth.png")).unwrap();
    let (ok, text) = dataset(&["seven-scenes", s, "--out", &fresh("h")]);
    assert!(!ok && text.contains("frame-000043.depth.png"), "{text}");
    std::fs::copy(
        src.join("frame-000044.depth.png"),
        src.join("frame-000043.depth.png"),
    )
    .unwrap();
    std::fs::remove_file(src.join("frame-000047.pose.txt")).unwrap();
    let (ok, text) = dataset(&["seven-scenes", s, "--out", &fresh("c")]);
    assert!(!ok && text.contains("frame-000047.pose.txt"), "{text}");
}
