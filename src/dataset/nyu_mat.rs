//! The official NYU Depth v2 labelled file `nyu_depth_v2_labeled.mat`, read directly: a
//! MATLAB v7.3 file, i.e. HDF5 after a 512-byte user block, opened with the pure-Rust
//! `hdf5-pure` crate and read one image at a time (only the chunks that hold the image are
//! read and inflated).
//!
//! Datasets used, in h5py shapes (MATLAB's dimensions reversed), for N images of W x H
//! pixels: `images` (N, 3, W, H) u8, `depths` (N, W, H) f32 metres, `labels` (N, W, H) u16
//! 894-class ids (0 = unlabelled). MATLAB is column-major, so `images[i, c, x, y]` is channel
//! `c` of pixel `(x, y)`; images are transposed to row-major here. Labels are mapped to the 40
//! classes with [`default_894_to_40`] (unlabelled -> void); a depth that is not positive and
//! finite becomes 0 (missing). The other datasets (`rawDepths`, `instances`, `names`...) are
//! not read. Image `i` (0-based) has id `i + 1` on 6 digits (`000433`), as in the PNG layouts
//! and the standard 1-based split lists.

use super::depth::DepthImage;
use super::labels::LabelImage;
use super::nyu::{NyuItem, default_894_to_40};
use crate::error::{Error, Result};
use hdf5_pure::{DType, Dataset, File};
use image::RgbImage;
use std::path::{Path, PathBuf};

/// An open `nyu_depth_v2_labeled.mat`.
#[derive(Clone)]
pub struct NyuMat {
    path: PathBuf,
    images: Dataset,
    depths: Dataset,
    labels: Dataset,
    len: usize,
    width: u32,
    height: u32,
    map894: Vec<u8>,
}

impl std::fmt::Debug for NyuMat {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NyuMat")
            .field("path", &self.path)
            .field("len", &self.len)
            .field("width", &self.width)
            .field("height", &self.height)
            .finish()
    }
}

impl NyuMat {
    /// Opens the file and checks that `images`, `depths` and `labels` exist with the expected
    /// types and agreeing shapes; no image is read.
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let file = File::open_streaming(path).map_err(|e| match e {
            hdf5_pure::Error::Io(io) => Error::io(path, io),
            e => Error::invalid(path, format!("not a MATLAB v7.3 (HDF5) file: {e}")),
        })?;
        let open = |name: &str, types: &[DType], axes: &str| -> Result<(Dataset, Vec<u64>)> {
            let bad = |msg: String| Error::invalid(path, format!("dataset '{name}': {msg}"));
            let ds = file
                .dataset(name)
                .map_err(|e| bad(format!("cannot open it: {e}")))?;
            let dtype = ds.dtype().map_err(|e| bad(e.to_string()))?;
            if !types.contains(&dtype) {
                let want: Vec<String> = types.iter().map(DType::to_string).collect();
                return Err(bad(format!("type {dtype}, expected {}", want.join(" or "))));
            }
            let shape = ds.shape().map_err(|e| bad(e.to_string()))?;
            if shape.len() != axes.split(", ").count() {
                return Err(bad(format!("shape {shape:?}, expected ({axes})")));
            }
            Ok((ds, shape))
        };
        let (images, s) = open("images", &[DType::U8], "N, 3, width, height")?;
        let (depths, d) = open("depths", &[DType::F32, DType::F64], "N, width, height")?;
        let (labels, l) = open("labels", &[DType::U16], "N, width, height")?;
        if s[1] != 3 {
            return Err(Error::invalid(
                path,
                format!("dataset 'images': shape {s:?}, expected (N, 3, width, height)"),
            ));
        }
        let want = [s[0], s[2], s[3]];
        for (name, shape) in [("depths", &d), ("labels", &l)] {
            if shape[..] != want {
                return Err(Error::invalid(
                    path,
                    format!("dataset '{name}': shape {shape:?} does not match 'images' {s:?}"),
                ));
            }
        }
        // At most 2^28 pixels an image (16384 x 16384), so buffer sizes cannot overflow.
        let too_big = || Error::invalid(path, format!("dataset 'images': shape {s:?} too large"));
        if s[2].saturating_mul(s[3]) > 1 << 28 {
            return Err(too_big());
        }
        let width = u32::try_from(s[2]).map_err(|_| too_big())?;
        let height = u32::try_from(s[3]).map_err(|_| too_big())?;
        let len = usize::try_from(s[0]).map_err(|_| too_big())?;
        Ok(NyuMat {
            path: path.to_path_buf(),
            images,
            depths,
            labels,
            len,
            width,
            height,
            map894: default_894_to_40(),
        })
    }

    /// The file's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Number of images.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the file holds no image.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The id of image `index` (0-based): its 1-based index on 6 digits.
    pub fn id(index: usize) -> String {
        format!("{:06}", index + 1)
    }

    /// Loads image `index` (0-based: id `000433` is index 432).
    pub fn load(&self, index: usize) -> Result<NyuItem> {
        let id = Self::id(index);
        if index >= self.len {
            return Err(Error::invalid(
                &self.path,
                format!("image {id} out of range: the file has {} images", self.len),
            ));
        }
        let (w, h) = (self.width as usize, self.height as usize);
        let n = w * h;
        let bad = |name: &str, msg: String| {
            Error::invalid(&self.path, format!("dataset '{name}', image {id}: {msg}"))
        };
        // One image: the window of one row along the first (image) axis.
        fn check<T>(v: Result<Vec<T>, hdf5_pure::Error>, len: usize) -> Result<Vec<T>, String> {
            match v {
                Ok(v) if v.len() == len => Ok(v),
                Ok(v) => Err(format!("read {} values, expected {len}", v.len())),
                Err(e) => Err(e.to_string()),
            }
        }
        let row = index as u64;

        let planes =
            check(self.images.read_u8_rows(row, 1), 3 * n).map_err(|m| bad("images", m))?;
        let mut rgb = vec![0u8; 3 * n];
        for (c, plane) in planes.chunks_exact(n).enumerate() {
            for (k, v) in to_row_major(plane, w, h).into_iter().enumerate() {
                rgb[3 * k + c] = v;
            }
        }
        let rgb = RgbImage::from_raw(self.width, self.height, rgb)
            .ok_or_else(|| bad("images", "image size overflows".into()))?;

        let depth = check(self.depths.read_f32_rows(row, 1), n).map_err(|m| bad("depths", m))?;
        let depth = DepthImage {
            width: self.width,
            height: self.height,
            data: to_row_major(&depth, w, h)
                .into_iter()
                .map(|d| if d.is_finite() && d > 0.0 { d } else { 0.0 })
                .collect(),
        };

        let ids = check(self.labels.read_u16_rows(row, 1), n).map_err(|m| bad("labels", m))?;
        let ids = to_row_major(&ids, w, h);
        let labels =
            super::nyu::map_894_to_40(&ids, w, &self.map894).map_err(|m| bad("labels", m))?;

        Ok(NyuItem {
            id,
            rgb,
            depth: Some(depth),
            labels: LabelImage {
                width: self.width,
                height: self.height,
                data: labels,
            },
        })
    }
}

/// A `w x h` image stored column by column (MATLAB order: `x * h + y`) in row-major order.
fn to_row_major<T: Copy + Default>(cols: &[T], w: usize, h: usize) -> Vec<T> {
    let mut out = vec![T::default(); w * h];
    for (x, col) in cols.chunks_exact(h).take(w).enumerate() {
        for (y, &v) in col.iter().enumerate() {
            out[y * w + x] = v;
        }
    }
    out
}
