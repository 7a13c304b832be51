//! P2 prolongation between consecutive levels of a [`Hierarchy`], and the
//! prolongations of systems of P2⊕B3 fields (the shell's `p2b-psri` and
//! `p2b-mitc` layouts, docs/formulation.md §7) for [`super::Multigrid`].
//!
//! P2 spaces are nested under uniform refinement: a coarse P2 function is
//! quadratic on each child triangle, so its interpolant at the fine P2
//! nodes (vertices, then edge midpoints, as [`Space`] numbers them) is the
//! function itself. Row i of the prolongation holds the coarse P2 basis
//! functions of the parent triangle at fine node i. The cubic bubble
//! b_T = 27 λ1λ2λ3 of a coarse triangle is no fine P2⊕B3 function: the
//! coarser levels are P2 alone (their bubbles dropped), and the finest
//! level's bubbles get no coarse correction (zero rows), only the
//! smoother's. The Galerkin operator PᵀAP of the finest level is then A's
//! energy on the coarse P2 functions, symmetric positive definite when A
//! is.

use crate::assembly::{DofNumbering, Triplets};
use crate::error::{Error, Result};
use crate::mesh::{Hierarchy, Mesh};
use crate::space::{Element, Space};
use faer::sparse::SparseColMat;

/// The P2 interpolation from `coarse` to its uniform refinement `fine`, on
/// every P2 node of both (no Dirichlet elimination): rows the fine nodes,
/// columns the coarse ones, each numbered vertices first, then edges.
pub fn p2_prolongation(coarse: &Mesh, fine: &Mesh) -> Result<SparseColMat<usize, f64>> {
    let n = coarse.n_vertices();
    let not_nested = |detail: String| {
        Error::mesh(
            fine.source.clone(),
            format!(
                "P2 prolongation: the fine mesh ({} vertices, {} triangles) is not the uniform \
                 refinement of the coarse one ({n} vertices, {} edges, {} triangles): {detail}",
                fine.n_vertices(),
                fine.n_triangles(),
                coarse.n_edges(),
                coarse.n_triangles()
            ),
        )
    };
    if fine.n_vertices() != n + coarse.n_edges() || fine.n_triangles() != 4 * coarse.n_triangles() {
        return Err(not_nested("sizes".into()));
    }
    let fine_vertices = fine.n_vertices();
    let n_fine = fine_vertices + fine.n_edges();
    let coarse_space = Space::new(coarse, Element::P2);
    let mut p = Triplets::new(n_fine, n + coarse.n_edges());
    p.reserve(6 * n_fine);
    let mut done = vec![false; n_fine];
    for t in 0..coarse.n_triangles() {
        let (parent, edges) = (coarse.triangles[t], coarse.triangle_edges[t]);
        let (coarse_dofs, _) = coarse_space.element_dofs(t);
        // A fine vertex of this coarse triangle in its barycentric
        // coordinates: a coarse vertex, or the midpoint of edge i (opposite
        // vertex i).
        let barycentric = |w: usize| -> Option<[f64; 3]> {
            let mut l = [0.0; 3];
            if let Some(i) = parent.iter().position(|&v| v == w) {
                l[i] = 1.0;
                return Some(l);
            }
            let i = edges.iter().position(|&e| n + e == w)?;
            l[(i + 1) % 3] = 0.5;
            l[(i + 2) % 3] = 0.5;
            Some(l)
        };
        for child in 4 * t..4 * t + 4 {
            let corners = fine.triangles[child];
            let mut l = [[0.0; 3]; 3];
            for k in 0..3 {
                l[k] = barycentric(corners[k]).ok_or_else(|| {
                    not_nested(format!(
                        "fine triangle {child} has vertex {} outside coarse triangle {t}",
                        corners[k]
                    ))
                })?;
            }
            for i in 0..3 {
                let (j, k) = ((i + 1) % 3, (i + 2) % 3);
                let midpoint = std::array::from_fn(|c| 0.5 * (l[j][c] + l[k][c]));
                let nodes = [
                    (corners[i], l[i]),
                    (fine_vertices + fine.triangle_edges[child][i], midpoint),
                ];
                for (node, at) in nodes {
                    if std::mem::replace(&mut done[node], true) {
                        continue;
                    }
                    let basis = Element::P2.basis(at);
                    for (d, &value) in basis.values[..6].iter().enumerate() {
                        // The basis at these dyadic points is exact: zeros are 0.0.
                        if value != 0.0 {
                            p.push(node, coarse_dofs[d], value);
                        }
                    }
                }
            }
        }
    }
    Ok(p.into_sparse())
}

/// The multigrid unknowns of a system of scalar P2 or P2⊕B3 fields (the
/// shell's `p2b-psri` and `p2b-mitc` layouts) on a hierarchy: on the finest
/// level its free dofs (the matrix's unknowns, bubbles included), on each
/// coarser level its free P2 dofs; and the prolongations between them, each
/// field prolonged by [`p2_prolongation`].
pub struct P2FieldLevels {
    /// `prolongations[l]`: level l → level l + 1 (coarsest first).
    pub prolongations: Vec<SparseColMat<usize, f64>>,
    /// Unknowns per level, coarsest first.
    pub sizes: Vec<usize>,
}

/// One level of such a system: where each field's block starts among the
/// level's dofs (a block: the P2 nodes, vertices then edges, then the
/// bubbles if the field has them), and which dofs are free.
#[derive(Debug, Clone, Copy)]
pub struct FieldLevel<'a> {
    pub offsets: &'a [usize],
    pub numbering: &'a DofNumbering,
}

impl P2FieldLevels {
    /// `levels[l]`: the fields of `hierarchy.levels[l]`, the same number on
    /// every level. A fine dof that is fixed where the coarse dofs it
    /// interpolates are free loses those entries: exact on a clamped or
    /// simply supported part, whose fixed fine nodes interpolate fixed
    /// coarse nodes of the same edge. Unknowns tied to others
    /// (`LinearTies`) are not modelled.
    pub fn new(hierarchy: &Hierarchy, levels: &[FieldLevel<'_>]) -> Result<Self> {
        let finest = hierarchy.n_levels() - 1;
        let fields = levels.first().map_or(0, |f| f.offsets.len());
        if levels.len() != hierarchy.n_levels() || levels.iter().any(|f| f.offsets.len() != fields)
        {
            return Err(Error::numerical(
                "multigrid",
                "P2 field levels",
                format!(
                    "{} levels of fields for a hierarchy of {} levels, or different numbers of \
                     fields",
                    levels.len(),
                    hierarchy.n_levels()
                ),
            ));
        }
        for (l, level) in levels.iter().enumerate() {
            let mesh = &hierarchy.levels[l];
            let p2_nodes = mesh.n_vertices() + mesh.n_edges();
            let n_total = level.numbering.n_total();
            let overlapping = level
                .offsets
                .iter()
                .zip(level.offsets.iter().skip(1).chain([&n_total]))
                .any(|(&start, &next)| next < start + p2_nodes);
            if overlapping {
                return Err(Error::numerical(
                    "multigrid",
                    "P2 field levels",
                    format!(
                        "level {l}: a field block shorter than the mesh's {p2_nodes} P2 nodes \
                         (offsets {:?}, {n_total} dofs)",
                        level.offsets
                    ),
                ));
            }
        }
        // Each level's unknown of every one of its dofs.
        let unknowns: Vec<(Vec<Option<usize>>, usize)> = levels
            .iter()
            .enumerate()
            .map(|(l, level)| match l == finest {
                true => {
                    let numbering = &level.numbering;
                    let index = (0..numbering.n_total()).map(|d| numbering.free_index(d));
                    (index.collect(), numbering.n_free())
                }
                false => p2_unknowns(&hierarchy.levels[l], level),
            })
            .collect();
        let mut prolongations = Vec::with_capacity(finest);
        for l in 0..finest {
            let scalar = p2_prolongation(&hierarchy.levels[l], &hierarchy.levels[l + 1])?;
            let (coarse, fine) = (&unknowns[l], &unknowns[l + 1]);
            let mut p = Triplets::new(fine.1, coarse.1);
            p.reserve(fields * scalar.val().len());
            for (&coarse_offset, &fine_offset) in
                levels[l].offsets.iter().zip(levels[l + 1].offsets)
            {
                for j in 0..scalar.ncols() {
                    let Some(col) = coarse.0[coarse_offset + j] else {
                        continue;
                    };
                    let rows = scalar.symbolic().row_idx_of_col(j);
                    for (i, &value) in rows.zip(scalar.val_of_col(j)) {
                        if let Some(row) = fine.0[fine_offset + i] {
                            p.push(row, col, value);
                        }
                    }
                }
            }
            prolongations.push(p.into_sparse());
        }
        Ok(P2FieldLevels {
            prolongations,
            sizes: unknowns.iter().map(|u| u.1).collect(),
        })
    }
}

/// The free P2 dofs of a level (its bubbles left out), numbered field by
/// field: each dof's unknown, and their number.
fn p2_unknowns(mesh: &Mesh, level: &FieldLevel<'_>) -> (Vec<Option<usize>>, usize) {
    let p2_nodes = mesh.n_vertices() + mesh.n_edges();
    let numbering = &level.numbering;
    let mut index = vec![None; numbering.n_total()];
    let mut count = 0;
    for &offset in level.offsets {
        for d in offset..offset + p2_nodes {
            if numbering.free_index(d).is_some() {
                index[d] = Some(count);
                count += 1;
            }
        }
    }
    (index, count)
}
