//! Which probe centers are in the solvent (SES only).
//!
//! The SES is the region no probe ball in the solvent reaches. Probe centers lie in the
//! probe-center space F, the points no SAS ball holds, and F falls into connected
//! pieces: the unbounded one, which is the solvent, and cavities a probe fits in but
//! cannot reach from outside, behind mouths narrower than the probe. A probe in such a
//! cavity is not in the solvent, so its cavity is solvent-excluded, like every enclosed
//! void. The voxel fill alone cannot tell: the wall between a cavity's probe balls and
//! the solvent's can be thinner than a voxel, and then no voxel center lies in it and
//! the cavity looks like an open pocket (adk_open at 0.5 Angstrom: 1,000 voxels behind a
//! mouth that passes a probe of 1.10 Angstrom, not 1.4).
//!
//! So the pieces are found on the probe centers themselves, the free samples of the SAS
//! spheres (see [`super::spheres`]):
//! 1. on each atom's sphere, free samples closer than [`LINK`] are in one patch;
//! 2. patches of two atoms meet where their SAS spheres cross. The circle of the
//!    crossing is sampled, from either atom the same points, and each point of it that
//!    no other SAS ball holds joins the nearest free sample (within [`LINK`]) of each
//!    sphere;
//! 3. the joined patches are the pieces of the free SAS surface, each bounding one piece
//!    of F. At a piece's highest-x sample F lies in the direction of the sphere's
//!    normal. If that normal has x > 0, F is outside the piece: it is the outer surface
//!    of a piece of the SAS solid, facing the solvent. Otherwise F is inside it: it is
//!    the wall of a cavity.
//!
//! Probe centers on cavity walls are dropped. A piece of the SAS solid floating inside a
//! cavity (an ion held off its walls) counts as facing the solvent; the voxel fill then
//! fills that cavity when its voxels are enclosed, as before. Mouths are told open or
//! shut to within the sampling: adk_open's, which passes a probe of 1.099 Angstrom, is
//! open at probe 1.09 and shut at 1.10.
//!
//! Cost: one pass over every atom's samples (as many as the block pass tests) with a
//! k-d tree of each atom's free samples, before the blocks; memory per worker is one
//! atom's samples, and for the whole molecule a few numbers per patch.
// Index arithmetic over the grid's axes: z, y, x and i, j, k read as in the formulas.
#![allow(clippy::many_single_char_names)]

use std::collections::HashMap;

use glam::DVec3;
use kiddo::{ImmutableKdTree, SquaredEuclidean};

use super::balls::{Balls, SAMPLE};
use crate::progress::Progress;

/// Free samples of one sphere closer than this (Angstrom) are in one patch, and a
/// crossing circle's point joins a sphere's nearest free sample within it.
pub const LINK: f64 = 2.0 * SAMPLE;

/// [`LINK`] for the samples of `balls`: twice their spacing.
fn link(balls: &Balls) -> f64 {
    2.0 * balls.sample
}

/// Which of an atom's free samples are probe centers in the solvent.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Access {
    /// All of them (the usual case).
    All,
    /// None: the atom's free samples all lie on cavity walls, or it has none.
    None,
    /// Those whose bit is set (bit k: sample k of the atom's sphere).
    Some(Vec<u64>),
}

impl Access {
    /// Whether sample `k` of the atom may be a probe center (if it is free).
    #[must_use]
    pub fn has(&self, k: usize) -> bool {
        match self {
            Access::All => true,
            Access::None => false,
            Access::Some(bits) => bits[k / 64] >> (k % 64) & 1 == 1,
        }
    }
}

/// What [`solvent_access`] found.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Cavities {
    /// Pieces of the free SAS surface that wall a cavity.
    pub count: u64,
    /// Atoms with samples on such walls.
    pub atoms: u64,
}

/// The patches of one atom's free samples.
struct Patches {
    /// Sphere index of each free sample.
    free: Vec<u32>,
    /// Patch of each free sample.
    patch: Vec<u32>,
    /// Per patch: (x, normal x) of its highest-x sample.
    top: Vec<(f64, f64)>,
    /// The free samples, for "nearest free sample" queries.
    tree: Option<ImmutableKdTree<f64, 3>>,
}

/// A run of points of a crossing circle that join one patch of one of its atoms.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Run {
    /// The crossing: atoms `lo < hi`.
    lo: u32,
    hi: u32,
    /// Which atom's patch: `hi` if true.
    at_hi: bool,
    /// Circle points `from..=to`.
    from: u32,
    to: u32,
    patch: u32,
}

fn root(p: &mut [u32], mut a: u32) -> u32 {
    while p[a as usize] != a {
        p[a as usize] = p[p[a as usize] as usize];
        a = p[a as usize];
    }
    a
}

fn union(p: &mut [u32], a: u32, b: u32) {
    let (ra, rb) = (root(p, a), root(p, b));
    if ra != rb {
        p[ra.max(rb) as usize] = ra.min(rb);
    }
}

fn patches(balls: &Balls, i: usize, others: &[u32]) -> Patches {
    let (c, big) = (balls.centers[i], balls.sas_radius(i));
    let unit = balls.unit_sphere(i);
    let mut free = Vec::new();
    let mut pts = Vec::new();
    for (k, u) in unit.iter().enumerate() {
        let q = c + big * *u;
        if !balls.buried(q, others) {
            free.push(k as u32);
            pts.push(q.to_array());
        }
    }
    if pts.is_empty() {
        return Patches {
            free,
            patch: Vec::new(),
            top: Vec::new(),
            tree: None,
        };
    }
    let tree = ImmutableKdTree::<f64, 3>::new_from_slice(&pts);
    let mut uf: Vec<u32> = (0..pts.len() as u32).collect();
    // Free samples closer than LINK: of the sphere's pairs that may be (the same for
    // every sphere of this radius), those whose world points are, by the distance a
    // k-d tree would compute (the squares summed x, y, z).
    let mut at = vec![u32::MAX; unit.len()];
    for (a, &k) in free.iter().enumerate() {
        at[k as usize] = a as u32;
    }
    let link2 = link(balls) * link(balls);
    for &(ka, kb) in balls.sphere_links(i) {
        let (a, b) = (at[ka as usize], at[kb as usize]);
        if a == u32::MAX || b == u32::MAX {
            continue;
        }
        let (p, q) = (pts[a as usize], pts[b as usize]);
        let d2 = (p[0] - q[0]) * (p[0] - q[0]) + (p[1] - q[1]) * (p[1] - q[1]);
        if d2 + (p[2] - q[2]) * (p[2] - q[2]) <= link2 {
            union(&mut uf, a, b);
        }
    }
    let mut id = vec![u32::MAX; pts.len()];
    let mut patch = Vec::with_capacity(pts.len());
    let mut top: Vec<(f64, f64)> = Vec::new();
    for a in 0..pts.len() {
        let r = root(&mut uf, a as u32) as usize;
        if id[r] == u32::MAX {
            id[r] = top.len() as u32;
            top.push((f64::NEG_INFINITY, 0.0));
        }
        let p = id[r] as usize;
        patch.push(p as u32);
        if pts[a][0] > top[p].0 {
            top[p] = (pts[a][0], unit[free[a] as usize].x);
        }
    }
    Patches {
        free,
        patch,
        top,
        tree: Some(tree),
    }
}

/// The circle where the SAS spheres of atoms `lo < hi` cross, as `m` points
/// `center + r (cos t u + sin t v)`, `t = 2 pi k / m`; None if they do not cross. Computed
/// from the pair alone, so both atoms get the same points.
fn crossing(balls: &Balls, lo: usize, hi: usize) -> Option<(DVec3, f64, DVec3, DVec3, usize)> {
    let (ca, cb) = (balls.centers[lo], balls.centers[hi]);
    let (ra, rb) = (balls.sas_radius(lo), balls.sas_radius(hi));
    let d = cb - ca;
    let l = d.length();
    if l >= ra + rb || l <= (ra - rb).abs() {
        return None;
    }
    let e = d / l;
    let t = (l * l + ra * ra - rb * rb) / (2.0 * l);
    let r2 = ra * ra - t * t;
    if r2 <= 0.0 {
        return None;
    }
    let r = r2.sqrt();
    let helper = if e.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
    let u = e.cross(helper).normalize();
    let v = e.cross(u);
    let m = ((std::f64::consts::TAU * r / balls.sample).ceil() as usize).max(8);
    Some((ca + t * e, r, u, v, m))
}

/// One atom's free samples (bit k: sample k), as [`Free`] keeps them.
fn free_bits(balls: &Balls, i: usize, free: &[u32]) -> Vec<u64> {
    let mut bits = vec![0u64; balls.unit_sphere(i).len().div_ceil(64)];
    for &k in free {
        bits[k as usize / 64] |= 1 << (k % 64);
    }
    bits
}

/// What one atom gives: its patches' tops, the runs of its crossing circles that join
/// them, and its free samples.
type AtomPass = (Vec<(f64, f64)>, Vec<Run>, Vec<u64>);

/// One atom's patches (count, tops), the runs of its crossing circles that join them,
/// and its free samples.
fn atom_pass(balls: &Balls, i: usize, others: &mut Vec<u32>) -> AtomPass {
    balls.sas_neighbours(i, others);
    let p = patches(balls, i, others);
    let bits = free_bits(balls, i, &p.free);
    let Some(tree) = &p.tree else {
        return (p.top, Vec::new(), bits);
    };
    let mut runs = Vec::new();
    for &j in others.iter() {
        let j = j as usize;
        let (lo, hi) = (i.min(j), i.max(j));
        let Some((center, r, u, v, m)) = crossing(balls, lo, hi) else {
            continue;
        };
        let mut cur: Option<Run> = None;
        for k in 0..m {
            let t = std::f64::consts::TAU * k as f64 / m as f64;
            let q = center + r * (t.cos() * u + t.sin() * v);
            let free = !others.iter().any(|&o| {
                let o = o as usize;
                o != lo && o != hi && {
                    let ro = balls.sas_radius(o);
                    (q - balls.centers[o]).length_squared() < ro * ro * (1.0 - 1e-12)
                }
            });
            let patch = if free {
                let nb = tree.nearest_one::<SquaredEuclidean>(&q.to_array());
                (nb.distance <= link(balls) * link(balls)).then(|| p.patch[nb.item as usize])
            } else {
                None
            };
            match (patch, cur.as_mut()) {
                (Some(pa), Some(run)) if run.patch == pa && run.to + 1 == k as u32 => {
                    run.to = k as u32;
                }
                (Some(pa), _) => {
                    if let Some(run) = cur.take() {
                        runs.push(run);
                    }
                    cur = Some(Run {
                        lo: lo as u32,
                        hi: hi as u32,
                        at_hi: i == hi,
                        from: k as u32,
                        to: k as u32,
                        patch: pa,
                    });
                }
                (None, _) => {
                    if let Some(run) = cur.take() {
                        runs.push(run);
                    }
                }
            }
        }
        if let Some(run) = cur.take() {
            runs.push(run);
        }
    }
    (p.top, runs, bits)
}

/// The free samples of every atom's SAS sphere (bit k of atom i: sample k of its sphere
/// lies in no other SAS ball), found once here so that the blocks need not test again.
/// A few hundred bytes per atom.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Free(pub Vec<Vec<u64>>);

impl Free {
    /// The free samples of atom `i`, in increasing order.
    pub fn samples(&self, i: usize) -> impl Iterator<Item = usize> + '_ {
        self.0[i].iter().enumerate().flat_map(|(w, &word)| {
            let mut b = word;
            std::iter::from_fn(move || {
                (b != 0).then(|| {
                    let t = b.trailing_zeros() as usize;
                    b &= b - 1;
                    w * 64 + t
                })
            })
        })
    }
}

/// Decide, for every atom, which of its free SAS samples are probe centers in the
/// solvent (see the module documentation); also returns every atom's free samples.
pub fn solvent_access(
    balls: &Balls,
    workers: usize,
    progress: &dyn Progress,
) -> Result<(Vec<Access>, Free, Cavities), crate::grid::GridError> {
    solvent_access_on(balls, workers, progress, &crate::grid::Whole)
}

/// [`solvent_access`] with the atoms' own pass (the heavy part) split over the
/// processes of `decomp`: each takes a contiguous share of the atoms, and every process
/// gets every atom's result, so all find the same.
pub fn solvent_access_on(
    balls: &Balls,
    workers: usize,
    progress: &dyn Progress,
    decomp: &dyn crate::grid::Decomposition,
) -> Result<(Vec<Access>, Free, Cavities), crate::grid::GridError> {
    const CHUNK: usize = 64;
    let n = balls.centers.len();
    let chunks: Vec<usize> = (0..n.div_ceil(CHUNK)).collect();
    let (parts, me) = (decomp.parts(), decomp.part());
    let share = |p: usize| p * chunks.len() / parts..(p + 1) * chunks.len() / parts;
    progress.start("voxelize: probe space", n as u64);
    let mine = crate::parallel::map_bounded(&chunks[share(me)], workers, |&ch| {
        crate::progress::check_interrupt(progress)?;
        let mut others = Vec::new();
        let out: Vec<_> = (ch * CHUNK..(ch * CHUNK + CHUNK).min(n))
            .map(|i| atom_pass(balls, i, &mut others))
            .collect();
        progress.advance(out.len() as u64);
        Ok::<_, crate::grid::GridError>(out)
    })?;
    progress.finish();
    let per_chunk: Vec<Vec<AtomPass>> = if parts == 1 {
        mine
    } else {
        let bytes = encode(mine.iter().flatten());
        let all = decomp.all_gather_bytes(bytes)?;
        all.iter()
            .enumerate()
            .map(|(p, b)| decode(b, p))
            .collect::<Result<_, _>>()?
    };

    // Global patch ids.
    let mut base = vec![0u32; n + 1];
    let mut tops = Vec::new();
    let mut runs = Vec::new();
    let mut free = Free(Vec::with_capacity(n));
    for (i, (top, r, bits)) in per_chunk.into_iter().flatten().enumerate() {
        base[i + 1] = base[i] + top.len() as u32;
        tops.extend(top);
        runs.extend(r);
        free.0.push(bits);
    }
    let mut uf: Vec<u32> = (0..tops.len() as u32).collect();
    // Runs of one crossing, from either atom, that share circle points join patches.
    runs.sort_by_key(|r| (r.lo, r.hi, r.at_hi, r.from));
    for pair in runs.chunk_by(|a, b| (a.lo, a.hi) == (b.lo, b.hi)) {
        let split = pair.partition_point(|r| !r.at_hi);
        let (on_lo, on_hi) = pair.split_at(split);
        for a in on_lo {
            for b in on_hi {
                if a.from <= b.to && b.from <= a.to {
                    union(
                        &mut uf,
                        base[a.lo as usize] + a.patch,
                        base[b.hi as usize] + b.patch,
                    );
                }
            }
        }
    }
    // Per piece, its highest-x sample; the piece faces the solvent if F lies in +x there.
    let mut best: HashMap<u32, (f64, f64)> = HashMap::new();
    for (g, &(x, nx)) in tops.iter().enumerate() {
        let r = root(&mut uf, g as u32);
        let e = best.entry(r).or_insert((x, nx));
        if x > e.0 {
            *e = (x, nx);
        }
    }
    let mut cavities = Cavities {
        count: best.values().filter(|&&(_, nx)| nx <= 0.0).count() as u64,
        atoms: 0,
    };
    let solvent: Vec<bool> = (0..tops.len() as u32)
        .map(|g| best[&root(&mut uf, g)].1 > 0.0)
        .collect();
    let mut access = vec![Access::All; n];
    let mut mixed = Vec::new();
    for (i, a) in access.iter_mut().enumerate() {
        let s = &solvent[base[i] as usize..base[i + 1] as usize];
        if s.iter().all(|&b| b) {
            continue;
        }
        cavities.atoms += 1;
        if s.iter().all(|&b| !b) {
            *a = Access::None;
        } else {
            mixed.push(i);
        }
    }
    // Atoms with patches on both sides: their samples one by one (the same patches
    // again, computed the same way).
    let bits = crate::parallel::map_bounded(&mixed, workers, |&i| {
        crate::progress::check_interrupt(progress)?;
        let mut others = Vec::new();
        balls.sas_neighbours(i, &mut others);
        let p = patches(balls, i, &others);
        let mut bits = vec![0u64; balls.unit_sphere(i).len().div_ceil(64)];
        for (&k, &pa) in p.free.iter().zip(&p.patch) {
            if solvent[(base[i] + pa) as usize] {
                bits[k as usize / 64] |= 1 << (k % 64);
            }
        }
        Ok::<_, crate::grid::GridError>(bits)
    })?;
    for (&i, b) in mixed.iter().zip(bits) {
        access[i] = Access::Some(b);
    }
    Ok((access, free, cavities))
}

/// The atoms' passes as bytes, for the other processes ([`decode`]): per atom the
/// tops, the runs and the free samples, each a count (u32) and the items, little-endian.
fn encode<'a>(atoms: impl Iterator<Item = &'a AtomPass>) -> Vec<u8> {
    let mut out = Vec::new();
    let len = |out: &mut Vec<u8>, n: usize| {
        out.extend_from_slice(
            &u32::try_from(n)
                .expect("fewer than 2^32 items")
                .to_le_bytes(),
        );
    };
    for (tops, runs, bits) in atoms {
        len(&mut out, tops.len());
        for (x, nx) in tops {
            out.extend_from_slice(&x.to_le_bytes());
            out.extend_from_slice(&nx.to_le_bytes());
        }
        len(&mut out, runs.len());
        for r in runs {
            for v in [r.lo, r.hi, u32::from(r.at_hi), r.from, r.to, r.patch] {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
        len(&mut out, bits.len());
        for b in bits {
            out.extend_from_slice(&b.to_le_bytes());
        }
    }
    out
}

/// The atoms' passes process `part` sent ([`encode`]), one entry per atom.
fn decode(bytes: &[u8], part: usize) -> Result<Vec<AtomPass>, crate::grid::GridError> {
    struct Reader<'a>(&'a [u8]);
    impl Reader<'_> {
        fn take<const N: usize>(&mut self) -> Option<[u8; N]> {
            let (head, tail) = self.0.split_at_checked(N)?;
            self.0 = tail;
            head.try_into().ok()
        }
        fn u32(&mut self) -> Option<u32> {
            self.take().map(u32::from_le_bytes)
        }
        fn f64(&mut self) -> Option<f64> {
            self.take().map(f64::from_le_bytes)
        }
        fn atom(&mut self) -> Option<AtomPass> {
            let tops = (0..self.u32()?)
                .map(|_| Some((self.f64()?, self.f64()?)))
                .collect::<Option<Vec<_>>>()?;
            let runs = (0..self.u32()?)
                .map(|_| {
                    Some(Run {
                        lo: self.u32()?,
                        hi: self.u32()?,
                        at_hi: self.u32()? != 0,
                        from: self.u32()?,
                        to: self.u32()?,
                        patch: self.u32()?,
                    })
                })
                .collect::<Option<Vec<_>>>()?;
            let bits = (0..self.u32()?)
                .map(|_| self.take().map(u64::from_le_bytes))
                .collect::<Option<Vec<_>>>()?;
            Some((tops, runs, bits))
        }
    }
    let mut r = Reader(bytes);
    let mut atoms = Vec::new();
    while !r.0.is_empty() {
        atoms.push(r.atom().ok_or_else(|| {
            crate::grid::GridError::Ranks(format!(
                "rank {part} sent a probe-space pass this rank cannot read (are all ranks the same harmap?)"
            ))
        })?);
    }
    Ok(atoms)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::progress::Silent;

    /// Atoms of radius 1.7 on a sphere of radius `shell` (a Fibonacci spiral of `n`),
    /// without those within `hole` Angstrom of the sphere's top.
    fn shell(n: usize, shell: f64, hole: f64) -> Balls {
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        let mut centers = Vec::new();
        for i in 0..n {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let r = (1.0 - z * z).sqrt();
            let t = golden * i as f64;
            let c = shell * DVec3::new(r * t.cos(), r * t.sin(), z);
            if (c - DVec3::new(0.0, 0.0, shell)).length() >= hole {
                centers.push(c);
            }
        }
        let radii = vec![1.7; centers.len()];
        Balls::new(centers, radii, 1.4, SAMPLE)
    }

    #[test]
    fn a_closed_shell_walls_one_cavity_and_an_open_one_none() {
        // Radius 7: 80 atoms leave no gap a probe passes, and inside, F is a ball of
        // radius about 7 - 3.1.
        let closed = shell(80, 7.0, 0.0);
        let (access, _, cav) = solvent_access(&closed, 2, &Silent).unwrap();
        assert_eq!(cav.count, 1, "{cav:?}");
        assert_eq!(cav.atoms as usize, closed.centers.len());
        assert!(access.iter().all(|a| matches!(a, Access::Some(_))));
        // A mouth wider than the probe: one piece, in the solvent.
        let open = shell(80, 7.0, 6.0);
        let (access, _, cav) = solvent_access(&open, 2, &Silent).unwrap();
        assert_eq!(cav, Cavities::default());
        assert!(access.iter().all(|a| *a == Access::All));
    }

    /// What a rank sends of its atoms' passes reads back the same, and a cut message
    /// is an error (not a panic, not a shorter list).
    #[test]
    fn atom_passes_go_through_bytes_unchanged() {
        let balls = shell(40, 6.0, 2.5);
        let mut others = Vec::new();
        let atoms: Vec<AtomPass> = (0..balls.centers.len())
            .map(|i| atom_pass(&balls, i, &mut others))
            .collect();
        assert!(atoms
            .iter()
            .any(|(t, r, b)| !t.is_empty() && !r.is_empty() && !b.is_empty()));
        let bytes = encode(atoms.iter());
        assert_eq!(decode(&bytes, 1).unwrap(), atoms);
        assert!(decode(&bytes[..bytes.len() - 3], 1).is_err());
        assert!(decode(&[], 1).unwrap().is_empty());
    }

    #[test]
    fn separate_atoms_all_face_the_solvent() {
        let centers = vec![
            DVec3::ZERO,
            DVec3::new(20.0, 0.0, 0.0),
            DVec3::new(2.0, 0.0, 0.0),
        ];
        let balls = Balls::new(centers, vec![1.5; 3], 1.4, SAMPLE);
        let (access, _, cav) = solvent_access(&balls, 1, &Silent).unwrap();
        assert_eq!(cav, Cavities::default());
        assert_eq!(access, vec![Access::All; 3]);
    }
}
