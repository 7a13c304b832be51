//! P1 prolongation between consecutive levels of a [`Hierarchy`], on the
//! free (non-Dirichlet) vertices as the membrane numbers them.
//!
//! With the numbering of `mesh::refine` (fine vertex `n + e` is the midpoint
//! of coarse edge e = [a, b]), the P1 interpolant of a coarse function is
//! `u_f[i] = u_c[i]` for `i < n` and `u_f[n + e] = (u_c[a] + u_c[b]) / 2`:
//! exact for linear functions, and on nested meshes the coarse basis
//! function φ_j is Σ_i P_ij ψ_i, so Pᵀ A_fine P is the coarse stiffness
//! matrix. A midpoint snapped onto a curved boundary gets the same average:
//! the coarse function extended linearly along the chord, not its value at
//! the snapped point (which lies outside the coarse domain). Where the
//! boundary is Dirichlet, snapped vertices are fixed and their rows drop out.
//!
//! Dirichlet vertices are eliminated as `assembly::eliminate` does: rows of
//! fixed fine vertices and columns of fixed coarse vertices are dropped, so
//! P maps coarse free values (with zero on the fixed vertices: corrections
//! vanish there) to fine free values. A fine vertex is fixed exactly when it
//! lies on a fixed boundary edge, whose end points are then fixed too: no
//! entry that links a free coarse vertex to a fixed fine one is lost, and
//! the Galerkin identity holds on the free unknowns.

use crate::assembly::{assemble_linear, DofNumbering, Triplets};
use crate::error::{Error, Result};
use crate::mesh::{Hierarchy, Mesh};
use crate::quadrature::TriangleRule;
use crate::space::{Element, Space};
use faer::sparse::SparseColMat;

/// The P1 interpolation from `coarse` to its uniform refinement `fine`,
/// rows and columns numbered by `fine_free` and `coarse_free`
/// (`DofNumbering::all_free` for every vertex).
pub fn p1_prolongation(
    coarse: &Mesh,
    fine: &Mesh,
    coarse_free: &DofNumbering,
    fine_free: &DofNumbering,
) -> Result<SparseColMat<usize, f64>> {
    let n = coarse.n_vertices();
    if fine.n_vertices() != n + coarse.n_edges()
        || coarse_free.n_total() != n
        || fine_free.n_total() != fine.n_vertices()
    {
        return Err(Error::mesh(
            fine.source.clone(),
            format!(
                "P1 prolongation: the fine mesh ({} vertices) is not the uniform refinement of \
                 the coarse one ({n} vertices, {} edges), or the numberings ({} and {} dofs) \
                 do not match them",
                fine.n_vertices(),
                coarse.n_edges(),
                coarse_free.n_total(),
                fine_free.n_total()
            ),
        ));
    }
    let mut p = Triplets::new(fine_free.n_free(), coarse_free.n_free());
    p.reserve(n + 2 * coarse.n_edges());
    for v in 0..n {
        if let (Some(i), Some(j)) = (fine_free.free_index(v), coarse_free.free_index(v)) {
            p.push(i, j, 1.0);
        }
    }
    for (e, ends) in coarse.edges.iter().enumerate() {
        let Some(i) = fine_free.free_index(n + e) else {
            continue;
        };
        for &v in ends {
            if let Some(j) = coarse_free.free_index(v) {
                p.push(i, j, 0.5);
            }
        }
    }
    Ok(p.into_sparse())
}

/// A hierarchy's P1 unknowns: per level the free vertices, and the
/// prolongations between consecutive levels.
pub struct P1Levels {
    /// `numberings[l]`: the free vertices of `levels[l]`.
    pub numberings: Vec<DofNumbering>,
    /// `prolongations[l]`: level l → level l + 1, on the free vertices.
    pub prolongations: Vec<SparseColMat<usize, f64>>,
}

impl P1Levels {
    /// Vertices on boundary edges tagged `dirichlet` are fixed (all tags if
    /// None, as `Space::boundary_dof_mask`; `Some(&[])`: none).
    pub fn new(hierarchy: &Hierarchy, dirichlet: Option<&[i32]>) -> Result<Self> {
        let numberings: Vec<DofNumbering> = hierarchy
            .levels
            .iter()
            .map(|m| DofNumbering::from_fixed_mask(&m.boundary_vertex_mask(dirichlet)))
            .collect();
        let prolongations = hierarchy
            .levels
            .windows(2)
            .zip(numberings.windows(2))
            .map(|(m, d)| p1_prolongation(&m[0], &m[1], &d[0], &d[1]))
            .collect::<Result<_>>()?;
        Ok(P1Levels {
            numberings,
            prolongations,
        })
    }
}

impl P1Levels {
    /// What the boundary values g_D of each level add to the P1 interpolant
    /// on the next level's free vertices: `lifts[l][i]` is Σ_j ½ g_D(x_j)
    /// over the fixed end points j of the coarse edge whose midpoint is the
    /// free vertex i of level l + 1 (0 elsewhere). The interpolant of a
    /// whole function (free values u, fixed values g_D) is then P u + lift.
    pub fn lifts(&self, hierarchy: &Hierarchy, g_d: impl Fn([f64; 2]) -> f64) -> Vec<Vec<f64>> {
        hierarchy
            .levels
            .windows(2)
            .zip(self.numberings.windows(2))
            .map(|(m, d)| {
                let (coarse, (coarse_free, fine_free)) = (&m[0], (&d[0], &d[1]));
                let n = coarse.n_vertices();
                let mut lift = vec![0.0; fine_free.n_free()];
                for (e, ends) in coarse.edges.iter().enumerate() {
                    let Some(i) = fine_free.free_index(n + e) else {
                        continue;
                    };
                    for &v in ends {
                        if coarse_free.free_index(v).is_none() {
                            lift[i] += 0.5 * g_d(coarse.vertices[v]);
                        }
                    }
                }
                lift
            })
            .collect()
    }
}

/// The P1 stiffness matrix ∫ ∇u·∇v of `mesh` on the free vertices of
/// `numbering` (Dirichlet vertices eliminated, as the membrane's K), whole.
pub fn p1_stiffness(mesh: &Mesh, numbering: &DofNumbering) -> SparseColMat<usize, f64> {
    let fixed = vec![0.0; numbering.n_total()];
    crate::assembly::p1_stiffness(mesh, numbering, &fixed, 0).0
}

/// The P1 load vector ∫ f v of a constant f on the free vertices.
pub fn p1_load(mesh: &Mesh, numbering: &DofNumbering, f: f64) -> Vec<f64> {
    let space = Space::new(mesh, Element::P1);
    let rule = TriangleRule::exact_for(2);
    numbering.restrict(&assemble_linear(&space, &rule, |v, _| f * v.value))
}
