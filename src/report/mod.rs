//! Pictures of a run: the theta-psi atlas of the paper and the mapped sphere.
//!
//! Points are colored by a coordinate of the seed (viridis), or for molecule runs by
//! the chain or named domain (a categorical palette with a legend) or the residue
//! number (turbo, with a color bar) of the atom nearest the seed ([`domains`]). Drawn
//! with `plotters` (PNG through its bitmap backend, SVG through its SVG backend) and an
//! embedded DejaVu Sans, so no system fonts are needed. Files are written under a
//! temporary name and renamed when whole.

//!
//! Files: `paint` (the colors, caption and legend), `palette` (the colormaps), `plot`
//! (the atlas), `legend`, `sphere` (the sphere view), [`domains`] (the molecule's atoms
//! and domains nearest the seeds).

use std::path::{Path, PathBuf};

use plotters::prelude::*;

use crate::run::RunDir;
use crate::trace::read_seeds;

pub mod domains;
pub mod html;
mod legend;
mod paint;
mod palette;
mod plot;
mod sphere;

use paint::paint;
use plot::{atlas_points, draw_atlas, staged_draw, title};
use sphere::draw_sphere;

/// Errors of drawing.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    /// Nothing to draw, or a file name the backends cannot write.
    #[error("{0}")]
    Unavailable(String),
    /// The plotting backend failed.
    #[error("{}: drawing failed: {message}", path.display())]
    Draw {
        /// The file.
        path: PathBuf,
        /// The backend's message.
        message: String,
    },
}

static FONT: &[u8] = include_bytes!("../../assets/fonts/DejaVuSans.ttf");

fn register_font() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // The embedded font is valid; a failure would only mean no text.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    });
}

/// What the atlas colors its points by.
#[derive(Clone, Debug, PartialEq, Eq, Default)]
pub enum ColorBy {
    /// The seed's position along the shape's main axis (principal component of the seed
    /// positions): regions of the shape get their own colors.
    #[default]
    Axis,
    /// The seed's height (world z).
    Z,
    /// The seed's distance from the center: protrusions (arms, spikes, ears) light,
    /// the body dark.
    Distance,
    /// Molecules: the chain of the atom nearest the seed.
    Chain,
    /// Molecules: the residue number of the atom nearest the seed, so that domains
    /// (stretches of the sequence) get their own colors.
    Residue,
    /// Molecules: which of these named stretches of residues the atom nearest the seed
    /// is in (a color per name, gray for the rest).
    Domains(Vec<domains::Domain>),
}

impl ColorBy {
    /// The `--color` name.
    #[must_use]
    pub fn name(&self) -> &'static str {
        match self {
            ColorBy::Axis => "axis",
            ColorBy::Z => "z",
            ColorBy::Distance => "distance",
            ColorBy::Chain => "chain",
            ColorBy::Residue => "residue",
            ColorBy::Domains(_) => "domain",
        }
    }
}

/// The coloring `harmap run` draws its atlas with: residues for molecule formats that
/// number them (PDB, mmCIF, PQR), else the main axis.
#[must_use]
pub fn default_coloring(attrs: &serde_json::Value) -> ColorBy {
    match attrs.pointer("/input/format").and_then(|f| f.as_str()) {
        Some("pdb" | "ent" | "cif" | "mmcif" | "pqr") => ColorBy::Residue,
        _ => ColorBy::Axis,
    }
}

/// Draw the theta-psi atlas of a traced run to `dest` (.png or .svg), or with `sphere`
/// the mapped sphere from four viewpoints. Returns the number of points drawn.
pub fn atlas(run: &RunDir, dest: &Path, sphere: bool, by: &ColorBy) -> Result<usize, crate::Error> {
    let t = read_seeds(run)?;
    let paint = paint(run, &t, by)?;
    let c = &paint.colors;
    let pts = atlas_points(&t, c, paint.background);
    if pts.is_empty() {
        return Err(ReportError::Unavailable(format!(
            "{}: no seed reached the center; nothing to draw",
            run.root().display()
        ))
        .into());
    }
    let title = title(run, &t);
    if sphere {
        staged_draw(
            dest,
            (1600, 470),
            |root| draw_sphere(&root, &title, &t, c),
            |root| draw_sphere(&root, &title, &t, c),
        )?;
    } else {
        staged_draw(
            dest,
            (1200, 680),
            |root| draw_atlas(&root, &title, &pts, &paint.caption, &paint.legend),
            |root| draw_atlas(&root, &title, &pts, &paint.caption, &paint.legend),
        )?;
    }
    Ok(pts.len())
}
