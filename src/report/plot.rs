//! The theta-psi atlas: its title, its points in drawing order, and the picture, written
//! as PNG or SVG under a temporary name.

use std::fmt::Write as _;
use std::path::Path;

use plotters::prelude::*;

use super::legend::draw_legend;
use super::paint::{shape_name, Legend};
use super::{register_font, ReportError};
use crate::run::RunDir;
use crate::trace::SeedTable;

/// The title line with the counts and, when measured, the bijectivity numbers.
pub(super) fn title(run: &RunDir, t: &SeedTable) -> String {
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
    if let Some(r) = crate::run::report_in::<Bijectivity>(&a, "trace") {
        if let Some(m) = r.surface {
            let _ = write!(s, "; {} of {} triangles flipped", m.flipped, m.measured);
            if let Some(u) = r.untangle {
                let _ = write!(s, " (untangled from {})", u.flipped_arrivals);
            }
        }
        if let Some(c) = r.collisions {
            let _ = write!(s, "; {} collisions", c.seeds);
        }
        if let Some(c) = r.indistinguishable {
            let _ = write!(s, "; {} indistinguishable", c.seeds);
        }
    }
    if let Some(f) = crate::run::report_in::<Folds>(&a, "map").and_then(|m| m.folded) {
        let _ = write!(s, "; {} voxels folded", f.voxels);
    }
    s
}

/// The fields of the trace's report ([`crate::trace::TraceReport`]) the title shows.
#[derive(serde::Deserialize)]
struct Bijectivity {
    surface: Option<Flips>,
    untangle: Option<Untangled>,
    collisions: Option<CollidingSeeds>,
    indistinguishable: Option<CollidingSeeds>,
}

/// The map's folded voxels, of its report.
#[derive(serde::Deserialize)]
struct Folds {
    folded: Option<FoldCount>,
}

/// Of the map report's `folded`.
#[derive(serde::Deserialize)]
struct FoldCount {
    voxels: u64,
}

/// Of [`crate::trace::metrics::SurfaceMetrics`].
#[derive(serde::Deserialize)]
struct Flips {
    measured: u64,
    flipped: u64,
}

/// Of [`crate::trace::untangle::UntangleReport`].
#[derive(serde::Deserialize)]
struct Untangled {
    flipped_arrivals: u64,
}

/// Of [`crate::trace::metrics::Collisions`].
#[derive(serde::Deserialize)]
struct CollidingSeeds {
    seeds: u64,
}

/// The title's font size: 20 pixels, smaller where a long title would not fit `width`
/// pixels (about 0.5 em a character).
pub(super) fn title_size(title: &str, width: u32) -> u32 {
    let chars = title.chars().count().max(1) as u32;
    (2 * width / chars).clamp(11, 20)
}

/// Write `draw`'s picture to `dest` (PNG or SVG by extension) through a temporary file.
pub(super) fn staged_draw(
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
pub(super) fn atlas_points(
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

pub(super) fn draw_atlas<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    title: &str,
    pts: &[(f64, f64, RGBColor)],
    caption: &str,
    legend: &Legend,
) -> Result<(), String> {
    let e = |x: DrawingAreaErrorKind<DB::ErrorType>| x.to_string();
    root.fill(&WHITE).map_err(e)?;
    let mut chart = ChartBuilder::on(root)
        .caption(title, ("sans-serif", title_size(title, 1200)))
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
