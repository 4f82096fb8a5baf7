//! The inverse map: (phi, theta, psi) -> x, by tracing uphill in phi from the stop ball
//! along the direction (theta, psi) until phi is reached.
//!
//! A forward streamline ends where it enters the stop ball, at c + R d(theta, psi); the
//! inverse starts there and follows the tracer's direction field backwards (up phi)
//! with classical RK4 steps of a quarter voxel, then places the point where phi is
//! reached by linear interpolation of u = 1 - phi on the last step. Inside the stop ball
//! the forward map is the direction from the center, so a phi below the stop sphere's is
//! found on the ray from the center by bisection.
//!
//! The field is held whole (16 bytes per voxel, plus 8 while it is built); a grid whose
//! field does not fit `--mem` is refused with the budget it needs.

use glam::DVec3;

use crate::grid::{BlockStore, GridError, MemBudget};
use crate::run::RunDir;
use crate::trace::field::Tile;
use crate::trace::integrate::StopBall;

/// Step of the uphill integration (voxels).
const STEP: f64 = 0.25;
/// Steps allowed per point.
const MAX_STEPS: usize = 200_000;

/// Where a point of the inverse map is, or why it has none.
pub type InverseResult = Result<DVec3, String>;

/// The inverse map of a mapped (solved) run, ready to evaluate.
pub struct Inverse {
    tile: Tile,
    ball: StopBall,
    origin: DVec3,
    spacing: f64,
}

impl Inverse {
    /// Load the direction field of `run` within `mem`.
    pub fn new(
        run: &RunDir,
        stop_radius: Option<f64>,
        mem: MemBudget,
    ) -> Result<Self, crate::Error> {
        let attrs = run.require_stage("solve")?;
        let spec = run.grid()?;
        let ball = crate::trace::stage::stop_ball(&attrs, &spec, stop_radius, run.root())?;
        let n = spec.num_voxels();
        let need = n * 24;
        if need > mem.work_bytes() {
            return Err(GridError::Budget {
                budget: mem.to_string(),
                what: "the inverse map (the whole direction field)".into(),
                needed: crate::grid::human(need + crate::grid::BASE_BYTES),
                suggest: crate::grid::human((need + crate::grid::BASE_BYTES).next_power_of_two()),
            }
            .into());
        }
        let u = run.open_image::<f64>("u")?;
        let s = spec.shape;
        let block = u.read_region([-1, -1, -1], s.map(|c| c as usize + 2), f64::NAN)?;
        let tile = Tile::from_u(&block, [0, 0, 0], s.map(|c| c as usize));
        Ok(Self {
            tile,
            ball,
            origin: DVec3::from_array(spec.origin),
            spacing: spec.spacing,
        })
    }

    /// u = 1 - phi at `p` (voxel coordinates), if every corner of its cell has one.
    fn u(&self, p: DVec3) -> Option<f64> {
        self.tile.interpolate(p).ok().map(|(_, u)| u)
    }

    /// The world point with `(phi, theta, psi)`, or why there is none.
    pub fn point(&self, phi: f64, theta: f64, psi: f64) -> InverseResult {
        if !(0.0..=1.0).contains(&phi) {
            return Err(format!("phi {phi} is outside [0, 1]"));
        }
        self.point_u(1.0 - phi, theta, psi)
    }

    /// The world point with u = 1 - phi = `u`, `theta`, `psi`: the same as
    /// [`Inverse::point`], precise where phi rounds to 1.
    pub fn point_u(&self, u: f64, theta: f64, psi: f64) -> InverseResult {
        if !(0.0..=1.0).contains(&u) {
            return Err(format!("u = 1 - phi = {u} is outside [0, 1]"));
        }
        if !(0.0..=std::f64::consts::PI).contains(&theta) || !psi.is_finite() {
            return Err(format!(
                "theta {theta} must lie in [0, pi] and psi be finite"
            ));
        }
        let d = crate::trace::unit(theta, psi);
        let c = self.ball.center;
        let target = u;
        let start = c + self.ball.radius * d;
        let u0 = self.u(start).ok_or_else(|| {
            "the stop sphere is outside the solved region in this direction".to_owned()
        })?;
        let p = if target >= u0 {
            // Within the stop ball: on the ray from the center, where u falls from 1.
            let (mut lo, mut hi) = (0.0, self.ball.radius);
            for _ in 0..60 {
                let mid = 0.5 * (lo + hi);
                match self.u(c + mid * d) {
                    Some(u) if u > target => lo = mid,
                    _ => hi = mid,
                }
            }
            c + 0.5 * (lo + hi) * d
        } else {
            self.uphill(start, u0, target)?
        };
        Ok(self.origin + self.spacing * p)
    }

    /// Follow the field backwards (up phi, down u) from `p` (u = `up`) to u = `target`.
    fn uphill(&self, mut p: DVec3, mut up: f64, target: f64) -> InverseResult {
        let back = |q: DVec3| -> Option<DVec3> { self.tile.direction(q).ok().map(|v| -v) };
        let lost = || {
            "the streamline leaves the solid before phi is reached (a region the forward map does not reach)".to_owned()
        };
        for _ in 0..MAX_STEPS {
            let k1 = back(p).ok_or_else(lost)?;
            let k2 = back(p + 0.5 * STEP * k1).ok_or_else(lost)?;
            let k3 = back(p + 0.5 * STEP * k2).ok_or_else(lost)?;
            let k4 = back(p + STEP * k3).ok_or_else(lost)?;
            let next = p + STEP / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4);
            let un = self.u(next).ok_or_else(lost)?;
            if un <= target {
                let t = if up > un {
                    (up - target) / (up - un)
                } else {
                    1.0
                };
                return Ok(p + t.clamp(0.0, 1.0) * (next - p));
            }
            if un >= up {
                // u no longer falls: the boundary sheet (u = 0 all round) or a ridge.
                return if target <= 0.0 && un <= 1e-12 {
                    Ok(next)
                } else {
                    Err("phi stops rising before the requested value (flat field)".to_owned())
                };
            }
            p = next;
            up = un;
        }
        Err(format!(
            "no phi = {} within {MAX_STEPS} steps",
            1.0 - target
        ))
    }
}

/// Rows of an inverse-map CSV: how many, and how many had no point.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct InverseCounts {
    /// Rows read.
    pub rows: u64,
    /// Rows without a point (their `status` says why).
    pub failed: u64,
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
    use crate::export::ExportError;
    use std::io::Write;
    let bad = |msg: String| -> crate::Error { ExportError::Unavailable(msg).into() };
    let text = std::fs::read_to_string(input)
        .map_err(|e| bad(format!("{}: cannot read: {e}", input.display())))?;
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty());
    let (_, header) = lines.next().ok_or_else(|| {
        bad(format!(
            "{}: empty file; expected a header with phi,theta,psi",
            input.display()
        ))
    })?;
    let cols: Vec<&str> = header.split(',').map(str::trim).collect();
    let col = |name: &str| {
        cols.iter()
            .position(|c| c.eq_ignore_ascii_case(name))
            .ok_or_else(|| {
                bad(format!(
                    "{}:1: no column `{name}` in the header `{header}` (expected phi,theta,psi)",
                    input.display()
                ))
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
                bad(format!(
                    "{}:{}: {} columns, the header has {}",
                    input.display(),
                    i + 1,
                    f.len(),
                    cols.len()
                ))
            })?;
            v[k] = s
                .parse::<f64>()
                .ok()
                .filter(|x| !x.is_nan())
                .ok_or_else(|| {
                    bad(format!(
                        "{}:{}: `{s}` in column {} is not a number",
                        input.display(),
                        i + 1,
                        cols[c]
                    ))
                })?;
        }
        rows.push(v);
    }
    let stop_radius = run
        .attrs()?
        .pointer("/stages/trace/options/stop_radius")
        .and_then(serde_json::Value::as_f64);
    let inv = Inverse::new(run, stop_radius, mem)?;
    progress.start("inverse", rows.len() as u64);
    let points: Vec<InverseResult> = {
        use rayon::prelude::*;
        rows.par_iter()
            .map(|r| {
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
