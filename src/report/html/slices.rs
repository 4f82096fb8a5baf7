//! Slices of a field through the center voxel, colored and encoded as small PNGs.
//!
//! One plane per axis (z, y and x through the center voxel), read through the run's
//! store one plane at a time (never the whole grid), shrunk by an integer stride to at
//! most [`MAX_SIDE`] pixels, enlarged by an integer factor when the grid is small, and
//! drawn with the second grid axis up. Voxels where the field is undefined (NaN: outside
//! the problem, or not mapped) are light gray.
// Index arithmetic over the grid's axes: z, y, x and i, j, k read as in the formulas.
#![allow(clippy::many_single_char_names)]

use plotters::style::colors::colormaps::{ColorMap, ViridisRGB};
use plotters::style::RGBColor;

use crate::grid::{BlockStore, Scalar};
use crate::run::RunDir;

/// The longest side of a slice picture, pixels.
pub const MAX_SIDE: usize = 220;

/// The color of an undefined voxel.
const UNDEFINED: [u8; 3] = [225, 225, 225];

/// How values become colors.
#[derive(Clone, Copy, Debug)]
pub enum Colormap {
    /// Viridis over `[lo, hi]`.
    Viridis {
        /// Value at the dark end.
        lo: f64,
        /// Value at the light end.
        hi: f64,
    },
    /// A hue wheel over one turn `[-pi, pi)`: for an angle that wraps (psi), so that
    /// -pi and pi get the same color.
    Cyclic,
}

impl Colormap {
    /// The color of `v`.
    #[must_use]
    pub fn color(self, v: f64) -> [u8; 3] {
        if !v.is_finite() {
            return UNDEFINED;
        }
        match self {
            Colormap::Viridis { lo, hi } => {
                let t = ((v - lo) / (hi - lo)).clamp(0.0, 1.0);
                let RGBColor(r, g, b) = ViridisRGB.get_color_normalized(t as f32, 0.0, 1.0);
                [r, g, b]
            }
            Colormap::Cyclic => {
                let t = (v / std::f64::consts::TAU).rem_euclid(1.0);
                hue(t)
            }
        }
    }

    /// A CSS `linear-gradient` of the map from its low end (left) to its high end.
    #[must_use]
    pub fn css_gradient(self) -> String {
        let stops: Vec<String> = (0..=8)
            .map(|k| {
                let t = f64::from(k) / 8.0;
                let v = match self {
                    Colormap::Viridis { lo, hi } => lo + t * (hi - lo),
                    Colormap::Cyclic => -std::f64::consts::PI + t * std::f64::consts::TAU,
                };
                let [r, g, b] = self.color(v);
                format!("#{r:02x}{g:02x}{b:02x} {:.1}%", t * 100.0)
            })
            .collect();
        format!("linear-gradient(to right, {})", stops.join(", "))
    }
}

/// A bright hue wheel (HSV with S = 0.75, V = 0.95), `t` in [0, 1).
fn hue(t: f64) -> [u8; 3] {
    let h = t * 6.0;
    let (s, v) = (0.75, 0.95);
    let f = h - h.floor();
    let p = v * (1.0 - s);
    let q = v * (1.0 - s * f);
    let w = v * (1.0 - s * (1.0 - f));
    let (r, g, b) = match h.floor() as u32 % 6 {
        0 => (v, w, p),
        1 => (q, v, p),
        2 => (p, v, w),
        3 => (p, q, v),
        4 => (w, p, v),
        _ => (v, p, q),
    };
    [r, g, b].map(|c| (c * 255.0).round() as u8)
}

/// A picture of one slice.
pub struct Slice {
    /// Which plane: "z = 31" etc.
    pub plane: String,
    /// The PNG file.
    pub png: Vec<u8>,
    /// Pixel size.
    pub size: (u32, u32),
}

/// The three planes through `center` (`[z, y, x]`) of image `name` of `run`, read as
/// `T`, in the order z, y, x.
pub fn center_slices<T: Scalar + Into<f64>>(
    run: &RunDir,
    name: &str,
    center: [u64; 3],
    map: Colormap,
) -> Result<Vec<Slice>, crate::Error> {
    let store = run.open_image::<T>(name)?;
    let shape = store.spec().shape;
    let n = shape.map(|s| s as usize);
    let c = [0, 1, 2].map(|k| center[k].min(shape[k].saturating_sub(1)) as i64);
    let nan = T::from_f64(f64::NAN);
    let mut out = Vec::with_capacity(3);
    // (fixed axis, the axis drawn across, the axis drawn up)
    for (axis, across, up) in [(0usize, 2usize, 1usize), (1, 2, 0), (2, 1, 0)] {
        let mut origin = [0i64; 3];
        origin[axis] = c[axis];
        let mut ext = n;
        ext[axis] = 1;
        let block = store.read_region(origin, ext, nan)?;
        let (w, h) = (n[across], n[up]);
        let value = |i: usize, j: usize| {
            let mut v = [0usize; 3];
            v[across] = i;
            v[up] = j;
            v[axis] = 0;
            block.data[block.offset(v[0], v[1], v[2])].into()
        };
        let (png, size) = picture(w, h, value, map);
        let names = ["z", "y", "x"];
        out.push(Slice {
            plane: format!(
                "{} = {} ({} across, {} up)",
                names[axis], c[axis], names[across], names[up]
            ),
            png,
            size,
        });
    }
    Ok(out)
}

/// Color a `w` x `h` plane (`value(i, j)`, j up) into a PNG no longer than
/// [`MAX_SIDE`] on its long side (a stride when larger, an integer zoom when small).
fn picture(
    w: usize,
    h: usize,
    value: impl Fn(usize, usize) -> f64,
    map: Colormap,
) -> (Vec<u8>, (u32, u32)) {
    let long = w.max(h).max(1);
    let stride = long.div_ceil(MAX_SIDE);
    let zoom = (MAX_SIDE / long.div_ceil(stride)).max(1);
    let (sw, sh) = (w.div_ceil(stride), h.div_ceil(stride));
    let (pw, ph) = (sw * zoom, sh * zoom);
    let mut rgb = vec![0u8; pw * ph * 3];
    for py in 0..ph {
        // Row 0 of the picture is the top: the largest j.
        let j = (sh - 1 - py / zoom) * stride;
        for px in 0..pw {
            let i = (px / zoom) * stride;
            let c = map.color(value(i, j));
            rgb[(py * pw + px) * 3..][..3].copy_from_slice(&c);
        }
    }
    let (pw, ph) = (pw as u32, ph as u32);
    (super::png::encode_rgb(pw, ph, &rgb), (pw, ph))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cyclic_map_joins_at_minus_and_plus_pi() {
        let pi = std::f64::consts::PI;
        assert_eq!(Colormap::Cyclic.color(-pi), Colormap::Cyclic.color(pi));
        assert_ne!(Colormap::Cyclic.color(0.0), Colormap::Cyclic.color(pi));
    }

    #[test]
    fn viridis_ends_and_undefined_values() {
        let m = Colormap::Viridis { lo: 0.0, hi: 1.0 };
        // Viridis runs from dark purple to yellow.
        let [r0, _, b0] = m.color(0.0);
        let [r1, g1, b1] = m.color(1.0);
        assert!(b0 > r0 && r1 > b1 && g1 > b1);
        assert_eq!(m.color(-5.0), m.color(0.0), "clamped");
        assert_eq!(m.color(f64::NAN), UNDEFINED);
    }

    #[test]
    fn a_small_plane_is_zoomed_and_drawn_with_its_second_axis_up() {
        // 4 x 2 plane: value = j (0 bottom row, 1 top row).
        let m = Colormap::Viridis { lo: 0.0, hi: 1.0 };
        let (png, (w, h)) = picture(4, 2, |_, j| j as f64, m);
        assert_eq!((w, h), (220, 110));
        assert_eq!(&png[1..4], b"PNG");
    }

    #[test]
    fn a_large_plane_is_strided_down_to_the_limit() {
        let m = Colormap::Cyclic;
        let (_, (w, h)) = picture(1000, 10, |i, _| i as f64, m);
        assert!(w as usize <= MAX_SIDE && w >= 200, "{w}");
        assert!(h >= 2);
    }
}
