//! Pictures of a run: the theta-psi atlas of the paper and the mapped sphere.
//!
//! Drawn with `plotters` (PNG through its bitmap backend, SVG through its SVG backend)
//! and an embedded DejaVu Sans, so no system fonts are needed. Files are written under a
//! temporary name and renamed when whole.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use glam::DVec3;
use plotters::prelude::*;
use plotters::style::colors::colormaps::ViridisRGB;

use crate::run::RunDir;
use crate::trace::{read_seeds, SeedTable};

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
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
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
}

/// The coordinate the colors come from, scaled to [0, 1].
fn color_values(t: &SeedTable, by: ColorBy, center: Option<DVec3>) -> Vec<f64> {
    let v: Vec<f64> = match by {
        ColorBy::Z => t.position.iter().map(|p| p.z).collect(),
        ColorBy::Distance => {
            let c = center.unwrap_or(DVec3::ZERO);
            t.position.iter().map(|p| (*p - c).length()).collect()
        }
        ColorBy::Axis => {
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

fn color(x: f64) -> RGBColor {
    ViridisRGB::get_color(x as f32)
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

/// Points of the atlas: (psi, theta) in degrees and a color value in [0, 1].
fn atlas_points(t: &SeedTable, c: &[f64]) -> Vec<(f64, f64, f64)> {
    (0..t.position.len())
        .filter(|&i| t.stop[i] == 0 && t.theta[i].is_finite())
        .map(|i| (t.psi[i].to_degrees(), t.theta[i].to_degrees(), c[i]))
        .collect()
}

fn draw_atlas<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    title: &str,
    pts: &[(f64, f64, f64)],
    caption: &str,
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
                .map(|&(x, y, c)| Circle::new((x, y), r, color(c).filled())),
        )
        .map_err(e)?;
    root.draw(&Text::new(
        caption.to_owned(),
        (70, root.dim_in_pixel().1 as i32 - 18),
        ("sans-serif", 13).into_font().color(&BLACK.mix(0.7)),
    ))
    .map_err(e)?;
    root.present().map_err(e)?;
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
    c: &[f64],
) -> Result<(), String> {
    let e = |x: DrawingAreaErrorKind<DB::ErrorType>| x.to_string();
    root.fill(&WHITE).map_err(e)?;
    let root = root.titled(title, ("sans-serif", 20)).map_err(e)?;
    let panels = root.split_evenly((1, 4));
    let pts: Vec<(DVec3, f64)> = (0..t.position.len())
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
        let mut front: Vec<&(DVec3, f64)> = pts.iter().filter(|(s, _)| s.dot(view) > 0.0).collect();
        front.sort_by(|a, b| a.0.dot(view).total_cmp(&b.0.dot(view)));
        let r = if front.len() > 20_000 { 1 } else { 2 };
        chart
            .draw_series(
                front
                    .iter()
                    .map(|(s, v)| Circle::new((s.dot(sx), s.dot(sy)), r, color(*v).filled())),
            )
            .map_err(e)?;
    }
    Ok(())
}

/// Draw the theta-psi atlas of a traced run to `dest` (.png or .svg), or with `sphere`
/// the mapped sphere from four viewpoints. Returns the number of points drawn.
pub fn atlas(run: &RunDir, dest: &Path, sphere: bool, by: ColorBy) -> Result<usize, crate::Error> {
    let t = read_seeds(run)?;
    let center: Option<DVec3> = run
        .attrs()?
        .get("center")
        .and_then(|c| serde_json::from_value::<[f64; 3]>(c.clone()).ok())
        .map(DVec3::from_array);
    let c = color_values(&t, by, center);
    let pts = atlas_points(&t, &c);
    if pts.is_empty() {
        return Err(ReportError::Unavailable(format!(
            "{}: no seed reached the center; nothing to draw",
            run.root().display()
        ))
        .into());
    }
    let title = title(run, &t);
    let caption = match by {
        ColorBy::Axis => "color: position of the seed along the shape's main axis",
        ColorBy::Z => "color: height (z) of the seed",
        ColorBy::Distance => "color: distance of the seed from the center (light: far)",
    };
    if sphere {
        staged_draw(
            dest,
            (1600, 470),
            |root| draw_sphere(&root, &title, &t, &c),
            |root| draw_sphere(&root, &title, &t, &c),
        )?;
    } else {
        staged_draw(
            dest,
            (1200, 680),
            |root| draw_atlas(&root, &title, &pts, caption),
            |root| draw_atlas(&root, &title, &pts, caption),
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
