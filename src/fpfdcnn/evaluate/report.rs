//! The report in words: the settings described, and the markdown tables.

use super::{ConditionResult, MatchingEvalConfig, MatchingReport, PairResult};

/// The range matcher's settings, e.g. "140 px window centred by a global affine motion
/// estimate, mutual, ratio 0.9".
pub fn describe_matcher(cfg: &MatchingEvalConfig) -> String {
    let mut s = format!(
        "{} px window {}",
        cfg.range.window,
        if cfg.guide.is_some() {
            "centred by a global affine motion estimate"
        } else {
            "centred at the keypoint"
        }
    );
    if cfg.range.mutual {
        s.push_str(", mutual");
    }
    if let Some(r) = cfg.range.ratio {
        s.push_str(&format!(", ratio {r}"));
        if cfg.range.ratio_exclusion_px > 0.0 {
            s.push_str(&format!(
                " against the nearest keypoint beyond {} px",
                cfg.range.ratio_exclusion_px
            ));
        }
    }
    if cfg.guide.is_some() && cfg.derotation.min_deg > 0.0 {
        s.push_str(&format!(
            "; FPFDCNN's image B turned back by a global roll of {} degrees or more",
            cfg.derotation.min_deg
        ));
    }
    if let Some(r) = &cfg.refine {
        s.push_str(&format!(
            "; {} matches refined by patch correlation ({}x{} patch, up to {} px, NCC >= {})",
            if cfg.refine_orb {
                "FPFDCNN's and ORB's"
            } else {
                "FPFDCNN's"
            },
            2 * r.patch_radius + 1,
            2 * r.patch_radius + 1,
            r.search_px,
            r.min_ncc
        ));
    }
    s
}

/// FPFDCNN's keypoint selection, e.g. "top 500, NMS 4 px, FP map and descriptors averaged
/// over 4 cell-grid placements, smoothed 2 px".
pub fn describe_detector(cfg: &crate::fpfdcnn::inference::DetectorConfig) -> String {
    let mut s = format!("top {}, NMS {} px", cfg.top_k, cfg.nms_radius);
    if cfg.input_scale != 1.0 {
        s.push_str(&format!(", image resized x{}", cfg.input_scale));
    }
    if cfg.grid_shifts > 1 {
        let what = if cfg.average_descriptors {
            "FP map and descriptors"
        } else {
            "FP map"
        };
        s.push_str(&format!(
            ", {what} averaged over {} cell-grid placements",
            cfg.grid_shifts
        ));
    }
    if cfg.grid_shifts == 1 && cfg.descriptor_spread > 0 {
        s.push_str(&format!(
            ", descriptors spread over +-{} px diagonals",
            cfg.descriptor_spread
        ));
    }
    if cfg.levels > 1 {
        s.push_str(&format!(
            ", {} pyramid levels x{}",
            cfg.levels, cfg.level_factor
        ));
    }
    if cfg.smoothing > 0.0 {
        s.push_str(&format!(", smoothed {} px", cfg.smoothing));
    }
    if cfg.subpixel_radius > 0 {
        s.push_str(&format!(
            ", refined to corners within {} px",
            cfg.subpixel_radius
        ));
    }
    s
}

/// Each pair's figures as a markdown table per condition: accuracy, the pair's common
/// offset and the share within 5 px of it, for each method (`eval matching --per-pair`).
pub fn per_pair_markdown(r: &MatchingReport) -> String {
    let mut methods = vec![("ORB + BF", &r.orb_bf)];
    if let Some(f) = &r.fpfdcnn_range {
        methods.push(("FPFDCNN + range", f));
    }
    let cell = |p: &PairResult| {
        let share = |n: usize| 100.0 * n as f64 / p.matches.max(1) as f64;
        let offset = p
            .offset_px
            .map_or("–".to_string(), |o| format!("{:+.1}, {:+.1}", o[0], o[1]));
        format!(
            "{:.1} % ({}/{}) | {offset} | {:.1} %",
            share(p.correct),
            p.correct,
            p.matches,
            share(p.within_offset)
        )
    };
    let mut s = String::new();
    for (scenario, blurred) in [("Clear", false), ("Blurred", true)] {
        let rows: Vec<&ConditionResult> = methods
            .iter()
            .filter_map(|(_, m)| {
                if blurred {
                    m.blurred.as_ref()
                } else {
                    Some(&m.clean)
                }
            })
            .collect();
        if rows.len() < methods.len() {
            continue;
        }
        s.push_str(&format!("\n{scenario} pairs\n\n| pair |"));
        for (name, _) in &methods {
            s.push_str(&format!(
                " {name}: accuracy | offset (px) | within 5 px of it |"
            ));
        }
        s.push_str(&format!(
            "\n|---|{}\n",
            "---|---|---|".repeat(methods.len())
        ));
        for (k, &(a, b)) in r.pairs.iter().enumerate() {
            s.push_str(&format!("| {a}-{b} |"));
            for c in &rows {
                match c.pairs.get(k) {
                    Some(p) => s.push_str(&format!(" {} |", cell(p))),
                    None => s.push_str(" – | – | – |"),
                }
            }
            s.push('\n');
        }
    }
    s
}

/// The report as markdown tables shaped like the paper's Tables 6 and 7.
pub fn markdown(r: &MatchingReport) -> String {
    let detector = if r.fpfdcnn_detector.is_empty() {
        String::new()
    } else {
        format!("; FPFDCNN keypoints: {}", r.fpfdcnn_detector)
    };
    let mut s = format!(
        "Sequence `{}`, {} pairs {} frames apart{}{}; range matcher: {}{detector}\n\n| Scenario | Method | Accuracy (correct / matches) | keypoints / image | % within 2 / 5 / 10 / 20 px | % within 5 px of the pair's offset | repeatability (3 px) | matching score |\n|---|---|---|---|---|---|---|---|\n",
        r.sequence,
        r.pairs.len(),
        r.gap,
        r.blur
            .as_ref()
            .map(|b| format!(", blur {b} on both images"))
            .unwrap_or_default(),
        if r.roll_deg != 0.0 {
            format!(", image B rolled by {} degrees", r.roll_deg)
        } else {
            String::new()
        },
        r.range_matcher
    );
    let mut methods = vec![("ORB + BF matcher", &r.orb_bf)];
    if let Some(f) = &r.fpfdcnn_range {
        methods.push(("FPFDCNN + range matcher", f));
    }
    let row = |s: &mut String, scen: &str, name: &str, c: &ConditionResult| {
        s.push_str(&format!(
            "| {scen} | {name} | {:.1} % ({}/{}) | {:.0} | {} | {:.1} % | {:.1} % | {:.1} % |\n",
            100.0 * c.accuracy,
            c.correct,
            c.matches,
            c.keypoints,
            c.within_px
                .iter()
                .map(|(_, f)| format!("{:.0}", 100.0 * f))
                .collect::<Vec<_>>()
                .join(" / "),
            100.0 * c.offset_removed_accuracy,
            100.0 * c.repeatability,
            100.0 * c.matching_score,
        ));
    };
    for (name, m) in &methods {
        row(&mut s, "Clear", name, &m.clean);
    }
    for (name, m) in &methods {
        if let Some(b) = &m.blurred {
            row(&mut s, "Blurred", name, b);
        }
    }
    if let Some(f) = &r.fpfdcnn_range {
        let turned: Vec<String> = std::iter::once(&f.clean)
            .chain(f.blurred.as_ref())
            .map(|c| c.derotated_pairs.to_string())
            .collect();
        if turned.iter().any(|t| t != "0") {
            s.push_str(&format!(
                "\nFPFDCNN's image B turned back by its estimated roll on {} of {} pairs ({}).\n",
                turned.join(" / "),
                r.pairs.len(),
                if turned.len() > 1 {
                    "clear / blurred"
                } else {
                    "clear"
                }
            ));
        }
    }
    for (name, m) in &methods {
        let counts: Vec<String> = std::iter::once(&m.clean)
            .chain(m.blurred.as_ref())
            .map(|c| c.refined_matches.to_string())
            .collect();
        if m.clean.refined_matches + m.blurred.as_ref().map_or(0, |b| b.refined_matches) > 0 {
            s.push_str(&format!(
                "\n{name}: matches moved by patch correlation {} ({}).\n",
                counts.join(" / "),
                if counts.len() > 1 {
                    "clear / blurred"
                } else {
                    "clear"
                }
            ));
        }
    }
    for (rates, what) in [
        (
            &r.harris_repeatability,
            "the strongest Harris corners, FPFDCNN's detector targets",
        ),
        (
            &r.adapted_repeatability,
            "Harris corners after homographic adaptation",
        ),
    ] {
        if rates.is_empty() {
            continue;
        }
        let rates: Vec<String> = rates
            .iter()
            .map(|v| format!("{:.1} %", 100.0 * v))
            .collect();
        s.push_str(&format!(
            "\nRepeatability (3 px) of {what}: {} ({}).\n",
            rates.join(" / "),
            if rates.len() > 1 {
                "clear / blurred"
            } else {
                "clear"
            }
        ));
    }
    s.push_str("\n| Scenario | Method | errT (%) | errR (deg/m) | rotation error (deg) | translation error (mm) | PnP failures |\n|---|---|---|---|---|---|---|\n");
    let f = |v: Option<f64>, k: f64, d: usize| {
        v.map(|x| format!("{:.*}", d, x * k))
            .unwrap_or_else(|| "-".into())
    };
    for (scen, blurred) in [("Clear", false), ("Blurred", true)] {
        for (name, m) in &methods {
            let c = if blurred {
                match &m.blurred {
                    Some(b) => b,
                    None => continue,
                }
            } else {
                &m.clean
            };
            s.push_str(&format!(
                "| {scen} | {name} | {} | {} | {} | {} | {} |\n",
                f(c.err_t_percent, 1.0, 2),
                f(c.err_r_deg_per_m, 1.0, 4),
                f(c.mean_rot_error_deg, 1.0, 3),
                f(c.mean_trans_error_m, 1000.0, 1),
                c.pnp_failures
            ));
        }
    }
    s
}
