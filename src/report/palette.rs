//! The colormaps: a categorical palette, turbo and viridis.

use plotters::prelude::*;
use plotters::style::colors::colormaps::ViridisRGB;

/// Tableau 10: distinct hues of similar weight, for categories.
pub(super) const PALETTE: [(u8, u8, u8); 10] = [
    (78, 121, 167),
    (242, 142, 43),
    (225, 87, 89),
    (118, 183, 178),
    (89, 161, 79),
    (237, 201, 72),
    (176, 122, 161),
    (255, 157, 167),
    (156, 117, 95),
    (186, 176, 172),
];

/// Turbo (Mikhailov 2019, its polynomial approximation): a rainbow whose lightness runs
/// smoothly, so neighbouring residue numbers look alike and distant ones differ in hue.
pub(super) fn turbo(x: f64) -> RGBColor {
    let x = x.clamp(0.0, 1.0);
    let poly = |c: [f64; 6]| {
        let v = c[0] + x * (c[1] + x * (c[2] + x * (c[3] + x * (c[4] + x * c[5]))));
        (v.clamp(0.0, 1.0) * 255.0).round() as u8
    };
    RGBColor(
        poly([
            0.135_721_38,
            4.615_392_6,
            -42.660_322_58,
            132.131_082_34,
            -152.942_393_96,
            59.286_379_43,
        ]),
        poly([
            0.091_402_61,
            2.194_188_39,
            4.842_966_58,
            -14.185_033_33,
            4.277_298_57,
            2.829_566_04,
        ]),
        poly([
            0.106_673_3,
            12.641_946_08,
            -60.582_048_36,
            110.362_767_71,
            -89.903_109_12,
            27.348_249_73,
        ]),
    )
}

pub(super) fn viridis(x: f64) -> RGBColor {
    ViridisRGB::get_color(x as f32)
}
