//! The 40 NYUv2 classes of the semantic map: names from
//! `datasets/meta/nyuv2/nyu40_class_names.txt` and colours from the NYU40 palette
//! `nyu40_colormap_scannet.csv` (rows 1-40 are classes 0-39), both embedded.

use std::sync::OnceLock;

/// Number of semantic classes.
pub const NUM_CLASSES: usize = 40;
/// Label of a point without a class.
pub const VOID: u8 = crate::dataset::labels::VOID;

const NAMES_TXT: &str = include_str!("../../datasets/meta/nyuv2/nyu40_class_names.txt");
const PALETTE_CSV: &str = include_str!("../../datasets/meta/nyuv2/nyu40_colormap_scannet.csv");

struct Tables {
    names: Vec<String>,
    palette: [[u8; 3]; NUM_CLASSES],
}

fn tables() -> &'static Tables {
    static T: OnceLock<Tables> = OnceLock::new();
    T.get_or_init(|| {
        let mut names = vec![String::new(); NUM_CLASSES];
        for line in NAMES_TXT.lines() {
            let mut it = line.trim().splitn(2, char::is_whitespace);
            if let (Some(id), Some(name)) = (it.next(), it.next())
                && let Ok(id) = id.parse::<usize>()
                && (1..=NUM_CLASSES).contains(&id)
            {
                names[id - 1] = name.trim().to_string();
            }
        }
        let mut palette = [[128u8; 3]; NUM_CLASSES];
        for line in PALETTE_CSV.lines().skip(1) {
            let f: Vec<&str> = line.split(',').collect();
            if f.len() >= 5
                && let Ok(id) = f[0].trim().parse::<usize>()
                && (1..=NUM_CLASSES).contains(&id)
            {
                let c = |s: &str| s.trim().parse::<u8>().unwrap_or(128);
                palette[id - 1] = [c(f[2]), c(f[3]), c(f[4])];
            }
        }
        for (k, n) in names.iter_mut().enumerate() {
            if n.is_empty() {
                *n = format!("class {k}");
            }
        }
        Tables { names, palette }
    })
}

/// Name of a class (`"void"` for 255, `"label N"` beyond the 40 classes).
pub fn name(label: u8) -> String {
    match label as usize {
        l if l < NUM_CLASSES => tables().names[l].clone(),
        _ if label == VOID => "void".into(),
        l => format!("label {l}"),
    }
}

/// Display colour of a class (grey for void and unknown labels).
pub fn color(label: u8) -> [u8; 3] {
    match label as usize {
        l if l < NUM_CLASSES => tables().palette[l],
        _ => [128, 128, 128],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_and_palette_are_embedded() {
        assert_eq!(name(0), "wall");
        assert_eq!(name(1), "floor");
        assert_eq!(name(8), "window");
        assert_eq!(name(39), "otherprop");
        assert_eq!(name(255), "void");
        assert_eq!(color(0), [174, 199, 232]);
        assert_eq!(color(1), [152, 223, 138]);
    }
}
