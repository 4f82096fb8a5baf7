//! VTK XML image data (`.vti`): every field as point data on the voxel centers, appended
//! raw with UInt64 size headers, as VTK's XML file formats describe. A comment after the
//! XML declaration marks the file as harmap's own export.

use std::fmt::Write as _;
use std::io::Write;
use std::path::Path;

use super::source::{write_z_slabs, Source};
use super::Field;
use crate::export::Staged;
use crate::grid::GridSpec;
use crate::progress::Progress;

/// The comment line that marks a VTI file written by harmap.
pub(super) const MARK: &str = "<!-- harmap export -->";

/// Write `fields` (opened as `sources`) to `out`.
pub(super) fn write(
    out: &mut Staged,
    spec: &GridSpec,
    fields: &[Field],
    sources: &[Source],
    dest: &Path,
    progress: &dyn Progress,
) -> Result<(), crate::Error> {
    let n = spec.num_voxels();
    let s = spec.shape;
    let mut xml = String::new();
    xml.push_str("<?xml version=\"1.0\"?>\n");
    xml.push_str(MARK);
    xml.push('\n');
    xml.push_str("<VTKFile type=\"ImageData\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n");
    let extent = format!("0 {} 0 {} 0 {}", s[2] - 1, s[1] - 1, s[0] - 1);
    let _ = writeln!(
        xml,
        "  <ImageData WholeExtent=\"{extent}\" Origin=\"{} {} {}\" Spacing=\"{h} {h} {h}\">",
        spec.origin[0],
        spec.origin[1],
        spec.origin[2],
        h = spec.spacing
    );
    let _ = writeln!(xml, "    <Piece Extent=\"{extent}\">");
    let _ = writeln!(xml, "      <PointData Scalars=\"{}\">", fields[0].name());
    let mut offset = 0u64;
    for f in fields {
        let ty = match f.bytes() {
            8 => "Float64",
            4 => "Float32",
            _ => "UInt8",
        };
        let _ = writeln!(xml,
            "        <DataArray type=\"{ty}\" Name=\"{}\" format=\"appended\" offset=\"{offset}\"/>",
            f.name()
        );
        offset += 8 + n * f.bytes() as u64;
    }
    xml.push_str(
        "      </PointData>\n    </Piece>\n  </ImageData>\n  <AppendedData encoding=\"raw\">\n   _",
    );
    out.out.write_all(xml.as_bytes()).map_err(|e| out.io(e))?;
    for (f, src) in fields.iter().zip(sources) {
        let bytes = n * f.bytes() as u64;
        out.out
            .write_all(&bytes.to_le_bytes())
            .map_err(|e| out.io(e))?;
        write_z_slabs(src, spec, &mut out.out, dest, progress)?;
    }
    out.out
        .write_all(b"\n  </AppendedData>\n</VTKFile>\n")
        .map_err(|e| out.io(e))?;
    Ok(())
}
