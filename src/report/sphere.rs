//! The mapped sphere seen from four viewpoints.

use glam::DVec3;
use plotters::prelude::*;

use crate::trace::SeedTable;

/// Views of the sphere: (name, view direction toward the viewer, screen x, screen y).
pub(super) fn views() -> [(&'static str, DVec3, DVec3, DVec3); 4] {
    [
        ("from +x", DVec3::X, DVec3::Y, DVec3::Z),
        ("from -x", -DVec3::X, -DVec3::Y, DVec3::Z),
        ("from +z (north pole)", DVec3::Z, DVec3::X, DVec3::Y),
        ("from -z (south pole)", -DVec3::Z, DVec3::X, -DVec3::Y),
    ]
}

pub(super) fn draw_sphere<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    title: &str,
    t: &SeedTable,
    c: &[RGBColor],
) -> Result<(), String> {
    let e = |x: DrawingAreaErrorKind<DB::ErrorType>| x.to_string();
    root.fill(&WHITE).map_err(e)?;
    let root = root
        .titled(title, ("sans-serif", super::plot::title_size(title, 1600)))
        .map_err(e)?;
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
