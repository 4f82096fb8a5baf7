//! The solve's convergence history as an inline SVG: the relative residual and the
//! largest change of each iteration on a log axis, with the stop tolerance.
// Index arithmetic over the grid's axes: z, y, x and i, j, k read as in the formulas.
#![allow(clippy::many_single_char_names)]

use std::fmt::Write as _;

/// A line of the plot: its name, color and values (one per iteration from 0).
pub struct Series<'a> {
    /// Legend text.
    pub name: &'a str,
    /// CSS color.
    pub color: &'a str,
    /// The values; non-positive and non-finite ones are left out (no log).
    pub values: &'a [f64],
}

const W: f64 = 640.0;
const H: f64 = 300.0;
const LEFT: f64 = 64.0;
const RIGHT: f64 = 16.0;
const TOP: f64 = 16.0;
const BOTTOM: f64 = 44.0;

/// An SVG (a `<svg>` element) of `series` against the iteration on a log10 y axis,
/// with a dashed horizontal line at `target` when it is positive. None when no series
/// has a positive value.
#[must_use]
#[allow(clippy::too_many_lines)] // one SVG plot: axes, ticks, series and legend share one coordinate frame
pub fn log_history(series: &[Series<'_>], target: Option<f64>) -> Option<String> {
    let positive = |v: f64| v.is_finite() && v > 0.0;
    let mut lo = f64::INFINITY;
    let mut hi = f64::NEG_INFINITY;
    let mut n = 0usize;
    for s in series {
        n = n.max(s.values.len());
        for &v in s.values.iter().filter(|&&v| positive(v)) {
            lo = lo.min(v.log10());
            hi = hi.max(v.log10());
        }
    }
    if !lo.is_finite() {
        return None;
    }
    if let Some(t) = target.filter(|&t| positive(t)) {
        lo = lo.min(t.log10());
        hi = hi.max(t.log10());
    }
    // Whole decades, at least one.
    let (lo, hi) = (lo.floor(), hi.ceil().max(lo.floor() + 1.0));
    let xmax = (n.saturating_sub(1)).max(1) as f64;
    let px = |i: f64| LEFT + (W - LEFT - RIGHT) * i / xmax;
    let py = |v: f64| TOP + (H - TOP - BOTTOM) * (hi - v.log10()) / (hi - lo);
    let mut s = String::new();
    let _ = write!(
        s,
        r#"<svg class="plot" viewBox="0 0 {W} {H}" width="{W}" height="{H}" role="img" aria-label="convergence history">"#
    );
    let _ = write!(
        s,
        r##"<rect x="{LEFT}" y="{TOP}" width="{}" height="{}" fill="#fff" stroke="#999"/>"##,
        W - LEFT - RIGHT,
        H - TOP - BOTTOM
    );
    // Decade grid lines and labels; at most about ten labels.
    let decades = (hi - lo) as i64;
    let every = (decades / 10 + 1).max(1);
    for d in (lo as i64)..=(hi as i64) {
        let y = py(10f64.powi(d as i32));
        let _ = write!(
            s,
            r##"<line x1="{LEFT}" x2="{}" y1="{y:.1}" y2="{y:.1}" stroke="#e4e4e4"/>"##,
            W - RIGHT
        );
        if (d - lo as i64) % every == 0 {
            let _ = write!(
                s,
                r#"<text x="{}" y="{:.1}" text-anchor="end" font-size="11">1e{d}</text>"#,
                LEFT - 6.0,
                y + 4.0
            );
        }
    }
    // Iteration ticks: about six.
    let step = nice_step(xmax / 6.0);
    let mut i = 0.0;
    while i <= xmax + 1e-9 {
        let x = px(i);
        let _ = write!(
            s,
            r##"<line x1="{x:.1}" x2="{x:.1}" y1="{}" y2="{}" stroke="#999"/><text x="{x:.1}" y="{}" text-anchor="middle" font-size="11">{}</text>"##,
            H - BOTTOM,
            H - BOTTOM + 4.0,
            H - BOTTOM + 16.0,
            i as u64
        );
        i += step;
    }
    let _ = write!(
        s,
        r#"<text x="{}" y="{}" text-anchor="middle" font-size="12">iteration</text>"#,
        LEFT + (W - LEFT - RIGHT) / 2.0,
        H - 8.0
    );
    if let Some(t) = target.filter(|&t| positive(t)) {
        let y = py(t);
        let _ = write!(
            s,
            r##"<line x1="{LEFT}" x2="{}" y1="{y:.1}" y2="{y:.1}" stroke="#555" stroke-dasharray="5 4"/><text x="{}" y="{:.1}" text-anchor="end" font-size="11" fill="#555">rtol {t:.0e}</text>"##,
            W - RIGHT,
            W - RIGHT - 4.0,
            y - 4.0
        );
    }
    for (k, ser) in series.iter().enumerate() {
        let pts: Vec<String> = ser
            .values
            .iter()
            .enumerate()
            .filter(|(_, &v)| positive(v))
            .map(|(i, &v)| format!("{:.1},{:.1}", px(i as f64), py(v)))
            .collect();
        if pts.is_empty() {
            continue;
        }
        let _ = write!(
            s,
            r#"<polyline fill="none" stroke="{}" stroke-width="2" points="{}"/>"#,
            ser.color,
            pts.join(" ")
        );
        if pts.len() <= 60 {
            for p in &pts {
                let (x, y) = p.split_once(',').unwrap_or(("0", "0"));
                let _ = write!(
                    s,
                    r#"<circle cx="{x}" cy="{y}" r="2.5" fill="{}"/>"#,
                    ser.color
                );
            }
        }
        let ly = TOP + 14.0 + 16.0 * k as f64;
        let lx = W - RIGHT - 170.0;
        let _ = write!(
            s,
            r#"<line x1="{lx}" x2="{}" y1="{ly}" y2="{ly}" stroke="{}" stroke-width="2"/><text x="{}" y="{}" font-size="11">{}</text>"#,
            lx + 18.0,
            ser.color,
            lx + 24.0,
            ly + 4.0,
            super::escape(ser.name)
        );
    }
    s.push_str("</svg>");
    Some(s)
}

/// 1, 2 or 5 times a power of ten, at least `raw` and at least 1.
fn nice_step(raw: f64) -> f64 {
    if raw <= 1.0 {
        return 1.0;
    }
    let p = 10f64.powf(raw.log10().floor());
    [1.0, 2.0, 5.0, 10.0]
        .into_iter()
        .map(|m| m * p)
        .find(|&s| s >= raw)
        .unwrap_or(10.0 * p)
}

#[cfg(test)]
#[allow(clippy::float_cmp)] // round steps are exact
mod tests {
    use super::*;

    #[test]
    fn a_residual_halving_each_iteration_falls_linearly_on_the_log_axis() {
        let v: Vec<f64> = (0..11).map(|i| 0.5f64.powi(i)).collect();
        let svg = log_history(
            &[Series {
                name: "residual",
                color: "#1f77b4",
                values: &v,
            }],
            Some(1e-3),
        )
        .unwrap();
        let pts = svg.split("points=\"").nth(1).unwrap();
        let pts: Vec<(f64, f64)> = pts[..pts.find('"').unwrap()]
            .split(' ')
            .map(|p| {
                let (x, y) = p.split_once(',').unwrap();
                (x.parse().unwrap(), y.parse().unwrap())
            })
            .collect();
        assert_eq!(pts.len(), 11);
        // Equal steps in x and in y (to the 0.1 px rounding).
        let dx = pts[1].0 - pts[0].0;
        let dy = pts[1].1 - pts[0].1;
        assert!(dy > 0.0, "falling values go down the page");
        for w in pts.windows(2) {
            assert!((w[1].0 - w[0].0 - dx).abs() < 0.2);
            assert!((w[1].1 - w[0].1 - dy).abs() < 0.2);
        }
        assert!(svg.contains("stroke-dasharray"), "the tolerance line");
    }

    #[test]
    fn nothing_to_plot_without_positive_values() {
        let v = [0.0, f64::NAN, -1.0];
        let s = [Series {
            name: "x",
            color: "#000",
            values: &v,
        }];
        assert!(log_history(&s, None).is_none());
    }

    #[test]
    fn steps_are_round_numbers() {
        assert_eq!(nice_step(0.3), 1.0);
        assert_eq!(nice_step(1.5), 2.0);
        assert_eq!(nice_step(3.0), 5.0);
        assert_eq!(nice_step(7.0), 10.0);
        assert_eq!(nice_step(130.0), 200.0);
    }
}
