//! Synthetic data generator speed: frames per second at 640x480 (release).
//!
//! `cargo bench --bench synth` prints frames/s for ray casting alone, for the
//! full frame (render + sensor simulation + PNG encoding of colour, depth,
//! exact depth and labels), and for a motion-blurred frame.

use image::{DynamicImage, ImageFormat};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use sdf_slam::synth::{self, Motion, Renderer, Scene, SynthConfig};
use std::io::Cursor;
use std::time::Instant;

fn png(img: DynamicImage) -> usize {
    let mut buf = Vec::new();
    img.write_to(&mut Cursor::new(&mut buf), ImageFormat::Png)
        .expect("encode");
    buf.len()
}

/// CPU seconds used by this process so far (Linux; 0 elsewhere).
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let fields: Vec<&str> = stat
        .rsplit(')')
        .next()
        .unwrap_or("")
        .split_whitespace()
        .collect();
    let ticks = |k: usize| {
        fields
            .get(k)
            .and_then(|v| v.parse::<f64>().ok())
            .unwrap_or(0.0)
    };
    // utime and stime are fields 14 and 15 of the whole line, 12 and 13 after the name.
    (ticks(11) + ticks(12)) / 100.0
}

/// Frames per second of wall time, and per second of CPU time divided by the
/// number of threads (what an otherwise idle machine would give).
fn rate(frames: usize, wall: Instant, cpu0: f64) -> (f64, f64) {
    let w = wall.elapsed().as_secs_f64();
    let c = (cpu_seconds() - cpu0).max(1e-9) / rayon::current_num_threads() as f64;
    (frames as f64 / w, frames as f64 / c.max(w * 0.05))
}

fn main() {
    let frames: usize = std::env::var("SYNTH_BENCH_FRAMES")
        .ok()
        .and_then(|v| v.parse().ok())
        .filter(|&n| n > 0)
        .unwrap_or(60);
    let cfg = SynthConfig {
        frames,
        ..SynthConfig::default()
    };
    let camera = cfg.camera().expect("camera");
    println!(
        "synth bench: {}x{}, {} frames per run, {} threads",
        camera.width,
        camera.height,
        frames,
        rayon::current_num_threads()
    );
    let only: Option<usize> = std::env::var("SYNTH_BENCH_SCENE")
        .ok()
        .and_then(|v| v.parse().ok());
    for (scene_index, kind) in [
        (0usize, synth::TrajectoryKind::Sweep),
        (1, synth::TrajectoryKind::Walk),
        (2, synth::TrajectoryKind::Rpy),
    ] {
        if only.is_some_and(|o| o != scene_index) {
            continue;
        }
        let seed = synth::scene_seed(cfg.seed, scene_index);
        let scene = Scene::generate(&cfg.room, seed).expect("scene");
        let renderer = Renderer::new(&scene, &camera, &cfg.render);
        let times: Vec<f64> = (0..frames).map(|k| k as f64 / cfg.fps).collect();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let motion = Motion::plan(
            kind,
            &scene,
            &camera,
            &cfg.motion,
            times[frames - 1] + 0.05,
            &times,
            &mut rng,
        )
        .expect("motion");
        let (t, c0) = (Instant::now(), cpu_seconds());
        let mut hits = 0usize;
        for &tk in &times {
            hits += renderer
                .render(&motion.pose(tk))
                .px
                .iter()
                .filter(|p| p.depth > 0.0)
                .count();
        }
        let render_fps = rate(frames, t, c0);
        let (t, c0) = (Instant::now(), cpu_seconds());
        let mut bytes = 0usize;
        for (k, &tk) in times.iter().enumerate() {
            let (f, _, _) = synth::render_frame(&renderer, &motion, &cfg, tk, k as u32, None);
            bytes += png(DynamicImage::ImageRgb8(f.rgb));
            bytes += png(DynamicImage::ImageLuma8(f.labels));
            for d in [Some(f.depth), f.depth_gt].into_iter().flatten() {
                let raw: Vec<u16> = d
                    .data
                    .iter()
                    .map(|&v| (v as f64 * 5000.0).round().min(65535.0) as u16)
                    .collect();
                let buf =
                    image::ImageBuffer::<image::Luma<u16>, _>::from_raw(d.width, d.height, raw)
                        .expect("buffer");
                bytes += png(DynamicImage::ImageLuma16(buf));
            }
        }
        let full_fps = rate(frames, t, c0);
        let mut blur = cfg.clone();
        blur.blur.enabled = true;
        let n = (frames / 6).max(2);
        let (t, c0) = (Instant::now(), cpu_seconds());
        for (k, &tk) in times.iter().take(n).enumerate() {
            let _ = synth::render_frame(&renderer, &motion, &blur, tk, k as u32, None);
        }
        let blur_fps = rate(n, t, c0);
        println!(
            "scene {scene_index} ({:?} room, {} solids, {kind:?}): frames/s wall (cpu-based): render {:.1} ({:.1}), render+sensor+PNG {:.1} ({:.1}), blurred x{} {:.2} ({:.2})  [{} hits, {} KB PNG]",
            scene.room.kind,
            scene.solids.len(),
            render_fps.0,
            render_fps.1,
            full_fps.0,
            full_fps.1,
            blur.blur.samples,
            blur_fps.0,
            blur_fps.1,
            hits,
            bytes / 1024
        );
    }
}
