//! `obstacle compare A.h5 B.h5`: two result files on the same mesh, field by
//! field. For each `/fields/<name>` and `/dofs/<name>` present in both: the
//! max-norm of the difference and its L²(ω) norm, absolute and relative to
//! A's (max-norm resp. L²) norm. The L²(ω) norm integrates the finite-element
//! function of the difference exactly (degree-6 rule: exact for (P1⊕B3)²
//! and (P2)²): vertex fields as P1, cell fields as P0, dof vectors in their
//! own space: the `space` attribute of `/dofs/<name>` (P0, P1, P1b, P2, P2b,
//! `^k` blocks), else told from the length (P0, P1, P2 or blocks of P1⊕B3).

use super::blocks::{components, result_mesh};
use super::ResultFile;
use crate::assembly::quad_points;
use crate::error::{Error, Result};
use crate::mesh::Mesh;
use crate::output::Location;
use crate::quadrature::TriangleRule;
use crate::space::{Element, Space, TriangleGeometry};
use std::path::Path;

/// One compared quantity.
#[derive(Debug, Clone, PartialEq)]
pub struct Difference {
    /// The dataset: "fields/u", "dofs/lambda", ...
    pub name: String,
    pub len: usize,
    /// max |A|.
    pub max_a: f64,
    /// max |A − B|.
    pub max_diff: f64,
    /// max |A − B| / max |A|.
    pub max_rel: f64,
    /// ‖A − B‖_L²(ω).
    pub l2_diff: f64,
    /// ‖A − B‖_L²(ω) / ‖A‖_L²(ω).
    pub l2_rel: f64,
}

impl Difference {
    /// The larger of the two relative differences (NaN counts as infinite).
    pub fn worst(&self) -> f64 {
        let w = self.max_rel.max(self.l2_rel);
        if w.is_nan() || self.max_rel.is_nan() || self.l2_rel.is_nan() {
            f64::INFINITY
        } else {
            w
        }
    }
}

/// The two files hold the same mesh: same vertices (to 1e-14 of the mesh
/// size), same triangles in the same order with the same vertex order, and
/// the same edge order when both store edges.
pub fn check_same_mesh(a: &ResultFile, pa: &Path, b: &ResultFile, pb: &Path) -> Result<()> {
    let fail =
        |r: String| Error::output(pb, format!("the mesh differs from {}'s: {r}", pa.display()));
    if a.vertices.len() != b.vertices.len() || a.triangles.len() != b.triangles.len() {
        return Err(fail(format!(
            "{} vertices and {} triangles against {} and {}",
            b.vertices.len(),
            b.triangles.len(),
            a.vertices.len(),
            a.triangles.len()
        )));
    }
    let scale = a
        .vertices
        .iter()
        .fold(1.0f64, |m, v| m.max(v[0].abs()).max(v[1].abs()));
    for (i, (p, q)) in a.vertices.iter().zip(&b.vertices).enumerate() {
        if (p[0] - q[0]).abs() > 1e-14 * scale || (p[1] - q[1]).abs() > 1e-14 * scale {
            return Err(fail(format!(
                "vertex {i} is {q:?} against {p:?} (another mesh, or another vertex order)"
            )));
        }
    }
    if let Some(t) = (0..a.triangles.len()).find(|&t| a.triangles[t] != b.triangles[t]) {
        return Err(fail(format!(
            "triangle {t} is {:?} against {:?} (another triangle or in-triangle vertex order)",
            b.triangles[t], a.triangles[t]
        )));
    }
    if let (Some(ea), Some(eb)) = (&a.edges, &b.edges) {
        if ea != eb {
            return Err(fail("/mesh/edges are in another order".into()));
        }
    }
    Ok(())
}

/// max |v_i|, NaN when any entry is NaN (`f64::max` would skip it and a
/// NaN in one file would compare equal to anything).
fn max_abs(v: &[f64]) -> f64 {
    v.iter().fold(0.0f64, |m, x| {
        if x.is_nan() || m.is_nan() {
            f64::NAN
        } else {
            m.max(x.abs())
        }
    })
}

fn relative(diff: f64, scale_a: f64, scale_b: f64) -> f64 {
    let scale = if scale_a > 0.0 { scale_a } else { scale_b };
    if scale > 0.0 {
        diff / scale
    } else if diff == 0.0 {
        0.0
    } else {
        f64::INFINITY
    }
}

/// ‖Σ blocks‖_L² of the FE function with coefficients `c` (one or more blocks).
fn l2_norm(mesh: &Mesh, blocks: &[(Element, Vec<f64>)]) -> f64 {
    let rule = TriangleRule::exact_for(6);
    let mut sum = 0.0;
    for (element, c) in blocks {
        let space = Space::new(mesh, *element);
        for t in 0..mesh.n_triangles() {
            let g = TriangleGeometry::new(mesh, t);
            for q in quad_points(&g, t, &rule) {
                let v = space.evaluate(c, t, q.lambda);
                sum += q.weight * v * v;
            }
        }
    }
    sum.sqrt()
}

/// How a stored vector is split into FE blocks.
#[derive(Debug, Clone, Copy)]
enum Layout {
    /// A vertex/cell field with its number of components.
    Field(usize, Location),
    /// A dof vector: k blocks of one element (its `space` attribute), or
    /// (None) told from the length.
    Dofs(Option<(Element, usize)>),
}

/// Splits a stored vector into FE blocks: a vertex/cell field by components,
/// a dof vector by its space, else by its length.
fn blocks(mesh: &Mesh, values: &[f64], layout: Layout) -> Option<Vec<(Element, Vec<f64>)>> {
    let field = match layout {
        Layout::Field(c, location) => Some((c, location)),
        Layout::Dofs(Some((element, k))) => {
            let n = Space::new(mesh, element).n_dofs();
            if k == 0 || values.len() != k * n {
                return None;
            }
            return Some(values.chunks(n).map(|c| (element, c.to_vec())).collect());
        }
        Layout::Dofs(None) => None,
    };
    match field {
        Some((c, location)) => {
            let element = match location {
                Location::Vertex => Element::P1,
                Location::Cell => Element::P0,
            };
            Some(
                (0..c.max(1))
                    .map(|k| {
                        (
                            element,
                            values.iter().skip(k).step_by(c.max(1)).copied().collect(),
                        )
                    })
                    .collect(),
            )
        }
        None => {
            if values.len() == mesh.n_vertices() + mesh.n_edges()
                && values.len() != mesh.n_vertices() + mesh.n_triangles()
            {
                return Some(vec![(Element::P2, values.to_vec())]);
            }
            let parts = components("x", values, mesh.n_vertices(), mesh.n_triangles())?;
            Some(
                parts
                    .into_iter()
                    .map(|p| (p.element, p.coefficients.to_vec()))
                    .collect(),
            )
        }
    }
}

fn difference(
    mesh: &Mesh,
    name: String,
    a: &[f64],
    b: &[f64],
    layout: Layout,
) -> Result<Difference> {
    let diff: Vec<f64> = a.iter().zip(b).map(|(x, y)| x - y).collect();
    let (ba, bb, bd) = match (
        blocks(mesh, a, layout),
        blocks(mesh, b, layout),
        blocks(mesh, &diff, layout),
    ) {
        (Some(x), Some(y), Some(z)) => (x, y, z),
        _ => {
            return Err(Error::output(
                &mesh.source,
                match layout {
                    Layout::Dofs(Some((element, k))) => format!(
                        "{name}: {} values are no {} vector on this mesh",
                        a.len(),
                        super::space_tag(element, k)
                    ),
                    _ => format!(
                        "{name}: {} values are no P0, P1, P2 or P1⊕B3 vector on this mesh",
                        a.len()
                    ),
                },
            ))
        }
    };
    let max_diff = max_abs(&diff);
    let l2_diff = l2_norm(mesh, &bd);
    Ok(Difference {
        len: a.len(),
        max_a: max_abs(a),
        max_diff,
        max_rel: relative(max_diff, max_abs(a), max_abs(b)),
        l2_diff,
        l2_rel: relative(l2_diff, l2_norm(mesh, &ba), l2_norm(mesh, &bb)),
        name,
    })
}

/// Compares the fields and dof vectors `names` (None: all present in both)
/// of two results on the same mesh (checked first).
pub fn compare_results(
    a: &ResultFile,
    pa: &Path,
    b: &ResultFile,
    pb: &Path,
    names: Option<&[String]>,
) -> Result<Vec<Difference>> {
    check_same_mesh(a, pa, b, pb)?;
    let mut mesh = result_mesh(a, pa)?;
    if let Some(e) = &a.edges {
        if *e != mesh.edges {
            return Err(Error::output(
                pa,
                "/mesh/edges is not in the mesh's edge order",
            ));
        }
    }
    mesh.source = pa.to_path_buf();
    let wanted = |n: &str| names.is_none_or(|ns| ns.iter().any(|x| x == n));
    let mut rows = Vec::new();
    for fa in a.data.fields.iter().filter(|f| wanted(&f.name)) {
        let Some(fb) = b.data.fields.iter().find(|f| f.name == fa.name) else {
            continue;
        };
        if fa.values.len() != fb.values.len()
            || fa.components != fb.components
            || fa.location != fb.location
        {
            return Err(Error::output(
                pb,
                format!(
                    "/fields/{} has another shape or location than in {}",
                    fa.name,
                    pa.display()
                ),
            ));
        }
        rows.push(difference(
            &mesh,
            format!("fields/{}", fa.name),
            &fa.values,
            &fb.values,
            Layout::Field(fa.components, fa.location),
        )?);
    }
    for (name, va) in a.data.dofs.iter().filter(|(n, _)| wanted(n)) {
        let Some((_, vb)) = b.data.dofs.iter().find(|(n, _)| n == name) else {
            continue;
        };
        if va.len() != vb.len() {
            return Err(Error::output(
                pb,
                format!(
                    "/dofs/{name} has {} values, {} has {}",
                    vb.len(),
                    pa.display(),
                    va.len()
                ),
            ));
        }
        let space = |r: &ResultFile| {
            r.data
                .dof_spaces
                .iter()
                .find(|(n, _)| n == name)
                .map(|(_, s)| s.clone())
        };
        let (sa, sb) = (space(a), space(b));
        if let (Some(x), Some(y)) = (&sa, &sb) {
            if x != y {
                return Err(Error::output(
                    pb,
                    format!(
                        "/dofs/{name} is in space {y}, in {} it is {x}",
                        pa.display()
                    ),
                ));
            }
        }
        let parsed = sa.or(sb).and_then(|s| super::parse_space_tag(&s));
        rows.push(difference(
            &mesh,
            format!("dofs/{name}"),
            va,
            vb,
            Layout::Dofs(parsed),
        )?);
    }
    if let Some(ns) = names {
        for n in ns {
            if !rows
                .iter()
                .any(|r| r.name == format!("fields/{n}") || r.name == format!("dofs/{n}"))
            {
                return Err(Error::output(
                    pb,
                    format!(
                        "`{n}` is not a field or dof vector of both {} and this file",
                        pa.display()
                    ),
                ));
            }
        }
    }
    if rows.is_empty() {
        return Err(Error::output(
            pb,
            format!("no field in common with {}", pa.display()),
        ));
    }
    Ok(rows)
}

/// The comparison as a Markdown table; the last column says whether both
/// relative differences are within `rtol`.
pub fn table(rows: &[Difference], rtol: f64) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "| quantity | values | max\\|A\\| | max\\|A−B\\| | relative | ‖A−B‖_L²(ω) | relative | ≤ {rtol:.0e} |"
    );
    let _ = writeln!(s, "|---|---:|---:|---:|---:|---:|---:|---|");
    for r in rows {
        let _ = writeln!(
            s,
            "| {} | {} | {:.4e} | {:.3e} | {:.3e} | {:.3e} | {:.3e} | {} |",
            r.name,
            r.len,
            r.max_a,
            r.max_diff,
            r.max_rel,
            r.l2_diff,
            r.l2_rel,
            if r.worst() <= rtol { "yes" } else { "NO" }
        );
    }
    s
}

/// `obstacle compare A B`: prints the table; an error (exit status 1) when a
/// relative difference exceeds `rtol`.
/// With `row`, one compact line a quantity: `| row | name | worst | rtol |`.
pub fn command(
    a: &Path,
    b: &Path,
    rtol: f64,
    fields: Option<&[String]>,
    row: Option<&str>,
) -> Result<()> {
    if !(rtol.is_finite() && rtol >= 0.0) {
        // Every comparison with NaN is false: `--rtol nan` would pass anything.
        return Err(Error::numerical(
            "compare",
            "--rtol",
            format!("must be a finite number ≥ 0, got {rtol}"),
        ));
    }
    let (ra, rb) = (super::read_result(a)?, super::read_result(b)?);
    let rows = compare_results(&ra, a, &rb, b, fields)?;
    match row {
        Some(label) => {
            for r in &rows {
                crate::outln!("| {label} | {} | {:.2e} | {rtol:.0e} |", r.name, r.worst());
            }
        }
        None => {
            crate::outln!("A = {}\nB = {}\n", a.display(), b.display());
            crate::out!("{}", table(&rows, rtol));
        }
    }
    let bad: Vec<String> = rows
        .iter()
        .filter(|r| r.worst() > rtol)
        .map(|r| format!("{} ({:.3e})", r.name, r.worst()))
        .collect();
    if bad.is_empty() {
        Ok(())
    } else {
        Err(Error::numerical(
            "compare",
            "relative difference",
            format!("beyond rtol = {rtol:e}: {}", bad.join(", ")),
        ))
    }
}
