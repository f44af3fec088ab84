//! The SLAM system wired to SDFCNN (labels for the map, metric depth in
//! monocular mode), checkpoints that do not fit, and the default sequence the
//! `slam` binary generates on first use. Tiny sizes: a 160x120 synthetic
//! sequence and an SDFCNN with a small inner size and decoder.

mod common;

use burn::module::{ModuleMapper, Param};
use burn::prelude::*;
use sdf_slam::bundled::{default_sequence_config, generate_sequence};
use sdf_slam::camera::Camera;
use sdf_slam::dataset::{DepthImage, LabelImage, TumSequence};
use sdf_slam::nn::BackendKind;
use sdf_slam::sdfcnn::{Sdfcnn, SdfcnnPredictor};
use sdf_slam::slam::frontend::tracking::FrameStatus;
use sdf_slam::slam::map::{KeypointDepth, points_from_depth};
use sdf_slam::slam::output::write_outputs;
use sdf_slam::slam::system::Control;
use sdf_slam::slam::{
    DepthMode, OrbSource, SdfcnnSource, SemanticInput, SemanticSource, Slam, SlamConfig, SlamOutput,
};
use sdf_slam::trajectory::Trajectory;
use std::path::PathBuf;
use std::sync::{Arc, Mutex, OnceLock};

const FRAMES: usize = 16;
/// The depth the test network predicts everywhere, metres.
const PLANE: f32 = 2.0;

fn tmp_dir(name: &str) -> common::ScratchDir {
    common::fresh_dir("slamnet", name)
}

/// The default sequence's configuration at a tiny size, generated once per
/// test binary with the function `slam` calls when the default is absent.
fn sequence() -> PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dest = common::shared_dir("slamnet_seq").join("default_sequence");
        let mut cfg = default_sequence_config();
        cfg.frames = FRAMES;
        cfg.resolution = "160x120".into();
        generate_sequence(&cfg, &dest, &|_| {}).unwrap();
        dest
    })
    .clone()
}

/// Sets the depth head to a constant: bias `PLANE`, weights 0 (depth1 is the
/// only convolution with one output channel and its bias the only 1-element
/// parameter).
struct ConstantDepth {
    bias: usize,
    weight: usize,
}

impl ModuleMapper for ConstantDepth {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let dims = param.val().dims();
        if D == 1 && dims[0] == 1 {
            self.bias += 1;
            param.map(|t| t.zeros_like().add_scalar(PLANE))
        } else if D == 4 && dims[0] == 1 {
            self.weight += 1;
            param.map(|t| t.zeros_like())
        } else {
            param
        }
    }
}

/// A randomly initialised tiny SDFCNN predicting depth `PLANE`, saved in half
/// precision like the bundled weights (`model.bpk` + `config.toml`).
fn checkpoint() -> PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = common::shared_dir("slamnet_ckpt");
        let device = BackendKind::Ndarray.device().expect("ndarray");
        let model: Sdfcnn =
            sdf_slam::nn::seeded_init(common::tiny_sdfcnn_config().init(&device).unwrap(), 7);
        let mut m = ConstantDepth { bias: 0, weight: 0 };
        let model = model.map(&mut m);
        assert_eq!((m.bias, m.weight), (1, 1), "the depth head was not found");
        common::write_tiny_sdfcnn(&dir, model);
        dir
    })
    .clone()
}

/// Records the frames a source was asked about.
struct Counting<S> {
    inner: S,
    calls: Arc<Mutex<Vec<usize>>>,
}

impl<S: SemanticSource> SemanticSource for Counting<S> {
    fn name(&self) -> &'static str {
        self.inner.name()
    }
    fn provides_depth(&self) -> bool {
        self.inner.provides_depth()
    }
    fn predict(
        &self,
        input: &SemanticInput<'_>,
    ) -> sdf_slam::Result<(LabelImage, Option<DepthImage>)> {
        self.calls.lock().unwrap().push(input.index);
        self.inner.predict(input)
    }
}

fn run(depth: DepthMode, threads: bool) -> (SlamOutput, Vec<usize>) {
    let seq = sequence();
    let mut cfg = SlamConfig::default();
    cfg.system.threads = threads;
    let calls = Arc::new(Mutex::new(Vec::new()));
    let semantics = Counting {
        inner: SdfcnnSource::load(&checkpoint(), BackendKind::Ndarray).unwrap(),
        calls: calls.clone(),
    };
    let slam = Slam {
        sequence: TumSequence::open(&seq).unwrap(),
        camera: Camera::from_file(seq.join("camera.toml")).unwrap(),
        keypoints: Box::new(OrbSource::from_config(&cfg.features)),
        config: cfg,
        depth,
        semantics: Box::new(semantics),
        max_frames: None,
    };
    let out = slam
        .run(Control {
            log: Arc::new(|_: &str| {}),
            ..Control::default()
        })
        .unwrap();
    let calls = calls.lock().unwrap().clone();
    (out, calls)
}

fn predictor() -> SdfcnnPredictor {
    SdfcnnPredictor::load(&checkpoint(), BackendKind::Ndarray).unwrap()
}

#[test]
fn default_sequence_generation_writes_a_readable_tum_sequence() {
    let seq = sequence();
    let s = TumSequence::open(&seq).unwrap();
    assert_eq!(s.len(), FRAMES);
    assert!(s.has_depth());
    assert_eq!(s.groundtruth.as_ref().unwrap().len(), FRAMES);
    let f = s.load_frame(FRAMES - 1).unwrap();
    assert_eq!(f.rgb.dimensions(), (160, 120));
    assert!(f.depth.is_some() && f.gt_pose.is_some());
    for list in ["labels.txt", "depth_gt.txt", "camera.toml", "scene.json"] {
        assert!(seq.join(list).is_file(), "{list}");
    }
    assert_eq!(
        Camera::from_file(seq.join("camera.toml")).unwrap().width,
        160
    );
    // Nothing but the sequence is left beside it (the staging folder is gone).
    let parent: Vec<_> = std::fs::read_dir(seq.parent().unwrap())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(parent, vec![std::ffi::OsString::from("default_sequence")]);
    // An existing sequence is never overwritten.
    let cfg = default_sequence_config();
    let e = generate_sequence(&cfg, &seq, &|_| {})
        .unwrap_err()
        .to_string();
    assert!(e.contains("already exists"), "{e}");
    assert_eq!(TumSequence::open(&seq).unwrap().len(), FRAMES);
}

#[test]
fn rgbd_map_takes_its_labels_from_sdfcnn_once_per_keyframe() {
    let (out, calls) = run(DepthMode::Sensor, false);
    assert_eq!(out.frames.len(), FRAMES);
    assert_eq!(out.semantic_source, "sdfcnn");
    assert!(
        out.semantic_failures.is_empty(),
        "{:?}",
        out.semantic_failures
    );
    // SDFCNN ran on each keyframe's frame exactly once, and on no other frame.
    let kf_frames: Vec<usize> = out.map.keyframes.iter().map(|k| k.frame_index).collect();
    assert!(!kf_frames.is_empty());
    assert_eq!(calls, kf_frames);
    // The first keyframe's labels are the network's (sensor depth in RGB-D mode).
    let seq = TumSequence::open(sequence()).unwrap();
    let kf = &out.map.keyframes[0];
    let rgb = seq.load_rgb(kf.frame_index).unwrap();
    let p = predictor().predict(&rgb).unwrap();
    let v = &kf.view;
    for y in 0..v.labels.height {
        for x in 0..v.labels.width {
            assert_eq!(v.labels.get(x, y), p.labels.get(x * v.stride, y * v.stride));
        }
    }
    // The view's depth is the sensor's, less the depth edges the map does not fuse.
    let sensor = seq.load_frame(kf.frame_index).unwrap().depth.unwrap();
    let mut same = 0;
    for y in 0..v.depth.height {
        for x in 0..v.depth.width {
            let (d, s) = (
                v.depth.data[(y * v.depth.width + x) as usize],
                sensor.data[(y * v.stride * sensor.width + x * v.stride) as usize],
            );
            assert!(d == s || d == 0.0, "({x}, {y}): {d} vs sensor {s}");
            same += usize::from(d == s);
        }
    }
    assert!(
        same * 10 > v.depth.data.len(),
        "{same} of {}",
        v.depth.data.len()
    );
    // Every fused point carries a network label (never void: every pixel has one).
    let points = out.semantic_map.points(&SlamConfig::default().labels, 1);
    assert!(points.len() > 100, "{}", points.len());
    assert!(points.iter().all(|q| q.label < 40));
    let dir = tmp_dir("rgbd_out");
    let report = write_outputs(
        &out,
        &seq,
        &Camera::from_file(sequence().join("camera.toml")).unwrap(),
        &SlamConfig::default(),
        &dir,
    )
    .unwrap();
    assert_eq!(report.labels, "sdfcnn");
    assert!(!report.label_histogram.is_empty());
    assert!(report.map_accuracy.is_some());
}

#[test]
fn monocular_mode_tracks_with_sdfcnn_depth() {
    let (out, calls) = run(DepthMode::Predicted, false);
    assert_eq!(out.frames.len(), FRAMES);
    let kf_frames: Vec<usize> = out.map.keyframes.iter().map(|k| k.frame_index).collect();
    assert_eq!(calls, kf_frames, "SDFCNN runs once per keyframe");
    // The keyframes' 3D keypoints (the PnP references, eqs 9-10) are SDFCNN's
    // depth back-projected: here the network's constant 2 m plane.
    let seq = TumSequence::open(sequence()).unwrap();
    let camera = Camera::from_file(sequence().join("camera.toml")).unwrap();
    let cfg = SlamConfig::default();
    let kf = &out.map.keyframes[0];
    let rgb = seq.load_rgb(kf.frame_index).unwrap();
    let depth = predictor().predict(&rgb).unwrap().depth;
    assert!(depth.data.iter().all(|d| (d - PLANE).abs() < 1e-3));
    let expected = points_from_depth(
        &kf.track.features,
        Some(&depth),
        &camera,
        KeypointDepth::from_config(&cfg.tracking),
    );
    assert!(kf.track.n_points() > 20, "{}", kf.track.n_points());
    assert_eq!(kf.track.points_cam, expected);
    assert!(
        kf.track
            .points_cam
            .iter()
            .flatten()
            .all(|p| (p.z - 2.0).abs() < 1e-3)
    );
    // The map is fused from the predicted depth, not the sensor's.
    assert!(kf.view.depth.data.iter().all(|d| (d - PLANE).abs() < 1e-3));
    // With 3D points from the network, PnP tracks (without them every frame
    // would be lost).
    let tracked = out
        .frames
        .iter()
        .filter(|f| f.status == FrameStatus::Tracked)
        .count();
    assert!(tracked >= FRAMES / 2, "{:?}", out.tracking);
    let traj = out.trajectory();
    assert_eq!(traj.len(), FRAMES);
    assert!(
        traj.poses
            .iter()
            .all(|p| p.translation.vector.iter().all(|v| v.is_finite()))
    );
    let dir = tmp_dir("mono_out");
    sdf_slam::slam::output::write_trajectory(&out, &dir).unwrap();
    assert_eq!(
        Trajectory::read_tum(dir.join("trajectory.txt"))
            .unwrap()
            .len(),
        FRAMES
    );

    // Three threads (tracking waits for mapping's SDFCNN depth of each new
    // keyframe) give the same trajectory.
    let (threaded, calls_t) = run(DepthMode::Predicted, true);
    assert!(threaded.threads);
    assert_eq!(calls_t, calls);
    for (a, b) in traj.poses.iter().zip(&threaded.trajectory().poses) {
        assert_eq!(a, b);
    }
}

#[test]
fn sdfcnn_checkpoints_that_do_not_fit_are_clear_errors() {
    let dir = tmp_dir("bad");
    let ckpt = checkpoint();
    std::fs::copy(ckpt.join("model.bpk"), dir.join("model.bpk")).unwrap();
    // Another decoder width than the weights have.
    std::fs::write(
        dir.join("config.toml"),
        common::TINY_SDFCNN_TOML.replace("decoder_dim = 16", "decoder_dim = 8"),
    )
    .unwrap();
    let e = SdfcnnSource::load(&dir, BackendKind::Ndarray)
        .unwrap_err()
        .to_string();
    assert!(e.contains("model.bpk") && e.contains("config.toml"), "{e}");
    // Another network's checkpoint.
    std::fs::write(dir.join("config.toml"), "model = \"fpfdcnn\"\n").unwrap();
    let e = SdfcnnSource::load(&dir, BackendKind::Ndarray)
        .unwrap_err()
        .to_string();
    assert!(e.contains("not an SDFCNN"), "{e}");
    // Not weights at all.
    std::fs::write(dir.join("config.toml"), common::TINY_SDFCNN_TOML).unwrap();
    std::fs::write(dir.join("model.bpk"), b"garbage").unwrap();
    let e = SdfcnnSource::load(&dir, BackendKind::Ndarray)
        .unwrap_err()
        .to_string();
    assert!(e.contains("model.bpk"), "{e}");
    // A network that does not predict the map's 40 classes.
    let cfg13 = common::tiny_sdfcnn_config().with_num_classes(13);
    let device = BackendKind::Ndarray.device().expect("ndarray");
    let p = SdfcnnPredictor::from_model(cfg13.init(&device).unwrap(), cfg13, device);
    let e = SdfcnnSource::new(p).unwrap_err().to_string();
    assert!(e.contains("13 classes") && e.contains("40"), "{e}");
    // No checkpoint there.
    let e = SdfcnnSource::load(&dir.join("nothing"), BackendKind::Ndarray)
        .unwrap_err()
        .to_string();
    assert!(e.contains("nothing"), "{e}");
}

#[test]
fn half_precision_weights_predict_like_the_network_on_ndarray() {
    // The bundled weights are f16; the default backend (ndarray) has no f16
    // tensors: they are cast to f32 on load.
    let p = predictor();
    let rgb = image::RgbImage::from_fn(64, 48, |x, y| {
        image::Rgb([(x * 4) as u8, (y * 5) as u8, 77])
    });
    let out = p.predict(&rgb).unwrap();
    assert_eq!((out.labels.width, out.labels.height), (64, 48));
    assert!(out.depth.data.iter().all(|d| (d - PLANE).abs() < 1e-3));
}
