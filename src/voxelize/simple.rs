//! Simple points for the (6, 26) pair: the object 6-connected (as the solver's 7-point
//! stencil sees it, and as [`super::euler`] and [`super::components`] count it), the
//! background 26-connected.
//!
//! A voxel is simple when adding it to the object (or removing it) changes no topology:
//! no piece, cavity or tunnel appears or disappears. Bertrand and Malandain (1994) show
//! it is a local property with two topological numbers over the 3x3x3 neighbourhood N26
//! of the voxel x, the voxel itself left out:
//! - T6(x, X): the 6-components of X within N18 (the neighbours sharing a face or an edge
//!   with x) that hold a face neighbour of x;
//! - T26(x, X'): the 26-components of the background X' within N26.
//!
//! x is simple iff both are 1. The neighbourhood is a 27-bit mask, bit
//! `(dz + 1) * 9 + (dy + 1) * 3 + (dx + 1)`; bit 13 (x itself) is ignored. Components are
//! flooded over bit masks with precomputed adjacency, a few dozen word operations.
// Index arithmetic over the grid's axes: z, y, x and i, j, k read as in the formulas.
#![allow(clippy::many_single_char_names)]

/// Bit of the neighbour at offset `(dz, dy, dx)`, each in -1..=1.
#[must_use]
pub const fn bit(dz: i64, dy: i64, dx: i64) -> u32 {
    ((dz + 1) * 9 + (dy + 1) * 3 + (dx + 1)) as u32
}

/// Offsets of the 27 positions, by bit.
const fn offset(b: usize) -> [i64; 3] {
    [
        (b / 9) as i64 - 1,
        ((b / 3) % 3) as i64 - 1,
        (b % 3) as i64 - 1,
    ]
}

/// How many coordinates of a position differ from the center's (1: face, 2: edge, 3:
/// corner neighbour).
const fn order(b: usize) -> u32 {
    let o = offset(b);
    (o[0] != 0) as u32 + (o[1] != 0) as u32 + (o[2] != 0) as u32
}

/// Masks of the positions `a` is adjacent to within the cube: sharing a face (`k = 1`)
/// or anything (`k = 3`).
const fn adjacency(k: u32) -> [u32; 27] {
    let mut out = [0u32; 27];
    let mut a = 0;
    while a < 27 {
        let mut b = 0;
        while b < 27 {
            let (oa, ob) = (offset(a), offset(b));
            let d = [oa[0] - ob[0], oa[1] - ob[1], oa[2] - ob[2]];
            let far = d[0].abs() > 1 || d[1].abs() > 1 || d[2].abs() > 1;
            let n = (d[0] != 0) as u32 + (d[1] != 0) as u32 + (d[2] != 0) as u32;
            if a != b && !far && n <= k {
                out[a] |= 1 << b;
            }
            b += 1;
        }
        a += 1;
    }
    out
}

const ADJ6: [u32; 27] = adjacency(1);
const ADJ26: [u32; 27] = adjacency(3);

/// Mask of the positions of a given neighbour order or less, without the center.
const fn up_to(k: u32) -> u32 {
    let mut m = 0u32;
    let mut b = 0;
    while b < 27 {
        if b != 13 && order(b) <= k {
            m |= 1 << b;
        }
        b += 1;
    }
    m
}

/// The 6 face neighbours.
const N6: u32 = up_to(1);
/// The 18 face and edge neighbours.
const N18: u32 = up_to(2);
/// All 26 neighbours.
const N26: u32 = up_to(3);

/// Number of components of `set` (under `adj`) that meet `seeds`.
fn count(set: u32, seeds: u32, adj: &[u32; 27]) -> u32 {
    let mut left = set;
    let mut n = 0;
    let mut todo = seeds & set;
    while todo != 0 {
        let start = todo.trailing_zeros();
        let mut comp = 1u32 << start;
        let mut frontier = comp;
        while frontier != 0 {
            let b = frontier.trailing_zeros() as usize;
            frontier &= frontier - 1;
            let grow = adj[b] & left & !comp;
            comp |= grow;
            frontier |= grow;
        }
        left &= !comp;
        todo &= !comp;
        n += 1;
        if n > 1 {
            break;
        }
    }
    n
}

/// Whether the center of a neighbourhood is simple for the 6-connected object whose
/// voxels are the set bits of `object` (bit 13, the center, is ignored).
#[must_use]
pub fn is_simple(object: u32) -> bool {
    let obj = object & N26;
    // T6: 6-components of the object within N18 that touch a face neighbour.
    if count(obj & N18, N6, &ADJ6) != 1 {
        return false;
    }
    // T26 of the background within N26.
    let bg = !obj & N26;
    count(bg, bg, &ADJ26) == 1
}

#[cfg(test)]
mod tests {
    use super::*;
    /// Brute force, independent of the topological numbers: in the cubical complex
    /// whose vertices are the object's voxels (edges between face neighbours, squares
    /// and cubes where all their voxels are in the object: the complex
    /// [`super::super::euler`] counts), adding x is a homotopy equivalence iff the link
    /// of x is contractible. The link lies on the octahedron around x: a vertex per
    /// face neighbour in the object, an edge per square through x, a triangle per cube
    /// through x. A subcomplex of that 2-sphere is contractible iff it is non-empty,
    /// connected, and its Euler characteristic is 1.
    fn brute(object: u32) -> bool {
        let has = |o: [i64; 3]| object >> bit(o[0], o[1], o[2]) & 1 == 1;
        let faces: Vec<[i64; 3]> = (0..27)
            .map(offset)
            .filter(|o| o.iter().map(|c| c.abs()).sum::<i64>() == 1)
            .collect();
        let add = |a: [i64; 3], b: [i64; 3]| [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
        let orth = |a: [i64; 3], b: [i64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2] == 0;
        let verts: Vec<usize> = (0..6).filter(|&i| has(faces[i])).collect();
        let mut edges = Vec::new();
        for &i in &verts {
            for &j in &verts {
                if i < j && orth(faces[i], faces[j]) && has(add(faces[i], faces[j])) {
                    edges.push((i, j));
                }
            }
        }
        let mut tris = 0i64;
        for &i in &verts {
            for &j in &verts {
                for &k in &verts {
                    let (a, b, c) = (faces[i], faces[j], faces[k]);
                    if i < j
                        && j < k
                        && orth(a, b)
                        && orth(b, c)
                        && orth(a, c)
                        && has(add(a, b))
                        && has(add(b, c))
                        && has(add(a, c))
                        && has(add(add(a, b), c))
                    {
                        tris += 1;
                    }
                }
            }
        }
        if verts.is_empty() {
            return false;
        }
        // Connected: flood over the edges.
        let mut reached = vec![verts[0]];
        let mut k = 0;
        while k < reached.len() {
            let v = reached[k];
            for &(i, j) in &edges {
                for (p, q) in [(i, j), (j, i)] {
                    if p == v && !reached.contains(&q) {
                        reached.push(q);
                    }
                }
            }
            k += 1;
        }
        reached.len() == verts.len() && verts.len() as i64 - edges.len() as i64 + tris == 1
    }

    #[test]
    fn masks() {
        assert_eq!(N6.count_ones(), 6);
        assert_eq!(N18.count_ones(), 18);
        assert_eq!(N26.count_ones(), 26);
        assert_eq!(ADJ6[13].count_ones(), 6);
        assert_eq!(ADJ26[13].count_ones(), 26);
        assert_eq!(
            ADJ26[0].count_ones(),
            7,
            "a corner has 7 neighbours in the cube"
        );
        assert_eq!(bit(0, 0, 0), 13);
    }

    #[test]
    fn known_cases() {
        // Nothing around: adding the voxel makes a new piece.
        assert!(!is_simple(0));
        // Everything around: adding it fills a cavity.
        assert!(!is_simple(N26));
        // Two pieces in N18 joined through a corner voxel, and the background cut in two:
        // closes one loop and opens another (the Betti numbers stay, yet not simple).
        assert!(!is_simple(0b110_0111_1110_1111_0101_0101_1111));
        // One face neighbour: grows a piece.
        assert!(is_simple(1 << bit(0, 0, -1)));
        // Only a corner neighbour: under 6-connectivity a new piece.
        assert!(!is_simple(1 << bit(1, 1, 1)));
        // Two opposite face neighbours, nothing else: joins two pieces (or closes a loop).
        assert!(!is_simple(1 << bit(0, 0, -1) | 1 << bit(0, 0, 1)));
        // A full lower half-space: simple.
        let lower = (0..9).fold(0, |m, b| m | 1 << b);
        assert!(is_simple(lower));
    }

    /// Against brute force on random neighbourhoods of every density, and on every
    /// neighbourhood of the 6 face and 12 edge neighbours with no corner set.
    #[test]
    fn matches_brute_force() {
        let mut s = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        };
        let mut simple = 0;
        for i in 0..60_000 {
            // Density from 1/8 to 7/8 set.
            let k = 1 + i % 7;
            let mut m = 0u32;
            for b in 0..27 {
                if next() % 8 < k {
                    m |= 1 << b;
                }
            }
            let got = is_simple(m);
            simple += u32::from(got);
            assert_eq!(got, brute(m), "neighbourhood {m:#029b}");
        }
        assert!(simple > 1000, "the sample holds simple points ({simple})");
        for sub in 0u32..1 << 18 {
            let mut m = 0u32;
            let mut j = 0;
            for b in 0..27 {
                if b != 13 && order(b) <= 2 {
                    if sub >> j & 1 == 1 {
                        m |= 1 << b;
                    }
                    j += 1;
                }
            }
            assert_eq!(is_simple(m), brute(m), "neighbourhood {m:#029b}");
        }
    }
}
