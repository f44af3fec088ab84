//! Camera motions through a generated room: hand-held sweeps, roll/pitch/yaw
//! shaking about a point, a ground robot turning and driving, and random walks.
//!
//! A motion is a list of keys (position, yaw, pitch, roll) at a fixed spacing,
//! interpolated with Catmull-Rom splines, so a pose exists at any time (motion
//! blur samples between frames). Every plan is checked at each frame (and blur
//! sub-frame): the camera keeps `clearance` metres from all solids and looks at
//! scene content (median depth of a ray grid at least 0.7 m); a failing plan is
//! redrawn.

use super::config::{MotionConfig, TrajectoryKind};
use super::detmath::{atan2, sin_cos};
use super::geom::{Ray, V3};
use super::scene::Scene;
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::geometry::Pose;
use nalgebra::{Isometry3, Matrix3, Point2, Rotation3, Translation3, UnitQuaternion, Vector3};
use rand::RngExt;
use rand_chacha::ChaCha8Rng;
use std::f64::consts::{PI, TAU};

/// One key of a motion: position and yaw / pitch / roll (radians; yaw about
/// the world `z` axis from `+x`, pitch up, roll about the optical axis).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Key {
    /// Camera position in the world, metres.
    pub pos: [f64; 3],
    /// Yaw about the world `z` axis from `+x`, radians.
    pub yaw: f64,
    /// Pitch up, radians.
    pub pitch: f64,
    /// Roll about the optical axis, radians.
    pub roll: f64,
}

/// A smooth camera motion.
#[derive(Debug, Clone)]
pub struct Motion {
    /// The kind of motion.
    pub kind: TrajectoryKind,
    /// Time of the first key, seconds (before 0 so that blur can look back).
    t0: f64,
    /// Time between keys.
    dt: f64,
    keys: Vec<Key>,
}

/// Camera-to-world pose from a position and yaw / pitch / roll. The camera
/// frame is the TUM / OpenCV one: `x` right, `y` down, `z` forward.
pub(crate) fn pose_from_angles(pos: [f64; 3], yaw: f64, pitch: f64, roll: f64) -> Pose {
    let (sy, cy) = sin_cos(yaw);
    let (sp, cp) = sin_cos(pitch);
    let (sr, cr) = sin_cos(roll);
    let f = Vector3::new(cp * cy, cp * sy, sp);
    let r = Vector3::new(sy, -cy, 0.0);
    let d = f.cross(&r);
    let (r2, d2) = (r * cr + d * sr, d * cr - r * sr);
    let m = Matrix3::from_columns(&[r2, d2, f]);
    let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(m));
    Isometry3::from_parts(Translation3::new(pos[0], pos[1], pos[2]), q)
}

fn catmull(p0: f64, p1: f64, p2: f64, p3: f64, s: f64) -> f64 {
    let (s2, s3) = (s * s, s * s * s);
    0.5 * (2.0 * p1
        + (p2 - p0) * s
        + (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3) * s2
        + (3.0 * p1 - p0 - 3.0 * p2 + p3) * s3)
}

impl Motion {
    /// The key values interpolated at time `t` (seconds from the first frame).
    pub fn key(&self, t: f64) -> Key {
        let n = self.keys.len();
        let x = ((t - self.t0) / self.dt).clamp(0.0, (n - 1) as f64);
        let i = (x.floor() as usize).min(n.saturating_sub(2));
        let s = x - i as f64;
        let k = |j: isize| self.keys[(i as isize + j).clamp(0, n as isize - 1) as usize];
        let (a, b, c, d) = (k(-1), k(0), k(1), k(2));
        let f = |g: fn(&Key) -> f64| catmull(g(&a), g(&b), g(&c), g(&d), s);
        Key {
            pos: [f(|k| k.pos[0]), f(|k| k.pos[1]), f(|k| k.pos[2])],
            yaw: f(|k| k.yaw),
            pitch: f(|k| k.pitch),
            roll: f(|k| k.roll),
        }
    }

    /// Camera-to-world pose at time `t`.
    pub fn pose(&self, t: f64) -> Pose {
        let k = self.key(t);
        pose_from_angles(k.pos, k.yaw, k.pitch, k.roll)
    }

    /// Plans a motion of `duration` seconds in `scene`, redrawing plans until
    /// one passes the clearance and view checks at every time in `check_times`.
    pub fn plan(
        kind: TrajectoryKind,
        scene: &Scene,
        camera: &Camera,
        cfg: &MotionConfig,
        duration: f64,
        check_times: &[f64],
        rng: &mut ChaCha8Rng,
    ) -> Result<Motion> {
        const ATTEMPTS: usize = 60;
        let probe = ViewProbe::new(camera, 6, 5);
        let content = ViewProbe::new(camera, 12, 9);
        let mut last = String::new();
        for _ in 0..ATTEMPTS {
            let keys = match kind {
                TrajectoryKind::Sweep => sweep(scene, cfg, duration, &content, rng),
                TrajectoryKind::Rpy => rpy(scene, cfg, duration, &content, rng),
                TrajectoryKind::Robot => robot(scene, cfg, duration, rng),
                TrajectoryKind::Walk => walk(scene, cfg, duration, &content, rng),
            };
            let Some((dt, keys)) = keys else {
                last = "no free starting point".into();
                continue;
            };
            let m = Motion {
                kind,
                t0: -2.0 * dt,
                dt,
                keys,
            };
            match m.check(scene, cfg, &probe, check_times) {
                Ok(()) => return Ok(m),
                Err(why) => last = why,
            }
        }
        Err(Error::msg(format!(
            "could not plan a {kind:?} trajectory in this room after {ATTEMPTS} attempts ({last}); \
             try another seed, a larger room or a smaller motion.clearance"
        )))
    }

    fn check(
        &self,
        scene: &Scene,
        cfg: &MotionConfig,
        probe: &ViewProbe,
        times: &[f64],
    ) -> std::result::Result<(), String> {
        let min_view = if self.kind == TrajectoryKind::Robot {
            0.6
        } else {
            0.7
        };
        let clearance = min_clearance(self.kind, cfg);
        for (i, &t) in times.iter().enumerate() {
            let k = self.key(t);
            let p = V3::new(k.pos[0] as f32, k.pos[1] as f32, k.pos[2] as f32);
            let c = scene.clearance(&p);
            if (c as f64) < clearance {
                return Err(format!("camera {c:.2} m from a surface at t = {t:.2} s"));
            }
            if i % 4 == 0 {
                let view = probe.median_depth(scene, &self.pose(t));
                if view < min_view {
                    return Err(format!(
                        "camera faces a surface {view:.2} m away at t = {t:.2} s"
                    ));
                }
            }
        }
        Ok(())
    }
}

/// The clearance a motion keeps: the robot's camera, 0.4 m above the floor,
/// keeps at most 0.35 m.
fn min_clearance(kind: TrajectoryKind, cfg: &MotionConfig) -> f64 {
    if kind == TrajectoryKind::Robot {
        cfg.clearance.min(0.35)
    } else {
        cfg.clearance
    }
}

/// A coarse grid of camera rays to judge what the camera looks at.
struct ViewProbe {
    rays: Vec<[f64; 2]>,
}

impl ViewProbe {
    fn new(cam: &Camera, nx: usize, ny: usize) -> Self {
        let mut rays = Vec::new();
        for j in 0..ny {
            for i in 0..nx {
                let px = Point2::new(
                    (i as f64 + 0.5) / nx as f64 * cam.width as f64 - 0.5,
                    (j as f64 + 0.5) / ny as f64 * cam.height as f64 - 0.5,
                );
                let n = cam.normalized(&px);
                rays.push([n.x, n.y]);
            }
        }
        ViewProbe { rays }
    }

    /// Depth and label along each probe ray.
    fn cast(&self, scene: &Scene, pose: &Pose) -> Vec<(f32, u8)> {
        let o = pose.translation.vector.map(|v| v as f32);
        self.rays
            .iter()
            .map(|r| {
                let dir = (pose.rotation * Vector3::new(r[0], r[1], 1.0)).map(|v| v as f32);
                scene
                    .cast(&Ray::new(o, dir), 1e-4, 100.0)
                    .map_or((0.0, crate::classes::VOID), |h| {
                        (h.t, scene.solids[h.solid as usize].label)
                    })
            })
            .collect()
    }

    fn median_depth(&self, scene: &Scene, pose: &Pose) -> f32 {
        let mut d: Vec<f32> = self.cast(scene, pose).iter().map(|c| c.0).collect();
        d.sort_by(f32::total_cmp);
        d[d.len() / 2]
    }

    /// Number of distinct labels in view, 0 when the view is blocked (median
    /// depth under 0.8 m).
    fn content(&self, scene: &Scene, pose: &Pose) -> usize {
        let hits = self.cast(scene, pose);
        let mut d: Vec<f32> = hits.iter().map(|c| c.0).collect();
        d.sort_by(f32::total_cmp);
        if d[d.len() / 2] < 0.8 {
            return 0;
        }
        let mut labels: Vec<u8> = hits.iter().map(|c| c.1).collect();
        labels.sort_unstable();
        labels.dedup();
        labels.len()
    }
}

fn v3(p: [f64; 3]) -> V3 {
    V3::new(p[0] as f32, p[1] as f32, p[2] as f32)
}

/// A random point with at least `clear` metres of free space around it.
fn free_point(scene: &Scene, rng: &mut ChaCha8Rng, z: (f64, f64), clear: f64) -> Option<[f64; 3]> {
    let r = &scene.room;
    for _ in 0..400 {
        let p = [
            rng.random_range(0.0..r.width as f64),
            rng.random_range(0.0..r.depth as f64),
            rng.random_range(z.0..=z.1),
        ];
        if scene.clearance(&v3(p)) as f64 >= clear {
            return Some(p);
        }
    }
    None
}

/// Whether the straight segment `a -> b` stays `clear` metres from everything.
fn segment_free(scene: &Scene, a: [f64; 3], b: [f64; 3], clear: f64) -> bool {
    let len = dist(a, b);
    let n = (len / 0.05).ceil().max(1.0) as usize;
    (0..=n).all(|i| {
        let s = i as f64 / n as f64;
        let p = [
            a[0] + (b[0] - a[0]) * s,
            a[1] + (b[1] - a[1]) * s,
            a[2] + (b[2] - a[2]) * s,
        ];
        scene.clearance(&v3(p)) as f64 >= clear
    })
}

/// Yaw and pitch looking from `from` at `to`; yaw unwrapped next to `near`.
fn look(from: [f64; 3], to: [f64; 3], near: f64) -> (f64, f64) {
    let (dx, dy, dz) = (to[0] - from[0], to[1] - from[1], to[2] - from[2]);
    let mut yaw = atan2(dy, dx);
    while yaw - near > PI {
        yaw -= TAU;
    }
    while yaw - near < -PI {
        yaw += TAU;
    }
    let pitch = atan2(dz, (dx * dx + dy * dy).sqrt()).clamp(-1.1, 1.1);
    (yaw, pitch)
}

/// A point of interest, preferring those between `z0` and `z1` metres high.
fn interest(scene: &Scene, rng: &mut ChaCha8Rng, z0: f32, z1: f32) -> [f64; 3] {
    let good: Vec<&V3> = scene
        .interest
        .iter()
        .filter(|p| p.z >= z0 && p.z <= z1)
        .collect();
    let p = if !good.is_empty() {
        *good[rng.random_range(0..good.len())]
    } else if !scene.interest.is_empty() {
        scene.interest[rng.random_range(0..scene.interest.len())]
    } else {
        V3::new(scene.room.width * 0.5, scene.room.depth * 0.5, 0.8)
    };
    [p.x as f64, p.y as f64, p.z as f64]
}

/// A smooth random signal in about `[-1, 1]`: a sum of three sines.
struct Wobble {
    f: [f64; 3],
    ph: [f64; 3],
}

impl Wobble {
    fn new(rng: &mut ChaCha8Rng, freq: f64) -> Self {
        let mut f = [0.0; 3];
        let mut ph = [0.0; 3];
        for k in 0..3 {
            f[k] = freq * rng.random_range(0.6..1.5) * (1.0 + k as f64 * 0.7);
            ph[k] = rng.random_range(0.0..TAU);
        }
        Wobble { f, ph }
    }

    fn at(&self, t: f64) -> f64 {
        (0..3)
            .map(|k| sin_cos(TAU * self.f[k] * t + self.ph[k]).0 * [0.6, 0.3, 0.15][k])
            .sum::<f64>()
            / 1.05
    }
}

/// Hand-held sweep: oscillates sideways in front of something, looking at it.
fn sweep(
    scene: &Scene,
    cfg: &MotionConfig,
    duration: f64,
    content: &ViewProbe,
    rng: &mut ChaCha8Rng,
) -> Option<(f64, Vec<Key>)> {
    // The viewpoint and target that show the most classes, of a few candidates.
    let mut best: Option<(usize, [f64; 3], [f64; 3])> = None;
    for _ in 0..300 {
        let target = interest(scene, rng, 0.3, 1.25);
        let Some(c) = free_point(scene, rng, (1.1, 1.7), cfg.clearance + 0.25) else {
            break;
        };
        let d = dist([c[0], c[1], 0.0], [target[0], target[1], 0.0]);
        if !(1.2..2.8).contains(&d) || !segment_free(scene, c, target, 0.0) {
            continue;
        }
        let (yaw, pitch) = look(c, target, 0.0);
        let n = content.content(scene, &pose_from_angles(c, yaw, pitch, 0.0));
        if best.is_none_or(|b| n > b.0) {
            best = Some((n, c, target));
        }
        if n >= 7 {
            break;
        }
    }
    let (_, c0, target) = best?;
    let (dx, dy) = (target[0] - c0[0], target[1] - c0[1]);
    let dl = (dx * dx + dy * dy).sqrt();
    let side = [-dy / dl, dx / dl];
    let amp = rng.random_range(0.3..0.8);
    let period = rng.random_range(5.0..9.0) / cfg.speed;
    let (wx, wy, wz) = (
        Wobble::new(rng, 0.3),
        Wobble::new(rng, 0.3),
        Wobble::new(rng, 0.25),
    );
    let (wyaw, wpitch, wroll) = (
        Wobble::new(rng, 0.4),
        Wobble::new(rng, 0.5),
        Wobble::new(rng, 0.3),
    );
    let phase = rng.random_range(0.0..TAU);
    let dt = 0.1;
    let mut keys = Vec::new();
    let mut yaw = 0.0;
    let n = (duration / dt).ceil() as usize + 5;
    for i in 0..n {
        let t = (i as f64 - 2.0) * dt;
        let s = sin_cos(TAU * t / period + phase).0;
        let lat = amp * s;
        let pos = [
            c0[0] + side[0] * lat + 0.08 * wx.at(t),
            c0[1] + side[1] * lat + 0.08 * wy.at(t),
            c0[2] + 0.06 * wz.at(t),
        ];
        let aim = [
            target[0] + side[0] * lat * 0.5,
            target[1] + side[1] * lat * 0.5,
            target[2],
        ];
        let (y, p) = look(pos, aim, yaw);
        yaw = y;
        keys.push(Key {
            pos,
            yaw: y + 0.12 * wyaw.at(t),
            pitch: p + 0.08 * wpitch.at(t),
            roll: 0.06 * wroll.at(t),
        });
    }
    Some((dt, keys))
}

/// Roll / pitch / yaw about a nearly fixed point (like TUM fr1_rpy).
fn rpy(
    scene: &Scene,
    cfg: &MotionConfig,
    duration: f64,
    content: &ViewProbe,
    rng: &mut ChaCha8Rng,
) -> Option<(f64, Vec<Key>)> {
    let mut best: Option<(usize, [f64; 3], [f64; 3])> = None;
    for _ in 0..40 {
        let c = free_point(scene, rng, (1.2, 1.7), cfg.clearance + 0.35)?;
        let target = interest(scene, rng, 0.3, 1.8);
        let (yaw, pitch) = look(c, target, 0.0);
        let n = content.content(scene, &pose_from_angles(c, yaw, pitch * 0.5, 0.0));
        if best.is_none_or(|b| n > b.0) {
            best = Some((n, c, target));
        }
        if n >= 7 {
            break;
        }
    }
    let (_, c0, target) = best?;
    let (yaw0, pitch0) = look(c0, target, 0.0);
    let f = 0.45 * cfg.speed;
    let (wy, wp, wr) = (
        Wobble::new(rng, f),
        Wobble::new(rng, f),
        Wobble::new(rng, f),
    );
    let (wx, wyy, wz) = (
        Wobble::new(rng, 0.3),
        Wobble::new(rng, 0.3),
        Wobble::new(rng, 0.3),
    );
    let (ay, ap, ar) = (
        rng.random_range(0.35..0.6),
        rng.random_range(0.2..0.35),
        rng.random_range(0.25..0.45),
    );
    let dt = 0.05;
    let n = (duration / dt).ceil() as usize + 5;
    let keys = (0..n)
        .map(|i| {
            let t = (i as f64 - 2.0) * dt;
            Key {
                pos: [
                    c0[0] + 0.03 * wx.at(t),
                    c0[1] + 0.03 * wyy.at(t),
                    c0[2] + 0.02 * wz.at(t),
                ],
                yaw: yaw0 + ay * wy.at(t),
                pitch: (pitch0 * 0.5 + ap * wp.at(t)).clamp(-0.9, 0.9),
                roll: ar * wr.at(t),
            }
        })
        .collect();
    Some((dt, keys))
}

/// Free distance along a horizontal heading at height `z`.
/// Free distance along a horizontal heading, at the camera's height and near the floor.
fn free_ahead(scene: &Scene, p: [f64; 3], heading: f64) -> f64 {
    let (s, c) = sin_cos(heading);
    let dir = V3::new(c as f32, s as f32, 0.0);
    [0.08, p[2]]
        .iter()
        .map(|&z| {
            let ray = Ray::new(v3([p[0], p[1], z]), dir);
            scene.cast(&ray, 1e-4, 50.0).map_or(50.0, |h| h.t as f64)
        })
        .fold(f64::MAX, f64::min)
}

/// A ground robot (camera 0.4 m up): a full turn in place, then driving,
/// turning in place towards open space whenever something is ahead.
fn robot(
    scene: &Scene,
    cfg: &MotionConfig,
    duration: f64,
    rng: &mut ChaCha8Rng,
) -> Option<(f64, Vec<Key>)> {
    let z = 0.4;
    let clear = min_clearance(TrajectoryKind::Robot, cfg);
    let mut p = free_point(scene, rng, (z, z + 1e-9), clear + 0.03)?;
    let dt = 0.1;
    let speed = rng.random_range(0.25..0.4) * cfg.speed;
    let turn_rate = rng.random_range(0.35..0.55) * cfg.speed;
    let dir = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
    let mut heading = rng.random_range(0.0..TAU);
    let pitch = -rng.random_range(0.0..0.12);
    let mut turn_left = TAU * rng.random_range(0.8..1.1) * dir;
    let (wp, wr) = (Wobble::new(rng, 1.5), Wobble::new(rng, 1.5));
    let n = (duration / dt).ceil() as usize + 5;
    let mut keys = Vec::with_capacity(n);
    for i in 0..n {
        let t = (i as f64 - 2.0) * dt;
        keys.push(Key {
            pos: p,
            yaw: heading,
            pitch: pitch + 0.006 * wp.at(t),
            roll: 0.006 * wr.at(t),
        });
        if turn_left.abs() > 1e-9 {
            let step = turn_left.clamp(-turn_rate * dt, turn_rate * dt);
            heading += step;
            turn_left -= step;
            continue;
        }
        // A step that stays clear of everything, also beside the robot.
        let step = |h: f64, len: f64| {
            let (s, c) = sin_cos(h);
            [p[0] + c * len, p[1] + s * len, z]
        };
        let clear_at = |q: [f64; 3]| scene.clearance(&v3(q)) as f64 >= clear + 0.05;
        let next = step(heading, speed * dt);
        if free_ahead(scene, p, heading) < 0.9 + clear
            || !clear_at(next)
            || !clear_at(step(heading, 0.3))
        {
            // Turn towards the most open of a few random headings.
            let mut best = (0.0, 0.0);
            for _ in 0..12 {
                let d = rng.random_range(-PI..PI);
                let f = free_ahead(scene, p, heading + d);
                if f > best.0 && clear_at(step(heading + d, 0.3)) {
                    best = (f, d);
                }
            }
            // Nowhere to go: turn on the spot and look again.
            turn_left = if best.0 > 0.0 { best.1 } else { PI * 0.5 };
            continue;
        }
        p = next;
    }
    Some((dt, keys))
}

/// A smooth random walk between free points, looking at random things.
fn walk(
    scene: &Scene,
    cfg: &MotionConfig,
    duration: f64,
    content: &ViewProbe,
    rng: &mut ChaCha8Rng,
) -> Option<(f64, Vec<Key>)> {
    // The most informative of a few targets, seen from `from`.
    let choose = |rng: &mut ChaCha8Rng, from: [f64; 3]| {
        let mut best = (0, interest(scene, rng, 0.2, 2.0));
        for _ in 0..6 {
            let t = interest(scene, rng, 0.2, 2.0);
            let (yaw, pitch) = look(from, t, 0.0);
            let n = content.content(scene, &pose_from_angles(from, yaw, pitch, 0.0));
            if n > best.0 {
                best = (n, t);
            }
        }
        best.1
    };
    let clear = cfg.clearance + 0.2;
    let mut way = vec![free_point(scene, rng, (1.0, 1.8), clear)?];
    let speed = rng.random_range(0.25..0.45) * cfg.speed;
    let mut length = 0.0;
    while length < duration * speed + 1.0 {
        let a = *way.last()?;
        let mut next = None;
        for _ in 0..100 {
            let b = free_point(scene, rng, (1.0, 1.8), clear)?;
            let d = dist(a, b);
            if (0.6..2.5).contains(&d) && segment_free(scene, a, b, clear) {
                next = Some((b, d));
                break;
            }
        }
        let (b, d) = next?;
        way.push(b);
        length += d;
    }
    let dt = 0.25;
    let n = (duration / dt).ceil() as usize + 5;
    let mut keys = Vec::with_capacity(n);
    let (mut seg, mut along) = (0usize, 0.0f64);
    let mut target = choose(rng, way[0]);
    let mut next_target = rng.random_range(2.5..5.0);
    let mut aim = target;
    let mut yaw = 0.0;
    let wr = Wobble::new(rng, 0.3);
    for i in 0..n {
        let t = (i as f64 - 2.0) * dt;
        let (a, b) = (way[seg], way[(seg + 1).min(way.len() - 1)]);
        let len = dist(a, b).max(1e-9);
        let s = (along / len).min(1.0);
        let pos = [
            a[0] + (b[0] - a[0]) * s,
            a[1] + (b[1] - a[1]) * s,
            a[2] + (b[2] - a[2]) * s,
        ];
        if t > next_target {
            target = choose(rng, pos);
            next_target = t + rng.random_range(2.5..5.0);
        }
        // The gaze follows the target with a lag.
        for k in 0..3 {
            aim[k] += (target[k] - aim[k]) * 0.25;
        }
        let (y, p) = look(pos, aim, yaw);
        yaw = y;
        keys.push(Key {
            pos,
            yaw: y,
            pitch: p,
            roll: 0.05 * wr.at(t),
        });
        along += speed * dt;
        if along > len && seg + 2 < way.len() {
            along -= len;
            seg += 1;
        }
    }
    Some((dt, keys))
}

/// Extra distance a still view keeps from every surface beyond `motion.clearance`, metres.
pub(crate) const VIEW_MARGIN: f64 = 0.1;

/// An independent random view (for still-image training sets): a free point
/// `cfg.view_height` high (0.8 to 1.8 m by default) looking at something in the room.
pub(crate) fn random_view(
    scene: &Scene,
    camera: &Camera,
    cfg: &MotionConfig,
    rng: &mut ChaCha8Rng,
) -> Result<Pose> {
    let probe = ViewProbe::new(camera, 12, 9);
    let mut best: Option<(usize, Pose)> = None;
    for _ in 0..300 {
        let [lo, hi] = cfg.view_height;
        let Some(p) = free_point(scene, rng, (lo, hi), cfg.clearance + VIEW_MARGIN) else {
            break;
        };
        let mut target = interest(scene, rng, 0.0, 2.5);
        for v in target.iter_mut() {
            *v += rng.random_range(-0.3..0.3);
        }
        let (yaw, pitch) = look(p, target, 0.0);
        let pose = pose_from_angles(p, yaw, pitch, rng.random_range(-0.08..0.08));
        let n = probe.content(scene, &pose);
        if n > 0 && best.as_ref().is_none_or(|b| n > b.0) {
            best = Some((n, pose));
        }
        if n >= 5 {
            break;
        }
    }
    best.map(|b| b.1)
        .ok_or_else(|| Error::msg("could not find a free random view in this room"))
}

/// Distance between two points.
fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    let (x, y, z) = (b[0] - a[0], b[1] - a[1], b[2] - a[2]);
    (x * x + y * y + z * z).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::config::RoomConfig;
    use rand::SeedableRng;

    #[test]
    fn angles_give_the_tum_camera_frame() {
        // Yaw 0, pitch 0: looking along +x, image right is -y, image down is -z.
        let p = pose_from_angles([1.0, 2.0, 3.0], 0.0, 0.0, 0.0);
        let f = p.rotation * Vector3::z();
        let r = p.rotation * Vector3::x();
        let d = p.rotation * Vector3::y();
        assert!((f - Vector3::x()).norm() < 1e-12);
        assert!((r + Vector3::y()).norm() < 1e-12);
        assert!((d + Vector3::z()).norm() < 1e-12);
    }

    #[test]
    fn every_kind_plans_a_clear_motion() {
        let cam = Camera::tum_fr1().resized(80, 60);
        let cfg = MotionConfig::default();
        let times: Vec<f64> = (0..150).map(|i| i as f64 / 30.0).collect();
        for (i, kind) in [
            TrajectoryKind::Sweep,
            TrajectoryKind::Rpy,
            TrajectoryKind::Robot,
            TrajectoryKind::Walk,
        ]
        .into_iter()
        .enumerate()
        {
            let scene = Scene::generate(&RoomConfig::default(), 100 + i as u64).unwrap();
            let mut rng = ChaCha8Rng::seed_from_u64(i as u64);
            let m = Motion::plan(kind, &scene, &cam, &cfg, 5.0, &times, &mut rng).unwrap();
            let mut prev = m.pose(0.0);
            for &t in &times[1..] {
                let p = m.pose(t);
                let step = (p.translation.vector - prev.translation.vector).norm();
                let turn = (p.rotation.inverse() * prev.rotation).angle();
                // Smooth at 30 Hz: under 5 cm and 6 degrees per frame.
                assert!(
                    step < 0.05 && turn < 0.1,
                    "{kind:?} t {t}: {step} m {turn} rad"
                );
                if kind == TrajectoryKind::Robot {
                    assert!((p.translation.vector.z - 0.4).abs() < 1e-9);
                }
                prev = p;
            }
        }
    }
}
