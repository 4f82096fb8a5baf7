//! Balls to a solid: the van der Waals (vdW), solvent-accessible (SAS) and
//! solvent-excluded (SES) solids of a molecule, block by block with exact distances.
//!
//! - vdW: voxel centers within an atom's radius;
//! - SAS: within radius + probe;
//! - SES: the region no probe ball in the solvent reaches: a voxel inside the SAS solid is
//!   outside the SES when a probe center that touches no atom (a point of the SAS
//!   surface not inside another atom's SAS ball) lies within one probe radius of it.
//!   Probe centers range over the SAS surface continuously, not over grid points: each
//!   atom's SAS sphere is sampled densely (spacing `SAMPLE` Angstrom, far below the
//!   voxel), the samples buried in other SAS balls are dropped, and a k-d tree of the
//!   rest answers "nearest probe center" per voxel.
//!
//! A block needs the atoms within its box grown by the largest radius plus two probe
//! radii, and the probe centers within one probe radius of the box: nothing else.

use glam::DVec3;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use serde::{Deserialize, Serialize};

use crate::grid::{BlockStore, GridError, GridSpec};
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

/// Spacing (Angstrom, or the input's unit) of probe centers on the SAS spheres.
pub const SAMPLE: f64 = 0.1;

/// Atoms in cells of a uniform grid, for "atoms near this box" queries.
struct AtomGrid {
    cell: f64,
    lo: DVec3,
    dims: [usize; 3],
    start: Vec<u32>,
    items: Vec<u32>,
}

impl AtomGrid {
    fn new(centers: &[DVec3], cell: f64) -> Self {
        let lo = centers
            .iter()
            .fold(DVec3::splat(f64::INFINITY), |a, &c| a.min(c));
        let hi = centers
            .iter()
            .fold(DVec3::splat(f64::NEG_INFINITY), |a, &c| a.max(c));
        let dims = ((hi - lo) / cell)
            .floor()
            .to_array()
            .map(|d| d as usize + 1);
        let idx = |c: DVec3| -> usize {
            let k = ((c - lo) / cell).floor();
            (k.z as usize * dims[1] + k.y as usize) * dims[0] + k.x as usize
        };
        let n = dims[0] * dims[1] * dims[2];
        let mut count = vec![0u32; n + 1];
        for &c in centers {
            count[idx(c) + 1] += 1;
        }
        for i in 0..n {
            count[i + 1] += count[i];
        }
        let mut fill = count.clone();
        let mut items = vec![0u32; centers.len()];
        for (i, &c) in centers.iter().enumerate() {
            let k = idx(c);
            items[fill[k] as usize] = i as u32;
            fill[k] += 1;
        }
        Self {
            cell,
            lo,
            dims,
            start: count,
            items,
        }
    }

    /// Atoms whose center lies in the box `[a, b]` (world), and perhaps a few more.
    fn near(&self, a: DVec3, b: DVec3, out: &mut Vec<u32>) {
        out.clear();
        let k0 = ((a - self.lo) / self.cell).floor();
        let k1 = ((b - self.lo) / self.cell).floor();
        let clamp = |v: f64, d: usize| v.max(0.0).min(d as f64 - 1.0) as usize;
        if k1.x < 0.0 || k1.y < 0.0 || k1.z < 0.0 {
            return;
        }
        if k0.x >= self.dims[0] as f64 || k0.y >= self.dims[1] as f64 || k0.z >= self.dims[2] as f64
        {
            return;
        }
        for z in clamp(k0.z, self.dims[2])..=clamp(k1.z, self.dims[2]) {
            for y in clamp(k0.y, self.dims[1])..=clamp(k1.y, self.dims[1]) {
                let row = (z * self.dims[1] + y) * self.dims[0];
                let (x0, x1) = (clamp(k0.x, self.dims[0]), clamp(k1.x, self.dims[0]));
                let (s, e) = (
                    self.start[row + x0] as usize,
                    self.start[row + x1 + 1] as usize,
                );
                out.extend_from_slice(&self.items[s..e]);
            }
        }
    }
}

/// Points spread evenly over the unit sphere (a Fibonacci spiral).
fn sphere_points(n: usize) -> Vec<DVec3> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let r = (1.0 - z * z).sqrt();
            let t = golden * i as f64;
            DVec3::new(r * t.cos(), r * t.sin(), z)
        })
        .collect()
}

/// Write the solid of `mol` (1 inside, 0 outside) into `solid`, block by block.
pub fn molecule_solid(
    mol: &Molecule,
    surface: MolSurface,
    probe: f64,
    solid: &dyn BlockStore<u8>,
    workers: usize,
    progress: &dyn Progress,
) -> Result<(), GridError> {
    let spec = solid.spec().clone();
    let centers: Vec<DVec3> = mol.atoms.iter().map(|a| a.pos).collect();
    let radii: Vec<f64> = mol.atoms.iter().map(|a| a.radius).collect();
    let rmax = radii.iter().copied().fold(0.0, f64::max);
    let grow = match surface {
        MolSurface::Vdw => 0.0,
        MolSurface::Sas | MolSurface::Ses => probe,
    };
    let grid = AtomGrid::new(&centers, (rmax + probe).max(1.0));
    // Unit-sphere samples per atom size, shared.
    let mut spheres: std::collections::HashMap<u64, Vec<DVec3>> = std::collections::HashMap::new();
    if surface == MolSurface::Ses {
        for &r in &radii {
            let big = r + probe;
            let n = ((4.0 * std::f64::consts::PI * big * big) / (SAMPLE * SAMPLE)).ceil() as usize;
            spheres
                .entry(big.to_bits())
                .or_insert_with(|| sphere_points(n.max(12)));
        }
    }
    let blocks = spec.block_indices();
    progress.start("voxelize: molecular solid", blocks.len() as u64);
    crate::parallel::map_bounded(&blocks, workers, |&b| {
        let out = block_solid(
            &spec, b, &centers, &radii, &grid, grow, surface, probe, rmax, &spheres,
        );
        solid.write_block(b, &out)?;
        progress.advance(1);
        Ok::<_, GridError>(())
    })?;
    progress.finish();
    Ok(())
}

#[allow(clippy::too_many_arguments)]
fn block_solid(
    spec: &GridSpec,
    b: Idx3,
    centers: &[DVec3],
    radii: &[f64],
    grid: &AtomGrid,
    grow: f64,
    surface: MolSurface,
    probe: f64,
    rmax: f64,
    spheres: &std::collections::HashMap<u64, Vec<DVec3>>,
) -> Vec<u8> {
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
    // Probe centers within one probe radius of the block (SES only).
    let tree = if surface == MolSurface::Ses {
        let mut pts: Vec<[f64; 3]> = Vec::new();
        let mut others = Vec::new();
        let (plo, phi) = (lo - DVec3::splat(probe), hi + DVec3::splat(probe));
        let mut cand = Vec::new();
        grid.near(
            plo - DVec3::splat(rmax + probe),
            phi + DVec3::splat(rmax + probe),
            &mut cand,
        );
        for &i in &cand {
            let (c, big) = (centers[i as usize], radii[i as usize] + probe);
            // The sphere must come within the grown box.
            let nearest = c.clamp(plo, phi);
            if (nearest - c).length() > big {
                continue;
            }
            grid.near(
                c - DVec3::splat(big + rmax + probe),
                c + DVec3::splat(big + rmax + probe),
                &mut others,
            );
            others.retain(|&j| {
                j != i && (centers[j as usize] - c).length() < big + radii[j as usize] + probe
            });
            for u in &spheres[&big.to_bits()] {
                let q = c + big * *u;
                if q.cmplt(plo).any() || q.cmpgt(phi).any() {
                    continue;
                }
                let buried = others.iter().any(|&j| {
                    let rj = radii[j as usize] + probe;
                    (q - centers[j as usize]).length_squared() < rj * rj * (1.0 - 1e-12)
                });
                if !buried {
                    pts.push(q.to_array());
                }
            }
        }
        Some(pts)
    } else {
        None
    };
    let tree = tree
        .filter(|p| !p.is_empty())
        .map(|p| ImmutableKdTree::<f64, 3>::new_from_slice(&p));
    let probe2 = probe * probe;
    let mut k = 0;
    for z in 0..sh[0] {
        for y in 0..sh[1] {
            for x in 0..sh[2] {
                let p = corner([st[0] + z, st[1] + y, st[2] + x]);
                let mut in_vdw = false;
                let mut in_grown = false;
                for &i in &near {
                    let d2 = (p - centers[i as usize]).length_squared();
                    let r = radii[i as usize];
                    if d2 <= r * r {
                        in_vdw = true;
                        in_grown = true;
                        break;
                    }
                    let g = r + grow;
                    if d2 <= g * g {
                        in_grown = true;
                    }
                }
                out[k] = u8::from(match surface {
                    MolSurface::Vdw => in_vdw,
                    MolSurface::Sas => in_grown,
                    MolSurface::Ses => {
                        in_vdw
                            || (in_grown
                                && tree.as_ref().is_none_or(|t| {
                                    t.nearest_one::<SquaredEuclidean>(&p.to_array()).distance
                                        >= probe2
                                }))
                    }
                });
                k += 1;
            }
        }
    }
    out
}
