//! The over-relaxation factor of red-black SOR.

/// The optimal SOR factor for the model problem on a domain about `n` voxels across:
/// `2 / (1 + sin(pi / n))`.
#[must_use]
pub fn optimal_omega(n: f64) -> f64 {
    2.0 / (1.0 + (std::f64::consts::PI / n.max(2.0)).sin())
}
