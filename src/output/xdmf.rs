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
/// The group of step k of an adaptive result: `/steps/000`, `/steps/001`,
/// ... (`hdf5_io` writes them, the XDMF points into them).
pub fn step_group(k: usize) -> String {
    format!("/steps/{k:03}")
}

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
    let mut out = String::new();
    open_document(&mut out);
    render_grid(&mut out, "    ", h5_file_name, "", None, mesh, data, in_3d);
    close_document(&mut out);
    out
}

/// An adaptive result's steps as a temporal collection (`/steps/NNN`, time = step
/// index), so ParaView plays them.
pub fn render_steps(h5_file_name: &str, steps: &[(&Mesh, &ResultData)]) -> String {
    let mut out = String::new();
    open_document(&mut out);
    out.push_str("    <Grid Name=\"steps\" GridType=\"Collection\" CollectionType=\"Temporal\">\n");
    for (k, (mesh, data)) in steps.iter().enumerate() {
        let group = step_group(k);
        let in_3d = data.surface.is_some();
        render_grid(
            &mut out,
            "      ",
            h5_file_name,
            &group,
            Some(k),
            mesh,
            data,
            in_3d,
        );
    }
    out.push_str("    </Grid>\n");
    close_document(&mut out);
    out
}

fn open_document(out: &mut String) {
    out.push_str("<?xml version=\"1.0\" encoding=\"utf-8\"?>\n");
    out.push_str("<!DOCTYPE Xdmf SYSTEM \"Xdmf.dtd\" []>\n");
    out.push_str("<Xdmf Version=\"3.0\" xmlns:xi=\"http://www.w3.org/2001/XInclude\">\n");
    out.push_str("  <Domain>\n");
}

fn close_document(out: &mut String) {
    out.push_str("  </Domain>\n");
    out.push_str("</Xdmf>\n");
}

/// One grid: the mesh and fields stored under `group` ("" for the root).
#[allow(clippy::too_many_arguments)]
fn render_grid(
    out: &mut String,
    indent: &str,
    h5_file_name: &str,
    group: &str,
    time: Option<usize>,
    mesh: &Mesh,
    data: &ResultData,
    in_3d: bool,
) {
    let nv = mesh.vertices.len();
    let nt = mesh.triangles.len();
    let inner = format!("{indent}  ");
    let item = format!("{indent}    ");
    let name = if group.is_empty() {
        "mesh"
    } else {
        &group[1..]
    };
    let _ = writeln!(
        out,
        "{indent}<Grid Name=\"{}\" GridType=\"Uniform\">",
        xml_escape(name)
    );
    if let Some(t) = time {
        let _ = writeln!(out, "{inner}<Time Value=\"{t}\"/>");
    }
    let _ = writeln!(
        out,
        "{inner}<Topology TopologyType=\"Triangle\" NumberOfElements=\"{nt}\" NodesPerElement=\"3\">"
    );
    data_item(
        out,
        &item,
        &format!("{nt} 3"),
        "Int",
        &format!("{h5_file_name}:{group}/mesh/triangles"),
    );
    let _ = writeln!(out, "{inner}</Topology>");
    let (geometry, dims, dataset) = if in_3d {
        ("XYZ", format!("{nv} 3"), "/mesh/surface")
    } else {
        ("XY", format!("{nv} 2"), "/mesh/vertices")
    };
    let _ = writeln!(out, "{inner}<Geometry GeometryType=\"{geometry}\">");
    data_item(
        out,
        &item,
        &dims,
        "Float",
        &format!("{h5_file_name}:{group}{dataset}"),
    );
    let _ = writeln!(out, "{inner}</Geometry>");
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
            "{inner}<Attribute Name=\"{}\" AttributeType=\"{}\" Center=\"{center}\">",
            xml_escape(&field.name),
            attribute_type(field.components)
        );
        data_item(
            out,
            &item,
            &dims,
            "Float",
            &format!("{h5_file_name}:{group}/fields/{}", field.name),
        );
        let _ = writeln!(out, "{inner}</Attribute>");
    }
    let _ = writeln!(out, "{indent}</Grid>");
}
