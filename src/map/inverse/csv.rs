//! `harmap inverse`'s files: the points read from a CSV file, placed in the order of
//! their directions, written back with their positions.

use glam::DVec3;

use super::{direction_key, Inverse, InverseResult, MapError};
use crate::grid::MemBudget;
use crate::run::RunDir;

/// Rows of an inverse-map CSV: how many, and how many had no point.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct InverseCounts {
    /// Rows read.
    pub rows: u64,
    /// Rows without a point (their `status` says why).
    pub failed: u64,
}

/// The stop radius of the map's report or of the trace's options.
#[derive(serde::Deserialize)]
struct StopRadius {
    stop_radius: Option<f64>,
}

/// Read `input` (CSV with a header naming `phi` (or `u` = 1 - phi, preferred when
/// present), `theta` and `psi`; other columns are ignored) and write `output`: `phi,theta,psi,x,y,z,status` per row, x, y, z empty and
/// status the reason where a row has no point. Written under a temporary name.
pub fn inverse_csv(
    run: &RunDir,
    input: &std::path::Path,
    output: &std::path::Path,
    mem: MemBudget,
    progress: &dyn crate::progress::Progress,
) -> Result<InverseCounts, crate::Error> {
    use std::io::Write;
    let (first, by_u, rows) = read_points(input)?;
    // The map's stop ball (the trace may have been run again with another since).
    let attrs = run.attrs()?;
    let stop_radius = match crate::run::report_in::<StopRadius>(&attrs, "map") {
        Some(m) => m.stop_radius,
        None => crate::run::options_in::<StopRadius>(&attrs, "trace").and_then(|t| t.stop_radius),
    };
    let inv = Inverse::new(run, stop_radius, mem)?;
    if let Some(problem) = &inv.boundary().problem {
        progress.warn(problem);
    }
    progress.start("inverse", rows.len() as u64);
    // In the Z order of their directions, so consecutive points climb through the same
    // tiles; results go back to the rows' order. (Bands of theta swept in psi went round
    // the sphere for every band: with --mem 256MiB on the 512^3 ball, 10,000 points deep
    // in the solid rebuilt their tiles over and over.)
    let mut order: Vec<usize> = (0..rows.len()).collect();
    order.sort_by_key(|&i| (direction_key(rows[i][1], rows[i][2]), i));
    let sorted: Vec<InverseResult> = {
        use rayon::prelude::*;
        order
            .par_iter()
            .with_min_len(64)
            .map(|&i| {
                let r = &rows[i];
                let p = if by_u {
                    inv.point_u(r[0], r[1], r[2])
                } else {
                    inv.point(r[0], r[1], r[2])
                };
                progress.advance(1);
                p
            })
            .collect()
    };
    let mut points: Vec<InverseResult> = vec![Ok(DVec3::ZERO); rows.len()];
    for (p, &i) in sorted.into_iter().zip(&order) {
        points[i] = p;
    }
    progress.finish();
    let mut out = crate::export::Staged::create(output)?;
    let mut failed = 0;
    writeln!(out.out, "{first},theta,psi,x,y,z,status").map_err(|e| out.io(e))?;
    for (r, p) in rows.iter().zip(&points) {
        match p {
            Ok(x) => writeln!(
                out.out,
                "{},{},{},{},{},{},ok",
                r[0], r[1], r[2], x.x, x.y, x.z
            ),
            Err(why) => {
                failed += 1;
                writeln!(
                    out.out,
                    "{},{},{},,,,{}",
                    r[0],
                    r[1],
                    r[2],
                    why.replace(',', ";")
                )
            }
        }
        .map_err(|e| out.io(e))?;
    }
    out.commit()?;
    Ok(InverseCounts {
        rows: rows.len() as u64,
        failed,
    })
}

/// The rows of the points file `input`: the name of the first column (`u` when the
/// header has it, else `phi`), whether it is u, and (phi or u, theta, psi) per row.
fn read_points(
    input: &std::path::Path,
) -> Result<(&'static str, bool, Vec<[f64; 3]>), crate::Error> {
    let bad = |line: usize, what: String| -> crate::Error {
        MapError::Points {
            path: input.to_path_buf(),
            line: line as u64,
            what,
        }
        .into()
    };
    let text = std::fs::read_to_string(input).map_err(|e| {
        if e.kind() == std::io::ErrorKind::NotFound {
            MapError::PointsMissing {
                path: input.to_path_buf(),
            }
        } else {
            MapError::PointsUnreadable {
                path: input.to_path_buf(),
                source: e,
            }
        }
    })?;
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty());
    let (_, header) = lines
        .next()
        .ok_or_else(|| bad(1, "empty file; expected a header with phi,theta,psi".into()))?;
    let cols: Vec<&str> = header.split(',').map(str::trim).collect();
    let col = |name: &str| {
        cols.iter()
            .position(|c| c.eq_ignore_ascii_case(name))
            .ok_or_else(|| {
                bad(
                    1,
                    format!("no column `{name}` in the header `{header}` (expected phi,theta,psi)"),
                )
            })
    };
    // u = 1 - phi keeps its precision where phi rounds to 1 (thin parts): prefer it.
    let by_u = cols.iter().any(|c| c.eq_ignore_ascii_case("u"));
    let first = if by_u { "u" } else { "phi" };
    let idx = [col(first)?, col("theta")?, col("psi")?];
    let mut rows = Vec::new();
    for (i, line) in lines {
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        let mut v = [0.0; 3];
        for (k, &c) in idx.iter().enumerate() {
            let s = f.get(c).ok_or_else(|| {
                bad(
                    i + 1,
                    format!("{} columns, the header has {}", f.len(), cols.len()),
                )
            })?;
            v[k] = s
                .parse::<f64>()
                .ok()
                .filter(|x| !x.is_nan())
                .ok_or_else(|| {
                    bad(
                        i + 1,
                        format!("`{s}` in column {} is not a number", cols[c]),
                    )
                })?;
        }
        rows.push(v);
    }
    Ok((first, by_u, rows))
}
