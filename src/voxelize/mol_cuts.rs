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
//!   probe` stays outside every probe ball) comes within [`NEAR`] voxels of one, and
//!   the first contact is then found exactly among the probe centers that can reach
//!   the rest of the arm.
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

/// Sphere tracing hands over to the exact contact this close (voxels) to a probe ball.
const NEAR: f64 = 0.05;
/// The over-relaxation of the sphere-tracing steps.
const RELAX: f64 = 1.6;
/// Sphere-tracing steps an arm takes at most (a grazing arm converges slowly; where it
/// stops is then within the tolerance of the tangent point or left at the staircase).
const STEPS: usize = 200;

/// Bytes one worker holds beyond [`super::cuts::worker_bytes`]: the block's atoms and,
/// for the SES, its probe centers and their tree (a few per square Angstrom of the
/// block's SAS surface, bounded here by the block's faces at the sample spacing).
#[must_use]
pub fn worker_bytes(chunk: u64, spacing: f64, surface: MolSurface) -> u64 {
    if surface != MolSurface::Ses {
        return 8 * chunk * chunk;
    }
    let side = chunk as f64 * spacing + 6.0;
    let sample = sample_for(spacing);
    // Up to a few sheets of SAS surface through the grown box.
    (4.0 * 6.0 * side * side / (sample * sample) * 48.0) as u64
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
        }
    }

    /// Where the segment `p + s h e` (`s` in voxels) leaves the union of the near
    /// atoms' grown balls, from `s = 0` inside it.
    fn union_exit(&self, p: DVec3, e: DVec3) -> Option<f64> {
        let h = self.spec.spacing;
        // The chords of the balls the line meets, as intervals of s.
        let mut chords: Vec<(f64, f64)> = Vec::new();
        for &i in &self.near {
            let i = i as usize;
            let r = self.balls.radii[i] + self.grow;
            let d = p - self.balls.centers[i];
            let b = d.dot(e) / h;
            let c = (d.length_squared() - r * r) / (h * h);
            let disc = b * b - c;
            if disc <= 0.0 {
                continue;
            }
            let q = disc.sqrt();
            if -b + q > 0.0 {
                chords.push((-b - q, -b + q));
            }
        }
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
    /// every one. Sphere tracing, over-relaxed by [`RELAX`] (Keinert et al., "Enhanced
    /// Sphere Tracing", 2014: a long step is kept only when the free balls about its
    /// two ends overlap, so no probe ball lies between them), brings the segment within
    /// [`NEAR`] voxels of a probe ball; then the exact first contact is taken over the
    /// probe centers that can reach the rest of the segment up to the nearest ball's
    /// entry.
    fn probe_entry(&self, p: DVec3, e: DVec3) -> Option<f64> {
        let tree = self.tree.as_ref()?;
        let h = self.spec.spacing;
        let probe = self.balls.probe;
        let at = |s: f64| p + s * h * e;
        // The free distance at s in voxels (how far the segment may go from there
        // without entering a probe ball), and the nearest probe center.
        let gap = |s: f64| {
            let n = tree.nearest_one::<SquaredEuclidean>(&at(s).to_array());
            ((n.distance.sqrt() - probe) / h, n.item)
        };
        // Where the segment enters the probe ball about center `k`, from `from` on.
        let entry = |k: u64, from: f64| {
            let c = DVec3::from(self.pts[k as usize]);
            let d = (p - c) / h;
            let b = d.dot(e);
            let disc = b * b - (d.length_squared() - (probe / h).powi(2));
            if disc < 0.0 {
                return None;
            }
            let q = disc.sqrt();
            let (t1, t2) = (-b - q, -b + q);
            (t2 >= from).then_some(t1.max(from))
        };
        let (mut s, (mut g, mut k)) = (0.0, gap(0.0));
        if g < 0.0 {
            return None; // the start is not solid (a voxel the repair added)
        }
        let mut relax = RELAX;
        for _ in 0..STEPS {
            if s + g > 1.0 {
                return None; // the free ball about s holds the rest of the arm
            }
            if g < NEAR {
                break;
            }
            let next = (s + relax * g).min(1.0);
            let step = next - s;
            let (gn, kn) = gap(next);
            if relax > 1.0 && (gn + g < step || gn < 0.0) {
                // The two free balls do not overlap: a probe ball may lie between.
                relax = 1.0;
                continue;
            }
            (s, g, k) = (next, gn, kn);
        }
        // Free up to `lo`; the nearest center's ball is entered by `hi` at the latest.
        let lo = s + g.max(0.0);
        let hi = entry(k, lo).unwrap_or(1.0).min(1.0);
        let mut best = entry(k, lo).filter(|&t| t <= 1.0);
        if hi > lo {
            // Any ball entered in lo..hi has its center within a probe radius of it.
            let reach = probe + 0.5 * (hi - lo) * h;
            let mid = at(0.5 * (lo + hi));
            for n in tree.within_unsorted::<SquaredEuclidean>(&mid.to_array(), reach * reach) {
                if let Some(t) = entry(n.item, lo) {
                    if t <= hi && best.is_none_or(|b| t < b) {
                        best = Some(t);
                    }
                }
            }
        }
        best
    }
}

impl BlockCrossings for MolBlock<'_> {
    fn arm(&self, _local: [usize; 3], g: [i64; 3], a: usize, up: bool) -> Option<f64> {
        #[allow(clippy::cast_sign_loss)] // a voxel of the grid
        let p = self.spec.voxel_center(g.map(|c| c as u64));
        let axis = [DVec3::Z, DVec3::Y, DVec3::X][a];
        let e = if up { axis } else { -axis };
        match self.surface {
            MolSurface::Vdw | MolSurface::Sas => self.union_exit(p, e),
            MolSurface::Ses => self.probe_entry(p, e),
        }
    }
}
