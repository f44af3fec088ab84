//! The official NYUv2 `.mat` file (MATLAB v7.3 = HDF5) read directly: the h5py-made fixture
//! (scripts/nyu_mat_fixture.py) against the PNG fixture it was made from, split lists, the
//! MATLAB axis order on a tiny file, and errors on bad input.

mod common;

use hdf5_pure::FileBuilder;
use sdf_slam::dataset::{NyuDataset, NyuMat};
use std::path::Path;
use std::time::Instant;

const MAT: &str = "datasets/fixtures/nyuv2_mat/nyu_depth_v2_labeled_fixture.mat";
const PNG: &str = "datasets/fixtures/nyuv2";
const TEST_SPLIT: &str = "datasets/meta/nyuv2/splits_test_1based.txt";

fn tmp(name: &str) -> common::ScratchDir {
    common::fresh_dir("nyu_mat", name)
}

#[test]
fn mat_images_equal_the_png_fixture() {
    // The standard test split holds 433 and 464 (at lines 169 and 182).
    let mat = NyuDataset::open(MAT, Some(Path::new(TEST_SPLIT))).unwrap();
    assert_eq!(mat.len(), 654);
    let png = NyuDataset::open(PNG, None).unwrap();
    for (m, p) in [(168, 0), (181, 1)] {
        let t = Instant::now();
        let a = mat.load(m).unwrap();
        eprintln!("loaded {} from the .mat fixture in {:?}", a.id, t.elapsed());
        let b = png.load(p).unwrap();
        assert_eq!(a.id, b.id);
        assert_eq!(a.rgb.dimensions(), (640, 480));
        assert!(a.rgb == b.rgb, "{}: RGB differs", a.id);
        assert!(a.labels == b.labels, "{}: labels differ", a.id);
        let (da, db) = (a.depth.unwrap(), b.depth.unwrap());
        assert_eq!((da.width, da.height), (db.width, db.height));
        for (x, y) in da.data.iter().zip(&db.data) {
            assert!((x - y).abs() <= 1.0 / 5000.0 && (*x == 0.0) == (*y == 0.0));
        }
    }
}

#[test]
fn split_lists_select_1based_indices() {
    let all = NyuDataset::open(MAT, None).unwrap();
    assert_eq!(all.len(), 1449);
    assert_eq!(
        (all.samples[0].id.as_str(), all.samples[1448].id.as_str()),
        ("000001", "001449")
    );
    let d = tmp("split");
    std::fs::write(d.join("s.txt"), "464\n000433\n2000\n").unwrap();
    let ds = NyuDataset::open(MAT, Some(&d.join("s.txt"))).unwrap();
    let ids: Vec<&str> = ds.samples.iter().map(|s| s.id.as_str()).collect();
    assert_eq!(ids, ["000464", "000433"]);
    let png = NyuDataset::open(PNG, None).unwrap();
    assert!(ds.load(1).unwrap().labels == png.load(0).unwrap().labels);
    // An image without data (unwritten chunks) reads as zeros: black, void, no depth.
    let blank = all.load(0).unwrap();
    assert!(blank.rgb.as_raw().iter().all(|&v| v == 0));
    assert!(blank.labels.data.iter().all(|&v| v == 255));
    assert_eq!(blank.depth.unwrap().valid_fraction(), 0.0);
}

const W: u64 = 4;
const H: u64 = 3;

/// A 2-image file of 4x3 pixels with MATLAB's axis order; `labels` adds the labels dataset.
fn tiny(path: &Path, labels: impl FnOnce(&mut FileBuilder)) {
    let mut b = FileBuilder::new();
    b.with_userblock(512);
    b.with_userblock_content(b"MATLAB 7.3 MAT-file");
    let mut img = Vec::new();
    for i in 0..2 {
        for c in 0..3 {
            for x in 0..W {
                for y in 0..H {
                    img.push((i * 100 + c * 30 + x * 5 + y) as u8);
                }
            }
        }
    }
    let mut depth: Vec<f32> = (0..2 * W * H).map(|k| 0.5 + k as f32 / 10.0).collect();
    depth[W as usize * H as usize + 1] = f32::NAN; // image 1, x 0, y 1
    depth[W as usize * H as usize + H as usize] = -1.0; // image 1, x 1, y 0
    b.create_dataset("images")
        .with_u8_data(&img)
        .with_shape(&[2, 3, W, H])
        .with_chunks(&[1, 2, 3, 2])
        .with_deflate(6);
    b.create_dataset("depths")
        .with_f32_data(&depth)
        .with_shape(&[2, W, H])
        .with_chunks(&[2, 3, 2])
        .with_deflate(6);
    labels(&mut b);
    b.write(path).unwrap();
}

/// 894-class ids 0 (unlabelled), 1 (book), 3 (cabinet), 4 (ceiling) at (x + y) % 4.
const IDS: [u16; 4] = [0, 1, 3, 4];
const IDS40: [u8; 4] = [255, 39, 2, 21];

fn labels_u16(b: &mut FileBuilder) {
    let l: Vec<u16> = (0..2 * W * H)
        .map(|k| IDS[((k % (W * H)) / H + k % H) as usize % 4])
        .collect();
    b.create_dataset("labels")
        .with_u16_data(&l)
        .with_shape(&[2, W, H])
        .with_chunks(&[1, 4, 3])
        .with_deflate(6);
}

#[test]
fn matlab_axes_are_transposed_to_row_major() {
    let d = tmp("axes");
    let p = d.join("tiny.mat");
    tiny(&p, labels_u16);
    let mat = NyuMat::open(&p).unwrap();
    assert_eq!(mat.len(), 2);
    let a = mat.load(1).unwrap();
    assert_eq!(a.id, "000002");
    assert_eq!(a.rgb.dimensions(), (W as u32, H as u32));
    let depth = a.depth.unwrap();
    for x in 0..W as u32 {
        for y in 0..H as u32 {
            let px = a.rgb.get_pixel(x, y).0;
            let want = [0, 30, 60].map(|c| (100 + c + x * 5 + y) as u8);
            assert_eq!(px, want, "({x}, {y})");
            assert_eq!(a.labels.get(x, y), IDS40[(x + y) as usize % 4]);
            let k = (W * H) as u32 + x * H as u32 + y;
            let want = if k == 13 || k == 15 {
                0.0
            } else {
                0.5 + k as f32 / 10.0
            };
            assert_eq!(depth.data[(y * W as u32 + x) as usize], want, "({x}, {y})");
        }
    }
}

fn err(p: &Path) -> String {
    NyuDataset::open(p, None).unwrap_err().to_string()
}

#[test]
fn bad_files_are_clear_errors() {
    let d = tmp("bad");
    let p = d.join("text.mat");
    std::fs::write(&p, "MATLAB 5.0 MAT-file, not HDF5").unwrap();
    let e = err(&p);
    assert!(
        e.contains("text.mat") && e.contains("not a MATLAB v7.3 (HDF5) file"),
        "{e}"
    );
    let e = err(&d.join("missing.mat"));
    assert!(e.contains("missing.mat") && e.contains("no such"), "{e}");

    let p = d.join("no_labels.mat");
    tiny(&p, |_| {});
    let e = err(&p);
    assert!(
        e.contains("no_labels.mat") && e.contains("dataset 'labels'"),
        "{e}"
    );

    let p = d.join("shape.mat");
    tiny(&p, |b| {
        b.create_dataset("labels")
            .with_u16_data(&[0; 2 * 3 * 4])
            .with_shape(&[2, 3, 4]);
    });
    let e = err(&p);
    assert!(
        e.contains("shape.mat") && e.contains("'labels': shape [2, 3, 4] does not match"),
        "{e}"
    );

    let p = d.join("type.mat");
    tiny(&p, |b| {
        b.create_dataset("labels")
            .with_f32_data(&[0.0; 2 * 4 * 3])
            .with_shape(&[2, 4, 3]);
    });
    let e = err(&p);
    assert!(
        e.contains("type.mat") && e.contains("'labels': type f32, expected u16"),
        "{e}"
    );

    let p = d.join("ids.mat");
    tiny(&p, |b| {
        let mut l = [0u16; 2 * 4 * 3];
        l[4 * 3 + 2 * 3 + 1] = 1000; // image 1, x 2, y 1
        b.create_dataset("labels")
            .with_u16_data(&l)
            .with_shape(&[2, 4, 3]);
    });
    let ds = NyuDataset::open(&p, None).unwrap();
    assert!(ds.load(0).is_ok());
    let e = ds.load(1).unwrap_err().to_string();
    assert!(
        e.contains("ids.mat")
            && e.contains("image 000002")
            && e.contains("label 1000 at pixel (2, 1)"),
        "{e}"
    );
    let e = ds.load(2).unwrap_err().to_string();
    assert!(e.contains("ids.mat") && e.contains("out of range"), "{e}");
    let e = NyuMat::open(&p).unwrap().load(7).unwrap_err().to_string();
    assert!(
        e.contains("ids.mat") && e.contains("image 000008 out of range"),
        "{e}"
    );

    // A truncated file: an error naming the file, at open or at load, never a panic.
    let bytes = std::fs::read(MAT).unwrap();
    let p = d.join("truncated.mat");
    std::fs::write(&p, &bytes[..bytes.len() / 2]).unwrap();
    let e = match NyuDataset::open(&p, Some(Path::new(TEST_SPLIT))) {
        Ok(ds) => ds.load(181).and(ds.load(168)).unwrap_err(),
        Err(e) => e,
    };
    assert!(e.to_string().contains("truncated.mat"), "{e}");
}
