//! Balls to a solid: the van der Waals (vdW), solvent-accessible (SAS) and
//! solvent-excluded (SES) solids of a molecule, block by block with exact distances.
//!
//! - vdW: voxel centers within an atom's radius;
//! - SAS: within radius + probe;
//! - SES: the region no probe ball in the solvent reaches: a voxel inside the SAS solid is
//!   outside the SES when a probe center that touches no atom (a point of the SAS
//!   surface not inside another atom's SAS ball) lies within one probe radius of it.
//!   Probe centers range over the SAS surface continuously, not over grid points: each
//!   atom's SAS sphere is sampled densely (spacing `SAMPLE` = 0.1 Angstrom, or a fifth
//!   of the voxel on coarser grids: far below the voxel), the samples buried in other SAS balls are dropped, and a k-d tree of the
//!   rest answers "nearest probe center" per voxel. Samples on the walls of cavities a
//!   probe cannot reach from the solvent are no probe centers ([`super::solvent`] finds
//!   them first, in one pass over the atoms), and voxels outside the SAS solid whose
//!   nearest sample is on such a wall, inside a cavity, are solid.
//!
//! A block needs the atoms within its box grown by the largest radius plus two probe
//! radii, and the probe centers within one probe radius of the box: nothing else. The
//! atoms are drawn into the block ball by ball, and an exact distance transform of the
//! probe centers' voxels decides every voxel but a thin shell around the SES surface,
//! where the k-d tree answers ([`super::probe_band`]); the result is the same as asking
//! the tree at every voxel.
// Index arithmetic over the grid's axes: z, y, x and i, j, k read as in the formulas.
#![allow(clippy::many_single_char_names)]

use glam::DVec3;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use serde::{Deserialize, Serialize};

use super::balls::Balls;
pub use super::balls::SAMPLE;
use super::probe_band::{rasterize, ProbeBand, Verdict, ATOM, GROWN, OUT};
use super::solvent::{solvent_access_on, Access, Cavities, Free};
use crate::grid::{BlockStore, Decomposition, GridError, GridSpec};
use crate::input::molecule::Molecule;
use crate::math::Idx3;
use crate::progress::Progress;

/// Which molecular solid.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MolSurface {
    /// The union of the atoms' van der Waals balls.
    Vdw,
    /// The union of the balls grown by the probe radius.
    Sas,
    /// The solvent-excluded solid (vdW plus the crevices no probe reaches).
    #[default]
    Ses,
}

/// The SES's balls and which of their samples are probe centers in the solvent, as the
/// solid pass found them.
pub struct ProbeSpace {
    /// The atoms with their SAS spheres' samples.
    pub(super) balls: Balls,
    /// Which samples are free, and which of those the solvent reaches.
    pub(super) access: (Vec<Access>, Free),
}

/// Write the solid of `mol` (1 inside, 0 outside) into `solid`, block by block (the
/// blocks `decomp` gives this process). For the SES, returns the cavities of the
/// probe-center space whose probes were left out (see [`super::solvent`]), which every
/// process finds alike, and the probe centers.
pub fn molecule_solid(
    mol: &Molecule,
    surface: MolSurface,
    probe: f64,
    solid: &dyn BlockStore<u8>,
    workers: usize,
    progress: &dyn Progress,
    decomp: &dyn Decomposition,
) -> Result<(Cavities, Option<ProbeSpace>), GridError> {
    let spec = solid.spec().clone();
    let centers: Vec<DVec3> = mol.atoms.iter().map(|a| a.pos).collect();
    let radii: Vec<f64> = mol.atoms.iter().map(|a| a.radius).collect();
    let grow = match surface {
        MolSurface::Vdw => 0.0,
        MolSurface::Sas | MolSurface::Ses => probe,
    };
    let (balls, access, cavities) = if surface == MolSurface::Ses {
        let balls = Balls::new(
            centers,
            radii,
            probe,
            super::balls::sample_for(spec.spacing),
        );
        let (access, free, cavities) = solvent_access_on(&balls, workers, progress, decomp)?;
        (balls, (access, free), cavities)
    } else {
        let balls = Balls::without_samples(centers, radii, probe);
        (balls, (Vec::new(), Free::default()), Cavities::default())
    };
    let blocks = decomp.owned(&spec);
    progress.start("voxelize: molecular solid", blocks.len() as u64);
    crate::parallel::map_bounded(&blocks, workers, |&b| {
        crate::progress::check_interrupt(progress)?;
        let out = block_solid(&spec, b, &balls, &access, grow, surface, true);
        solid.write_block(b, &out)?;
        progress.advance(1);
        Ok::<_, GridError>(())
    })?;
    progress.finish();
    let probes = (surface == MolSurface::Ses).then_some(ProbeSpace { balls, access });
    Ok((cavities, probes))
}

#[allow(clippy::too_many_lines)] // one block's solid: the atoms, their samples and the fill share the buffers
fn block_solid(
    spec: &GridSpec,
    b: Idx3,
    balls: &Balls,
    af: &(Vec<Access>, Free),
    grow: f64,
    surface: MolSurface,
    use_band: bool,
) -> Vec<u8> {
    let (centers, radii, probe, rmax, grid) = (
        &balls.centers,
        &balls.radii,
        balls.probe,
        balls.rmax,
        &balls.grid,
    );
    let st = spec.block_start(b);
    let sh = spec.block_shape(b);
    let corner = |v: [u64; 3]| spec.voxel_center(v);
    let lo = corner(st);
    let hi = corner([st[0] + sh[0] - 1, st[1] + sh[1] - 1, st[2] + sh[2] - 1]);
    let mut out = vec![0u8; (sh[0] * sh[1] * sh[2]) as usize];
    let mut near = Vec::new();
    let reach = rmax + grow;
    grid.near(
        lo - DVec3::splat(reach),
        hi + DVec3::splat(reach),
        &mut near,
    );
    if near.is_empty() {
        return out;
    }
    // Probe centers within one probe radius of the block (SES only): free samples of
    // the SAS spheres that face the solvent; and those on cavity walls, which tell the
    // voxels in a cavity's probe-center space.
    let (pts, cav) = if surface == MolSurface::Ses {
        probe_centers(
            balls,
            af,
            lo - DVec3::splat(probe),
            hi + DVec3::splat(probe),
        )
    } else {
        (Vec::new(), Vec::new())
    };
    let tree = (!pts.is_empty()).then(|| ImmutableKdTree::<f64, 3>::new_from_slice(&pts));
    // Cavities are small: only voxels in the box of their walls grown by the probe ask.
    let cav_box = cav.iter().fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(a, b), &q| (a.min(DVec3::from(q)), b.max(DVec3::from(q))),
    );
    let cav_box = (
        cav_box.0 - DVec3::splat(probe),
        cav_box.1 + DVec3::splat(probe),
    );
    let cav = (!cav.is_empty()).then(|| ImmutableKdTree::<f64, 3>::new_from_slice(&cav));
    let nearest = |t: &ImmutableKdTree<f64, 3>, p: DVec3| {
        t.nearest_one::<SquaredEuclidean>(&p.to_array()).distance
    };
    let probe2 = probe * probe;
    let state = rasterize(spec, st, sh, &near, centers, radii, grow);
    // Inside the SAS and no atom: the band decides, or the tree where it cannot.
    let band = (use_band && surface == MolSurface::Ses && state.contains(&GROWN))
        .then(|| ProbeBand::new(spec, st, sh, &pts, probe))
        .flatten();
    let (ny, nx) = (sh[1] as usize, sh[2] as usize);
    for (k, (o, &v)) in out.iter_mut().zip(&state).enumerate() {
        let (z, y, x) = (k / (ny * nx), (k / nx) % ny, k % nx);
        let p = || corner([st[0] + z as u64, st[1] + y as u64, st[2] + x as u64]);
        *o = u8::from(match (surface, v) {
            (MolSurface::Vdw, v) => v == ATOM,
            (MolSurface::Sas, v) => v != OUT,
            (MolSurface::Ses, ATOM) => true,
            // Inside the SAS: solid unless a probe in the solvent reaches it.
            (MolSurface::Ses, GROWN) => {
                let verdict = band.as_ref().map_or(Verdict::Ask, |b| b.verdict(z, y, x));
                match verdict {
                    Verdict::Solid => true,
                    Verdict::Open => false,
                    Verdict::Ask => tree.as_ref().is_none_or(|t| nearest(t, p()) >= probe2),
                }
            }
            // Outside: solid in a cavity's probe-center space, where the nearest probe
            // center (nearest point of that space's boundary) is on a cavity wall.
            (MolSurface::Ses, _) => cav.as_ref().is_some_and(|c| {
                let p = p();
                if p.cmplt(cav_box.0).any() || p.cmpgt(cav_box.1).any() {
                    return false;
                }
                let dc = nearest(c, p);
                dc < probe2 && tree.as_ref().is_none_or(|t| nearest(t, p) > dc)
            }),
        });
    }
    out
}

/// The probe centers in the box `plo..phi`: the free samples of the SAS spheres that
/// face the solvent, and those on cavity walls (which tell the voxels in a cavity's
/// probe-center space).
pub(super) fn probe_centers(
    balls: &Balls,
    (access, free): &(Vec<Access>, Free),
    plo: DVec3,
    phi: DVec3,
) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let (mut pts, mut cav) = (Vec::new(), Vec::new());
    let mut cand = Vec::new();
    let reach = DVec3::splat(balls.rmax + balls.probe);
    balls.grid.near(plo - reach, phi + reach, &mut cand);
    for &i in &cand {
        let i = i as usize;
        let (c, big) = (balls.centers[i], balls.sas_radius(i));
        // The sphere must come within the box.
        let nearest = c.clamp(plo, phi);
        if (nearest - c).length() > big {
            continue;
        }
        let unit = balls.unit_sphere(i);
        // The free samples, found by the probe-space pass.
        for k in free.samples(i) {
            let q = c + big * unit[k];
            if q.cmplt(plo).any() || q.cmpgt(phi).any() {
                continue;
            }
            if access[i].has(k) {
                pts.push(q.to_array());
            } else {
                cav.push(q.to_array());
            }
        }
    }
    (pts, cav)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::progress::Silent;

    /// The SES of `centers` (radius 1.7, probe 1.4) on a grid of `spacing` in blocks of
    /// 16, with the band and with the tree at every voxel: (solid voxels, SAS voxels).
    fn both_ways(centers: Vec<DVec3>, spacing: f64) -> (u64, u64) {
        let radii = vec![1.7; centers.len()];
        let probe = 1.4;
        let lo = centers
            .iter()
            .fold(DVec3::splat(f64::INFINITY), |a, &c| a.min(c));
        let hi = centers
            .iter()
            .fold(DVec3::splat(f64::NEG_INFINITY), |a, &c| a.max(c));
        let pad = 1.7 + probe + 2.0 * spacing;
        let n = ((hi - lo + 2.0 * pad) / spacing).ceil();
        let spec = GridSpec {
            shape: [n.z as u64, n.y as u64, n.x as u64],
            origin: (lo - DVec3::splat(pad)).to_array(),
            spacing,
            chunk: [16, 16, 16],
            unit: None,
        };
        let balls = Balls::new(
            centers,
            radii,
            probe,
            super::super::balls::sample_for(spacing),
        );
        let (access, free, _) = solvent_access_on(&balls, 2, &Silent, &crate::grid::Whole).unwrap();
        let af = (access, free);
        let (mut solid, mut sas) = (0, 0);
        for b in spec.block_indices() {
            let fast = block_solid(&spec, b, &balls, &af, probe, MolSurface::Ses, true);
            let slow = block_solid(&spec, b, &balls, &af, probe, MolSurface::Ses, false);
            assert_eq!(fast, slow, "block {b:?}");
            let grown = block_solid(&spec, b, &balls, &af, probe, MolSurface::Sas, true);
            solid += fast.iter().map(|&v| u64::from(v)).sum::<u64>();
            sas += grown.iter().map(|&v| u64::from(v)).sum::<u64>();
        }
        (solid, sas)
    }

    #[test]
    fn the_band_gives_the_solid_the_tree_gives_everywhere() {
        // A loose cluster (crevices, pockets) from a fixed pseudo-random sequence.
        let mut x = 12345u64;
        let mut next = || {
            x = x
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (x >> 11) as f64 / (1u64 << 53) as f64
        };
        let cluster: Vec<DVec3> = (0..40)
            .map(|_| DVec3::new(next(), next(), next()) * 11.0)
            .collect();
        let (solid, sas) = both_ways(cluster, 0.3);
        // The erosion did something: the SES is well inside the SAS.
        assert!(solid > 0 && solid < sas * 9 / 10, "{solid} {sas}");
        // A closed shell: a cavity inside, whose probe centers are no solvent's.
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        let shell: Vec<DVec3> = (0..80)
            .map(|i| {
                let z = 1.0 - 2.0 * (f64::from(i) + 0.5) / 80.0;
                let r = (1.0 - z * z).sqrt();
                let t = golden * f64::from(i);
                7.0 * DVec3::new(r * t.cos(), r * t.sin(), z)
            })
            .collect();
        let (solid, sas) = both_ways(shell, 0.4);
        assert!(solid > 0 && solid <= sas, "{solid} {sas}");
    }
}
