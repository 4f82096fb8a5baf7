//! The legend under the atlas: a color bar with ticks, or a swatch per category.

use plotters::prelude::*;

use super::paint::Legend;

/// Draw `legend` in one row that ends at `right` (pixels, the text's top line).
pub(super) fn draw_legend<DB: DrawingBackend>(
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

/// A round step (1, 2 or 5 times a power of ten) that cuts `span` into at most `n`
/// pieces.
pub(super) fn nice_step(span: i32, n: i32) -> i32 {
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
