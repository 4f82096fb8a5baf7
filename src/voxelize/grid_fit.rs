//! Choosing the grid: spacing from `--resolution` or `--spacing`, padding, placement.

use super::{VoxelizeError, VoxelizeOptions};
use crate::grid::GridSpec;
use crate::math::Vec3;

/// The largest grid harmap accepts, in voxels (2^36: 64 GiB of u8 labels).
pub const MAX_VOXELS: u64 = 1 << 36;
/// The largest extent along one axis.
pub const MAX_AXIS: u64 = 1 << 15;
/// The smallest padding: four exterior layers plus one free voxel.
pub const MIN_PADDING: u64 = 5;

/// Refuse a grid larger than harmap handles, naming what asked for it.
pub fn check_shape(shape: [u64; 3], what: &str) -> Result<(), VoxelizeError> {
    let total = shape.iter().try_fold(1u64, |acc, &n| acc.checked_mul(n));
    if shape.iter().any(|&n| n > MAX_AXIS) || total.is_none_or(|t| t > MAX_VOXELS) {
        return Err(VoxelizeError::Options(format!(
            "{what} gives a grid of {} x {} x {} voxels ({:.3e}); the largest grid harmap handles is 2^36 voxels with at most {MAX_AXIS} along an axis; choose a smaller --resolution or a larger --spacing",
            shape[2],
            shape[1],
            shape[0],
            shape.iter().map(|&n| n as f64).product::<f64>()
        )));
    }
    Ok(())
}

/// `v` as a person reads it: plain decimals for ordinary sizes, scientific notation
/// for tiny or huge ones (Rust prints 1e-300 with 300 digits).
fn readable(v: f64) -> String {
    if v == 0.0 || (1e-4..1e9).contains(&v.abs()) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

fn check_padding(padding: u64) -> Result<(), VoxelizeError> {
    if padding > MAX_AXIS {
        return Err(VoxelizeError::Options(format!(
            "--padding {padding} is larger than a grid axis may be ({MAX_AXIS})"
        )));
    }
    if padding < MIN_PADDING {
        return Err(VoxelizeError::Options(format!(
            "--padding {padding} is too small: the four exterior layers need at least {MIN_PADDING} voxels around the shape"
        )));
    }
    Ok(())
}

/// The grid for a surface with bounding box `(lo, hi)` (world units): the shape is
/// centered, with `padding` voxels on every side.
pub fn fit_bbox(lo: Vec3, hi: Vec3, o: &VoxelizeOptions) -> Result<GridSpec, VoxelizeError> {
    check_padding(o.padding)?;
    let extent = hi - lo;
    let longest = extent.max_element();
    if !(longest.is_finite() && longest > 0.0) {
        return Err(VoxelizeError::Options(format!(
            "the shape has no extent (bounding box {lo} to {hi}); nothing to voxelize"
        )));
    }
    let (h, what) = match (o.resolution, o.spacing) {
        (Some(_), Some(_)) => {
            return Err(VoxelizeError::Options(
                "give either --resolution or --spacing, not both".into(),
            ))
        }
        (Some(0), None) => {
            return Err(VoxelizeError::Options(
                "--resolution must be at least 1 voxel".into(),
            ))
        }
        (Some(n), None) => (longest / n as f64, format!("--resolution {n}")),
        (None, Some(s)) if !(s.is_finite() && s > 0.0) => {
            return Err(VoxelizeError::Options(format!(
                "--spacing must be a positive length, got {s}"
            )))
        }
        (None, Some(s)) => (s, format!("--spacing {}", readable(s))),
        (None, None) => (
            longest / DEFAULT_RESOLUTION as f64,
            format!("the default --resolution {DEFAULT_RESOLUTION}"),
        ),
    };
    let n = extent.to_array().map(|e| ((e / h) - 1e-9).ceil().max(1.0));
    if n.iter().any(|&c| c > MAX_AXIS as f64) {
        // Too many to count in integers: say how many, in scientific notation.
        return Err(VoxelizeError::Options(format!(
            "{what} gives a grid of {:.3e} x {:.3e} x {:.3e} voxels; the largest grid harmap handles is 2^36 voxels with at most {MAX_AXIS} along an axis; choose a smaller --resolution or a larger --spacing",
            n[0], n[1], n[2]
        )));
    }
    let shape_xyz = n.map(|c| c as u64 + 2 * o.padding);
    let shape = [shape_xyz[2], shape_xyz[1], shape_xyz[0]];
    check_shape(shape, &what)?;
    let mid = (lo + hi) * 0.5;
    let origin = [0, 1, 2].map(|a| mid[a] - (shape_xyz[a] - 1) as f64 * 0.5 * h);
    Ok(GridSpec {
        shape,
        origin,
        spacing: h,
        chunk: [o.chunk; 3],
        unit: o.unit.clone(),
    })
}

/// The grid for a label volume of `shape` `[z, y, x]`: its voxel `(k, j, i)` sits at
/// world `(i, j, k) * spacing`, with `padding` voxels added around it.
pub fn fit_volume(shape: [u64; 3], o: &VoxelizeOptions) -> Result<GridSpec, VoxelizeError> {
    check_padding(o.padding)?;
    if o.resolution.is_some() {
        return Err(VoxelizeError::Options(
            "--resolution does not apply to a label volume: it keeps its own voxels (use --spacing to give their size)".into(),
        ));
    }
    let h = o.spacing.unwrap_or(1.0);
    if !(h.is_finite() && h > 0.0) {
        return Err(VoxelizeError::Options(format!(
            "--spacing must be a positive length, got {h}"
        )));
    }
    let padded = shape.map(|n| n + 2 * o.padding);
    check_shape(padded, "the label volume with its padding")?;
    let p = -(o.padding as f64) * h;
    Ok(GridSpec {
        shape: padded,
        origin: [p, p, p],
        spacing: h,
        chunk: [o.chunk; 3],
        unit: o.unit.clone(),
    })
}

/// Resolution used when neither `--resolution` nor `--spacing` is given.
pub const DEFAULT_RESOLUTION: u64 = 128;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resolution_spans_the_longest_side() {
        let o = VoxelizeOptions {
            resolution: Some(100),
            ..VoxelizeOptions::default()
        };
        let g = fit_bbox(Vec3::ZERO, Vec3::new(2.0, 1.0, 0.5), &o).unwrap();
        assert_eq!(g.shape, [25 + 12, 50 + 12, 100 + 12]);
        assert!((g.spacing - 0.02).abs() < 1e-15);
        // The shape is centered: first and last voxel centers are symmetric about it.
        let c0 = g.voxel_center([0, 0, 0]);
        let c1 = g.voxel_center([g.shape[0] - 1, g.shape[1] - 1, g.shape[2] - 1]);
        assert!(((c0 + c1) * 0.5 - Vec3::new(1.0, 0.5, 0.25)).length() < 1e-12);
    }

    #[test]
    fn bad_sizes_are_refused() {
        let o = |r| VoxelizeOptions {
            resolution: Some(r),
            ..VoxelizeOptions::default()
        };
        assert!(fit_bbox(Vec3::ZERO, Vec3::ONE, &o(0)).is_err());
        let e = fit_bbox(Vec3::ZERO, Vec3::ONE, &o(1_000_000)).unwrap_err();
        assert!(e.to_string().contains("largest grid"), "{e}");
        let p = VoxelizeOptions {
            padding: 2,
            ..VoxelizeOptions::default()
        };
        assert!(fit_bbox(Vec3::ZERO, Vec3::ONE, &p).is_err());
        assert!(fit_bbox(Vec3::ZERO, Vec3::ZERO, &VoxelizeOptions::default()).is_err());
    }
}
