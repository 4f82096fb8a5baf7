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
//!   rest answers "nearest probe center" per voxel. Samples on the walls of cavities a
//!   probe cannot reach from the solvent are no probe centers ([`super::solvent`] finds
//!   them first, in one pass over the atoms), and voxels outside the SAS solid whose
//!   nearest sample is on such a wall, inside a cavity, are solid.
//!
//! A block needs the atoms within its box grown by the largest radius plus two probe
//! radii, and the probe centers within one probe radius of the box: nothing else.

use std::collections::HashMap;

use glam::DVec3;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use serde::{Deserialize, Serialize};

use super::solvent::{solvent_access, Access, Cavities};
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

/// The balls of a molecule with what the passes share: the atom grid and, for the SES,
/// the unit-sphere samples per SAS radius.
pub struct Balls {
    /// Atom centers.
    pub centers: Vec<DVec3>,
    /// Atom radii.
    pub radii: Vec<f64>,
    /// Probe radius.
    pub probe: f64,
    rmax: f64,
    grid: AtomGrid,
    spheres: HashMap<u64, Vec<DVec3>>,
}

impl Balls {
    /// Balls at `centers` of `radii`, with unit-sphere samples for SAS spheres of
    /// `probe`.
    #[must_use]
    pub fn new(centers: Vec<DVec3>, radii: Vec<f64>, probe: f64) -> Self {
        let mut b = Self::without_samples(centers, radii, probe);
        for &r in &b.radii {
            let big = r + probe;
            let n = ((4.0 * std::f64::consts::PI * big * big) / (SAMPLE * SAMPLE)).ceil() as usize;
            b.spheres
                .entry(big.to_bits())
                .or_insert_with(|| sphere_points(n.max(12)));
        }
        b
    }

    fn without_samples(centers: Vec<DVec3>, radii: Vec<f64>, probe: f64) -> Self {
        let rmax = radii.iter().copied().fold(0.0, f64::max);
        let grid = AtomGrid::new(&centers, (rmax + probe).max(1.0));
        Self {
            centers,
            radii,
            probe,
            rmax,
            grid,
            spheres: HashMap::new(),
        }
    }

    /// Radius of atom `i`'s SAS ball.
    #[must_use]
    pub fn sas_radius(&self, i: usize) -> f64 {
        self.radii[i] + self.probe
    }

    /// Unit-sphere samples of atom `i`'s SAS sphere (SES only).
    #[must_use]
    pub fn unit_sphere(&self, i: usize) -> &[DVec3] {
        &self.spheres[&self.sas_radius(i).to_bits()]
    }

    /// The atoms other than `i` whose SAS balls meet atom `i`'s, into `out`.
    pub fn sas_neighbours(&self, i: usize, out: &mut Vec<u32>) {
        let (c, big) = (self.centers[i], self.sas_radius(i));
        let reach = big + self.rmax + self.probe;
        self.grid
            .near(c - DVec3::splat(reach), c + DVec3::splat(reach), out);
        out.retain(|&j| {
            j as usize != i
                && (self.centers[j as usize] - c).length() < big + self.sas_radius(j as usize)
        });
        // Deepest first: those hide most of the sphere, so `buried` stops sooner.
        let depth = |j: u32| (self.centers[j as usize] - c).length() - self.sas_radius(j as usize);
        out.sort_by(|&a, &b| depth(a).total_cmp(&depth(b)).then(a.cmp(&b)));
    }

    /// Whether `q` lies inside one of the SAS balls of `others`.
    #[must_use]
    pub fn buried(&self, q: DVec3, others: &[u32]) -> bool {
        others.iter().any(|&j| {
            let rj = self.sas_radius(j as usize);
            (q - self.centers[j as usize]).length_squared() < rj * rj * (1.0 - 1e-12)
        })
    }
}

/// Write the solid of `mol` (1 inside, 0 outside) into `solid`, block by block. For the
/// SES, returns the cavities of the probe-center space whose probes were left out (see
/// [`super::solvent`]).
pub fn molecule_solid(
    mol: &Molecule,
    surface: MolSurface,
    probe: f64,
    solid: &dyn BlockStore<u8>,
    workers: usize,
    progress: &dyn Progress,
) -> Result<Cavities, GridError> {
    let spec = solid.spec().clone();
    let centers: Vec<DVec3> = mol.atoms.iter().map(|a| a.pos).collect();
    let radii: Vec<f64> = mol.atoms.iter().map(|a| a.radius).collect();
    let grow = match surface {
        MolSurface::Vdw => 0.0,
        MolSurface::Sas | MolSurface::Ses => probe,
    };
    let (balls, access, cavities) = if surface == MolSurface::Ses {
        let balls = Balls::new(centers, radii, probe);
        let (access, cavities) = solvent_access(&balls, workers, progress);
        (balls, access, cavities)
    } else {
        let balls = Balls::without_samples(centers, radii, probe);
        (balls, Vec::new(), Cavities::default())
    };
    let blocks = spec.block_indices();
    progress.start("voxelize: molecular solid", blocks.len() as u64);
    crate::parallel::map_bounded(&blocks, workers, |&b| {
        let out = block_solid(&spec, b, &balls, &access, grow, surface);
        solid.write_block(b, &out)?;
        progress.advance(1);
        Ok::<_, GridError>(())
    })?;
    progress.finish();
    Ok(cavities)
}

fn block_solid(
    spec: &GridSpec,
    b: Idx3,
    balls: &Balls,
    access: &[Access],
    grow: f64,
    surface: MolSurface,
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
    let (mut pts, mut cav): (Vec<[f64; 3]>, Vec<[f64; 3]>) = (Vec::new(), Vec::new());
    if surface == MolSurface::Ses {
        let mut others = Vec::new();
        let (plo, phi) = (lo - DVec3::splat(probe), hi + DVec3::splat(probe));
        let mut cand = Vec::new();
        grid.near(
            plo - DVec3::splat(rmax + probe),
            phi + DVec3::splat(rmax + probe),
            &mut cand,
        );
        for &i in &cand {
            let i = i as usize;
            let (c, big) = (centers[i], balls.sas_radius(i));
            // The sphere must come within the grown box.
            let nearest = c.clamp(plo, phi);
            if (nearest - c).length() > big {
                continue;
            }
            balls.sas_neighbours(i, &mut others);
            for (k, u) in balls.unit_sphere(i).iter().enumerate() {
                let q = c + big * *u;
                if q.cmplt(plo).any() || q.cmpgt(phi).any() {
                    continue;
                }
                if !balls.buried(q, &others) {
                    if access[i].has(k) {
                        pts.push(q.to_array());
                    } else {
                        cav.push(q.to_array());
                    }
                }
            }
        }
    }
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
                    // Inside the SAS: solid unless a probe in the solvent reaches it.
                    // Outside: solid in a cavity's probe-center space, where the
                    // nearest probe center (nearest point of that space's boundary)
                    // is on a cavity wall.
                    MolSurface::Ses if in_grown => {
                        in_vdw || tree.as_ref().is_none_or(|t| nearest(t, p) >= probe2)
                    }
                    MolSurface::Ses => cav.as_ref().is_some_and(|c| {
                        if p.cmplt(cav_box.0).any() || p.cmpgt(cav_box.1).any() {
                            return false;
                        }
                        let dc = nearest(c, p);
                        dc < probe2 && tree.as_ref().is_none_or(|t| nearest(t, p) > dc)
                    }),
                });
                k += 1;
            }
        }
    }
    out
}
