//! The NYUv2 loader on real labelled images (datasets/fixtures/nyuv2) and the
//! segmentation / depth metrics on them.

mod common;

use sdf_slam::dataset::{LabelImage, NyuDataset};
use sdf_slam::metrics::{ConfusionMatrix, DepthAccumulator};
use std::path::Path;

const NYU: &str = "datasets/fixtures/nyuv2";

fn tmp(name: &str) -> common::ScratchDir {
    common::fresh_dir("nyu", name)
}

#[test]
fn flat_layout_with_depth_labels_and_palette_masks() {
    let ds = NyuDataset::open(NYU, None).unwrap();
    let ids: Vec<&str> = ds.samples.iter().map(|s| s.id.as_str()).collect();
    assert_eq!(ids, vec!["000433", "000464", "000834"]);
    let a = ds.load(0).unwrap();
    assert_eq!(a.rgb.dimensions(), (640, 480));
    let d = a.depth.as_ref().unwrap();
    assert!(d.valid_fraction() > 0.4 && d.valid_fraction() < 0.9);
    let classes: std::collections::BTreeSet<u8> = a.labels.data.iter().copied().collect();
    assert_eq!(
        classes.into_iter().collect::<Vec<_>>(),
        vec![0, 1, 8, 10, 21, 37, 38, 39, 255]
    );
    // The masks_only sample: palette PNG, indices read as stored, no depth.
    let m = ds.load(2).unwrap();
    assert!(m.depth.is_none());
    assert_eq!(m.rgb.dimensions(), (625, 468));
    assert!(m.labels.data.contains(&33) && m.labels.data.iter().all(|&v| v < 40 || v == 255));
}

#[test]
fn split_lists_by_index_and_id() {
    let d = tmp("split");
    std::fs::write(d.join("test.txt"), "433\n999\n").unwrap();
    let ds = NyuDataset::open(NYU, Some(&d.join("test.txt"))).unwrap();
    assert_eq!(ds.len(), 1);
    assert_eq!(ds.samples[0].id, "000433");
    std::fs::write(d.join("ids.txt"), "000464\n").unwrap();
    assert_eq!(
        NyuDataset::open(NYU, Some(&d.join("ids.txt")))
            .unwrap()
            .samples[0]
            .id,
        "000464"
    );
    std::fs::write(d.join("empty.txt"), "# nothing\n").unwrap();
    let e = NyuDataset::open(NYU, Some(&d.join("empty.txt")))
        .unwrap_err()
        .to_string();
    assert!(e.contains("empty.txt") && e.contains("no sample"), "{e}");
}

#[test]
fn folder_layout_and_bad_labels() {
    let d = tmp("folders");
    for sub in ["rgb", "depth", "labels"] {
        std::fs::create_dir_all(d.join(sub)).unwrap();
    }
    let src = Path::new(NYU);
    std::fs::copy(src.join("000433_rgb.png"), d.join("rgb/000001.png")).unwrap();
    std::fs::copy(src.join("000433_depth.png"), d.join("depth/000001.png")).unwrap();
    std::fs::copy(src.join("000433_seg40.png"), d.join("labels/000001.png")).unwrap();
    let ds = NyuDataset::open(&d, None).unwrap();
    assert_eq!(ds.len(), 1);
    assert!(ds.load(0).unwrap().depth.is_some());
    // A label value outside 0-39 and 255.
    let mut l = LabelImage::read_png(d.join("labels/000001.png")).unwrap();
    l.data[5 * 640 + 7] = 77;
    l.write_png(d.join("labels/000001.png")).unwrap();
    let e = ds.load(0).unwrap_err().to_string();
    assert!(
        e.contains("000001.png") && e.contains("label 77 at pixel (7, 5)"),
        "{e}"
    );
    // Depth of the wrong size.
    std::fs::copy(src.join("000433_seg40.png"), d.join("labels/000001.png")).unwrap();
    image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::new(64, 48)
        .save(d.join("depth/000001.png"))
        .unwrap();
    let e = ds.load(0).unwrap_err().to_string();
    assert!(e.contains("64x48"), "{e}");
    assert!(
        NyuDataset::open(tmp("none"), None)
            .unwrap_err()
            .to_string()
            .contains("no samples")
    );
}

#[test]
fn metrics_on_real_labels() {
    let ds = NyuDataset::open(NYU, None).unwrap();
    let a = ds.load(0).unwrap();
    // Perfect prediction (void pixels predicted as wall).
    let pred: Vec<u8> = a
        .labels
        .data
        .iter()
        .map(|&v| if v == 255 { 0 } else { v })
        .collect();
    let mut m = ConfusionMatrix::new(40);
    m.add(&a.labels.data, &pred);
    assert_eq!((m.mpa(), m.miou(), m.pixel_accuracy()), (1.0, 1.0, 1.0));
    // Predicting wall everywhere: MPA = 1/present classes, mIoU = wall share / classes.
    let mut m = ConfusionMatrix::new(40);
    m.add(&a.labels.data, &vec![0u8; pred.len()]);
    let present = m.per_class().iter().filter(|c| c.gt_pixels > 0).count();
    assert_eq!(present, 8);
    assert!((m.mpa() - 1.0 / 8.0).abs() < 1e-12);
    let d = a.depth.unwrap();
    let mut acc = DepthAccumulator::default();
    acc.add(&d.data, &d.data.iter().map(|v| v * 1.1).collect::<Vec<_>>());
    let r = acc.finish().unwrap();
    assert!((r.rel - 0.1).abs() < 1e-5 && r.delta1 == 1.0);
}

#[test]
fn the_894_to_40_table_maps_known_classes() {
    let map = sdf_slam::dataset::nyu::default_894_to_40();
    assert_eq!(map.len(), 895);
    assert_eq!(map[0], 255); // unlabelled -> void
    assert_eq!(map[1], 39); // book -> otherprop
    assert_eq!(map[3], 2); // cabinet -> cabinet
    assert_eq!(map[4], 21); // ceiling -> ceiling
}

/// 894-class labels need 16 bits (ids up to 894): `<id>_seg894.png` is read as 8- or 16-bit
/// greyscale and mapped to 40 classes; an id the table lacks is an error naming the pixel.
#[test]
fn sixteen_bit_894_class_labels_are_mapped_to_40() {
    let d = tmp("seg894");
    let src = Path::new(NYU);
    std::fs::copy(src.join("000433_rgb.png"), d.join("000001_rgb.png")).unwrap();
    std::fs::copy(src.join("000433_depth.png"), d.join("000001_depth.png")).unwrap();
    let map = sdf_slam::dataset::nyu::default_894_to_40();
    let (w, h) = (640u32, 480u32);
    // Every id of the table in turn, including ones above 255.
    let ids: Vec<u16> = (0..w * h).map(|k| (k % 895) as u16).collect();
    let save = |ids: &[u16]| {
        image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(w, h, ids.to_vec())
            .unwrap()
            .save(d.join("000001_seg894.png"))
            .unwrap()
    };
    save(&ids);
    let ds = NyuDataset::open(&d, None).unwrap();
    let labels = ds.load(0).unwrap().labels;
    assert!(
        map[300] != 255 || map[800] != 255,
        "the test needs ids above 255 that map"
    );
    for (k, &id) in ids.iter().enumerate() {
        assert_eq!(labels.data[k], map[id as usize], "pixel {k}, id {id}");
    }
    // An id beyond the table.
    let mut bad = ids.clone();
    bad[3 * 640 + 2] = 2000;
    save(&bad);
    let e = ds.load(0).unwrap_err().to_string();
    assert!(
        e.contains("000001_seg894.png") && e.contains("label 2000 at pixel (2, 3)"),
        "{e}"
    );
}
