//! Timestamped camera trajectories in the TUM format
//! (`timestamp tx ty tz qx qy qz qw`, camera-to-world), as read by evo.

use crate::error::{Error, Result};
use crate::geometry::{Pose, pose_from_tum, pose_to_tum};
use crate::io::{parse_f64, read_text, records, write_atomic_with};
use nalgebra::Point3;
use std::io::Write;
use std::path::Path;

/// Largest coordinate a trajectory file may hold, metres (a planet's worth).
pub(crate) const MAX_POSITION: f64 = 1e7;

/// A trajectory: strictly increasing timestamps (seconds) and poses.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Trajectory {
    /// Timestamp of each pose, seconds.
    pub stamps: Vec<f64>,
    /// Camera-to-world poses, one per stamp.
    pub poses: Vec<Pose>,
}

impl Trajectory {
    /// An empty trajectory.
    pub fn new() -> Self {
        Self::default()
    }

    /// Builds a trajectory, checking that stamps are finite and strictly increasing.
    pub fn from_parts(stamps: Vec<f64>, poses: Vec<Pose>) -> Result<Self> {
        if stamps.len() != poses.len() {
            return Err(Error::msg(format!(
                "{} timestamps but {} poses",
                stamps.len(),
                poses.len()
            )));
        }
        if let Some(i) = (1..stamps.len()).find(|&i| stamps[i] <= stamps[i - 1]) {
            return Err(Error::msg(format!(
                "timestamps not strictly increasing at pose {i}: {} after {}",
                stamps[i],
                stamps[i - 1]
            )));
        }
        Ok(Trajectory { stamps, poses })
    }

    /// Number of poses.
    pub fn len(&self) -> usize {
        self.stamps.len()
    }

    /// Whether it has no poses.
    pub fn is_empty(&self) -> bool {
        self.stamps.is_empty()
    }

    /// Appends a pose; its stamp must be later than the last one.
    pub fn push(&mut self, stamp: f64, pose: Pose) -> Result<()> {
        if let Some(&last) = self.stamps.last()
            && stamp <= last
        {
            return Err(Error::msg(format!(
                "timestamp {stamp} is not after the previous one ({last})"
            )));
        }
        self.stamps.push(stamp);
        self.poses.push(pose);
        Ok(())
    }

    /// Camera positions in world coordinates.
    pub fn positions(&self) -> Vec<Point3<f64>> {
        self.poses
            .iter()
            .map(|p| Point3::from(p.translation.vector))
            .collect()
    }

    /// Length of the path travelled by the camera, in metres.
    pub fn path_length(&self) -> f64 {
        self.positions()
            .windows(2)
            .map(|w| (w[1] - w[0]).norm())
            .sum()
    }

    /// A trajectory made of the poses at the given indices.
    pub fn select(&self, ids: &[usize]) -> Trajectory {
        Trajectory {
            stamps: ids.iter().map(|&i| self.stamps[i]).collect(),
            poses: ids.iter().map(|&i| self.poses[i]).collect(),
        }
    }

    /// Reads a TUM trajectory file. Comment (`#`) and blank lines are skipped;
    /// a malformed line, a non-finite value, a zero quaternion or a timestamp
    /// that does not increase is an error naming the file and line.
    pub fn read_tum(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let text = read_text(path)?;
        let mut traj = Trajectory::new();
        for rec in records(&text) {
            let f = &rec.fields;
            if f.len() != 8 {
                return Err(Error::parse(
                    path,
                    rec.line,
                    format!(
                        "expected 8 fields 'timestamp tx ty tz qx qy qz qw', found {}",
                        f.len()
                    ),
                ));
            }
            const NAMES: [&str; 8] = ["timestamp", "tx", "ty", "tz", "qx", "qy", "qz", "qw"];
            let mut v = [0.0; 8];
            for k in 0..8 {
                v[k] = parse_f64(path, rec.line, NAMES[k], f[k])?;
            }
            // Squares of larger positions overflow (ATE would be inf or 0).
            if let Some(k) = (1..4).find(|&k| v[k].abs() > MAX_POSITION) {
                return Err(Error::parse(
                    path,
                    rec.line,
                    format!(
                        "{} = {} m is out of range (|position| at most {MAX_POSITION:e} m)",
                        NAMES[k], f[k]
                    ),
                ));
            }
            let pose = pose_from_tum([v[1], v[2], v[3]], [v[4], v[5], v[6], v[7]])
                .ok_or_else(|| Error::parse(path, rec.line, "quaternion is zero"))?;
            if let Some(&last) = traj.stamps.last()
                && v[0] <= last
            {
                return Err(Error::parse(
                    path,
                    rec.line,
                    format!(
                        "timestamp {} is not after the previous one ({last}): timestamps must be strictly increasing",
                        f[0]
                    ),
                ));
            }
            traj.stamps.push(v[0]);
            traj.poses.push(pose);
        }
        if traj.is_empty() {
            return Err(Error::invalid(path, "no poses in trajectory file"));
        }
        Ok(traj)
    }

    /// Writes the trajectory in TUM format, atomically.
    pub fn write_tum(&self, path: impl AsRef<Path>) -> Result<()> {
        write_atomic_with(path, |w| {
            writeln!(w, "# timestamp tx ty tz qx qy qz qw")?;
            for (s, p) in self.stamps.iter().zip(&self.poses) {
                let (t, q) = pose_to_tum(p);
                writeln!(
                    w,
                    "{s:.6} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9}",
                    t[0], t[1], t[2], q[0], q[1], q[2], q[3]
                )?;
            }
            Ok(())
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::pose_from_tum;

    fn tmp(name: &str) -> crate::io::ScratchDir {
        crate::io::ScratchDir::new(&format!("traj_{name}")).unwrap()
    }

    #[test]
    fn write_read_round_trip() {
        let mut t = Trajectory::new();
        t.push(
            1.0,
            pose_from_tum([1.0, 2.0, 3.0], [0.0, 0.0, 0.0, 1.0]).unwrap(),
        )
        .unwrap();
        t.push(
            1.5,
            pose_from_tum([1.5, 2.0, 3.0], [0.1, 0.2, 0.3, 0.9]).unwrap(),
        )
        .unwrap();
        let dir = tmp("rt");
        let p = dir.join("rt.txt");
        t.write_tum(&p).unwrap();
        let r = Trajectory::read_tum(&p).unwrap();
        assert_eq!(r.stamps, t.stamps);
        for (a, b) in r.poses.iter().zip(&t.poses) {
            assert!((a.translation.vector - b.translation.vector).norm() < 1e-9);
            assert!(a.rotation.angle_to(&b.rotation) < 1e-8);
        }
        assert!(t.push(1.5, t.poses[0]).is_err());
    }

    #[test]
    fn malformed_lines_name_file_and_line() {
        let cases = [
            ("1 0 0 0 0 0 0 1\n2 0 0 0 0 0 1\n", ":2:", "8 fields"),
            (
                "# c\n1 0 0 0 0 0 0 1\n2 0 x 0 0 0 0 1\n",
                ":3:",
                "ty is not a number",
            ),
            (
                "1 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n",
                ":2:",
                "strictly increasing",
            ),
            ("1 0 0 nan 0 0 0 1\n", ":1:", "not finite"),
            ("1 0 0 0 0 0 0 0\n", ":1:", "quaternion"),
        ];
        let dir = tmp("bad");
        for (i, (text, at, what)) in cases.iter().enumerate() {
            let p = dir.join(format!("bad{i}.txt"));
            std::fs::write(&p, text).unwrap();
            let e = Trajectory::read_tum(&p).unwrap_err().to_string();
            assert!(
                e.contains(&format!("bad{i}.txt{at}")) && e.contains(what),
                "{e}"
            );
        }
        let dir = tmp("empty");
        let p = dir.join("empty.txt");
        std::fs::write(&p, "# nothing\n").unwrap();
        assert!(
            Trajectory::read_tum(&p)
                .unwrap_err()
                .to_string()
                .contains("no poses")
        );
        assert!(Trajectory::read_tum(tmp("missing").join("missing.txt")).is_err());
    }
}
