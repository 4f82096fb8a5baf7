//! Pictures of a run: the theta-psi atlas of the paper and the mapped sphere.
//!
//! Points are colored by a coordinate of the seed (viridis), or for molecule runs by
//! the chain or named domain (a categorical palette with a legend) or the residue
//! number (turbo, with a color bar) of the atom nearest the seed ([`domains`]). Drawn
//! with `plotters` (PNG through its bitmap backend, SVG through its SVG backend) and an
//! embedded DejaVu Sans, so no system fonts are needed. Files are written under a
//! temporary name and renamed when whole.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use glam::DVec3;
use plotters::prelude::*;
use plotters::style::colors::colormaps::ViridisRGB;

use crate::run::RunDir;
use crate::trace::{read_seeds, SeedTable};

pub mod domains;
pub mod html;

/// Errors of drawing.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    /// Nothing to draw, or a file name the backends cannot write.
    #[error("{0}")]
    Unavailable(String),
    /// The plotting backend failed.
    #[error("{}: drawing failed: {message}", path.display())]
    Draw {
        /// The file.
        path: PathBuf,
        /// The backend's message.
        message: String,
    },
}

static FONT: &[u8] = include_bytes!("../../assets/fonts/DejaVuSans.ttf");

fn register_font() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // The embedded font is valid; a failure would only mean no text.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    });
}

/// What the atlas colors its points by.
#[derive(Clone, Debug, PartialEq, Eq, Default)]
pub enum ColorBy {
    /// The seed's position along the shape's main axis (principal component of the seed
    /// positions): regions of the shape get their own colors.
    #[default]
    Axis,
    /// The seed's height (world z).
    Z,
    /// The seed's distance from the center: protrusions (arms, spikes, ears) light,
    /// the body dark.
    Distance,
    /// Molecules: the chain of the atom nearest the seed.
    Chain,
    /// Molecules: the residue number of the atom nearest the seed, so that domains
    /// (stretches of the sequence) get their own colors.
    Residue,
    /// Molecules: which of these named stretches of residues the atom nearest the seed
    /// is in (a color per name, gray for the rest).
    Domains(Vec<domains::Domain>),
}

impl ColorBy {
    /// The `--color` name.
    #[must_use]
    pub fn name(&self) -> &'static str {
        match self {
            ColorBy::Axis => "axis",
            ColorBy::Z => "z",
            ColorBy::Distance => "distance",
            ColorBy::Chain => "chain",
            ColorBy::Residue => "residue",
            ColorBy::Domains(_) => "domain",
        }
    }
}

/// The coloring `harmap run` draws its atlas with: residues for molecule formats that
/// number them (PDB, mmCIF, PQR), else the main axis.
#[must_use]
pub fn default_coloring(attrs: &serde_json::Value) -> ColorBy {
    match attrs.pointer("/input/format").and_then(|f| f.as_str()) {
        Some("pdb" | "ent" | "cif" | "mmcif" | "pqr") => ColorBy::Residue,
        _ => ColorBy::Axis,
    }
}

/// What the colors of a picture mean, drawn under the atlas.
enum Legend {
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
struct Paint {
    colors: Vec<RGBColor>,
    /// A color whose points are drawn before all others (the rest, around highlighted
    /// parts).
    background: Option<RGBColor>,
    caption: String,
    legend: Legend,
}

/// Tableau 10: distinct hues of similar weight, for categories.
const PALETTE: [(u8, u8, u8); 10] = [
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
fn turbo(x: f64) -> RGBColor {
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

fn viridis(x: f64) -> RGBColor {
    ViridisRGB::get_color(x as f32)
}

/// The colors of the seeds of `t` for `by`.
fn paint(run: &RunDir, t: &SeedTable, by: &ColorBy) -> Result<Paint, crate::Error> {
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
enum Coord {
    Axis,
    Z,
    Distance,
}

/// The coordinate the colors come from, scaled to [0, 1].
fn color_values(t: &SeedTable, by: Coord, center: Option<DVec3>) -> Vec<f64> {
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
fn principal_axis(c: glam::DMat3) -> DVec3 {
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
fn shape_name(run: &RunDir) -> String {
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

/// The title line with the counts and, when measured, the bijectivity numbers.
fn title(run: &RunDir, t: &SeedTable) -> String {
    let a = run.attrs().unwrap_or_default();
    let reached = (0..t.stop.len()).filter(|&i| t.sphere(i).is_some()).count();
    let kind = if t.vertex.is_empty() {
        "boundary seeds"
    } else {
        "surface vertices"
    };
    let mut s = format!(
        "{}: {} of {} {kind} reached the center",
        shape_name(run),
        reached,
        t.position.len()
    );
    let r = a.pointer("/stages/trace/result");
    if let Some(m) = r.and_then(|r| r.get("surface")).filter(|m| !m.is_null()) {
        let _ = write!(
            s,
            "; {} of {} triangles flipped",
            m["flipped"], m["measured"]
        );
    }
    if let Some(c) = r.and_then(|r| r.pointer("/collisions/seeds")) {
        let _ = write!(s, "; {c} collisions");
    }
    s
}

/// Write `draw`'s picture to `dest` (PNG or SVG by extension) through a temporary file.
fn staged_draw(
    dest: &Path,
    size: (u32, u32),
    draw: impl Fn(DrawingArea<BitMapBackend<'_>, plotters::coord::Shift>) -> Result<(), String> + Copy,
    draw_svg: impl Fn(DrawingArea<SVGBackend<'_>, plotters::coord::Shift>) -> Result<(), String>,
) -> Result<(), crate::Error> {
    register_font();
    let ext = dest
        .extension()
        .map(|e| e.to_string_lossy().to_lowercase())
        .unwrap_or_default();
    let name = dest
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = dest.with_file_name(format!(".{name}.partial-{}.{ext}", std::process::id()));
    let fail = |message: String| ReportError::Draw {
        path: dest.to_owned(),
        message,
    };
    let res = match ext.as_str() {
        "png" => {
            let root = BitMapBackend::new(&tmp, size).into_drawing_area();
            draw(root)
        }
        "svg" => {
            let root = SVGBackend::new(&tmp, size).into_drawing_area();
            draw_svg(root)
        }
        _ => {
            return Err(ReportError::Unavailable(format!(
                "{}: give a .png or .svg file name",
                dest.display()
            ))
            .into())
        }
    };
    if let Err(m) = res {
        let _ = std::fs::remove_file(&tmp);
        return Err(fail(m).into());
    }
    std::fs::rename(&tmp, dest).map_err(|e| fail(e.to_string()))?;
    Ok(())
}

/// Points of the atlas: (psi, theta) in degrees and a color, in drawing order: points
/// of the `background` color first; then points in sparse parts of the atlas before
/// those in crowded one-degree cells, so that the small lobes into which the map
/// squeezes thin parts of a shape are not hidden under the points around them.
fn atlas_points(
    t: &SeedTable,
    c: &[RGBColor],
    background: Option<RGBColor>,
) -> Vec<(f64, f64, RGBColor)> {
    let pts: Vec<(f64, f64, RGBColor)> = (0..t.position.len())
        .filter(|&i| t.stop[i] == 0 && t.theta[i].is_finite())
        .map(|i| (t.psi[i].to_degrees(), t.theta[i].to_degrees(), c[i]))
        .collect();
    let cell = |&(psi, theta, _): &(f64, f64, RGBColor)| {
        let x = ((psi + 180.0).floor() as usize).min(359);
        let y = (theta.floor() as usize).min(179);
        y * 360 + x
    };
    let mut count = vec![0u32; 360 * 180];
    for p in &pts {
        count[cell(p)] += 1;
    }
    let mut order: Vec<usize> = (0..pts.len()).collect();
    order.sort_by_key(|&i| (Some(pts[i].2) != background, count[cell(&pts[i])]));
    order.into_iter().map(|i| pts[i]).collect()
}

fn draw_atlas<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    title: &str,
    pts: &[(f64, f64, RGBColor)],
    caption: &str,
    legend: &Legend,
) -> Result<(), String> {
    let e = |x: DrawingAreaErrorKind<DB::ErrorType>| x.to_string();
    root.fill(&WHITE).map_err(e)?;
    let mut chart = ChartBuilder::on(root)
        .caption(title, ("sans-serif", 20))
        .margin(14)
        .x_label_area_size(44)
        .y_label_area_size(56)
        .build_cartesian_2d(-180.0..180.0, 180.0..0.0)
        .map_err(e)?;
    chart
        .configure_mesh()
        .x_desc("psi (azimuth), degrees")
        .y_desc("theta (polar angle), degrees")
        .x_labels(13)
        .y_labels(7)
        .label_style(("sans-serif", 14))
        .light_line_style(WHITE.mix(0.0))
        .draw()
        .map_err(e)?;
    let r = if pts.len() > 50_000 {
        1
    } else if pts.len() > 5_000 {
        2
    } else {
        3
    };
    chart
        .draw_series(
            pts.iter()
                .map(|&(x, y, c)| Circle::new((x, y), r, c.filled())),
        )
        .map_err(e)?;
    let (w, h) = root.dim_in_pixel();
    let (w, h) = (w as i32, h as i32);
    let small = ("sans-serif", 13).into_font().color(&BLACK.mix(0.7));
    root.draw(&Text::new(caption.to_owned(), (70, h - 18), small.clone()))
        .map_err(e)?;
    draw_legend(root, legend, (w - 30, h - 18)).map_err(e)?;
    root.present().map_err(e)?;
    Ok(())
}

/// A round step (1, 2 or 5 times a power of ten) that cuts `span` into at most `n`
/// pieces.
fn nice_step(span: i32, n: i32) -> i32 {
    let mut p = 1;
    loop {
        for m in [1, 2, 5] {
            if span <= m * p * n {
                return m * p;
            }
        }
        p *= 10;
    }
}

/// Draw `legend` in one row that ends at `right` (pixels, the text's top line).
fn draw_legend<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    legend: &Legend,
    right: (i32, i32),
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let font = ("sans-serif", 13).into_font().color(&BLACK.mix(0.8));
    let width = |s: &str| {
        root.estimate_text_size(s, &font)
            .map_or(7 * s.len() as i32, |(w, _)| w as i32)
    };
    let (x1, y) = right;
    match legend {
        Legend::None => {}
        Legend::Bar { label, lo, hi, map } => {
            // The bar over the line of the caption, its tick numbers on that line.
            let (bar, top) = (300, y - 15);
            let x0 = x1 - bar;
            for k in 0..bar {
                let c = map(f64::from(k) / f64::from(bar - 1));
                root.draw(&Rectangle::new(
                    [(x0 + k, top), (x0 + k + 1, top + 11)],
                    c.filled(),
                ))?;
            }
            root.draw(&Text::new(
                label.clone(),
                (x0 - 8 - width(label), top - 1),
                font.clone(),
            ))?;
            let span = f64::from((hi - lo).max(1));
            let at = |v: i32| x0 + (f64::from(v - lo) / span * f64::from(bar - 1)).round() as i32;
            let step = nice_step(hi - lo, 6);
            let mut ticks = vec![*lo];
            let mut v = (lo.div_euclid(step) + 1) * step;
            while v < *hi {
                // Round ticks not crowding the ends.
                if f64::from(v - lo) > 0.08 * span && f64::from(hi - v) > 0.08 * span {
                    ticks.push(v);
                }
                v += step;
            }
            if hi > lo {
                ticks.push(*hi);
            }
            let tick_font = ("sans-serif", 12).into_font().color(&BLACK.mix(0.8));
            for v in ticks {
                let x = at(v);
                root.draw(&PathElement::new(
                    [(x, top + 11), (x, top + 14)],
                    BLACK.mix(0.6),
                ))?;
                let t = v.to_string();
                root.draw(&Text::new(
                    t.clone(),
                    (x - width(&t) / 2, top + 15),
                    tick_font.clone(),
                ))?;
            }
        }
        Legend::Categories(items) => {
            // At most 12 shown; the rest are summed up.
            let shown = &items[..items.len().min(12)];
            let more =
                (items.len() > shown.len()).then(|| format!("+{} more", items.len() - shown.len()));
            let mut x = x1 - more.as_deref().map_or(0, |m| width(m) + 10);
            let mut at = Vec::new();
            for (name, _) in shown.iter().rev() {
                x -= width(name) + 26;
                at.push(x);
            }
            at.reverse();
            for ((name, c), &x) in shown.iter().zip(&at) {
                root.draw(&Rectangle::new([(x, y), (x + 12, y + 12)], c.filled()))?;
                root.draw(&Text::new(name.clone(), (x + 16, y), font.clone()))?;
            }
            if let Some(m) = more {
                root.draw(&Text::new(m.clone(), (x1 - width(&m), y), font.clone()))?;
            }
        }
    }
    Ok(())
}

/// Views of the sphere: (name, view direction toward the viewer, screen x, screen y).
fn views() -> [(&'static str, DVec3, DVec3, DVec3); 4] {
    [
        ("from +x", DVec3::X, DVec3::Y, DVec3::Z),
        ("from -x", -DVec3::X, -DVec3::Y, DVec3::Z),
        ("from +z (north pole)", DVec3::Z, DVec3::X, DVec3::Y),
        ("from -z (south pole)", -DVec3::Z, DVec3::X, -DVec3::Y),
    ]
}

fn draw_sphere<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    title: &str,
    t: &SeedTable,
    c: &[RGBColor],
) -> Result<(), String> {
    let e = |x: DrawingAreaErrorKind<DB::ErrorType>| x.to_string();
    root.fill(&WHITE).map_err(e)?;
    let root = root.titled(title, ("sans-serif", 20)).map_err(e)?;
    let panels = root.split_evenly((1, 4));
    let pts: Vec<(DVec3, RGBColor)> = (0..t.position.len())
        .filter_map(|i| t.sphere(i).map(|s| (s, c[i])))
        .collect();
    for (area, (name, view, sx, sy)) in panels.iter().zip(views()) {
        let mut chart = ChartBuilder::on(area)
            .caption(name, ("sans-serif", 15))
            .margin(8)
            .build_cartesian_2d(-1.1..1.1, -1.1..1.1)
            .map_err(e)?;
        // The outline of the sphere.
        chart
            .draw_series(LineSeries::new(
                (0..=200).map(|k| {
                    let a = std::f64::consts::TAU * f64::from(k) / 200.0;
                    (a.cos(), a.sin())
                }),
                BLACK.mix(0.4),
            ))
            .map_err(e)?;
        // Front hemisphere only, far points first.
        let mut front: Vec<&(DVec3, RGBColor)> =
            pts.iter().filter(|(s, _)| s.dot(view) > 0.0).collect();
        front.sort_by(|a, b| a.0.dot(view).total_cmp(&b.0.dot(view)));
        let r = if front.len() > 20_000 { 1 } else { 2 };
        chart
            .draw_series(
                front
                    .iter()
                    .map(|(s, v)| Circle::new((s.dot(sx), s.dot(sy)), r, v.filled())),
            )
            .map_err(e)?;
    }
    Ok(())
}

/// Draw the theta-psi atlas of a traced run to `dest` (.png or .svg), or with `sphere`
/// the mapped sphere from four viewpoints. Returns the number of points drawn.
pub fn atlas(run: &RunDir, dest: &Path, sphere: bool, by: &ColorBy) -> Result<usize, crate::Error> {
    let t = read_seeds(run)?;
    let paint = paint(run, &t, by)?;
    let c = &paint.colors;
    let pts = atlas_points(&t, c, paint.background);
    if pts.is_empty() {
        return Err(ReportError::Unavailable(format!(
            "{}: no seed reached the center; nothing to draw",
            run.root().display()
        ))
        .into());
    }
    let title = title(run, &t);
    if sphere {
        staged_draw(
            dest,
            (1600, 470),
            |root| draw_sphere(&root, &title, &t, c),
            |root| draw_sphere(&root, &title, &t, c),
        )?;
    } else {
        staged_draw(
            dest,
            (1200, 680),
            |root| draw_atlas(&root, &title, &pts, &paint.caption, &paint.legend),
            |root| draw_atlas(&root, &title, &pts, &paint.caption, &paint.legend),
        )?;
    }
    Ok(pts.len())
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
