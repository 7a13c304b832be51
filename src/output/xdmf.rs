//! The XDMF companion of a result file: `FILE.xdmf` beside `FILE.h5`, so that
//! ParaView (Xdmf3 reader) and VisIt open the mesh and its vertex/cell fields
//! directly. The heavy data stay in the HDF5 file, referenced by its file name
//! only (relative), so the pair can be moved together.
//!
//! Choices (XDMF 3, also read by XDMF 2 readers):
//! - Topology `Triangle` from `/mesh/triangles`. The dataset is `u64`; it is
//!   described as `NumberType="Int" Precision="8"` because 64-bit unsigned is not
//!   an XDMF array type everywhere (Xdmf2 and older Xdmf3 stop at UInt32), and
//!   HDF5 converts u64 → i64 on reading (indices are far below 2^63).
//! - Geometry `XY` from `/mesh/vertices` (`Float`, `Precision="8"`); for a
//!   shell (`/mesh/surface` present) `XYZ` from `/mesh/surface`, so the shell
//!   appears in 3D and "Warp By Vector" on u deforms it. The shell's flat
//!   parameter domain is `FILE.domain.xdmf` (same fields, XY geometry).
//! - A field with 1 component is a `Scalar`, with 3 a `Vector`; any other count
//!   is a `Matrix` (ParaView takes the last dimension as the component count).
//!   Vertex fields are `Center="Node"`, cell fields `Center="Cell"`.
//! - `/dofs`, `/mesh/edges` and `/solver` are not described (not fields on the mesh).

use super::{Location, ResultData};
use crate::mesh::Mesh;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// The XDMF file written beside a result file: same name, extension `.xdmf`.
pub fn xdmf_path(h5_path: &Path) -> PathBuf {
    h5_path.with_extension("xdmf")
}

/// A shell's parameter-domain view beside its 3D XDMF: `FILE.domain.xdmf`.
pub fn domain_xdmf_path(h5_path: &Path) -> PathBuf {
    h5_path.with_extension("domain.xdmf")
}

/// Escapes text for an XML attribute value or element content.
pub fn xml_escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            _ => out.push(c),
        }
    }
    out
}

/// XDMF `AttributeType` for a component count.
pub fn attribute_type(components: usize) -> &'static str {
    match components {
        1 => "Scalar",
        3 => "Vector",
        _ => "Matrix",
    }
}

fn data_item(out: &mut String, indent: &str, dims: &str, number_type: &str, reference: &str) {
    let _ = writeln!(
        out,
        "{indent}<DataItem Dimensions=\"{dims}\" NumberType=\"{number_type}\" Precision=\"8\" Format=\"HDF\">{}</DataItem>",
        xml_escape(reference)
    );
}

/// Renders the XDMF document for a result file named `h5_file_name` (a bare file
/// name, no directory) holding `mesh` and `data.fields` in the docs/formulation.md §5 layout.
/// The caller has validated the data (field lengths match the mesh).
pub fn render(h5_file_name: &str, mesh: &Mesh, data: &ResultData) -> String {
    render_view(h5_file_name, mesh, data, data.surface.is_some())
}

/// A shell's flat parameter-domain view (`FILE.domain.xdmf`): the same
/// fields on the XY geometry of `/mesh/vertices`.
pub fn render_domain(h5_file_name: &str, mesh: &Mesh, data: &ResultData) -> String {
    render_view(h5_file_name, mesh, data, false)
}

/// The document on the 3D surface (`in_3d`) or on the parameter domain.
fn render_view(h5_file_name: &str, mesh: &Mesh, data: &ResultData, in_3d: bool) -> String {
    let nv = mesh.vertices.len();
    let nt = mesh.triangles.len();
    let mut out = String::new();
    out.push_str("<?xml version=\"1.0\" encoding=\"utf-8\"?>\n");
    out.push_str("<!DOCTYPE Xdmf SYSTEM \"Xdmf.dtd\" []>\n");
    out.push_str("<Xdmf Version=\"3.0\" xmlns:xi=\"http://www.w3.org/2001/XInclude\">\n");
    out.push_str("  <Domain>\n");
    out.push_str("    <Grid Name=\"mesh\" GridType=\"Uniform\">\n");
    let _ = writeln!(
        out,
        "      <Topology TopologyType=\"Triangle\" NumberOfElements=\"{nt}\" NodesPerElement=\"3\">"
    );
    data_item(
        &mut out,
        "        ",
        &format!("{nt} 3"),
        "Int",
        &format!("{h5_file_name}:/mesh/triangles"),
    );
    out.push_str("      </Topology>\n");
    let (geometry, dims, dataset) = if in_3d {
        ("XYZ", format!("{nv} 3"), "/mesh/surface")
    } else {
        ("XY", format!("{nv} 2"), "/mesh/vertices")
    };
    let _ = writeln!(out, "      <Geometry GeometryType=\"{geometry}\">");
    data_item(
        &mut out,
        "        ",
        &dims,
        "Float",
        &format!("{h5_file_name}:{dataset}"),
    );
    out.push_str("      </Geometry>\n");
    for field in &data.fields {
        let (center, n) = match field.location {
            Location::Vertex => ("Node", nv),
            Location::Cell => ("Cell", nt),
        };
        let dims = if field.components == 1 {
            format!("{n}")
        } else {
            format!("{n} {}", field.components)
        };
        let _ = writeln!(
            out,
            "      <Attribute Name=\"{}\" AttributeType=\"{}\" Center=\"{center}\">",
            xml_escape(&field.name),
            attribute_type(field.components)
        );
        data_item(
            &mut out,
            "        ",
            &dims,
            "Float",
            &format!("{h5_file_name}:/fields/{}", field.name),
        );
        out.push_str("      </Attribute>\n");
    }
    out.push_str("    </Grid>\n");
    out.push_str("  </Domain>\n");
    out.push_str("</Xdmf>\n");
    out
}
