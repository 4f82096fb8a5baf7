//! Atom balls and what the molecular passes share about them: a uniform grid of atoms
//! for "atoms near this box", and unit-sphere samples of the SAS spheres. Below both
//! [`super::spheres`] (the solid) and [`super::solvent`] (which probe centers the solvent
//! reaches), so neither needs the other's internals.

use std::collections::HashMap;

use glam::DVec3;

/// Spacing (Angstrom, or the input's unit) of probe centers on the SAS spheres: the
/// finest, used whenever the voxels are at most `5 * SAMPLE` wide (see [`sample_for`]).
pub const SAMPLE: f64 = 0.1;

/// The spacing of probe centers on the SAS spheres for voxels of `spacing`: [`SAMPLE`],
/// or a fifth of the voxel when that is coarser. The samples of a sphere, and the probe
/// centers a block holds, then grow with the surface counted in voxels, not with the
/// square of the probe radius in Angstrom: a probe of 40 or 100 A on a 3 A grid stays
/// within the memory budget. A fifth of a voxel keeps the gaps between probe centers
/// far below the voxel (the distance to the nearest one is off by about
/// `sample^2 / (8 * probe)`).
#[must_use]
pub fn sample_for(spacing: f64) -> f64 {
    SAMPLE.max(spacing / 5.0)
}

/// Atoms in cells of a uniform grid, for "atoms near this box" queries.
pub(super) struct AtomGrid {
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
    pub(super) fn near(&self, a: DVec3, b: DVec3, out: &mut Vec<u32>) {
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

/// Pairs `(a, b)`, `a < b`, of `unit` points less than `link` apart on the sphere of
/// radius `big`, with a relative margin of 1e-6 so that rounding of world coordinates
/// cannot leave a pair out.
fn close_pairs(unit: &[DVec3], big: f64, link: f64) -> Vec<(u32, u32)> {
    let pts: Vec<[f64; 3]> = unit.iter().map(|u| (big * *u).to_array()).collect();
    let tree = kiddo::ImmutableKdTree::<f64, 3>::new_from_slice(&pts);
    let r = link * (1.0 + 1e-6);
    let mut pairs = Vec::new();
    for (a, p) in pts.iter().enumerate() {
        for nb in tree.within_unsorted::<kiddo::SquaredEuclidean>(p, r * r) {
            if nb.item as usize > a {
                pairs.push((a as u32, nb.item as u32));
            }
        }
    }
    pairs.sort_unstable();
    pairs
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
    /// Spacing of the probe centers sampled on the SAS spheres (SES only).
    pub sample: f64,
    /// Largest atom radius.
    pub(super) rmax: f64,
    /// The atoms in cells, for "atoms near this box".
    pub(super) grid: AtomGrid,
    spheres: HashMap<u64, Vec<DVec3>>,
    /// Per SAS radius: the pairs of unit-sphere samples that may lie within
    /// `2 * sample` of each other on that sphere (a little more, for rounding).
    links: HashMap<u64, Vec<(u32, u32)>>,
}

impl Balls {
    /// Balls at `centers` of `radii`, with unit-sphere samples `sample` apart for SAS
    /// spheres of `probe`.
    #[must_use]
    pub fn new(centers: Vec<DVec3>, radii: Vec<f64>, probe: f64, sample: f64) -> Self {
        let mut b = Self::without_samples(centers, radii, probe);
        b.sample = sample;
        for &r in &b.radii {
            let big = r + probe;
            let n = ((4.0 * std::f64::consts::PI * big * big) / (sample * sample)).ceil() as usize;
            if let std::collections::hash_map::Entry::Vacant(e) = b.spheres.entry(big.to_bits()) {
                let pts = sphere_points(n.max(12));
                b.links
                    .insert(big.to_bits(), close_pairs(&pts, big, 2.0 * sample));
                e.insert(pts);
            }
        }
        b
    }

    pub(super) fn without_samples(centers: Vec<DVec3>, radii: Vec<f64>, probe: f64) -> Self {
        let rmax = radii.iter().copied().fold(0.0, f64::max);
        let grid = AtomGrid::new(&centers, (rmax + probe).max(1.0));
        Self {
            centers,
            radii,
            probe,
            sample: SAMPLE,
            rmax,
            grid,
            spheres: HashMap::new(),
            links: HashMap::new(),
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

    /// Pairs `(a, b)`, `a < b`, of atom `i`'s unit-sphere samples that may lie within
    /// `2 * sample` of each other on its SAS sphere (SES only).
    #[must_use]
    pub fn sphere_links(&self, i: usize) -> &[(u32, u32)] {
        &self.links[&self.sas_radius(i).to_bits()]
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
