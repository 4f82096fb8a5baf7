//! The report page's account of the topology repair: what it changed and where.

use std::fmt::Write as _;

use serde_json::Value;

use super::escape;

/// The fields of the voxelization's report the repair part shows.
#[derive(serde::Deserialize)]
struct RepairRecord {
    #[serde(default)]
    repair: Option<crate::voxelize::TopologyRepair>,
    #[serde(default)]
    surface_topology: Option<(u64, i64)>,
}

/// What the topology repair changed: the counts and the largest changed regions, or
/// that the solid needed none.
pub(super) fn repair_part(p: &mut String, a: &Value) {
    let Some(rec) = crate::run::report_in::<RepairRecord>(a, "voxelize") else {
        return;
    };
    if let Some((parts, genus)) = rec.surface_topology {
        let _ = write!(
            p,
            "<p>The input surface: {parts} connected part{}, genus {genus}.</p>",
            if parts == 1 { "" } else { "s" }
        );
    }
    let Some(r) = rec.repair else {
        p.push_str("<p id=\"repair\">Repair: none (the voxel solid needed no change to be one genus-0 piece).</p>");
        return;
    };
    let _ = write!(
        p,
        "<h3 id=\"repair\">Repair</h3><p class=\"warn\">The voxel solid was {} piece{} of genus {}; \
         the repair ({}) changed {} voxels ({:.3}% of the solid) to make it one piece of genus 0.</p>",
        r.components_before,
        if r.components_before == 1 { "" } else { "s" },
        r.genus_before,
        escape(&r.method),
        r.voxels_added + r.voxels_removed,
        100.0 * r.fraction,
    );
    let rows = vec![
        ("method", r.method.clone()),
        ("voxels added", r.voxels_added.to_string()),
        ("voxels removed", r.voxels_removed.to_string()),
        ("handles cut", r.handles_cut.to_string()),
        ("handles filled", r.handles_filled.to_string()),
        ("specks dropped", r.specks_dropped.to_string()),
        ("speck voxels", r.speck_voxels.to_string()),
        (
            "voxels the other method would change",
            // u64::MAX: the other method was not tried (the compact cut of large grids).
            if r.alternative_voxels == u64::MAX {
                "not tried".to_string()
            } else {
                r.alternative_voxels.to_string()
            },
        ),
        ("seconds", format!("{:.2}", r.seconds)),
    ];
    p.push_str("<table class=\"kv\">");
    for (k, v) in &rows {
        let _ = write!(p, "<tr><td>{}</td><td>{}</td></tr>", escape(k), escape(v));
    }
    p.push_str("</table>\n");
    if !r.regions.is_empty() {
        p.push_str(
            "<p>The largest changes:</p><table><tr><th>change</th><th>voxels</th>\
             <th>voxel (z, y, x)</th><th>position (x, y, z)</th></tr>",
        );
        for g in &r.regions {
            let _ = write!(
                p,
                "<tr><td>{}</td><td class=\"n\">{}</td><td>{}, {}, {}</td><td>{:.4}, {:.4}, {:.4}</td></tr>",
                escape(&g.kind),
                g.voxels,
                g.voxel[0],
                g.voxel[1],
                g.voxel[2],
                g.position[0],
                g.position[1],
                g.position[2]
            );
        }
        p.push_str("</table>");
    }
}
