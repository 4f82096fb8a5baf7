//! The inverse map: (phi, theta, psi) -> x, from the stop ball along the direction
//! (theta, psi) back up phi until phi is reached.
//!
//! A forward streamline of the exact map ends where it enters the stop ball, at
//! c + R d(theta, psi), after steps on levels of ln u (u = 1 - phi). The inverse starts
//! there and undoes those steps one by one ([`Inverse::undo_levels`]), which returns to
//! the voxel however much the forward map squeezed its streamlines. Where that stops
//! (near the boundary, or a streamline that began on its own steps) it follows the
//! tracer's direction field backwards with classical RK4 steps of a quarter voxel, and
//! places the point where u is reached by linear interpolation on the last step. Inside
//! the stop ball the forward map is the direction from the center, so a phi below the
//! stop sphere's is found on the ray from the center by bisection.
//!
//! Out of core: the field is built tile by tile (the tracer's node directions, with a
//! halo, so a point's value is the same in whichever tile holds it) into a cache bounded
//! by `--mem`; points are processed in the order of their directions, so consecutive
//! points climb through the same tiles.

mod csv;

pub use csv::{inverse_csv, InverseCounts};

use std::sync::Arc;

use glam::DVec3;

use super::MapError;
use crate::grid::{BlockStore, GridError, MemBudget};
use crate::run::RunDir;
use crate::trace::field::Tile;
use crate::trace::integrate::{level_step, onto_level, LevelEnd, LevelField, Rk45, StopBall};
use crate::trace::surface::{Boundary, BOUNDARY_MESH};

/// The fields of the map's report ([`super::MapReport`]) the inverse follows.
#[derive(serde::Deserialize)]
struct MapRecorded {
    /// Where the direction field's boundary values came from.
    boundary: Option<String>,
    /// The exact map's integrator.
    integrator: Option<Rk45>,
}

/// Step of the uphill integration (voxels).
const STEP: f64 = 0.25;
/// Steps allowed per point.
const MAX_STEPS: usize = 200_000;
/// Iterations allowed to undo one step on levels.
const MAX_ITERATIONS: usize = 60;
/// How close (voxels) an undone step must come back to where the forward step ended.
const UNDONE: f64 = 1e-9;
/// Levels closer than this (voxels) are not undone: within a fraction of a voxel of the
/// boundary, where u falls to 0 and the levels crowd, the rest is traced uphill.
const MIN_LEVEL_GAP: f64 = 0.02;

/// Where a point of the inverse map is, or why it has none.
pub type InverseResult = Result<DVec3, String>;

/// Tiles of the direction field, built on demand into an LRU cache.
struct Tiles {
    u: crate::grid::ZarrStore<f64>,
    grid: crate::math::Idx3,
    edge: u64,
    halo: i64,
    cache: std::sync::Mutex<crate::trace::tiles::Lru<Tile>>,
    boundary: Boundary,
}

impl Tiles {
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    fn key(&self, p: DVec3) -> ([u64; 3], u64) {
        let c = [p.z, p.y, p.x];
        let n = self.grid.map(|g| g.div_ceil(self.edge));
        let t: [u64; 3] = std::array::from_fn(|a| {
            let f = c[a].floor();
            let i = if f < 0.0 { 0 } else { f as u64 / self.edge };
            i.min(n[a] - 1)
        });
        (t, (t[0] * n[1] + t[1]) * n[2] + t[2])
    }

    /// The tile that owns the cell of `p`, with its halo.
    fn get(&self, p: DVec3) -> Result<Arc<Tile>, GridError> {
        let (t, k) = self.key(p);
        if let Some(tile) = self.cache.lock().expect("lock").get(k) {
            return Ok(tile);
        }
        let origin: [i64; 3] = std::array::from_fn(|a| (t[a] * self.edge) as i64 - self.halo);
        let shape: [usize; 3] = std::array::from_fn(|a| {
            let hi = ((t[a] + 1) * self.edge).min(self.grid[a]) as i64 + self.halo;
            (hi - origin[a]) as usize
        });
        let (u_origin, u_shape) = Tile::u_box(origin, shape);
        let block = self.u.read_region(u_origin, u_shape, f64::NAN)?;
        let tile = Arc::new(Tile::from_u(&block, origin, shape, self.boundary.index()));
        self.cache.lock().expect("lock").put(k, tile.clone());
        Ok(tile)
    }
}

/// The tile a point is in, kept while the point stays well inside it.
struct Cursor<'a> {
    tiles: &'a Tiles,
    tile: Option<Arc<Tile>>,
    error: Option<GridError>,
}

impl Cursor<'_> {
    fn tile(&mut self, p: DVec3) -> Option<&Tile> {
        let inside = |t: &Tile| {
            let c = [p.z.floor() as i64, p.y.floor() as i64, p.x.floor() as i64];
            (0..3).all(|a| c[a] - 2 >= t.origin[a] && c[a] + 3 < t.origin[a] + t.shape[a] as i64)
        };
        if !self.tile.as_deref().is_some_and(inside) {
            match self.tiles.get(p) {
                Ok(t) => self.tile = Some(t),
                Err(e) => {
                    self.error = Some(e);
                    return None;
                }
            }
        }
        self.tile.as_deref()
    }

    /// u = 1 - phi at `p`, if every corner of its cell has one.
    fn u(&mut self, p: DVec3) -> Option<f64> {
        self.tile(p)?.interpolate(p).ok().map(|(_, u)| u)
    }

    /// The direction up phi (down u) at `p`.
    fn back(&mut self, p: DVec3) -> Option<DVec3> {
        self.tile(p)?.direction(p).ok().map(|v| -v)
    }
}

/// `q` moved onto the trilinear u = `target` by Newton steps along its gradient (each
/// skipped where it would move more than half a voxel).
fn onto_u(cur: &mut Cursor<'_>, mut q: DVec3, target: f64) -> DVec3 {
    for _ in 0..3 {
        let Some((u, g)) = cur.tile(q).and_then(|t| t.u_trilinear(q)) else {
            break;
        };
        let m = (u - target) / g.length_squared();
        if !m.is_finite() || (m * g).length() > 0.5 {
            break;
        }
        q -= m * g;
    }
    q
}

impl LevelField for Cursor<'_> {
    fn level(&mut self, q: DVec3) -> Option<(f64, DVec3)> {
        self.tile(q)?.level(q)
    }
    fn velocity(&mut self, q: DVec3) -> Option<DVec3> {
        self.tile(q)?.level_velocity(q)
    }
}

/// A key whose order is a Z (Morton) order of directions: theta and psi cut into 2^16
/// steps each, their bits interleaved, so nearby directions mostly have nearby keys.
/// Values outside their ranges (refused later, row by row) are clamped.
fn direction_key(theta: f64, psi: f64) -> u64 {
    let q = |v: f64, lo: f64, hi: f64| -> u64 {
        let t = ((v - lo) / (hi - lo)).clamp(0.0, 1.0);
        if t.is_nan() {
            0
        } else {
            (t * 65535.0) as u64
        }
    };
    let spread = |mut x: u64| {
        x &= 0xffff;
        x = (x | (x << 8)) & 0x00ff_00ff;
        x = (x | (x << 4)) & 0x0f0f_0f0f;
        x = (x | (x << 2)) & 0x3333_3333;
        (x | (x << 1)) & 0x5555_5555
    };
    let pi = std::f64::consts::PI;
    spread(q(theta, 0.0, pi)) << 1 | spread(q(psi, -pi, pi))
}

/// The inverse map of a solved run, ready to evaluate.
pub struct Inverse {
    tiles: Tiles,
    ball: StopBall,
    /// The exact map's integrator, whose steps on levels are undone.
    rk: Rk45,
    origin: DVec3,
    spacing: f64,
}

impl Inverse {
    /// Set up the inverse of `run` within `mem`.
    pub fn new(
        run: &RunDir,
        stop_radius: Option<f64>,
        mem: MemBudget,
    ) -> Result<Self, crate::Error> {
        let attrs = run.require_stage("solve")?;
        let spec = run.grid()?;
        let ball = crate::trace::stage::stop_ball(&attrs, &spec, stop_radius, run.root()).map_err(
            |e| match e {
                crate::Error::Trace(crate::trace::TraceError::Options(m)) => {
                    MapError::Options(m).into()
                }
                e => e,
            },
        )?;
        let u = run.open_image::<f64>("u")?;
        let edge = spec.chunk.iter().copied().max().unwrap_or(64);
        let halo = 3;
        let side = [(edge + 2 * halo as u64) as usize; 3];
        // A tile; building one holds u over it with the margin, the boundary's
        // corrections, and the chunks the region is assembled from.
        let tile_bytes = Tile::bytes(side);
        let build = Tile::build_bytes(side) + 8 * crate::math::volume(spec.chunk) * 8;
        let threads = rayon::current_num_threads() as u64;
        // The field the map followed: boundary values from the input mesh only if the
        // map's were (a map recorded before they could be had the smoothed solid's).
        let mapped = crate::run::stage_record(&attrs, "map").is_some();
        let recorded = crate::run::report_in::<MapRecorded>(&attrs, "map");
        let map_boundary = recorded.as_ref().and_then(|m| m.boundary.as_deref());
        let boundary = if mapped && map_boundary != Some(BOUNDARY_MESH) {
            Boundary::default()
        } else {
            let mut b = Boundary::for_run(&attrs, &spec, mem);
            if mapped && b.mesh.is_none() {
                let why = b.problem.take().unwrap_or_else(|| {
                    "the input mesh is not used for this run now (--close, filled cavities or removed pieces)".into()
                });
                b.problem = Some(format!(
                    "{why}; the map used the mesh, so next to the boundary the inverse follows another field"
                ));
            }
            b
        };
        let avail = mem
            .work_bytes()
            .saturating_sub(threads * build + boundary.bytes());
        let cap = avail / tile_bytes;
        if cap < threads + 1 {
            let need = (threads + 1) * tile_bytes + threads * build + boundary.bytes();
            return Err(GridError::Budget {
                budget: mem.to_string(),
                what: "the inverse map (tiles of the direction field)".into(),
                needed: crate::grid::human(need + crate::grid::BASE_BYTES),
                suggest: crate::grid::human((need + crate::grid::BASE_BYTES).next_power_of_two()),
            }
            .into());
        }
        let total = spec.shape.iter().map(|n| n.div_ceil(edge)).product::<u64>();
        Ok(Self {
            tiles: Tiles {
                u,
                grid: spec.shape,
                edge,
                halo,
                cache: std::sync::Mutex::new(
                    crate::trace::tiles::Lru::new(cap.min(total) as usize),
                ),
                boundary,
            },
            ball,
            // The exact map's integrator as it recorded it, or today's.
            rk: recorded
                .and_then(|m| m.integrator)
                .unwrap_or_else(super::exact_integrator),
            origin: DVec3::from_array(spec.origin),
            spacing: spec.spacing,
        })
    }

    /// Where the field's boundary values come from (with a problem to warn about when
    /// the input mesh could not be read).
    #[must_use]
    pub fn boundary(&self) -> &Boundary {
        &self.tiles.boundary
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
        // The upwind map stores theta in f32, whose pi (3.1415927410...) is above f64's:
        // the pole as written must come back.
        let top = f64::from(std::f32::consts::PI);
        if !(0.0..=top).contains(&theta) || !psi.is_finite() {
            return Err(format!(
                "theta {theta} must lie in [0, pi] and psi be finite"
            ));
        }
        let theta = theta.min(std::f64::consts::PI);
        let d = crate::trace::unit(theta, psi);
        let c = self.ball.center;
        let target = u;
        let start = c + self.ball.radius * d;
        let mut cur = Cursor {
            tiles: &self.tiles,
            tile: None,
            error: None,
        };
        let Some(u0) = cur.u(start) else {
            if let Some(e) = cur.error {
                return Err(format!("reading u failed: {e}"));
            }
            return Err(
                "the stop sphere is outside the solved region in this direction".to_owned(),
            );
        };
        let p = if target >= u0 {
            // Within the stop ball: on the ray from the center, where u falls from 1.
            let (mut lo, mut hi) = (0.0, self.ball.radius);
            for _ in 0..60 {
                let mid = 0.5 * (lo + hi);
                match cur.u(c + mid * d) {
                    Some(u) if u > target => lo = mid,
                    _ => hi = mid,
                }
            }
            c + 0.5 * (lo + hi) * d
        } else {
            let r = match self.undo_levels(&mut cur, start, target) {
                Some((p, true)) => Ok(p),
                // Undone part of the way: uphill for the rest.
                Some((p, false)) => match cur.u(p) {
                    Some(up) => Self::uphill(&mut cur, p, up, target),
                    None => Self::uphill(&mut cur, start, u0, target),
                },
                None => Self::uphill(&mut cur, start, u0, target),
            };
            if let Some(e) = cur.error {
                return Err(format!("reading u failed: {e}"));
            }
            r?
        };
        Ok(self.origin + self.spacing * p)
    }

    /// The point with u = `target` whose streamline on levels (the exact map's, from the
    /// point on) enters the stop ball at `e`: the forward steps undone one by one, each
    /// by a fixed-point iteration on its starting level. None where that does not
    /// converge (a streamline that stepped on its own in the forward map, near the
    /// boundary or the stop ball); the caller then traces uphill.
    ///
    /// A forward step from x on level k lands on level k + 1 at F(x); given that point y,
    /// x = P_k(x + y - F(x)) is iterated, P_k taking a point onto level k. F is close to
    /// a shift along the flow, so this contracts by about the step's share of a voxel
    /// per iteration. Undone this way, the inverse is the forward map's own inverse to
    /// round-off, however much the forward map squeezed the streamlines together (down
    /// a thin arm, by 1e-10 and more); tracing uphill multiplies every error by that
    /// squeeze.
    fn undo_levels(&self, cur: &mut Cursor<'_>, e: DVec3, target: f64) -> Option<(DVec3, bool)> {
        let dl = self.rk.level_step;
        // u = 0 (the boundary): as far down the levels as they go, then uphill.
        let lt = if target > 0.0 {
            target.ln()
        } else {
            f64::NEG_INFINITY
        };
        let (le, _) = LevelField::level(cur, e)?;
        // The last level before the ball (ln u on the chord into the ball lies between
        // it and the next), and the first the forward streamline reached, as far as the
        // row's u tells (its voxel's ln u is the spline's, which may be a level off).
        let first = (lt / dl).ceil();
        let last = (le / dl).floor();
        for k in [last, last - 1.0] {
            if k < first {
                continue;
            }
            if let Some(p) = self.undo_from(cur, e, k, first, target) {
                return Some(p);
            }
        }
        None
    }

    /// [`Inverse::undo_levels`] with the forward streamline's last level `last` before it
    /// entered the ball at `e`, and its first, `first`: the point and whether it is the
    /// answer, or the last level undone (levels closer than [`MIN_LEVEL_GAP`], near the
    /// boundary, or a step that does not come undone), from which to go uphill.
    fn undo_from(
        &self,
        cur: &mut Cursor<'_>,
        e: DVec3,
        last: f64,
        first: f64,
        target: f64,
    ) -> Option<(DVec3, bool)> {
        let dl = self.rk.level_step;
        let (rk, ball) = (&self.rk, &self.ball);
        let into_ball =
            |cur: &mut Cursor<'_>, x: DVec3| level_step(cur, x, dl, (last + 1.0) * dl, rk, ball);
        // The point on level `last` whose step enters the ball at e.
        let start = onto_level(cur, e, last * dl);
        let x = Self::fixed_point(
            cur,
            start,
            e,
            |cur, x| onto_level(cur, x, last * dl),
            |cur, x| match into_ball(cur, x)? {
                LevelEnd::Ball(p) | LevelEnd::Level(p) => Some(p),
            },
        )?;
        if !matches!(into_ball(cur, x)?, LevelEnd::Ball(_)) {
            return None;
        }
        // Down the levels to the first; `above` is the point one level up.
        let (mut x, mut k, mut above) = (x, last, None);
        while k > first {
            let Some(below) = self.undo_level(cur, x, k) else {
                return Some((x, false));
            };
            (above, x, k) = (Some(x), below, k - 1.0);
        }
        // The forward streamline's first, partial step, from its voxel (where the
        // trilinear u is the row's) to the first level above the spline's ln u there:
        // one level below or above `first` when the two straddle a level.
        let mut answer = None;
        for _ in 0..2 {
            let Some(x0) = self.undo_partial(cur, x, k, target) else {
                break;
            };
            answer = Some(x0);
            let Some((l0, _)) = LevelField::level(cur, x0) else {
                break;
            };
            let f0 = (l0 / dl).ceil();
            if f0 < k {
                let Some(below) = self.undo_level(cur, x, k) else {
                    break;
                };
                (above, x, k) = (Some(x), below, k - 1.0);
            } else if f0 > k {
                let Some(a) = above.take() else { break };
                (x, k) = (a, k + 1.0);
            } else {
                break;
            }
        }
        Some(answer.map_or((x, false), |p| (p, true)))
    }

    /// The point on level `k - 1` whose step lands on `y` (on level `k`), unless the
    /// levels there are closer than [`MIN_LEVEL_GAP`] or the step does not come undone.
    fn undo_level(&self, cur: &mut Cursor<'_>, y: DVec3, k: f64) -> Option<DVec3> {
        let dl = self.rk.level_step;
        let (rk, ball) = (&self.rk, &self.ball);
        let v = cur.velocity(y)?;
        if v.length() * dl < MIN_LEVEL_GAP {
            return None;
        }
        let below = (k - 1.0) * dl;
        let start = onto_level(cur, y - dl * v, below);
        Self::fixed_point(
            cur,
            start,
            y,
            |cur, x| onto_level(cur, x, below),
            |cur, x| level_step(cur, x, dl, k * dl, rk, ball)?.on_level(),
        )
    }

    /// The point where the trilinear u is `target` whose first, partial step (from the
    /// spline's ln u there to level `k`) lands on `y`.
    fn undo_partial(&self, cur: &mut Cursor<'_>, y: DVec3, k: f64, target: f64) -> Option<DVec3> {
        let dl = self.rk.level_step;
        let (rk, ball) = (&self.rk, &self.ball);
        let v = cur.velocity(y)?;
        let start = onto_u(cur, y - (k * dl - target.ln()).max(0.0) * v, target);
        Self::fixed_point(
            cur,
            start,
            y,
            |cur, x| onto_u(cur, x, target),
            |cur, x| {
                let (l, _) = LevelField::level(cur, x)?;
                level_step(cur, x, (k * dl - l).max(0.0), k * dl, rk, ball)?.on_level()
            },
        )
    }

    /// x with `forward(x) = y`, from `x`: iterate x = project(x + y - forward(x)), where
    /// `project` takes a point onto the surface x must lie on.
    fn fixed_point(
        cur: &mut Cursor<'_>,
        mut x: DVec3,
        y: DVec3,
        project: impl Fn(&mut Cursor<'_>, DVec3) -> DVec3,
        forward: impl Fn(&mut Cursor<'_>, DVec3) -> Option<DVec3>,
    ) -> Option<DVec3> {
        for _ in 0..MAX_ITERATIONS {
            let r = y - forward(cur, x)?;
            x = project(cur, x + r);
            if r.length() <= 1e-13 * (1.0 + y.abs().max_element()) {
                return Some(x);
            }
        }
        let r = y - forward(cur, x)?;
        (r.length() <= UNDONE).then_some(x)
    }

    /// Follow the field backwards (up phi, down u) from `p` (u = `up`) to u = `target`.
    fn uphill(cur: &mut Cursor<'_>, mut p: DVec3, mut up: f64, target: f64) -> InverseResult {
        let lost = || {
            "the streamline leaves the solid before phi is reached (a region the forward map does not reach)".to_owned()
        };
        for _ in 0..MAX_STEPS {
            let k1 = cur.back(p).ok_or_else(lost)?;
            let k2 = cur.back(p + 0.5 * STEP * k1).ok_or_else(lost)?;
            let k3 = cur.back(p + 0.5 * STEP * k2).ok_or_else(lost)?;
            let k4 = cur.back(p + STEP * k3).ok_or_else(lost)?;
            let next = p + STEP / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4);
            let un = cur.u(next).ok_or_else(lost)?;
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

#[cfg(test)]
mod tests {
    use super::direction_key;
    use std::f64::consts::PI;

    /// The key goes through the four quarters of (theta, psi) in Z order, each whole
    /// before the next, and takes any number without panicking.
    #[test]
    fn direction_keys_follow_a_z_order() {
        let (t, p) = (PI / 4.0, PI / 2.0); // quarter centers: theta pi/4 or 3pi/4, psi -pi/2 or pi/2
        let quarters = [(t, -p), (t, p), (3.0 * t, -p), (3.0 * t, p)];
        let keys: Vec<u64> = quarters.iter().map(|&(a, b)| direction_key(a, b)).collect();
        assert!(keys.windows(2).all(|w| w[0] < w[1]), "{keys:?}");
        // A point near the first quarter's center sorts with it, not with the others.
        let near = direction_key(t + 0.01, -p + 0.01);
        assert!(near > keys[0] && near < keys[1], "{near} {keys:?}");
        assert_eq!(direction_key(-1.0, -10.0), 0);
        assert_eq!(direction_key(f64::NAN, f64::NAN), 0);
        assert_eq!(direction_key(10.0, 10.0), u64::from(u32::MAX));
    }
}
