//! A stored vector as finite-element blocks: the scalar components of a
//! `/dofs/<name>` vector (by its `space` attribute, or by its length in older
//! files), and the mesh of a result file. Used by `compare` and by the
//! cross-mesh errors of `transfer`.

use super::ResultFile;
use crate::error::Result;
use crate::mesh::Mesh;
use crate::space::{Element, Space};
use std::path::{Path, PathBuf};

/// One scalar component of a stored coefficient vector.
pub struct Component<'a> {
    pub name: String,
    pub element: Element,
    pub coefficients: &'a [f64],
}

/// Splits `/dofs/<name>` of a result into its scalar components, telling the
/// element from the length: k·(Nv + Nt) is k blocks of P1⊕B3 (named
/// name1..namek when k > 1), Nt is P0, Nv is P1.
pub fn components<'a>(
    name: &str,
    dofs: &'a [f64],
    n_vertices: usize,
    n_triangles: usize,
) -> Option<Vec<Component<'a>>> {
    let n_scalar = n_vertices + n_triangles;
    let single = |element| {
        Some(vec![Component {
            name: name.to_string(),
            element,
            coefficients: dofs,
        }])
    };
    if dofs.len() == n_triangles {
        single(Element::P0)
    } else if dofs.len() == n_vertices {
        single(Element::P1)
    } else if !dofs.is_empty() && dofs.len().is_multiple_of(n_scalar) {
        let k = dofs.len() / n_scalar;
        Some(
            (0..k)
                .map(|c| Component {
                    name: if k == 1 {
                        name.to_string()
                    } else {
                        format!("{name}{}", c + 1)
                    },
                    element: Element::P1Bubble,
                    coefficients: &dofs[c * n_scalar..(c + 1) * n_scalar],
                })
                .collect(),
        )
    } else {
        None
    }
}

/// Splits `/dofs/<name>` into the k blocks of `element` its `space`
/// attribute names (named name1..namek when k > 1).
pub fn components_in_space<'a>(
    name: &str,
    dofs: &'a [f64],
    mesh: &Mesh,
    element: Element,
    k: usize,
) -> Option<Vec<Component<'a>>> {
    let n = Space::new(mesh, element).n_dofs();
    if k == 0 || dofs.len() != k * n {
        return None;
    }
    Some(
        dofs.chunks(n)
            .enumerate()
            .map(|(c, coefficients)| Component {
                name: if k == 1 {
                    name.to_string()
                } else {
                    format!("{name}{}", c + 1)
                },
                element,
                coefficients,
            })
            .collect(),
    )
}

/// A result file's mesh (vertices and triangles only).
pub fn result_mesh(file: &ResultFile, path: &Path) -> Result<Mesh> {
    Mesh::from_triangles(
        file.vertices.clone(),
        file.triangles.clone(),
        PathBuf::from(path),
    )
}
