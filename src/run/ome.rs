//! The OME-Zarr 0.5 metadata of the run's images.

use serde_json::{json, Value};

use crate::grid::GridSpec;

/// OME-Zarr 0.5 `ome` attributes for a single-level image of the grid: axes z, y, x with
/// the grid's unit, scale = spacing, translation = world position of voxel (0, 0, 0).
#[must_use]
pub fn ome_multiscales(name: &str, spec: &GridSpec) -> Value {
    let axes: Vec<Value> = ["z", "y", "x"]
        .iter()
        .map(|a| match &spec.unit {
            Some(u) => json!({"name": a, "type": "space", "unit": u}),
            None => json!({"name": a, "type": "space"}),
        })
        .collect();
    json!({
        "version": "0.5",
        "multiscales": [{
            "name": name,
            "axes": axes,
            "datasets": [{
                "path": "0",
                "coordinateTransformations": [
                    {"type": "scale", "scale": [spec.spacing, spec.spacing, spec.spacing]},
                    {"type": "translation", "translation": [spec.origin[2], spec.origin[1], spec.origin[0]]}
                ]
            }]
        }]
    })
}
