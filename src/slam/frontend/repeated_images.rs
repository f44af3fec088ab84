//! Frames whose colour or depth image repeats the previous frame's.
//!
//! Some recordings hold frames whose images are byte-for-byte copies of the frame before. In
//! the 7-Scenes kitchen (frames 222-799 of `7scenes_redkitchen_0_799`) one frame in four to
//! six repeats the one before: 63 frames both images (the ground truth then stands nearly
//! still), 23 only the colour and 24 only the depth. Those 47 frames' colour and depth show
//! two different instants, about a centimetre apart at that camera's speed. The run's report
//! counts the repeats. They are found by content: a 64-bit hash of each decoded image,
//! compared with the previous frame's.

use crate::dataset::DepthImage;
use image::RgbImage;

/// Content hashes of one frame's images.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct ImageKeys {
    colour: u64,
    /// `None` without a depth image (monocular runs, a frame without depth).
    depth: Option<u64>,
}

impl ImageKeys {
    /// Hashes of the colour image and, when given, the depth image.
    pub fn new(rgb: &RgbImage, depth: Option<&DepthImage>) -> Self {
        let raw = rgb.as_raw();
        let words = raw.chunks(8).map(|c| {
            let mut w = [0u8; 8];
            w[..c.len()].copy_from_slice(c);
            u64::from_le_bytes(w)
        });
        let colour = hash_words(rgb.width(), rgb.height(), words);
        let depth = depth.map(|d| {
            let words = d.data.iter().map(|v| v.to_bits() as u64);
            hash_words(d.width, d.height, words)
        });
        ImageKeys { colour, depth }
    }

    /// What this frame repeats of `previous` (the frame just before it; `None` when that
    /// frame was not loaded).
    pub fn repeats(&self, previous: Option<&ImageKeys>) -> Repeats {
        let Some(p) = previous else {
            return Repeats::default();
        };
        Repeats {
            colour: self.colour == p.colour,
            depth: match (self.depth, p.depth) {
                (Some(a), Some(b)) => Some(a == b),
                _ => None,
            },
        }
    }
}

/// A 64-bit hash of an image's size and words (multiply-rotate per word, then a final mix):
/// not cryptographic, enough to tell a copy from a new image.
fn hash_words(width: u32, height: u32, words: impl Iterator<Item = u64>) -> u64 {
    const K: u64 = 0x9E37_79B9_7F4A_7C15;
    let mut h = ((width as u64) << 32 | height as u64).wrapping_mul(K);
    for w in words {
        h = (h ^ w).wrapping_mul(K).rotate_left(29);
    }
    h ^= h >> 33;
    h = h.wrapping_mul(0xFF51_AFD7_ED55_8CCD);
    h ^ (h >> 33)
}

/// Which of a frame's images repeat the previous frame's.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Repeats {
    /// Whether the colour image repeats the previous frame's.
    pub colour: bool,
    /// `None` unless both frames have depth.
    pub depth: Option<bool>,
}

/// Frames of a run by what they repeat, for the report.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct RepeatCounts {
    /// Every image repeats the previous frame's (both, or the colour in a monocular run).
    pub both: usize,
    /// Frames whose colour repeats but whose depth does not.
    pub colour_only: usize,
    /// Frames whose depth repeats but whose colour does not.
    pub depth_only: usize,
}

impl RepeatCounts {
    /// Counts one frame's repeats.
    pub fn add(&mut self, r: Repeats) {
        match (r.colour, r.depth) {
            (true, Some(true) | None) => self.both += 1,
            (true, Some(false)) => self.colour_only += 1,
            (false, Some(true)) => self.depth_only += 1,
            (false, _) => {}
        }
    }

    /// Frames that repeat any image.
    pub fn total(&self) -> usize {
        self.both + self.colour_only + self.depth_only
    }

    /// "N frames repeat all of the previous frame's images, N only its colour, N only its
    /// depth", for the report.
    pub fn describe(&self) -> String {
        let (n, verb) = match self.both {
            1 => ("frame", "repeats"),
            _ => ("frames", "repeat"),
        };
        format!(
            "{} {n} {verb} all of the previous frame's images, {} only its colour, {} only its depth",
            self.both, self.colour_only, self.depth_only
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rgb(v: u8) -> RgbImage {
        RgbImage::from_pixel(4, 3, image::Rgb([v, 2, 3]))
    }

    fn depth(v: f32) -> DepthImage {
        let mut d = DepthImage::new(4, 3);
        d.data.fill(v);
        d
    }

    #[test]
    fn repeats_are_found_by_content_per_stream() {
        let a = ImageKeys::new(&rgb(1), Some(&depth(1.0)));
        let same = ImageKeys::new(&rgb(1), Some(&depth(1.0)));
        let new_colour = ImageKeys::new(&rgb(9), Some(&depth(1.0)));
        let new_depth = ImageKeys::new(&rgb(1), Some(&depth(1.5)));
        let both = same.repeats(Some(&a));
        assert_eq!(
            both,
            Repeats {
                colour: true,
                depth: Some(true)
            }
        );
        let depth_only = new_colour.repeats(Some(&a));
        assert_eq!(
            depth_only,
            Repeats {
                colour: false,
                depth: Some(true)
            }
        );
        let colour_only = new_depth.repeats(Some(&a));
        assert_eq!(
            colour_only,
            Repeats {
                colour: true,
                depth: Some(false)
            }
        );
        // A changed pixel anywhere is a new image.
        let mut d = depth(1.0);
        d.data[11] = 1.001;
        let r = ImageKeys::new(&rgb(1), Some(&d)).repeats(Some(&a));
        assert_eq!(
            r,
            Repeats {
                colour: true,
                depth: Some(false)
            }
        );
        // Nothing before it, or no depth on one side.
        assert_eq!(a.repeats(None), Repeats::default());
        let mono = ImageKeys::new(&rgb(1), None);
        let r = mono.repeats(Some(&a));
        assert_eq!(
            r,
            Repeats {
                colour: true,
                depth: None
            }
        );
    }

    #[test]
    fn counts_split_by_stream() {
        let mut c = RepeatCounts::default();
        for r in [
            Repeats {
                colour: true,
                depth: Some(true),
            },
            Repeats {
                colour: true,
                depth: None,
            },
            Repeats {
                colour: true,
                depth: Some(false),
            },
            Repeats {
                colour: false,
                depth: Some(true),
            },
            Repeats {
                colour: false,
                depth: Some(false),
            },
            Repeats::default(),
        ] {
            c.add(r);
        }
        assert_eq!(
            c,
            RepeatCounts {
                both: 2,
                colour_only: 1,
                depth_only: 1
            }
        );
        assert_eq!(c.total(), 4);
        assert_eq!(
            c.describe(),
            "2 frames repeat all of the previous frame's images, 1 only its colour, 1 only its depth"
        );
    }
}
