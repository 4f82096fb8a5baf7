//! The shape center: the solid voxel deepest inside (largest Euclidean distance to the
//! nearest non-solid voxel), by an exact distance transform streamed slice by slice.
//!
//! Pass 1 (z ascending) records, per column (y, x), the distance along z to the last
//! non-solid voxel below, as u16 slices in a scratch file. Pass 2 (z descending) takes
//! the minimum with the distance to the next non-solid voxel above, which gives the exact
//! 1-D distance along z, then runs the lower-envelope transform of Felzenszwalb and
//! Huttenlocher along y and x within the slice: the exact squared Euclidean distance.
//! Resident: a few slices (`O(ny * nx)`), never the grid.
// Index arithmetic over the grid's axes: z, y, x and i, j, k read as in the formulas.
#![allow(clippy::many_single_char_names)]

use std::fs::OpenOptions;
use std::os::unix::fs::FileExt;
use std::path::Path;

use rayon::prelude::*;

use crate::grid::{BlockStore, GridError};
use crate::math::Idx3;
use crate::progress::Progress;

/// What the distance transform found.
#[derive(Clone, Copy, Debug)]
pub struct Deepest {
    /// The deepest solid voxel `[z, y, x]`.
    pub voxel: Idx3,
    /// Its distance (voxels) to the nearest non-solid voxel.
    pub depth: f64,
    /// The distance of the queried voxel, if one was asked for.
    pub query_depth: Option<f64>,
}

/// Distance cap in voxels (grids are at most 2^15 along an axis).
const FAR: u32 = 1 << 16;

/// The deepest solid voxel and its distance (voxels) to the nearest non-solid voxel.
/// Ties go to the lowest `[z, y, x]` in C order. With `query`, also the distance of that
/// voxel (0 when it is not solid).
#[allow(clippy::too_many_lines)] // the distance transform's three passes share the block buffers
pub fn deepest_voxel(
    store: &dyn BlockStore<u8>,
    scratch: &Path,
    query: Option<Idx3>,
    progress: &dyn Progress,
) -> Result<Deepest, crate::Error> {
    let spec = store.spec();
    let [nz, ny, nx] = spec.shape.map(|c| c as usize);
    let plane = ny * nx;
    let io = |source| GridError::Io {
        path: scratch.to_owned(),
        source,
    };
    let file = OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(true)
        .open(scratch)
        .map_err(io)?;
    let slice = |z: usize| -> Result<Vec<u8>, GridError> {
        crate::progress::check_interrupt(progress)?;
        Ok(store.read_region([z as i64, 0, 0], [1, ny, nx], 0)?.data)
    };
    progress.start("voxelize: center (distance transform)", 2 * nz as u64);
    let mut last = vec![FAR; plane]; // z of the last non-solid voxel, FAR = none yet
    let mut bytes = vec![0u8; plane * 2];
    for z in 0..nz {
        let s = slice(z)?;
        for (i, (&v, l)) in s.iter().zip(last.iter_mut()).enumerate() {
            if v != 1 {
                *l = z as u32;
            }
            let d = if *l == FAR { FAR - 1 } else { z as u32 - *l };
            bytes[2 * i..2 * i + 2]
                .copy_from_slice(&(d.min(u32::from(u16::MAX)) as u16).to_le_bytes());
        }
        file.write_all_at(&bytes, (z * plane * 2) as u64)
            .map_err(io)?;
        progress.advance(1);
    }
    let mut next = vec![FAR; plane];
    let mut best: (u64, Idx3) = (0, [0, 0, 0]);
    let mut g2 = vec![0u64; plane];
    let mut query_d2 = None;
    let mut t = vec![0u64; plane];
    for z in (0..nz).rev() {
        let s = slice(z)?;
        file.read_exact_at(&mut bytes, (z * plane * 2) as u64)
            .map_err(io)?;
        for i in 0..plane {
            if s[i] != 1 {
                next[i] = z as u32;
            }
            let down = u64::from(u16::from_le_bytes([bytes[2 * i], bytes[2 * i + 1]]));
            let up = if next[i] == FAR {
                u64::from(FAR)
            } else {
                u64::from(next[i] - z as u32)
            };
            let d = down.min(up);
            g2[i] = d * d;
        }
        // The distance of a voxel is at most its distance along z, so a slice whose
        // solid voxels all have g^2 below the best so far cannot hold the deepest voxel
        // (equal values may: ties go to the lower z, which comes later).
        let max_g2 = g2
            .iter()
            .zip(&s)
            .filter(|(_, &v)| v == 1)
            .map(|(&g, _)| g)
            .max()
            .unwrap_or(0);
        let q_here = query
            .filter(|q| q[0] == z as u64)
            .map(|q| (q[1] as usize, q[2] as usize));
        if (max_g2 == 0 || max_g2 < best.0) && q_here.is_none() {
            progress.advance(1);
            continue;
        }
        // Along y (columns), then along x (rows).
        t.par_chunks_mut(ny).enumerate().for_each(|(x, col)| {
            let f: Vec<u64> = (0..ny).map(|y| g2[y * nx + x]).collect();
            lower_envelope(&f, col);
        });
        let floor = best.0;
        let rows: Vec<(u64, usize, Option<u64>)> = (0..ny)
            .into_par_iter()
            .map(|y| {
                let f: Vec<u64> = (0..nx).map(|x| t[x * ny + y]).collect();
                // Likewise the in-plane column distance bounds the row's distances.
                let q_row = q_here.filter(|q| q.0 == y).map(|q| q.1);
                if q_row.is_none()
                    && (0..nx)
                        .filter(|&x| s[y * nx + x] == 1)
                        .all(|x| f[x] < floor)
                {
                    return (0, 0, None);
                }
                let mut d = vec![0u64; nx];
                lower_envelope(&f, &mut d);
                let mut b = (0u64, 0usize);
                for x in 0..nx {
                    if s[y * nx + x] == 1 && d[x] > b.0 {
                        b = (d[x], x);
                    }
                }
                (
                    b.0,
                    b.1,
                    q_row.map(|qx| if s[y * nx + qx] == 1 { d[qx] } else { 0 }),
                )
            })
            .collect();
        // The first maximum over y (ascending) keeps the lowest y; across slices z
        // descends, so an equal distance in a lower slice replaces the best.
        let mut slice_best = (0u64, [0u64; 3]);
        for (y, &(d, x, q)) in rows.iter().enumerate() {
            if q.is_some() {
                query_d2 = q;
            }
            if d > slice_best.0 {
                slice_best = (d, [z as u64, y as u64, x as u64]);
            }
        }
        if slice_best.0 > 0 && slice_best.0 >= best.0 {
            best = slice_best;
        }
        progress.advance(1);
    }
    progress.finish();
    drop(file);
    let _ = std::fs::remove_file(scratch);
    Ok(Deepest {
        voxel: best.1,
        depth: (best.0 as f64).sqrt(),
        query_depth: query_d2.map(|d| (d as f64).sqrt()),
    })
}

/// 1-D squared distance transform of sampled function `f` (Felzenszwalb-Huttenlocher):
/// `out[q] = min_p f[p] + (q - p)^2`.
fn lower_envelope(f: &[u64], out: &mut [u64]) {
    let n = f.len();
    let mut v = vec![0usize; n];
    let mut zb = vec![0f64; n + 1];
    let mut k = 0usize;
    zb[0] = f64::NEG_INFINITY;
    zb[1] = f64::INFINITY;
    let inter = |p: usize, q: usize| -> f64 {
        ((f[q] as f64 + (q * q) as f64) - (f[p] as f64 + (p * p) as f64))
            / (2.0 * (q as f64 - p as f64))
    };
    for q in 1..n {
        let mut s = inter(v[k], q);
        while s <= zb[k] {
            k -= 1;
            s = inter(v[k], q);
        }
        k += 1;
        v[k] = q;
        zb[k] = s;
        zb[k + 1] = f64::INFINITY;
    }
    k = 0;
    for (q, o) in out.iter_mut().enumerate() {
        while zb[k + 1] < q as f64 {
            k += 1;
        }
        let d = q.abs_diff(v[k]) as u64;
        *o = d * d + f[v[k]];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn envelope_matches_brute_force() {
        let f: Vec<u64> = vec![9, 0, 100, 100, 4, 100, 100, 100, 0, 25];
        let mut out = vec![0; f.len()];
        lower_envelope(&f, &mut out);
        for (q, &o) in out.iter().enumerate() {
            let brute = (0..f.len())
                .map(|p| f[p] + (q.abs_diff(p) as u64).pow(2))
                .min()
                .unwrap();
            assert_eq!(o, brute, "q = {q}");
        }
    }
}
