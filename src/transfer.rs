//! Fields of one mesh measured on another: the relative L²(ω) error of a
//! coarse solution against a reference on a finer mesh (thesis Fig. 5.10),
//! component by component.
//!
//! The coarse function is evaluated at the quadrature points of the fine
//! mesh (a [`PointLocator`] finds the coarse triangle), so the meshes need
//! not be nested; on nested meshes the rule is exact for the polynomial
//! difference (degree 5 is exact for (P1⊕B3)²).

use crate::assembly::quad_points;
use crate::error::{Error, Result};
use crate::mesh::{Mesh, PointLocator};
use crate::output::blocks::{components, components_in_space, result_mesh, Component};
use crate::output::{ResultData, ResultFile};
use crate::quadrature::TriangleRule;
use crate::space::{Space, TriangleGeometry};
use std::path::Path;

/// ‖f_coarse − f_fine‖_{L²} / ‖f_fine‖_{L²}, both integrated over the fine mesh.
pub fn relative_l2_error(
    coarse: &Space,
    coarse_c: &[f64],
    locator: &PointLocator,
    fine: &Space,
    fine_c: &[f64],
) -> f64 {
    let rule = TriangleRule::exact_for(5);
    let mesh = fine.mesh;
    let (mut diff, mut norm) = (0.0, 0.0);
    for t in 0..mesh.n_triangles() {
        let g = TriangleGeometry::new(mesh, t);
        for q in quad_points(&g, t, &rule) {
            let f = fine.evaluate(fine_c, t, q.lambda);
            let c = locator
                .locate(q.x)
                .map_or(0.0, |(tc, l)| coarse.evaluate(coarse_c, tc, l));
            diff += q.weight * (c - f) * (c - f);
            norm += q.weight * f * f;
        }
    }
    if norm > 0.0 {
        (diff / norm).sqrt()
    } else {
        diff.sqrt()
    }
}

/// Prolongation for nested iteration: the coarse function `coarse_c` of
/// `coarse` interpolated in `fine` (its nodal values at the fine nodes; for
/// P1⊕B3 the bubble amplitude from the barycentre value). Exact for P0 and
/// P1 on nested meshes; P1⊕B3 spaces are not nested (a coarse bubble is not
/// in the fine space), so there it is an interpolation, exact for affine
/// functions. Fine nodes outside the coarse mesh get 0.
pub fn prolong(coarse: &Space, coarse_c: &[f64], locator: &PointLocator, fine: &Space) -> Vec<f64> {
    fine.interpolate(|x| {
        locator
            .locate(x)
            .map_or(0.0, |(t, l)| coarse.evaluate(coarse_c, t, l))
    })
}

/// The coefficient vectors `/dofs/*` of a coarse result prolonged block by
/// block onto `fine` ([`prolong`] in the element of each vector's `space`
/// tag): the nested-iteration start. A vector without a readable tag, or
/// whose length is not k blocks of its element, is left out.
pub fn prolong_dofs(
    coarse: &ResultData,
    coarse_mesh: &Mesh,
    fine_mesh: &Mesh,
) -> Vec<(String, Vec<f64>)> {
    let locator = PointLocator::new(coarse_mesh);
    let mut out = Vec::new();
    for (name, values) in &coarse.dofs {
        let space = coarse
            .dof_spaces
            .iter()
            .find(|(n, _)| n == name)
            .and_then(|(_, tag)| crate::output::parse_space_tag(tag));
        let Some((element, k)) = space else { continue };
        let Some(blocks) = components_in_space(name, values, coarse_mesh, element, k) else {
            continue;
        };
        let (coarse_space, fine_space) = (
            Space::new(coarse_mesh, element),
            Space::new(fine_mesh, element),
        );
        let fine: Vec<f64> = blocks
            .iter()
            .flat_map(|b| prolong(&coarse_space, b.coefficients, &locator, &fine_space))
            .collect();
        out.push((name.clone(), fine));
    }
    out
}

/// Relative L² errors of every component of the fields `names` of `coarse`
/// against `fine`, in order (u → u1, u2, u3, ...).
pub fn relative_errors(
    coarse: (&ResultFile, &Path),
    fine: (&ResultFile, &Path),
    names: &[String],
) -> Result<Vec<(String, f64)>> {
    let (coarse_mesh, fine_mesh) = (
        result_mesh(coarse.0, coarse.1)?,
        result_mesh(fine.0, fine.1)?,
    );
    let locator = PointLocator::new(&coarse_mesh);
    let mut out = Vec::new();
    for name in names {
        let cs = stored_components(coarse.0, coarse.1, &coarse_mesh, name)?;
        let fs = stored_components(fine.0, fine.1, &fine_mesh, name)?;
        for (c, f) in cs.iter().zip(&fs) {
            let e = relative_l2_error(
                &Space::new(&coarse_mesh, c.element),
                c.coefficients,
                &locator,
                &Space::new(&fine_mesh, f.element),
                f.coefficients,
            );
            out.push((c.name.clone(), e));
        }
    }
    Ok(out)
}

/// The components of `/dofs/<name>` of a result on its mesh.
fn stored_components<'a>(
    file: &'a ResultFile,
    path: &Path,
    mesh: &Mesh,
    name: &str,
) -> Result<Vec<Component<'a>>> {
    let (_, v) = file
        .data
        .dofs
        .iter()
        .find(|(n, _)| n == name)
        .ok_or_else(|| Error::output(path, format!("has no /dofs/{name}")))?;
    let space = file
        .data
        .dof_spaces
        .iter()
        .find(|(n, _)| n == name)
        .and_then(|(_, tag)| crate::output::parse_space_tag(tag));
    let split = match space {
        Some((element, k)) => components_in_space(name, v, mesh, element, k),
        None => components(name, v, mesh.n_vertices(), mesh.n_triangles()),
    };
    split.ok_or_else(|| {
        Error::output(
            path,
            format!(
                "/dofs/{name} has {} values: not the blocks of its `space` attribute, nor (without one) P0, P1 or P1⊕B3 blocks on this mesh",
                v.len()
            ),
        )
    })
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::space::Element;

    /// The unit square, n × n cells cut along one diagonal (for unit tests).
    pub(crate) fn square(n: usize) -> Mesh {
        let mut vertices = Vec::new();
        for j in 0..=n {
            for i in 0..=n {
                vertices.push([i as f64 / n as f64, j as f64 / n as f64]);
            }
        }
        let id = |i: usize, j: usize| j * (n + 1) + i;
        let mut triangles = Vec::new();
        for j in 0..n {
            for i in 0..n {
                triangles.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                triangles.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
        Mesh::from_triangles(vertices, triangles, "sq".into()).unwrap()
    }

    /// A P1⊕B3 interpolant of an affine function is the same function on any
    /// mesh (error 0); of a quadratic, the error falls like h².
    #[test]
    fn errors_across_meshes() {
        let (coarse, fine) = (square(4), square(16));
        let locator = PointLocator::new(&coarse);
        let (cs, fs) = (
            Space::new(&coarse, Element::P1Bubble),
            Space::new(&fine, Element::P1Bubble),
        );
        let affine = |x: [f64; 2]| 1.0 + 2.0 * x[0] - x[1];
        let e = relative_l2_error(
            &cs,
            &cs.interpolate(affine),
            &locator,
            &fs,
            &fs.interpolate(affine),
        );
        assert!(e < 1e-14, "{e}");
        let quad = |x: [f64; 2]| x[0] * x[0] + x[1] * x[1];
        let fine_c = fs.interpolate(quad);
        let e4 = relative_l2_error(&cs, &cs.interpolate(quad), &locator, &fs, &fine_c);
        let mid = square(8);
        let ms = Space::new(&mid, Element::P1Bubble);
        let e8 = relative_l2_error(
            &ms,
            &ms.interpolate(quad),
            &PointLocator::new(&mid),
            &fs,
            &fine_c,
        );
        let rate = (e4 / e8).log2();
        assert!(rate > 1.8 && rate < 2.3, "rate {rate} ({e4:e} → {e8:e})");
        // Prolongation: exact for an affine P1⊕B3 function; for the
        // quadratic, no worse than the coarse function itself.
        let mloc = PointLocator::new(&mid);
        let pa = prolong(&ms, &ms.interpolate(affine), &mloc, &fs);
        let e = relative_l2_error(
            &fs,
            &pa,
            &PointLocator::new(&fine),
            &fs,
            &fs.interpolate(affine),
        );
        assert!(e < 1e-13, "prolongation error {e}");
        let pq = prolong(&ms, &ms.interpolate(quad), &mloc, &fs);
        let ep = relative_l2_error(&fs, &pq, &PointLocator::new(&fine), &fs, &fine_c);
        assert!(
            ep <= 1.5 * e8,
            "prolongation {ep:e} vs interpolation {e8:e}"
        );
        // P0 and the component split by length.
        let lambda = vec![0.0; 32];
        let c = components("lambda", &lambda, 25, 32).unwrap();
        assert_eq!(c[0].element, Element::P0);
        let v = vec![0.0; 3 * 57];
        let c = components("u", &v, 25, 32).unwrap();
        assert_eq!(c.len(), 3);
        assert_eq!(c[2].name, "u3");
        assert!(components("x", &[0.0; 7], 25, 32).is_none());
    }
}
