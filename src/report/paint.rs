//! The color of every seed: by a coordinate (along the shape's principal axis, height,
//! distance from the center), or for molecules by chain, domain or residue of the
//! nearest atom; with the caption and the legend that say what the colors mean.

use std::path::Path;

use glam::DVec3;
use plotters::prelude::*;

use super::palette::{turbo, viridis, PALETTE};
use super::{domains, ColorBy, ReportError};
use crate::run::RunDir;
use crate::trace::SeedTable;

/// What the colors of a picture mean, drawn under the atlas.
pub(super) enum Legend {
    /// The caption says it all.
    None,
    /// A color bar of a colormap over the values `lo..=hi` of `label`, with ticks.
    Bar {
        label: String,
        lo: i32,
        hi: i32,
        map: fn(f64) -> RGBColor,
    },
    /// A swatch and a name per category.
    Categories(Vec<(String, RGBColor)>),
}

/// The color of each seed, the caption and the legend.
pub(super) struct Paint {
    /// The color of each seed.
    pub(super) colors: Vec<RGBColor>,
    /// A color whose points are drawn before all others (the rest, around highlighted
    /// parts).
    pub(super) background: Option<RGBColor>,
    /// What the colors are, under the title.
    pub(super) caption: String,
    /// The legend under the atlas.
    pub(super) legend: Legend,
}

/// The colors of the seeds of `t` for `by`.
#[allow(clippy::many_single_char_names)]
// the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
#[allow(clippy::too_many_lines)] // one match over the ways to color, each a few lines of its own
pub(super) fn paint(run: &RunDir, t: &SeedTable, by: &ColorBy) -> Result<Paint, crate::Error> {
    let center: Option<DVec3> = run
        .attrs()?
        .get("center")
        .and_then(|c| serde_json::from_value::<[f64; 3]>(c.clone()).ok())
        .map(DVec3::from_array);
    let continuous = |coord: Coord, caption: &str| Paint {
        colors: color_values(t, coord, center)
            .into_iter()
            .map(viridis)
            .collect(),
        background: None,
        caption: caption.to_owned(),
        legend: Legend::None,
    };
    match by {
        ColorBy::Axis => {
            return Ok(continuous(
                Coord::Axis,
                "color: position of the seed along the shape's main axis",
            ))
        }
        ColorBy::Z => return Ok(continuous(Coord::Z, "color: height (z) of the seed")),
        ColorBy::Distance => {
            return Ok(continuous(
                Coord::Distance,
                "color: distance of the seed from the center (light: far)",
            ))
        }
        ColorBy::Chain | ColorBy::Residue | ColorBy::Domains(_) => {}
    }
    let m = domains::input_molecule(run, by.name())?;
    let near = domains::nearest_atoms(&m, &t.position);
    let refuse = |what: &str| {
        ReportError::Unavailable(format!(
            "{}: no atom of {} has {what} ({} format); use --color axis, z or distance",
            run.root().display(),
            shape_name(run),
            m.format
        ))
    };
    let category = |k: usize| {
        let (r, g, b) = PALETTE[k % PALETTE.len()];
        RGBColor(r, g, b)
    };
    match by {
        ColorBy::Chain => {
            if m.atoms.iter().all(|a| a.chain.is_empty()) {
                return Err(refuse("a chain id").into());
            }
            // Chains in the order the file first names them.
            let mut chains: Vec<&str> = Vec::new();
            for a in &m.atoms {
                if !chains.contains(&a.chain.as_str()) {
                    chains.push(&a.chain);
                }
            }
            let colors = near
                .iter()
                .map(|&i| {
                    category(
                        chains
                            .iter()
                            .position(|c| *c == m.atoms[i].chain)
                            .unwrap_or(0),
                    )
                })
                .collect();
            let legend = chains
                .iter()
                .enumerate()
                .map(|(k, c)| {
                    let name = if c.is_empty() { "(none)" } else { c };
                    (format!("chain {name}"), category(k))
                })
                .collect();
            let repeat = if chains.len() > PALETTE.len() {
                format!("; {} chains, so colors repeat", chains.len())
            } else {
                String::new()
            };
            Ok(Paint {
                colors,
                background: None,
                caption: format!("color: chain of the atom nearest the seed{repeat}"),
                legend: Legend::Categories(legend),
            })
        }
        ColorBy::Domains(list) => {
            if m.atoms.iter().all(|a| a.seq == 0) {
                return Err(refuse("a residue number").into());
            }
            // One color per name, in the order given.
            let mut names: Vec<&str> = Vec::new();
            for d in list {
                if !names.contains(&d.name.as_str()) {
                    names.push(&d.name);
                }
            }
            let rest = RGBColor(200, 200, 200);
            let colors = near
                .iter()
                .map(|&i| {
                    list.iter()
                        .find(|d| d.contains(&m.atoms[i]))
                        .and_then(|d| names.iter().position(|n| *n == d.name))
                        .map_or(rest, category)
                })
                .collect();
            let mut legend: Vec<(String, RGBColor)> = names
                .iter()
                .enumerate()
                .map(|(k, n)| {
                    let ranges: Vec<String> = list
                        .iter()
                        .filter(|d| d.name == *n)
                        .map(domains::Domain::range)
                        .collect();
                    (format!("{n} {}", ranges.join(", ")), category(k))
                })
                .collect();
            legend.push(("other".to_owned(), rest));
            Ok(Paint {
                colors,
                background: Some(rest),
                caption: "color: the domain of the atom nearest the seed".to_owned(),
                legend: Legend::Categories(legend),
            })
        }
        _ => {
            let numbered: Vec<i32> = m.atoms.iter().map(|a| a.seq).filter(|&s| s != 0).collect();
            let (Some(&lo), Some(&hi)) = (numbered.iter().min(), numbered.iter().max()) else {
                return Err(refuse("a residue number").into());
            };
            let span = f64::from((hi - lo).max(1));
            let colors = near
                .iter()
                .map(|&i| turbo(f64::from(m.atoms[i].seq - lo) / span))
                .collect();
            let chains = m
                .atoms
                .iter()
                .map(|a| a.chain.as_str())
                .collect::<std::collections::BTreeSet<_>>()
                .len();
            let scale = if chains > 1 {
                format!(" ({chains} chains on one scale)")
            } else {
                String::new()
            };
            Ok(Paint {
                colors,
                background: None,
                caption: format!("color: residue number of the atom nearest the seed{scale}"),
                legend: Legend::Bar {
                    label: "residue".to_owned(),
                    lo,
                    hi,
                    map: turbo,
                },
            })
        }
    }
}

/// A coordinate of the seeds that colors them.
#[derive(Clone, Copy)]
pub(super) enum Coord {
    Axis,
    Z,
    Distance,
}

/// The coordinate the colors come from, scaled to [0, 1].
pub(super) fn color_values(t: &SeedTable, by: Coord, center: Option<DVec3>) -> Vec<f64> {
    let v: Vec<f64> = match by {
        Coord::Z => t.position.iter().map(|p| p.z).collect(),
        Coord::Distance => {
            let c = center.unwrap_or(DVec3::ZERO);
            t.position.iter().map(|p| (*p - c).length()).collect()
        }
        Coord::Axis => {
            let n = t.position.len().max(1) as f64;
            let mean = t.position.iter().copied().sum::<DVec3>() / n;
            let mut c = glam::DMat3::ZERO;
            for p in &t.position {
                let d = *p - mean;
                c += glam::DMat3::from_cols(d * d.x, d * d.y, d * d.z);
            }
            let axis = principal_axis(c / n);
            t.position.iter().map(|p| (*p - mean).dot(axis)).collect()
        }
    };
    let (lo, hi) = v
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
            (a.min(x), b.max(x))
        });
    let span = if hi > lo { hi - lo } else { 1.0 };
    v.iter().map(|x| (x - lo) / span).collect()
}

/// The eigenvector of the largest eigenvalue of a symmetric matrix (power iteration).
pub(super) fn principal_axis(c: glam::DMat3) -> DVec3 {
    let mut v = DVec3::new(1.0, 0.7, 0.4).normalize();
    for _ in 0..200 {
        let w = c * v;
        match w.try_normalize() {
            Some(w) => v = w,
            None => return DVec3::X,
        }
    }
    // A sign that does not depend on rounding: the largest component positive.
    let a = v.abs();
    let k = if a.x >= a.y && a.x >= a.z {
        v.x
    } else if a.y >= a.z {
        v.y
    } else {
        v.z
    };
    if k < 0.0 {
        -v
    } else {
        v
    }
}

/// The shape's name for titles.
pub(super) fn shape_name(run: &RunDir) -> String {
    let a = run.attrs().unwrap_or_default();
    let input = a.get("input").cloned().unwrap_or_default();
    if let Some(b) = input.get("builtin").and_then(|b| b.as_str()) {
        return format!("built-in {b}");
    }
    input
        .get("path")
        .and_then(|p| p.as_str())
        .and_then(|p| Path::new(p).file_name())
        .map_or_else(
            || run.root().display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_principal_axis_of_an_elongated_cloud_is_its_long_side() {
        let mut c = glam::DMat3::ZERO;
        for i in -50..=50 {
            for d in [
                DVec3::new(0.2, f64::from(i), 0.1),
                DVec3::new(-0.2, f64::from(i), -0.1),
            ] {
                c += glam::DMat3::from_cols(d * d.x, d * d.y, d * d.z);
            }
        }
        let a = principal_axis(c);
        assert!((a - DVec3::Y).length() < 1e-6, "{a}");
    }
}
