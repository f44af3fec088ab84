//! ImageNet initialisation of SDFCNN's encoder: MobileNetV2-1.0 weights in torchvision's
//! names (`features.0.0.weight` … `features.17.conv.3.running_var`), read from a safetensors
//! file with `burn::store`. The paper, like Light-Weight RefineNet, starts its encoder from
//! ImageNet; the decoder and the judge layers keep their random initialisation.
//!
//! The name mapping lives here, in one table (`torchvision_names`), apart from the
//! architecture (`model.rs`):
//!
//! | SDFCNN (Table 13) | torchvision `features.N` |
//! |---|---|
//! | `layer1` (conv 3×3 s2, BN) | `0.0`, `0.1` |
//! | `layer2` block 0: depthwise, projection | `1.conv.0.0`, `1.conv.0.1`; `1.conv.1`, `1.conv.2` |
//! | `layer3` … `layer7_320` block *b*: expansion, depthwise, projection | `N.conv.0.0/0.1`, `N.conv.1.0/1.1`, `N.conv.2/3`, N = 2 … 17 |
//!
//! torchvision's block 1 has no expansion convolution (t = 1); ours keeps one (Table 13,
//! Layer2_1), which starts as the identity (1×1 identity weights, batch norm with unit
//! variance and zero mean): its input is already ReLU6-clipped, so the ImageNet network is
//! reproduced exactly up to BN's ε. `features.18` (the 320→1280 head conv) has no counterpart
//! in SDFCNN and is ignored, as are batch norm's `num_batches_tracked` counters; any other
//! tensor the table does not name, a missing tensor, one of another shape, of a non-float
//! type or holding a value that is not finite (or, F64, beyond f32's range) is an error
//! naming the tensor and the file. F16, BF16 and F64 tensors are converted to F32.

use burn::module::Param;
use burn::prelude::*;
use burn::store::burn_pack::{Bytes, DType, Tensor as PackTensor};
use burn::store::{ModuleSnapshot, ModuleStore, SafetensorsStore};
use burn::tensor::{bf16, f16};
use std::collections::BTreeMap;
use std::path::Path;

use super::Sdfcnn;
use super::model::ENCODER;
use crate::error::{Error, Result};

/// torchvision tensors with no counterpart in SDFCNN (the 1280-channel head), ignored.
const IGNORED_PREFIX: &str = "features.18.";
/// Batch norm's step counters (I64 scalars), which a file saved straight from torchvision's
/// `state_dict` holds; SDFCNN's batch norm keeps none, so they are ignored.
const IGNORED_SUFFIX: &str = ".num_batches_tracked";

/// What [`load_imagenet`] did.
#[derive(Debug, Clone, PartialEq)]
pub struct ImagenetLoad {
    /// Tensors copied into the encoder.
    pub loaded: usize,
    /// File tensors ignored (`features.18.*`, `*.num_batches_tracked`).
    pub ignored: Vec<String>,
}

/// `(SDFCNN path, torchvision name)` of every encoder tensor that has an ImageNet value.
pub(crate) fn torchvision_names() -> Vec<(String, String)> {
    let mut out = Vec::new();
    let mut conv_bn = |ours: &str, conv: &str, bn: &str| {
        out.push((format!("{ours}.conv.weight"), format!("{conv}.weight")));
        for (o, t) in [
            ("gamma", "weight"),
            ("beta", "bias"),
            ("running_mean", "running_mean"),
            ("running_var", "running_var"),
        ] {
            out.push((format!("{ours}.bn.{o}"), format!("{bn}.{t}")));
        }
    };
    conv_bn("layer1", "features.0.0", "features.0.1");
    let stages = [
        "layer2",
        "layer3",
        "layer4",
        "layer5",
        "layer6",
        "layer7",
        "layer7_320",
    ];
    let mut feature = 1;
    for (stage, &(expansion, _, blocks, _)) in stages.iter().zip(ENCODER.iter()) {
        for b in 0..blocks {
            let ours = format!("{stage}.blocks.{b}");
            let f = format!("features.{feature}.conv");
            if expansion == 1 {
                // torchvision: [dw conv-BN-ReLU6, project conv, BN]; our expansion is identity.
                conv_bn(
                    &format!("{ours}.depthwise"),
                    &format!("{f}.0.0"),
                    &format!("{f}.0.1"),
                );
                conv_bn(
                    &format!("{ours}.project"),
                    &format!("{f}.1"),
                    &format!("{f}.2"),
                );
            } else {
                conv_bn(
                    &format!("{ours}.expand"),
                    &format!("{f}.0.0"),
                    &format!("{f}.0.1"),
                );
                conv_bn(
                    &format!("{ours}.depthwise"),
                    &format!("{f}.1.0"),
                    &format!("{f}.1.1"),
                );
                conv_bn(
                    &format!("{ours}.project"),
                    &format!("{f}.2"),
                    &format!("{f}.3"),
                );
            }
            feature += 1;
        }
    }
    out
}

/// Copies the ImageNet MobileNetV2 weights of the safetensors file `path` into `model`'s
/// encoder (see the module docs) and makes Layer2's expansion the identity.
pub fn load_imagenet(mut model: Sdfcnn, path: &Path) -> Result<(Sdfcnn, ImagenetLoad)> {
    let mut store = SafetensorsStore::from_file(path);
    let file: BTreeMap<String, PackTensor> = store
        .get_all_tensors()
        .map_err(|e| Error::invalid(path, format!("cannot read safetensors: {e}")))?
        .clone();
    let ours: BTreeMap<String, Vec<usize>> = model
        .collect(None, None, false)
        .into_iter()
        .map(|t| (t.name.clone(), t.shape.to_vec()))
        .collect();
    let table = torchvision_names();
    let mut renamed = Vec::with_capacity(table.len());
    for (our, theirs) in &table {
        let t = file.get(theirs).ok_or_else(|| {
            Error::invalid(
                path,
                format!("tensor {theirs} (for SDFCNN's {our}) is missing from this file"),
            )
        })?;
        let want = ours.get(our).ok_or_else(|| {
            Error::msg(format!(
                "SDFCNN has no tensor {our}: the ImageNet name table is out of date"
            ))
        })?;
        if t.shape.as_slice() != want.as_slice() {
            return Err(Error::invalid(
                path,
                format!(
                    "tensor {theirs} has shape {:?}, SDFCNN's {our} needs {want:?}",
                    t.shape.as_slice()
                ),
            ));
        }
        let values = float_values(t, theirs, path)?;
        let bytes = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        renamed.push(PackTensor::new(
            our.clone(),
            DType::F32,
            t.shape.clone(),
            t.param_id,
            Bytes::from_bytes_vec(bytes),
        ));
    }
    let named: std::collections::HashSet<&str> = table.iter().map(|(_, t)| t.as_str()).collect();
    let mut ignored = Vec::new();
    for name in file.keys() {
        if named.contains(name.as_str()) {
            continue;
        }
        if name.starts_with(IGNORED_PREFIX) || name.ends_with(IGNORED_SUFFIX) {
            ignored.push(name.clone());
        } else {
            return Err(Error::invalid(
                path,
                format!(
                    "unexpected tensor {name}: not part of torchvision's MobileNetV2 feature \
                     extractor as SDFCNN reads it"
                ),
            ));
        }
    }
    let result = model.apply(renamed, None, None, false);
    if !result.errors.is_empty() || result.applied.len() != table.len() {
        return Err(Error::invalid(
            path,
            format!(
                "applied {} of {} ImageNet tensors: {:?}",
                result.applied.len(),
                table.len(),
                result.errors
            ),
        ));
    }
    model = model.with_identity_layer2_expansion();
    Ok((
        model,
        ImagenetLoad {
            loaded: table.len(),
            ignored,
        },
    ))
}

/// The values of the file's tensor `theirs` as `f32`. torchvision's weights are F32; F16,
/// BF16 and F64 files are converted. Another element type, a byte length that does not fit
/// the shape, or a value that is not finite is an error naming the tensor and the file.
fn float_values(t: &PackTensor, theirs: &str, path: &Path) -> Result<Vec<f32>> {
    let bytes = t
        .to_bytes()
        .map_err(|e| Error::invalid(path, format!("tensor {theirs}: cannot read its data: {e}")))?;
    let b: &[u8] = &bytes;
    let values: Vec<f32> = match t.dtype {
        DType::F32 => b
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect(),
        DType::F64 => {
            let wide: Vec<f64> = b
                .chunks_exact(8)
                .map(|c| f64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]))
                .collect();
            if let Some(v) = wide
                .iter()
                .find(|v| v.is_finite() && v.abs() > f32::MAX as f64)
            {
                return Err(Error::invalid(
                    path,
                    format!("tensor {theirs} holds {v}, beyond the range of f32"),
                ));
            }
            wide.into_iter().map(|v| v as f32).collect()
        }
        DType::F16 => b
            .chunks_exact(2)
            .map(|c| f16::from_bits(u16::from_le_bytes([c[0], c[1]])).to_f32())
            .collect(),
        DType::BF16 => b
            .chunks_exact(2)
            .map(|c| bf16::from_bits(u16::from_le_bytes([c[0], c[1]])).to_f32())
            .collect(),
        other => {
            return Err(Error::invalid(
                path,
                format!(
                    "tensor {theirs} holds {other:?} values; SDFCNN's weights are read from \
                     F32, F16, BF16 or F64 tensors"
                ),
            ));
        }
    };
    let want = t.shape.num_elements();
    if values.len() != want || b.len() != want * t.dtype.size() {
        return Err(Error::invalid(
            path,
            format!(
                "tensor {theirs} holds {} bytes, its shape {:?} of {:?} needs {}",
                b.len(),
                t.shape.as_slice(),
                t.dtype,
                want * t.dtype.size()
            ),
        ));
    }
    if let Some(i) = values.iter().position(|v| !v.is_finite()) {
        return Err(Error::invalid(
            path,
            format!(
                "tensor {theirs} holds a value that is not finite ({} at element {i})",
                values[i]
            ),
        ));
    }
    Ok(values)
}

/// An identity 1×1 convolution weight `[c, c, 1, 1]`.
pub(crate) fn identity_1x1(weight: Param<Tensor<4>>) -> Param<Tensor<4>> {
    weight.map(|w| {
        let [c, _, _, _] = w.dims();
        let device = w.device();
        Tensor::<2>::eye(c, &device).reshape([c, c, 1, 1])
    })
}

/// Pearson correlation, over the channels, between each batch norm's input mean on a batch
/// and its stored running mean (`BnProbe`s of [`Sdfcnn::encoder_bn_probe`]). Trained weights
/// in the right layers give r near 1 on natural images; a tensor in the wrong layer, or random
/// weights, give r near 0. Batch norms whose running means are all equal (Layer2's identity
/// expansion) are left out.
pub fn bn_agreement(probes: &[super::BnProbe]) -> Vec<(String, f64)> {
    probes
        .iter()
        .filter_map(|p| pearson(&p.batch_mean, &p.running_mean).map(|r| (p.name.clone(), r)))
        .collect()
}

/// Pearson's r of two equally long series; `None` when either is constant.
fn pearson(a: &[f32], b: &[f32]) -> Option<f64> {
    let n = a.len().min(b.len());
    if n < 2 {
        return None;
    }
    let mean = |v: &[f32]| v[..n].iter().map(|&x| x as f64).sum::<f64>() / n as f64;
    let (ma, mb) = (mean(a), mean(b));
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for i in 0..n {
        let (x, y) = (a[i] as f64 - ma, b[i] as f64 - mb);
        sab += x * y;
        saa += x * x;
        sbb += y * y;
    }
    (saa > 0.0 && sbb > 0.0).then(|| sab / (saa * sbb).sqrt())
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::sdfcnn::SdfcnnConfig;
    use burn::store::ModuleSnapshot;

    /// torchvision MobileNetV2's feature-extractor tensor shapes, as the real file has them.
    fn torchvision_shapes() -> Vec<(String, Vec<usize>)> {
        let mut out = Vec::new();
        let mut conv_bn = |conv: String, bn: String, shape: Vec<usize>| {
            let c = shape[0];
            out.push((format!("{conv}.weight"), shape));
            for t in ["weight", "bias", "running_mean", "running_var"] {
                out.push((format!("{bn}.{t}"), vec![c]));
            }
        };
        conv_bn(
            "features.0.0".into(),
            "features.0.1".into(),
            vec![32, 3, 3, 3],
        );
        let mut input = 32;
        let mut f = 1;
        for &(t, c, n, _) in ENCODER.iter() {
            for _ in 0..n {
                let hidden = input * t;
                let p = format!("features.{f}.conv");
                if t == 1 {
                    conv_bn(
                        format!("{p}.0.0"),
                        format!("{p}.0.1"),
                        vec![hidden, 1, 3, 3],
                    );
                    conv_bn(format!("{p}.1"), format!("{p}.2"), vec![c, hidden, 1, 1]);
                } else {
                    conv_bn(
                        format!("{p}.0.0"),
                        format!("{p}.0.1"),
                        vec![hidden, input, 1, 1],
                    );
                    conv_bn(
                        format!("{p}.1.0"),
                        format!("{p}.1.1"),
                        vec![hidden, 1, 3, 3],
                    );
                    conv_bn(format!("{p}.2"), format!("{p}.3"), vec![c, hidden, 1, 1]);
                }
                input = c;
                f += 1;
            }
        }
        conv_bn(
            "features.18.0".into(),
            "features.18.1".into(),
            vec![1280, 320, 1, 1],
        );
        out
    }

    /// Writes a safetensors file whose tensor `k` is filled with `(k + 1) / 1000`.
    fn write_safetensors(path: &Path, tensors: &[(String, Vec<usize>)]) {
        write_typed(path, tensors, &[], None);
    }

    /// [`write_safetensors`] with the tensors named in `types` stored as that safetensors
    /// dtype (F32, F64, F16, BF16 or I64), and the first value of `nan` NaN.
    fn write_typed(
        path: &Path,
        tensors: &[(String, Vec<usize>)],
        types: &[(&str, &str)],
        nan: Option<&str>,
    ) {
        let mut header = serde_json::Map::new();
        let mut data = Vec::new();
        for (k, (name, shape)) in tensors.iter().enumerate() {
            let n: usize = shape.iter().product();
            let start = data.len();
            let dtype = types
                .iter()
                .find(|(t, _)| t == name)
                .map_or("F32", |(_, d)| *d);
            for i in 0..n {
                let mut v = (k + 1) as f32 / 1000.0;
                if i == 0 && nan == Some(name.as_str()) {
                    v = f32::NAN;
                }
                match dtype {
                    "F64" => data.extend_from_slice(&(v as f64).to_le_bytes()),
                    "F16" => data.extend_from_slice(&f16::from_f32(v).to_le_bytes()),
                    "BF16" => data.extend_from_slice(&bf16::from_f32(v).to_le_bytes()),
                    "I64" => data.extend_from_slice(&(k as i64).to_le_bytes()),
                    _ => data.extend_from_slice(&v.to_le_bytes()),
                }
            }
            header.insert(
                name.clone(),
                serde_json::json!({"dtype": dtype, "shape": shape, "data_offsets": [start, data.len()]}),
            );
        }
        let mut json = serde_json::to_vec(&header).expect("json");
        while !json.len().is_multiple_of(8) {
            json.push(b' ');
        }
        let mut bytes = (json.len() as u64).to_le_bytes().to_vec();
        bytes.extend_from_slice(&json);
        bytes.extend_from_slice(&data);
        std::fs::write(path, bytes).expect("write safetensors");
    }

    /// A torchvision-named MobileNetV2 file of made-up values (tensor `k` = `(k + 1) / 1000`).
    pub(crate) fn write_fake_imagenet(path: &Path) {
        write_safetensors(path, &torchvision_shapes());
    }

    fn tmp(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("sdf_imagenet_{name}_{}", std::process::id()));
        std::fs::create_dir_all(&d).expect("temp dir");
        d.join("mnv2.safetensors")
    }

    use std::path::PathBuf;

    fn values(model: &Sdfcnn) -> BTreeMap<String, Vec<f32>> {
        model
            .collect(None, None, false)
            .into_iter()
            .map(|t| {
                let bytes = t.to_bytes().expect("bytes");
                let v = bytes
                    .chunks_exact(4)
                    .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                    .collect();
                (t.name.clone(), v)
            })
            .collect()
    }

    fn model() -> Sdfcnn {
        SdfcnnConfig::new()
            .with_inner_size([32, 32])
            .init(&Device::flex())
            .expect("valid")
    }

    #[test]
    fn every_tensor_lands_in_its_layer() {
        let shapes = torchvision_shapes();
        assert_eq!(shapes.len(), 260, "the real file's tensor count");
        let path = tmp("ok");
        write_safetensors(&path, &shapes);
        let (m, report) = load_imagenet(model(), &path).expect("loads");
        assert_eq!(report.loaded, 255);
        assert_eq!(report.ignored.len(), 5);
        let got = values(&m);
        let index: BTreeMap<&str, usize> = shapes
            .iter()
            .enumerate()
            .map(|(k, (n, _))| (n.as_str(), k))
            .collect();
        for (ours, theirs) in torchvision_names() {
            let want = (index[theirs.as_str()] + 1) as f32 / 1000.0;
            assert!(
                got[&ours].iter().all(|&v| v == want),
                "{ours} should hold {theirs}"
            );
        }
        // Layer2's expansion is the identity; the decoder keeps its own weights.
        let eye = &got["layer2.blocks.0.expand.conv.weight"];
        assert_eq!(eye.len(), 32 * 32);
        for (i, &v) in eye.iter().enumerate() {
            assert_eq!(v, if i / 32 == i % 32 { 1.0 } else { 0.0 });
        }
        assert_eq!(got["layer2.blocks.0.expand.bn.running_var"], vec![1.0; 32]);
        assert!(
            got["conv8.weight"]
                .iter()
                .any(|&v| v != got["conv8.weight"][0])
        );
        std::fs::remove_dir_all(path.parent().expect("dir")).ok();
    }

    #[test]
    fn missing_extra_and_misshaped_tensors_are_named() {
        let mut shapes = torchvision_shapes();
        type Edit = Box<dyn Fn(&mut Vec<(String, Vec<usize>)>)>;
        let cases: Vec<(&str, Edit)> = vec![
            (
                "features.7.conv.1.1.running_mean",
                Box::new(|s| s.retain(|(n, _)| n != "features.7.conv.1.1.running_mean")),
            ),
            (
                "classifier.1.weight",
                Box::new(|s| s.push(("classifier.1.weight".into(), vec![1000, 1280]))),
            ),
            (
                "features.3.conv.2.weight",
                Box::new(|s| {
                    for (n, shape) in s.iter_mut() {
                        if n == "features.3.conv.2.weight" {
                            *shape = vec![24, 144, 3, 3];
                        }
                    }
                }),
            ),
        ];
        for (k, (name, edit)) in cases.iter().enumerate() {
            let mut s = shapes.clone();
            edit(&mut s);
            let path = tmp(&format!("bad{k}"));
            write_safetensors(&path, &s);
            let e = load_imagenet(model(), &path).expect_err(name).to_string();
            assert!(
                e.contains(name) && e.contains("mnv2.safetensors"),
                "{name}: {e}"
            );
            std::fs::remove_dir_all(path.parent().expect("dir")).ok();
        }
        shapes.clear();
    }

    #[test]
    fn half_and_double_tensors_are_converted_and_other_types_or_nan_named() {
        let shapes = torchvision_shapes();
        let index: BTreeMap<&str, usize> = shapes
            .iter()
            .enumerate()
            .map(|(k, (n, _))| (n.as_str(), k))
            .collect();
        let types = [
            ("features.0.0.weight", "F16"),
            ("features.5.conv.1.0.weight", "BF16"),
            ("features.17.conv.3.running_var", "F64"),
        ];
        let path = tmp("typed");
        // torchvision's state_dict also holds batch norm's I64 step counters: ignored.
        let mut with_counter = shapes.clone();
        with_counter.push(("features.3.conv.0.1.num_batches_tracked".into(), vec![]));
        let mut counter_types = types.to_vec();
        counter_types.push(("features.3.conv.0.1.num_batches_tracked", "I64"));
        write_typed(&path, &with_counter, &counter_types, None);
        let (loaded, report) = load_imagenet(model(), &path).expect("F16, BF16 and F64 convert");
        assert!(
            report
                .ignored
                .iter()
                .any(|n| n.ends_with(".num_batches_tracked"))
        );
        let got = values(&loaded);
        for (ours, theirs) in torchvision_names() {
            if let Some((_, dtype)) = types.iter().find(|(t, _)| *t == theirs) {
                let want = (index[theirs.as_str()] + 1) as f32 / 1000.0;
                let tol = if *dtype == "F64" { 1e-7 } else { want / 100.0 };
                assert!(
                    got[&ours].iter().all(|&v| (v - want).abs() <= tol),
                    "{ours} from {dtype}: {:?} against {want}",
                    &got[&ours][..2]
                );
            }
        }
        // (tensor types, the tensor given a NaN, what the error says)
        type BadCase<'a> = (&'a [(&'a str, &'a str)], Option<&'a str>, &'a str);
        let bad: [BadCase; 3] = [
            (&[("features.9.conv.1.0.weight", "I64")], None, "I64"),
            (&[], Some("features.12.conv.0.1.running_var"), "not finite"),
            (
                &[("features.2.conv.0.1.weight", "F16")],
                Some("features.2.conv.0.1.weight"),
                "not finite",
            ),
        ];
        for (k, (types, nan, what)) in bad.iter().enumerate() {
            write_typed(&path, &shapes, types, *nan);
            let name = nan.unwrap_or_else(|| types[0].0);
            let e = load_imagenet(model(), &path).expect_err(name).to_string();
            assert!(
                e.contains(name) && e.contains("mnv2.safetensors") && e.contains(what),
                "case {k}: {e}"
            );
        }
        std::fs::remove_dir_all(path.parent().expect("dir")).ok();
    }

    #[test]
    fn pearson_of_agreeing_and_constant_series() {
        assert!((pearson(&[1.0, 2.0, 3.0], &[2.0, 4.0, 6.5]).expect("r") - 0.9986).abs() < 1e-3);
        assert_eq!(pearson(&[1.0, 1.0], &[1.0, 2.0]), None);
    }
}
