//! The 7-point stencil on a haloed block: red-black SOR sweeps and residuals.
//!
//! A block is a C-order box `[z, y, x]` of phi and of labels that includes a halo of at
//! least one voxel, whose values are read but never written. Only interior voxels
//! ([`INTERIOR`](crate::voxelize::labels::INTERIOR)) are updated; their six neighbours
//! are solid by construction, so no exterior (NaN) value is ever read. Units: voxels
//! (with equal spacing h, `phi = mean of the 6 neighbours` is the discrete Laplace
//! equation and h drops out).
//!
//! Colors: a voxel is red when `z + y + x` (global indices) is even. `parity` gives the
//! parity of the block's first voxel, so sweeps are the same whatever the blocking.

use crate::voxelize::labels::INTERIOR;

/// What one sweep or residual pass found, to be reduced in block order.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Stats {
    /// Largest |phi_new - phi_old| (sweeps) or |residual| (residual pass).
    pub max_abs: f64,
    /// Sum of squared updates or residuals.
    pub sum_sq: f64,
    /// Unknowns visited.
    pub count: u64,
}

impl Stats {
    /// Combine with the stats of the next block.
    #[must_use]
    pub fn then(self, o: Stats) -> Stats {
        Stats {
            max_abs: self.max_abs.max(o.max_abs),
            sum_sq: self.sum_sq + o.sum_sq,
            count: self.count + o.count,
        }
    }
}

#[inline]
fn neighbour_sum(phi: &[f64], i: usize, sy: usize, sz: usize) -> f64 {
    phi[i - 1] + phi[i + 1] + phi[i - sy] + phi[i + sy] + phi[i - sz] + phi[i + sz]
}

/// One SOR half-sweep over the voxels of `color` (0 red, 1 black) inside the box, the
/// halo of width `halo` excluded: `phi += omega * (mean of neighbours - phi)`.
/// `omega = 1` is Gauss-Seidel.
pub fn sor_half_sweep(
    phi: &mut [f64],
    labels: &[u8],
    shape: [usize; 3],
    halo: usize,
    parity: usize,
    color: usize,
    omega: f64,
) -> Stats {
    let [nz, ny, nx] = shape;
    let (sy, sz) = (nx, nx * ny);
    let mut st = Stats::default();
    for z in halo..nz - halo {
        for y in halo..ny - halo {
            // The first x of this row with the wanted color.
            let x0 = halo + (parity + z + y + halo + color) % 2;
            let row = (z * ny + y) * nx;
            for x in (x0..nx - halo).step_by(2) {
                let i = row + x;
                if labels[i] != INTERIOR {
                    continue;
                }
                let delta = omega * (neighbour_sum(phi, i, sy, sz) / 6.0 - phi[i]);
                phi[i] += delta;
                st.max_abs = st.max_abs.max(delta.abs());
                st.sum_sq += delta * delta;
                st.count += 1;
            }
        }
    }
    st
}

/// Residual `r = mean of neighbours - phi` (the discrete Laplacian / 6) over the
/// interior voxels of the box, the halo excluded.
#[must_use]
pub fn residual(phi: &[f64], labels: &[u8], shape: [usize; 3], halo: usize) -> Stats {
    let [nz, ny, nx] = shape;
    let (sy, sz) = (nx, nx * ny);
    let mut st = Stats::default();
    for z in halo..nz - halo {
        for y in halo..ny - halo {
            let row = (z * ny + y) * nx;
            for x in halo..nx - halo {
                let i = row + x;
                if labels[i] != INTERIOR {
                    continue;
                }
                let r = neighbour_sum(phi, i, sy, sz) / 6.0 - phi[i];
                st.max_abs = st.max_abs.max(r.abs());
                st.sum_sq += r * r;
                st.count += 1;
            }
        }
    }
    st
}

/// The optimal SOR factor for the model problem on a domain about `n` voxels across:
/// `2 / (1 + sin(pi / n))`.
#[must_use]
pub fn optimal_omega(n: f64) -> f64 {
    2.0 / (1.0 + (std::f64::consts::PI / n.max(2.0)).sin())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solve::dirichlet::initial;
    use crate::voxelize::labels::{BOUNDARY, CENTER};

    /// Concentric spheres on an n^3 grid: boundary shell at r >= R, sink at r <= r0.
    fn concentric(n: usize, r_out: f64, r0: f64) -> (Vec<f64>, Vec<u8>, Vec<f64>) {
        let c = (n as f64 - 1.0) / 2.0;
        let mut labels = vec![0u8; n * n * n];
        let mut exact = vec![f64::NAN; n * n * n];
        for z in 0..n {
            for y in 0..n {
                for x in 0..n {
                    let r =
                        ((z as f64 - c).powi(2) + (y as f64 - c).powi(2) + (x as f64 - c).powi(2))
                            .sqrt();
                    let i = (z * n + y) * n + x;
                    labels[i] = if r <= r0 {
                        CENTER
                    } else if r < r_out {
                        INTERIOR
                    } else {
                        BOUNDARY
                    };
                    exact[i] = ((1.0 / r0 - 1.0 / r) / (1.0 / r0 - 1.0 / r_out)).clamp(0.0, 1.0);
                }
            }
        }
        let phi = labels.iter().map(|&l| initial(l, 1e-4)).collect();
        (phi, labels, exact)
    }

    #[test]
    fn sor_solves_the_same_discrete_system_as_jacobi() {
        // SOR with the optimal factor and the paper's Jacobi iteration, both to a tiny
        // residual, agree; the answer obeys the maximum principle.
        let n = 16;
        let (mut sor, labels, _) = concentric(n, 7.0, 2.0);
        let mut jac = sor.clone();
        let omega = optimal_omega(14.0);
        for _ in 0..400 {
            sor_half_sweep(&mut sor, &labels, [n; 3], 1, 0, 0, omega);
            sor_half_sweep(&mut sor, &labels, [n; 3], 1, 0, 1, omega);
        }
        assert!(residual(&sor, &labels, [n; 3], 1).max_abs < 1e-13);
        let (sy, sz) = (n, n * n);
        for _ in 0..6000 {
            let old = jac.clone();
            for (i, &l) in labels.iter().enumerate() {
                if l == INTERIOR {
                    jac[i] = neighbour_sum(&old, i, sy, sz) / 6.0;
                }
            }
        }
        for (i, &l) in labels.iter().enumerate() {
            if l == INTERIOR {
                assert!(
                    (sor[i] - jac[i]).abs() < 1e-9,
                    "voxel {i}: SOR {} vs Jacobi {}",
                    sor[i],
                    jac[i]
                );
                assert!((0.0..=1.0).contains(&sor[i]));
            }
        }
    }

    #[test]
    fn colors_do_not_depend_on_the_blocking() {
        // Sweeping a box at once, or as two halves whose parity is passed in, updates
        // the same voxels with the same values.
        let n = 12;
        let (phi0, labels, _) = concentric(n, 5.0, 1.5);
        let mut whole = phi0.clone();
        sor_half_sweep(&mut whole, &labels, [n; 3], 1, 0, 0, 1.0);
        // The upper half in z as its own box (with one halo slice below it).
        let z0 = n / 2 - 1;
        let mut half: Vec<f64> = phi0[z0 * n * n..].to_vec();
        let lab: Vec<u8> = labels[z0 * n * n..].to_vec();
        sor_half_sweep(&mut half, &lab, [n - z0, n, n], 1, z0 % 2, 0, 1.0);
        assert_eq!(
            &half[n * n..(n - z0 - 1) * n * n],
            &whole[(z0 + 1) * n * n..(n - 1) * n * n]
        );
    }
}
