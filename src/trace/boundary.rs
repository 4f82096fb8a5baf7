//! Where the field's boundary values come from: the run's input mesh when the solid is
//! exactly its inside and it can be read within the budget, else the smoothed voxel
//! solid ([`super::surface`]).

use std::sync::Arc;

use super::nearest::{self, SurfaceIndex};
use crate::grid::{GridSpec, MemBudget};
use crate::input::TriMesh;
use crate::math::Vec3;

/// Where the boundary nodes' sub-voxel values come from: the run's input surface when
/// there is one (a triangle mesh, or the built-in starfish), else the smoothed voxel
/// solid.
#[derive(Clone, Default)]
pub struct Boundary {
    /// The input surface in voxel coordinates, indexed.
    pub mesh: Option<Arc<SurfaceIndex>>,
    /// Why an input mesh is not used (it could not be read), to warn about.
    pub problem: Option<String>,
}

impl Boundary {
    /// The boundary of a run whose voxelize stage recorded `attrs`, for a stage that
    /// runs within `mem`.
    #[must_use]
    pub fn for_run(attrs: &serde_json::Value, spec: &GridSpec, mem: MemBudget) -> Self {
        Self::with_mesh(attrs, spec, mem, None)
    }

    /// [`Boundary::for_run`] with the input mesh at hand, if it is (else it is read).
    #[must_use]
    pub fn with_mesh(
        attrs: &serde_json::Value,
        spec: &GridSpec,
        mem: MemBudget,
        loaded: Option<&TriMesh>,
    ) -> Self {
        if !Self::solid_is_the_mesh(attrs) {
            return Self::default();
        }
        let cache = Self::cache_bytes(attrs, mem);
        let read;
        let mesh = match loaded {
            Some(mesh) => mesh,
            None => match super::seeds::input_surface(attrs) {
                Ok(Some(mesh)) => {
                    read = mesh;
                    &read
                }
                Ok(None) => return Self::default(),
                Err(problem) => return Self::smoothed_because(&problem),
            },
        };
        // The index stays for the whole stage: a mesh too large for the budget gives
        // way to the smoothed solid rather than stop the stage.
        let index = SurfaceIndex::bytes_for(mesh.triangles.len());
        if index > mem.work_bytes() / 4 {
            return Self::smoothed_because(&format!(
                "the input mesh's {} triangles need up to {} as an index, more than a quarter of the {} --mem {mem} leaves for data (a larger --mem uses the mesh)",
                mesh.triangles.len(),
                crate::grid::human(index),
                crate::grid::human(mem.work_bytes())
            ));
        }
        Self::of_mesh(mesh, spec, cache)
    }

    /// The smoothed solid, with `problem` to warn about.
    fn smoothed_because(problem: &str) -> Self {
        Self {
            mesh: None,
            problem: Some(format!(
                "{problem}; the boundary nodes' sub-voxel values come from the smoothed voxel solid instead"
            )),
        }
    }

    /// Whether the voxel solid is the inside of the input surface, so that the surface
    /// is where the solid's boundary is: not when the voxelizer filled cavities (their
    /// walls lie inside the solid), closed tunnels (`--close`: the plugs' faces are no
    /// part of the mesh) or removed pieces.
    #[must_use]
    pub fn solid_is_the_mesh(attrs: &serde_json::Value) -> bool {
        /// The voxelize result's counts of voxels that are no part of the mesh's inside.
        #[derive(serde::Deserialize)]
        #[allow(
            clippy::struct_field_names,
            reason = "the names of the recorded fields"
        )]
        struct Changes {
            cavity_voxels: Option<u64>,
            closing_voxels: Option<u64>,
            removed_voxels: Option<u64>,
        }
        crate::run::report_in::<Changes>(attrs, "voxelize").is_none_or(|c| {
            [c.cavity_voxels, c.closing_voxels, c.removed_voxels]
                .iter()
                .all(|v| v.unwrap_or(0) == 0)
        })
    }

    /// The boundary from `mesh` (world coordinates) on the grid `spec`, keeping up to
    /// `cache_bytes` of answers for nodes.
    #[must_use]
    pub fn of_mesh(mesh: &TriMesh, spec: &GridSpec, cache_bytes: u64) -> Self {
        let vertices: Vec<Vec3> = mesh
            .vertices
            .iter()
            .map(|&v| spec.world_to_voxel(v))
            .collect();
        let index = SurfaceIndex::new(&vertices, &mesh.triangles).with_cache(cache_bytes);
        Self {
            mesh: Some(Arc::new(index)),
            problem: None,
        }
    }

    /// The cache a stage within `mem` gives the mesh's answers: about four nodes per
    /// boundary voxel the voxelizer counted (the voxel and the exterior nodes that share
    /// a cell with the solid), at most an eighth of the budget (the entries are charged
    /// with the hash table's slack).
    #[must_use]
    pub fn cache_bytes(attrs: &serde_json::Value, mem: MemBudget) -> u64 {
        /// The one field of the voxelization's report read here.
        #[derive(serde::Deserialize)]
        struct Counts {
            counts: Vec<u64>,
        }
        let boundary = crate::run::report_in::<Counts>(attrs, "voxelize")
            .and_then(|r| {
                r.counts
                    .get(usize::from(crate::voxelize::labels::BOUNDARY))
                    .copied()
            })
            .unwrap_or(0);
        (boundary * 4 * nearest::CACHE_ENTRY_BYTES).min(mem.work_bytes() / 8)
    }

    /// The index, if the mesh is used.
    #[must_use]
    pub fn index(&self) -> Option<&SurfaceIndex> {
        self.mesh.as_deref()
    }

    /// Bytes the index holds.
    #[must_use]
    pub fn bytes(&self) -> u64 {
        self.mesh.as_ref().map_or(0, |m| m.bytes())
    }

    /// What the run records as the boundary's source.
    #[must_use]
    pub fn name(&self) -> &'static str {
        if self.mesh.is_some() {
            BOUNDARY_MESH
        } else {
            BOUNDARY_SMOOTHED
        }
    }
}

/// [`Boundary::name`] with the input mesh.
pub const BOUNDARY_MESH: &str = "input mesh";
/// [`Boundary::name`] without it.
pub const BOUNDARY_SMOOTHED: &str = "smoothed voxel solid";
