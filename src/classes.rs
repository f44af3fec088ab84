//! The 40 NYUv2 semantic classes (Gupta et al. 2013 mapping of the 894 NYU labels),
//! 0-based as in the NYU PNG conversions: `0 = wall ... 39 = otherprop`, [`VOID`] = 255
//! for unlabelled pixels. Names from `nyu40_class_names.txt` (1-based there), colours
//! from the ScanNet NYU40 palette (`nyu40_colormap_scannet.csv`).

/// Number of semantic classes.
pub const NUM_CLASSES: usize = 40;

/// Label value of unlabelled / void pixels.
pub const VOID: u8 = 255;

/// Class names, indexed by the 0-based label.
pub const NYU40: [&str; NUM_CLASSES] = [
    "wall",
    "floor",
    "cabinet",
    "bed",
    "chair",
    "sofa",
    "table",
    "door",
    "window",
    "bookshelf",
    "picture",
    "counter",
    "blinds",
    "desk",
    "shelves",
    "curtain",
    "dresser",
    "pillow",
    "mirror",
    "floor mat",
    "clothes",
    "ceiling",
    "books",
    "refridgerator",
    "television",
    "paper",
    "towel",
    "shower curtain",
    "box",
    "whiteboard",
    "person",
    "night stand",
    "toilet",
    "sink",
    "lamp",
    "bathtub",
    "bag",
    "otherstructure",
    "otherfurniture",
    "otherprop",
];

/// Display colour of each class (ScanNet NYU40 palette), indexed by the 0-based label.
pub(crate) const PALETTE: [[u8; 3]; NUM_CLASSES] = [
    [174, 199, 232], // wall
    [152, 223, 138], // floor
    [31, 119, 180],  // cabinet
    [255, 187, 120], // bed
    [188, 189, 34],  // chair
    [140, 86, 75],   // sofa
    [255, 152, 150], // table
    [214, 39, 40],   // door
    [197, 176, 213], // window
    [148, 103, 189], // bookshelf
    [196, 156, 148], // picture
    [23, 190, 207],  // counter
    [178, 76, 76],   // blinds
    [247, 182, 210], // desk
    [66, 188, 102],  // shelves
    [219, 219, 141], // curtain
    [140, 57, 197],  // dresser
    [202, 185, 52],  // pillow
    [51, 176, 203],  // mirror
    [200, 54, 131],  // floor mat
    [92, 193, 61],   // clothes
    [78, 71, 183],   // ceiling
    [172, 114, 82],  // books
    [255, 127, 14],  // refridgerator
    [91, 163, 138],  // television
    [153, 98, 156],  // paper
    [140, 153, 101], // towel
    [158, 218, 229], // shower curtain
    [100, 125, 154], // box
    [178, 127, 135], // whiteboard
    [120, 185, 128], // person
    [146, 111, 194], // night stand
    [44, 160, 44],   // toilet
    [112, 128, 144], // sink
    [96, 207, 209],  // lamp
    [227, 119, 194], // bathtub
    [213, 92, 176],  // bag
    [94, 106, 211],  // otherstructure
    [82, 84, 163],   // otherfurniture
    [100, 85, 144],  // otherprop
];
/// Named constants for the labels the code refers to.
pub mod label {
    /// Label 0: "wall".
    pub const WALL: u8 = 0;
    /// Label 1: "floor".
    pub const FLOOR: u8 = 1;
    /// Label 2: "cabinet".
    pub const CABINET: u8 = 2;
    /// Label 3: "bed".
    pub(crate) const BED: u8 = 3;
    /// Label 4: "chair".
    pub(crate) const CHAIR: u8 = 4;
    /// Label 5: "sofa".
    pub(crate) const SOFA: u8 = 5;
    /// Label 6: "table".
    pub(crate) const TABLE: u8 = 6;
    /// Label 7: "door".
    pub(crate) const DOOR: u8 = 7;
    /// Label 8: "window".
    pub const WINDOW: u8 = 8;
    /// Label 9: "bookshelf".
    pub(crate) const BOOKSHELF: u8 = 9;
    /// Label 10: "picture".
    pub const PICTURE: u8 = 10;
    /// Label 11: "counter".
    pub(crate) const COUNTER: u8 = 11;
    /// Label 12: "blinds".
    pub(crate) const BLINDS: u8 = 12;
    /// Label 13: "desk".
    pub(crate) const DESK: u8 = 13;
    /// Label 14: "shelves".
    pub(crate) const SHELVES: u8 = 14;
    /// Label 15: "curtain".
    pub(crate) const CURTAIN: u8 = 15;
    /// Label 16: "dresser".
    pub(crate) const DRESSER: u8 = 16;
    /// Label 17: "pillow".
    pub(crate) const PILLOW: u8 = 17;
    /// Label 18: "mirror".
    pub(crate) const MIRROR: u8 = 18;
    /// Label 19: "floor mat".
    pub(crate) const FLOOR_MAT: u8 = 19;
    /// Label 20: "clothes".
    pub(crate) const CLOTHES: u8 = 20;
    /// Label 21: "ceiling".
    pub const CEILING: u8 = 21;
    /// Label 22: "books".
    pub(crate) const BOOKS: u8 = 22;
    /// Label 23: "refridgerator".
    pub(crate) const REFRIGERATOR: u8 = 23;
    /// Label 24: "television".
    pub(crate) const TELEVISION: u8 = 24;
    /// Label 25: "paper".
    pub(crate) const PAPER: u8 = 25;
    /// Label 26: "towel".
    pub const TOWEL: u8 = 26;
    /// Label 27: "shower curtain".
    pub const SHOWER_CURTAIN: u8 = 27;
    /// Label 28: "box".
    pub(crate) const BOX: u8 = 28;
    /// Label 29: "whiteboard".
    pub(crate) const WHITEBOARD: u8 = 29;
    /// Label 30: "person".
    pub const PERSON: u8 = 30;
    /// Label 31: "night stand".
    pub(crate) const NIGHT_STAND: u8 = 31;
    /// Label 32: "toilet".
    pub const TOILET: u8 = 32;
    /// Label 33: "sink".
    pub(crate) const SINK: u8 = 33;
    /// Label 34: "lamp".
    pub(crate) const LAMP: u8 = 34;
    /// Label 35: "bathtub".
    pub const BATHTUB: u8 = 35;
    /// Label 36: "bag".
    pub(crate) const BAG: u8 = 36;
    /// Label 37: "otherstructure".
    pub(crate) const OTHER_STRUCTURE: u8 = 37;
    /// Label 38: "otherfurniture".
    pub(crate) const OTHER_FURNITURE: u8 = 38;
    /// Label 39: "otherprop".
    pub(crate) const OTHER_PROP: u8 = 39;
}

/// Name of a label (`"void"` for [`VOID`], `None` for other values past 39).
pub fn name(label: u8) -> Option<&'static str> {
    match label {
        VOID => Some("void"),
        l => NYU40.get(l as usize).copied(),
    }
}

/// Display colour of void and of values past the 40 classes.
pub(crate) const VOID_COLOR: [u8; 3] = [0, 0, 0];

/// Display colour of a label ([`VOID_COLOR`] for void and out-of-range values).
pub(crate) fn colorize(label: u8) -> [u8; 3] {
    PALETTE.get(label as usize).copied().unwrap_or(VOID_COLOR)
}

/// Name of a label for reports: the class name, `"void"`, or `"label N"` past the classes.
pub fn display_name(label: u8) -> String {
    name(label).map_or_else(|| format!("label {label}"), str::to_string)
}

/// Colourises a label image with [`PALETTE`].
pub(crate) fn colorize_image(labels: &image::GrayImage) -> image::RgbImage {
    image::RgbImage::from_fn(labels.width(), labels.height(), |x, y| {
        image::Rgb(colorize(labels.get_pixel(x, y).0[0]))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_and_colours_match_the_nyu40_tables() {
        assert_eq!(NYU40[0], "wall");
        assert_eq!(NYU40[label::CEILING as usize], "ceiling");
        assert_eq!(NYU40[label::REFRIGERATOR as usize], "refridgerator");
        assert_eq!(NYU40[39], "otherprop");
        assert_eq!(colorize(label::WALL), [174, 199, 232]);
        assert_eq!(colorize(label::OTHER_PROP), [100, 85, 144]);
        assert_eq!(colorize(VOID), [0, 0, 0]);
        assert_eq!(name(VOID), Some("void"));
        assert_eq!(name(40), None);
        assert_eq!(display_name(40), "label 40");
        assert_eq!(display_name(label::FLOOR_MAT), "floor mat");
    }

    /// The tables are the files in `datasets/meta/nyuv2/` (1-based ids there).
    #[test]
    fn tables_match_the_meta_files() {
        let names = include_str!("../datasets/meta/nyuv2/nyu40_class_names.txt");
        let mut n = 0;
        for line in names.lines() {
            if let Some((id, name)) = line.trim().split_once(' ')
                && let Ok(id) = id.parse::<usize>()
            {
                assert_eq!(NYU40[id - 1], name.trim(), "class {id}");
                n += 1;
            }
        }
        assert_eq!(n, NUM_CLASSES);
        let csv = include_str!("../datasets/meta/nyuv2/nyu40_colormap_scannet.csv");
        let mut n = 0;
        for line in csv.lines().skip(1) {
            let f: Vec<u8> = line
                .split(',')
                .filter_map(|v| v.trim().parse::<u8>().ok())
                .collect();
            if let [id @ 1..=40, r, g, b] = f[..] {
                assert_eq!(PALETTE[id as usize - 1], [r, g, b], "class {id}");
                n += 1;
            }
        }
        assert_eq!(n, NUM_CLASSES);
    }
}
