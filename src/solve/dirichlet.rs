//! Dirichlet conditions of the paper (section 5, step 4), by label.
//!
//! The solver's unknown is `u = 1 - phi`, not phi. Over most of a shape with thin parts
//! phi is within 1e-16 of 1 (it decays like exp(-pi x / width) down an arm), where an f64
//! phi rounds to exactly 1 and its gradient to 0; u keeps full relative precision there
//! (values of 1e-22 are common on cactus10k at resolution 128). The linear system is the
//! same; only the stored quantity changes.

use super::blocks::BlockLoop;
use super::level::Level;
use crate::grid::GridError;
use crate::voxelize::labels::{BOUNDARY, CENTER, EXTERIOR, INTERIOR, LAYER1};

/// What phi is at a voxel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Node {
    /// An unknown of the linear system (interior voxel).
    Unknown,
    /// Held fixed: 1 on the boundary, 0 in the center ball, `1 + k eps` on exterior
    /// layer k.
    Fixed(f64),
    /// Not part of the problem (exterior beyond the layers): phi is NaN there.
    Outside,
}

/// The node a voxel of label `label` is, with layer spacing `eps` (the paper's 1e-4).
#[must_use]
pub fn node(label: u8, eps: f64) -> Node {
    match label {
        INTERIOR | super::cuts::CUT => Node::Unknown,
        BOUNDARY => Node::Fixed(1.0),
        CENTER => Node::Fixed(0.0),
        EXTERIOR => Node::Outside,
        k => Node::Fixed(1.0 + f64::from(k - LAYER1 + 1) * eps),
    }
}

/// The starting value of the solver's unknown u = 1 - phi at a voxel: the fixed value,
/// NaN outside, and for unknowns 0 (phi = 1, the value that holds over most of the
/// domain; the paper starts from random values, which only slows the first sweeps).
#[must_use]
pub fn initial_u(label: u8, eps: f64) -> f64 {
    match node(label, eps) {
        Node::Unknown => 0.0,
        Node::Fixed(v) => 1.0 - v,
        Node::Outside => f64::NAN,
    }
}

/// Set every voxel of generation 0 of the finest level to its starting value.
pub fn initialize(l: &Level, eps: f64, blocks: &BlockLoop<'_>) -> Result<(), GridError> {
    blocks.each(&l.spec, |b| {
        let m = l.mask.read_block(b)?;
        l.u[0].write_block(b, &m.iter().map(|&v| initial_u(v, eps)).collect::<Vec<_>>())
    })?;
    blocks.exchange(&l.field("u0"), &*l.u[0], &l.reach)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn labels_map_to_the_papers_conditions() {
        assert_eq!(node(BOUNDARY, 1e-4), Node::Fixed(1.0));
        assert_eq!(node(CENTER, 1e-4), Node::Fixed(0.0));
        assert_eq!(node(INTERIOR, 1e-4), Node::Unknown);
        assert_eq!(node(EXTERIOR, 1e-4), Node::Outside);
        assert_eq!(node(LAYER1, 0.5), Node::Fixed(1.5));
        assert_eq!(node(LAYER1 + 3, 0.5), Node::Fixed(3.0));
        assert!(initial_u(EXTERIOR, 1e-4).is_nan());
        assert_eq!(initial_u(CENTER, 1e-4).to_bits(), 1.0f64.to_bits());
        assert_eq!(initial_u(INTERIOR, 1e-4).to_bits(), 0.0f64.to_bits());
        assert_eq!(initial_u(LAYER1 + 1, 0.5).to_bits(), (-1.0f64).to_bits());
    }
}
