//! The report page of a run: one self-contained HTML file a person can open.
//!
//! [`write_report`] gathers what a run records (its `harmap` attributes) and what it
//! holds (the fields, the seed table) into one page: the input, the grid, the topology
//! and any repair, the solve's convergence history (an inline SVG), the trace's stop
//! reasons, flipped triangles, collisions and distortion, the map, the atlas and the
//! sphere view (PNGs drawn by [`super::atlas`]), slices of phi, theta and psi through
//! the center voxel, and the seconds and peak memory of every stage. Every picture is a
//! `data:` URI and the style is inline, so the page needs no network and no other file.
//! Stages not run yet are said to be missing; the page is written for any run that is
//! voxelized.
// Index arithmetic over the grid's axes: z, y, x and i, j, k read as in the formulas.
#![allow(clippy::many_single_char_names)]

use std::fmt::Write as _;
use std::path::Path;

use crate::run::{write_atomic, RunDir};

mod base64;
mod plot;
pub mod png;
mod repair;
mod sections;
mod slices;

use sections::{
    grid_section, input_section, map_section, pictures_section, slices_section, solve_section,
    timings_section, topology_section, trace_section,
};
pub use slices::Colormap;

const STYLE: &str = "
body{font-family:system-ui,-apple-system,'Segoe UI',Roboto,sans-serif;margin:0;background:#f6f6f4;color:#222}
main{max-width:1260px;margin:0 auto;padding:16px 24px 48px}
h1{font-size:1.6em;margin:.4em 0 .1em}h2{font-size:1.2em;margin:0 0 .5em;border-bottom:1px solid #ddd;padding-bottom:.2em}
section{background:#fff;border:1px solid #e2e2de;border-radius:6px;padding:12px 16px;margin:14px 0}
.sub{color:#666;margin:0 0 8px}.note{color:#666;font-size:.9em}.warn{color:#a33}
table{border-collapse:collapse;font-size:.92em;margin:4px 0 8px}td,th{padding:3px 10px 3px 0;text-align:left;vertical-align:top}
th{color:#555;font-weight:600}td.n{text-align:right;font-variant-numeric:tabular-nums}
table.kv td:first-child{color:#555;padding-right:18px}
.row{display:flex;flex-wrap:wrap;gap:18px;align-items:flex-start}
figure{margin:0}figcaption{font-size:.85em;color:#555;margin-top:4px}
img{max-width:100%;height:auto;image-rendering:pixelated;border:1px solid #ddd}
img.photo{image-rendering:auto}
.bar{height:10px;width:220px;border:1px solid #ccc}.ends{display:flex;justify-content:space-between;width:222px;font-size:.8em;color:#555}
pre{background:#f4f4f2;padding:6px 8px;font-size:.85em;overflow:auto;max-height:24em}
";

/// Write the report page of `run` to `out` (under a temporary name, renamed when
/// whole). The run must be voxelized; the later stages are shown when done.
pub fn write_report(run: &RunDir, out: &Path) -> Result<(), crate::Error> {
    let page = render(run)?;
    write_atomic(out, page.as_bytes())?;
    Ok(())
}

/// The report page of `run` as HTML text.
pub fn render(run: &RunDir) -> Result<String, crate::Error> {
    let attrs = run.require_stage("voxelize")?;
    let name = run
        .root()
        .file_name()
        .map_or_else(|| "run".to_owned(), |n| n.to_string_lossy().into_owned());
    let mut p = String::with_capacity(1 << 20);
    let _ = write!(
        p,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
         <meta name=\"viewport\" content=\"width=device-width,initial-scale=1\">\
         <link rel=\"icon\" href=\"data:,\">\
         <title>harmap report: {}</title><style>{STYLE}</style></head><body><main>\n\
         <h1>harmap report: {}</h1><p class=\"sub\">Run directory {} &middot; harmap {}</p>\n",
        escape(&name),
        escape(&name),
        escape(&run.root().display().to_string()),
        env!("CARGO_PKG_VERSION")
    );
    input_section(&mut p, &attrs);
    grid_section(&mut p, &attrs);
    topology_section(&mut p, &attrs);
    solve_section(&mut p, &attrs);
    trace_section(&mut p, &attrs);
    map_section(&mut p, &attrs);
    pictures_section(&mut p, run, &attrs);
    slices_section(&mut p, run, &attrs);
    timings_section(&mut p, &attrs);
    p.push_str("</main></body></html>\n");
    Ok(p)
}

/// `s` with the characters HTML gives a meaning escaped.
#[must_use]
pub fn escape(s: &str) -> String {
    let mut o = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => o.push_str("&amp;"),
            '<' => o.push_str("&lt;"),
            '>' => o.push_str("&gt;"),
            '"' => o.push_str("&quot;"),
            '\'' => o.push_str("&#39;"),
            _ => o.push(c),
        }
    }
    o
}

/// A `data:` URI of a PNG file.
#[must_use]
pub fn png_data_uri(png: &[u8]) -> String {
    format!("data:image/png;base64,{}", base64::encode(png))
}
