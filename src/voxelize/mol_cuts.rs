//! Where a molecule's surface crosses the arms of the solve's stencil (the array
//! `cuts`, see [`super::cuts`]): its surfaces are known exactly, so its runs get the
//! sub-voxel boundary of mesh runs.
//!
//! - vdW and SAS: the solid is a union of balls (radius `r` or `r + probe`); an arm
//!   leaves it where the segment leaves the union of the balls' chords, found exactly
//!   from the atoms near the block.
//! - SES: the solid is what no probe ball in the solvent reaches, the probe centers
//!   being the solvent's free samples of the SAS spheres ([`super::spheres`]). An arm
//!   from a solid voxel leaves it where it first enters a probe ball: sphere tracing
//!   the distance to the nearest probe center (1-Lipschitz, so a step of `distance -
//!   probe` stays outside every probe ball) and the nearest center's own ball leave a
//!   short rest of the arm, where the first contact is found exactly among the probe
//!   centers that can reach it.
//!
//! An arm whose start the surface does not hold (a voxel the closing, the cavity fill or
//! the topology repair added) or that meets no surface within a voxel is left at the
//! staircase (`theta = 1`) and counted, as mesh runs do.
// Index arithmetic over the grid's axes: z, y, x and i, j, k read as in the formulas.
#![allow(clippy::many_single_char_names)]

use glam::DVec3;
use kiddo::{ImmutableKdTree, SquaredEuclidean};

use super::balls::{sample_for, Balls};
use super::classify::CenterBall;
use super::cuts::{cut_blocks, BlockCrossings};
use super::solvent::{Access, Free};
use super::spheres::{probe_centers, MolSurface, ProbeSpace};
use crate::grid::{BlockStore, GridSpec};
use crate::input::molecule::Molecule;
use crate::math::Idx3;
use crate::progress::Progress;

/// The rest of an arm (voxels) short enough to search for the first contact among the
/// probe centers that can reach it: their count grows with its length.
const SHORT: f64 = 0.25;
/// An entry bounded within this (voxels) is taken as it is: a tenth of the stored
/// fraction's step (1/1023).
const EXACT: f64 = 1e-4;
/// Sphere-tracing steps an arm takes at most before that search (a grazing arm
/// shortens slowly; the search is exact whatever the length).
const STEPS: usize = 4;

/// Bytes one worker holds beyond [`super::cuts::worker_bytes`]: the block's atoms and,
/// for the SES, its probe centers and their tree (48 bytes each). The probe centers are
/// the solvent-facing samples of the SAS surface through the block's box grown by the
/// probe: counted here as two sheets across the box at the sample spacing (adk_open
/// at 0.5 Angstrom in blocks of 64 holds 180,000 a block on average, a sheet and a
/// half).
#[must_use]
pub fn worker_bytes(chunk: u64, spacing: f64, surface: MolSurface) -> u64 {
    if surface != MolSurface::Ses {
        return 8 * chunk * chunk;
    }
    let side = chunk as f64 * spacing + 2.0 * (spacing + 3.0);
    let sample = sample_for(spacing);
    (2.0 * side * side / (sample * sample) * 48.0) as u64
}

/// Write the cut arms of every block of `labels` for molecule `mol` into `out`; returns
/// the number of voxels with a cut arm and the number of arms to the exterior that met
/// no surface.
#[allow(clippy::too_many_arguments)] // the molecule's solid as voxelized, and the outputs
pub fn molecule_cuts(
    mol: &Molecule,
    surface: MolSurface,
    probe: f64,
    probes: Option<&ProbeSpace>,
    labels: &dyn BlockStore<u8>,
    ball: CenterBall,
    out: &dyn BlockStore<u64>,
    workers: usize,
    progress: &dyn Progress,
) -> Result<(u64, u64), crate::Error> {
    let spec = labels.spec().clone();
    let own;
    let (balls, access) = match (surface, probes) {
        (MolSurface::Ses, Some(p)) => (&p.balls, &p.access),
        (MolSurface::Ses, None) => {
            return Err(crate::grid::GridError::Ranks(
                "the SES's crossings came without the solid pass's probe centers".into(),
            )
            .into())
        }
        _ => {
            let centers: Vec<DVec3> = mol.atoms.iter().map(|a| a.pos).collect();
            let radii: Vec<f64> = mol.atoms.iter().map(|a| a.radius).collect();
            own = (
                Balls::without_samples(centers, radii, probe),
                (Vec::new(), Free::default()),
            );
            (&own.0, &own.1)
        }
    };
    let grow = match surface {
        MolSurface::Vdw => 0.0,
        MolSurface::Sas | MolSurface::Ses => probe,
    };
    cut_blocks(labels, ball, out, workers, progress, |b| {
        MolBlock::new(&spec, b, balls, access, grow, surface)
    })
}

/// What one block's arms need: the atoms near it (vdW, SAS) or the probe centers near
/// it (SES).
struct MolBlock<'a> {
    spec: &'a GridSpec,
    balls: &'a Balls,
    /// Atoms whose grown ball may meet an arm of the block.
    near: Vec<u32>,
    grow: f64,
    /// Probe centers within a probe radius of the block's arms (SES), and their tree.
    pts: Vec<[f64; 3]>,
    tree: Option<ImmutableKdTree<f64, 3>>,
    surface: MolSurface,
    /// The last voxel asked about (SES): its free distance and nearest probe center.
    start: std::cell::Cell<Option<([usize; 3], f64, u64)>>,
}

impl<'a> MolBlock<'a> {
    fn new(
        spec: &'a GridSpec,
        b: Idx3,
        balls: &'a Balls,
        access: &(Vec<Access>, Free),
        grow: f64,
        surface: MolSurface,
    ) -> Self {
        let st = spec.block_start(b);
        let sh = spec.block_shape(b);
        // The block's voxel centers, grown by one voxel: the arms' far ends.
        let h = DVec3::splat(spec.spacing);
        let lo = spec.voxel_center(st) - h;
        let hi = spec.voxel_center([st[0] + sh[0] - 1, st[1] + sh[1] - 1, st[2] + sh[2] - 1]) + h;
        let mut near = Vec::new();
        let mut tree = None;
        let mut pts = Vec::new();
        if surface == MolSurface::Ses {
            (pts, _) = probe_centers(
                balls,
                access,
                lo - DVec3::splat(balls.probe),
                hi + DVec3::splat(balls.probe),
            );
            tree = (!pts.is_empty()).then(|| ImmutableKdTree::<f64, 3>::new_from_slice(&pts));
        } else {
            let reach = balls.rmax + grow;
            balls.grid.near(
                lo - DVec3::splat(reach),
                hi + DVec3::splat(reach),
                &mut near,
            );
        }
        Self {
            spec,
            balls,
            near,
            grow,
            pts,
            tree,
            surface,
            start: std::cell::Cell::new(None),
        }
    }

    /// Where the segment `p + s h e` (`s` in voxels) leaves the union of the near
    /// atoms' grown balls, from `s = 0` inside it.
    fn union_exit(&self, p: DVec3, e: DVec3) -> Option<f64> {
        let h = self.spec.spacing;
        // The chords of the balls the line meets (not only touches), as intervals of s.
        let chords: Vec<(f64, f64)> = self
            .near
            .iter()
            .filter_map(|&i| {
                let i = i as usize;
                chord(
                    p,
                    e,
                    h,
                    self.balls.centers[i],
                    self.balls.radii[i] + self.grow,
                )
            })
            .filter(|&(t1, t2)| t1 < t2 && t2 > 0.0)
            .collect();
        // From s = 0, extend through every chord that starts before the end so far.
        let mut end = chords
            .iter()
            .filter(|c| c.0 <= 0.0)
            .map(|c| c.1)
            .fold(f64::NAN, f64::max);
        if end.is_nan() {
            return None; // the voxel is not in the union (a voxel the repair added)
        }
        loop {
            let next = chords
                .iter()
                .filter(|c| c.0 <= end && c.1 > end)
                .map(|c| c.1)
                .fold(end, f64::max);
            if next <= end {
                break;
            }
            end = next;
        }
        (end <= 1.0).then_some(end)
    }

    /// Where the segment `p + s h e` first enters a probe ball, from `s = 0` outside
    /// every one (`start`: the free distance at `p` in voxels and the nearest probe
    /// center, shared by the voxel's arms). The ball about the nearest probe center
    /// bounds the entry from above; plain sphere-tracing steps (the distance to the
    /// nearest probe center is 1-Lipschitz, so a step of `distance - probe` enters no
    /// probe ball) shorten the rest of the arm to [`SHORT`] voxels, or [`STEPS`]
    /// steps; the first contact is then exact among the probe centers that can reach
    /// that rest.
    fn probe_entry(&self, p: DVec3, e: DVec3, start: (f64, u64)) -> Option<f64> {
        let tree = self.tree.as_ref()?;
        let h = self.spec.spacing;
        let probe = self.balls.probe;
        let at = |s: f64| p + s * h * e;
        // Where the segment enters the probe ball about center `k`, from `from` on.
        let entry = |k: u64, from: f64| {
            let (t1, t2) = chord(p, e, h, DVec3::from(self.pts[k as usize]), probe)?;
            (t2 >= from).then_some(t1.max(from))
        };
        let (g, k) = start;
        if g < 0.0 {
            return None; // the start is not solid (a voxel the repair added)
        }
        // Free up to `lo`; some probe ball is entered by `hi` (or the arm ends there).
        let mut lo = g;
        let mut entered = entry(k, lo);
        let mut hi = entered.unwrap_or(1.0).min(1.0);
        for _ in 0..STEPS {
            if lo > 1.0 {
                return None; // the free balls hold the whole arm
            }
            if hi - lo <= SHORT {
                break;
            }
            let (d, k) = self.free(at(lo));
            if d <= 0.0 {
                break;
            }
            lo += d / h;
            if let Some(t) = entry(k, lo) {
                if t < hi {
                    (hi, entered) = (t, Some(t));
                }
            }
        }
        if lo > 1.0 {
            return None;
        }
        if let Some(t) = entered {
            if t <= 1.0 && t - lo < EXACT {
                return Some(t); // the entry is known to within the stored rounding
            }
        }
        let mut best: Option<f64> = None;
        // Any ball entered in lo..hi has its center within a probe radius of it.
        let reach = probe + 0.5 * (hi - lo).max(0.0) * h;
        let mid = at(0.5 * (lo + hi.max(lo)));
        for n in tree.within_unsorted::<SquaredEuclidean>(&mid.to_array(), reach * reach) {
            if let Some(t) = entry(n.item, lo) {
                if t <= 1.0 && best.is_none_or(|b| t < b) {
                    best = Some(t);
                }
            }
        }
        best
    }

    /// The free distance at `x` (to the nearest probe ball, negative inside one) and
    /// the nearest probe center.
    fn free(&self, x: DVec3) -> (f64, u64) {
        self.tree.as_ref().map_or((f64::INFINITY, 0), |t| {
            let n = t.nearest_one::<SquaredEuclidean>(&x.to_array());
            (n.distance.sqrt() - self.balls.probe, n.item)
        })
    }
}

/// The interval of `s` (voxels) where the line `p + s h e` (`e` a unit vector) lies in
/// the ball of radius `r` about `c`; None where it misses the ball.
fn chord(p: DVec3, e: DVec3, h: f64, c: DVec3, r: f64) -> Option<(f64, f64)> {
    let d = (p - c) / h;
    let b = d.dot(e);
    let disc = b * b - (d.length_squared() - (r / h).powi(2));
    if disc < 0.0 {
        return None;
    }
    let q = disc.sqrt();
    Some((-b - q, -b + q))
}

impl BlockCrossings for MolBlock<'_> {
    fn arm(&self, local: [usize; 3], g: [i64; 3], a: usize, up: bool) -> Option<f64> {
        #[allow(clippy::cast_sign_loss)] // a voxel of the grid
        let p = self.spec.voxel_center(g.map(|c| c as u64));
        let axis = [DVec3::Z, DVec3::Y, DVec3::X][a];
        let e = if up { axis } else { -axis };
        match self.surface {
            MolSurface::Vdw | MolSurface::Sas => self.union_exit(p, e),
            MolSurface::Ses => {
                // The voxel's arms come one after another: its free distance once.
                let start = match self.start.get() {
                    Some((at, d, k)) if at == local => (d, k),
                    _ => {
                        let (d, k) = self.free(p);
                        self.start.set(Some((local, d, k)));
                        (d, k)
                    }
                };
                self.probe_entry(p, e, (start.0 / self.spec.spacing, start.1))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::progress::Silent;
    use crate::voxelize::solvent::solvent_access_on;

    /// The first entry of `p + s h e` into any probe ball about `pts`, by brute force.
    fn brute_entry(pts: &[[f64; 3]], probe: f64, h: f64, p: DVec3, e: DVec3) -> Option<f64> {
        let mut best: Option<f64> = None;
        for q in pts {
            let d = (p - DVec3::from(*q)) / h;
            let b = d.dot(e);
            let disc = b * b - (d.length_squared() - (probe / h).powi(2));
            if disc < 0.0 {
                continue;
            }
            let (t1, t2) = (-b - disc.sqrt(), -b + disc.sqrt());
            if t2 >= 0.0 && t1 <= 1.0 {
                let t = t1.max(0.0);
                best = Some(best.map_or(t, |b| b.min(t)));
            }
        }
        best
    }

    #[test]
    fn ses_crossings_are_the_first_probe_ball_every_arm_meets() {
        // A loose cluster from a fixed pseudo-random sequence (crevices and pockets).
        let mut x = 12345u64;
        let mut next = || {
            x = x
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (x >> 11) as f64 / (1u64 << 53) as f64
        };
        let centers: Vec<DVec3> = (0..30)
            .map(|_| DVec3::new(next(), next(), next()) * 10.0)
            .collect();
        let radii = vec![1.7; centers.len()];
        let probe = 1.4;
        let h = 0.4;
        let balls = Balls::new(centers, radii, probe, sample_for(h));
        let (access, free, _) = solvent_access_on(&balls, 2, &Silent, &crate::grid::Whole).unwrap();
        let access = (access, free);
        let spec = GridSpec {
            shape: [48, 48, 48],
            origin: [-2.5; 3],
            spacing: h,
            chunk: [16, 16, 16],
            unit: None,
        };
        let (mut asked, mut cut) = (0, 0);
        for b in spec.block_indices() {
            let mb = MolBlock::new(&spec, b, &balls, &access, probe, MolSurface::Ses);
            if mb.tree.is_none() {
                continue;
            }
            let st = spec.block_start(b);
            for _ in 0..200 {
                let local = [0, 1, 2].map(|_| (next() * 16.0) as usize);
                let g = [0, 1, 2].map(|k| (st[k] + local[k] as u64) as i64);
                let p = spec.voxel_center(g.map(|c| c as u64));
                if mb.free(p).0 < 0.0 {
                    continue; // not solid
                }
                for a in 0..3 {
                    for up in [false, true] {
                        let axis = [DVec3::Z, DVec3::Y, DVec3::X][a];
                        let e = if up { axis } else { -axis };
                        let got = mb.arm(local, g, a, up);
                        let want = brute_entry(&mb.pts, probe, h, p, e);
                        asked += 1;
                        match (got, want) {
                            (Some(t), Some(w)) => {
                                cut += 1;
                                assert!((t - w).abs() <= EXACT, "{g:?} axis {a} {up}: {t} vs {w}");
                            }
                            (None, None) => {}
                            _ => panic!("{g:?} axis {a} {up}: {got:?} vs {want:?}"),
                        }
                    }
                }
            }
        }
        // Both kinds were tried: arms that meet a probe ball and arms that do not.
        assert!(cut > 50 && asked > cut + 50, "{asked} arms, {cut} cut");
    }

    #[test]
    fn vdw_crossings_leave_the_union_of_the_balls() {
        // Two overlapping balls along x: radius 2 at 0 and at 3; from the first's
        // center along +x the union is left at 5, along -x at -2.
        let balls = Balls::without_samples(
            vec![DVec3::ZERO, DVec3::new(3.0, 0.0, 0.0)],
            vec![2.0, 2.0],
            1.4,
        );
        let spec = GridSpec {
            shape: [16, 16, 32],
            origin: [-8.0, -4.0, -4.0],
            spacing: 0.5,
            chunk: [16, 16, 32],
            unit: None,
        };
        let mb = MolBlock::new(
            &spec,
            [0, 0, 0],
            &balls,
            &(Vec::new(), Free::default()),
            0.0,
            MolSurface::Vdw,
        );
        // Voxel x = 4.75 -> index 25.5: take 4.5 (index 25), 0.5 voxel from the exit.
        let at = |x: f64| mb.union_exit(DVec3::new(x, 0.0, 0.0), DVec3::X);
        assert!((at(4.5).unwrap() - 1.0).abs() < 1e-12);
        assert!((at(4.75).unwrap() - 0.5).abs() < 1e-12);
        assert!(
            at(3.0).is_none(),
            "2 Angstrom from the exit: beyond the arm"
        );
        // Through the overlap: from x = 1.9 the chords of both balls join.
        assert!(at(1.9).is_none());
        let back = |x: f64| mb.union_exit(DVec3::new(x, 0.0, 0.0), -DVec3::X);
        assert!((back(-1.75).unwrap() - 0.5).abs() < 1e-12);
        // Outside both balls: not solid.
        assert!(back(-2.5).is_none());
    }
}
