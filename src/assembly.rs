//! Assembly of forms into sparse matrices and vectors.
//!
//! Forms are plain functions of the trial function `u`, the test function `v`
//! and the quadrature point (scikit-fem style); the element loop, the DOF maps
//! and the quadrature live here once. Dirichlet conditions are imposed by
//! elimination ([`DofNumbering`]).

use crate::mesh::Mesh;
use crate::quadrature::TriangleRule;
use crate::space::{Element, LocalBasis, Space, TriangleGeometry, MAX_LOCAL};
use faer::sparse::{SparseColMat, SymbolicSparseColMat};

use crate::linalg::InteriorGroups;
/// The sparse kernels live in linalg/kernels.rs; re-exported for the FE users.
pub use crate::linalg::{mat_t_vec, mat_vec, norm2, norm_inf};

/// A basis function (or an FE function) at one quadrature point.
#[derive(Debug, Clone, Copy, Default)]
pub struct ShapeValue {
    pub value: f64,
    pub grad: [f64; 2],
}

/// One quadrature point of one triangle.
#[derive(Debug, Clone, Copy)]
pub struct QuadPoint {
    pub triangle: usize,
    pub lambda: [f64; 3],
    pub x: [f64; 2],
    /// Weight including the triangle area.
    pub weight: f64,
}

pub fn dot(a: [f64; 2], b: [f64; 2]) -> f64 {
    a[0] * b[0] + a[1] * b[1]
}

/// ∇u·∇v: the Laplacian's bilinear form.
pub fn laplace(u: &ShapeValue, v: &ShapeValue, _: &QuadPoint) -> f64 {
    dot(u.grad, v.grad)
}

/// u v: the L² (mass) bilinear form.
pub fn mass(u: &ShapeValue, v: &ShapeValue, _: &QuadPoint) -> f64 {
    u.value * v.value
}

/// Basis functions of an element tabulated at the points of a rule.
struct Tabulation {
    element: Element,
    at_points: Vec<LocalBasis>,
}

impl Tabulation {
    fn new(element: Element, rule: &TriangleRule) -> Self {
        Tabulation {
            element,
            at_points: rule.points.iter().map(|&l| element.basis(l)).collect(),
        }
    }

    /// Physical values and gradients of the local basis at point q of a triangle.
    fn shapes(&self, geometry: &TriangleGeometry, q: usize) -> [ShapeValue; MAX_LOCAL] {
        let mut s = [ShapeValue::default(); MAX_LOCAL];
        self.fill_shapes(geometry, q, &mut s);
        s
    }

    /// [`Tabulation::shapes`] written into `s` (an element loop's buffer:
    /// no array returned and copied per point).
    fn fill_shapes(&self, geometry: &TriangleGeometry, q: usize, s: &mut [ShapeValue; MAX_LOCAL]) {
        let b = &self.at_points[q];
        for i in 0..self.element.n_local() {
            s[i] = ShapeValue {
                value: b.values[i],
                grad: geometry.gradient(b.d_lambda[i]),
            };
        }
    }
}

/// The quadrature points of triangle t (geometry g) for a rule.
pub fn quad_points<'a>(
    g: &'a TriangleGeometry,
    t: usize,
    rule: &'a TriangleRule,
) -> impl Iterator<Item = QuadPoint> + 'a {
    rule.points
        .iter()
        .zip(&rule.weights)
        .map(move |(&lambda, &w)| QuadPoint {
            triangle: t,
            lambda,
            x: g.point(lambda),
            weight: w * g.area,
        })
}

/// Every quadrature point of the rule on the mesh, triangle by triangle: where
/// assembly evaluates data given as expressions (checked finite there).
/// Computed as they are read: a check of a number reads none.
pub fn quadrature_points<'a>(
    mesh: &'a crate::mesh::Mesh,
    rule: &'a TriangleRule,
) -> impl Iterator<Item = [f64; 2]> + 'a {
    (0..mesh.n_triangles()).flat_map(move |t| {
        let g = TriangleGeometry::new(mesh, t);
        rule.points.iter().map(move |&lambda| g.point(lambda))
    })
}

/// Coordinate-format matrix entries (duplicates are summed on conversion),
/// 32-bit indices: assembly's triplets are the peak of a large run's
/// assembly (the shell at n = 256: 132M entries, 3.2 GB as (usize, usize,
/// f64), 2.1 GB as (u32, u32, f64)).
#[derive(Debug, Clone, Default)]
pub struct Triplets {
    pub nrows: usize,
    pub ncols: usize,
    entries: Vec<(u32, u32, f64)>,
}

impl Triplets {
    /// An empty matrix; panics when a dimension exceeds 32-bit indices
    /// (4·10⁹ unknowns: the memory guard refuses such meshes long before).
    pub fn new(nrows: usize, ncols: usize) -> Self {
        assert!(
            u32::try_from(nrows).is_ok() && u32::try_from(ncols).is_ok(),
            "a {nrows}×{ncols} matrix: assembly indexes rows and columns in 32 bits"
        );
        Triplets {
            nrows,
            ncols,
            entries: Vec::new(),
        }
    }

    pub fn reserve(&mut self, additional: usize) {
        self.entries.reserve(additional);
    }

    /// Adds v at (r, c) (summed with the other entries there).
    #[inline]
    pub fn push(&mut self, r: usize, c: usize, v: f64) {
        debug_assert!(
            r < self.nrows && c < self.ncols,
            "({r}, {c}) outside the matrix"
        );
        self.entries.push((r as u32, c as u32, v));
    }

    /// The largest |value| of an entry as added.
    pub fn max_abs(&self) -> f64 {
        self.entries.iter().fold(0.0f64, |m, e| m.max(e.2.abs()))
    }

    /// Adds `other` (or its transpose) with rows shifted by `row_offset` and
    /// columns by `col_offset`, scaled: to build block matrices.
    pub fn add_block(
        &mut self,
        other: &Triplets,
        row_offset: usize,
        col_offset: usize,
        scale: f64,
        transpose: bool,
    ) {
        let rows = if transpose { other.ncols } else { other.nrows };
        let cols = if transpose { other.nrows } else { other.ncols };
        assert!(
            row_offset + rows <= self.nrows && col_offset + cols <= self.ncols,
            "a block outside the matrix"
        );
        let (dr, dc) = (row_offset as u32, col_offset as u32);
        self.entries.extend(other.entries.iter().map(|&(r, c, v)| {
            let (r, c) = if transpose { (c, r) } else { (r, c) };
            (r + dr, c + dc, scale * v)
        }));
    }

    /// The compressed matrix (duplicates summed, explicit zeros kept: the
    /// pattern is the elements' connectivity whatever the values). Consumes
    /// the entries and works in their allocation, so only the CSC arrays are
    /// allocated beside them: an in-place bucket sort (American flag sort)
    /// on column ranges of ~1/1024 of the columns, each bucket (small enough
    /// for the cache) sorted by column and each column by row, then duplicates summed while
    /// compacting to the front. The order in which an entry's duplicates
    /// are summed is fixed by the input (deterministic), not necessarily the
    /// order they were added in.
    pub fn into_sparse(self) -> SparseColMat<usize, f64> {
        let Triplets {
            nrows,
            ncols,
            mut entries,
        } = self;
        let shift = (usize::BITS - (ncols >> 10).leading_zeros()) as usize;
        let bucket = |e: &(u32, u32, f64)| (e.1 as usize) >> shift;
        let n_buckets = (ncols >> shift) + 1;
        let mut start = vec![0usize; n_buckets + 1];
        for e in &entries {
            start[bucket(e) + 1] += 1;
        }
        for b in 0..n_buckets {
            start[b + 1] += start[b];
        }
        // Cycle each misplaced entry into its bucket's next free slot.
        let mut next = start.clone();
        for b in 0..n_buckets {
            while next[b] < start[b + 1] {
                let target = bucket(&entries[next[b]]);
                if target == b {
                    next[b] += 1;
                } else {
                    entries.swap(next[b], next[target]);
                    next[target] += 1;
                }
            }
        }
        // Each bucket by column (a counting sort through a buffer the size
        // of one bucket), then each column by row: a column holds a few
        // dozen entries, where one sort of the bucket compares them all.
        let width = 1usize << shift;
        let mut column_start = vec![0usize; width + 1];
        let mut buffer: Vec<(u32, u32, f64)> = Vec::new();
        for b in 0..n_buckets {
            let bucket_entries = &mut entries[start[b]..start[b + 1]];
            let first_column = b << shift;
            column_start.fill(0);
            for e in bucket_entries.iter() {
                column_start[e.1 as usize - first_column + 1] += 1;
            }
            for c in 0..width {
                column_start[c + 1] += column_start[c];
            }
            buffer.clear();
            buffer.resize(bucket_entries.len(), (0, 0, 0.0));
            for e in bucket_entries.iter() {
                let c = e.1 as usize - first_column;
                buffer[column_start[c]] = *e;
                column_start[c] += 1;
            }
            // column_start[c] is now the end of column c (the start of c + 1).
            let mut begin = 0;
            for &end in &column_start[..width] {
                buffer[begin..end].sort_unstable_by_key(|e| e.0);
                begin = end;
            }
            bucket_entries.copy_from_slice(&buffer);
        }
        drop((start, next));
        // Sum duplicates, compact to the front, count per column.
        let mut col_ptr = vec![0usize; ncols + 1];
        let mut nnz = 0usize;
        let mut k = 0usize;
        while k < entries.len() {
            let mut e = entries[k];
            k += 1;
            while k < entries.len() && entries[k].0 == e.0 && entries[k].1 == e.1 {
                e.2 += entries[k].2;
                k += 1;
            }
            col_ptr[e.1 as usize + 1] += 1;
            entries[nnz] = e;
            nnz += 1;
        }
        for j in 0..ncols {
            col_ptr[j + 1] += col_ptr[j];
        }
        entries.truncate(nnz);
        entries.shrink_to_fit();
        let row_idx: Vec<usize> = entries.iter().map(|e| e.0 as usize).collect();
        let values: Vec<f64> = entries.iter().map(|e| e.2).collect();
        drop(entries);
        let symbolic = SymbolicSparseColMat::new_checked(nrows, ncols, col_ptr, None, row_idx);
        SparseColMat::new(symbolic, values)
    }
}

/// One element's unknowns for [`ElementMatrix`]: `coupled` couple with
/// each other and with `multipliers`; multipliers do not couple with each
/// other (the zero block of a saddle-point element). Free indices only.
#[derive(Debug, Clone, Default)]
pub struct ElementDofs {
    pub coupled: Vec<usize>,
    pub multipliers: Vec<usize>,
}

/// A symmetric-pattern matrix assembled element by element straight into
/// compressed columns, deal.II style: the pattern from the elements' dof
/// lists first ([`ElementMatrix::new`], symbolic), then each element's
/// dense block added at its positions ([`ElementMatrix::add`], numeric).
/// No triplets: the shell's at n = 256 were 2.1 GB, and sorting them was
/// most of its assembly's 11.7 s.
pub struct ElementMatrix {
    matrix: SparseColMat<usize, f64>,
}

impl ElementMatrix {
    /// The zero n×n matrix whose pattern is the union of the elements'
    /// couplings (`element(e, dofs)` fills element e's free dofs); every
    /// coupling is an entry, also where its value will be zero.
    pub fn new(n: usize, n_elements: usize, element: impl Fn(usize, &mut ElementDofs)) -> Self {
        let (mut element_ptr, mut element_dofs) = (vec![0usize], Vec::new());
        let mut dofs = ElementDofs::default();
        for e in 0..n_elements {
            dofs.coupled.clear();
            dofs.multipliers.clear();
            element(e, &mut dofs);
            element_dofs.extend(dofs.coupled.iter().map(|&d| index31(d)));
            element_dofs.extend(dofs.multipliers.iter().map(|&d| index31(d) | MULTIPLIER));
            element_ptr.push(element_dofs.len());
        }
        let rows = ElementLists {
            ptr: &element_ptr,
            dofs: &element_dofs,
        };
        ElementMatrix::of_pattern(pattern(n, n, rows, rows))
    }

    /// The zero nrows×ncols matrix whose pattern holds every (row, column)
    /// pair of each element (`element(e, rows, cols)` fills element e's
    /// free test and trial dofs): a rectangular form, e.g. a constraint.
    pub fn rectangular(
        nrows: usize,
        ncols: usize,
        n_elements: usize,
        element: impl Fn(usize, &mut Vec<usize>, &mut Vec<usize>),
    ) -> Self {
        let (mut row_ptr, mut row_dofs) = (vec![0usize], Vec::new());
        let (mut col_ptr, mut col_dofs) = (vec![0usize], Vec::new());
        let (mut rows, mut cols) = (Vec::new(), Vec::new());
        for e in 0..n_elements {
            rows.clear();
            cols.clear();
            element(e, &mut rows, &mut cols);
            row_dofs.extend(rows.iter().map(|&d| index31(d)));
            col_dofs.extend(cols.iter().map(|&d| index31(d)));
            row_ptr.push(row_dofs.len());
            col_ptr.push(col_dofs.len());
        }
        let rows = ElementLists {
            ptr: &row_ptr,
            dofs: &row_dofs,
        };
        let cols = ElementLists {
            ptr: &col_ptr,
            dofs: &col_dofs,
        };
        ElementMatrix::of_pattern(pattern(nrows, ncols, rows, cols))
    }

    fn of_pattern(symbolic: SymbolicSparseColMat<usize>) -> Self {
        let values = vec![0.0; symbolic.row_idx().len()];
        ElementMatrix {
            matrix: SparseColMat::new(symbolic, values),
        }
    }

    /// Adds `value(a, b)` at `(dofs[a], dofs[b])` for every pair of an
    /// element's free dofs that the pattern holds (`dofs[k] = None`: an
    /// eliminated dof, skipped); a pair outside the pattern is a bug of
    /// the caller's element dofs and panics.
    pub fn add(&mut self, dofs: &[Option<usize>], value: impl Fn(usize, usize) -> f64) {
        self.add_block(dofs, dofs, value);
    }

    /// Adds `value(a, b)` at `(rows[a], cols[b])`, as [`ElementMatrix::add`]
    /// for an element's test dofs `rows` and trial dofs `cols`.
    pub fn add_block(
        &mut self,
        rows: &[Option<usize>],
        cols: &[Option<usize>],
        value: impl Fn(usize, usize) -> f64,
    ) {
        let (symbolic, values) = self.matrix.parts_mut();
        let (col_ptr, row_idx) = (symbolic.col_ptr(), symbolic.row_idx());
        for (b, j) in cols.iter().enumerate() {
            let Some(j) = *j else { continue };
            let (start, column) = (col_ptr[j], &row_idx[col_ptr[j]..col_ptr[j + 1]]);
            for (a, i) in rows.iter().enumerate() {
                let Some(i) = *i else { continue };
                let v = value(a, b);
                match column.binary_search(&i) {
                    Ok(k) => values[start + k] += v,
                    Err(_) => assert!(v == 0.0, "({i}, {j}) is not in the elements' pattern"),
                }
            }
        }
    }

    pub fn into_sparse(self) -> SparseColMat<usize, f64> {
        self.matrix
    }
}

/// A multiplier's dof in [`ElementMatrix::new`]'s element lists: flagged by
/// the top bit (multipliers do not couple with each other).
const MULTIPLIER: u32 = 1 << 31;

/// A dof or element index in 31 bits (the pattern's lists: at 8M triangles
/// they are its peak, 4 bytes an entry where usize takes 8).
fn index31(i: usize) -> u32 {
    assert!(
        i < MULTIPLIER as usize,
        "{i}: assembly's pattern indexes dofs and elements in 31 bits"
    );
    i as u32
}

/// Each element's dofs, flat: element e's are `dofs[ptr[e]..ptr[e + 1]]`.
#[derive(Clone, Copy)]
struct ElementLists<'a> {
    ptr: &'a [usize],
    dofs: &'a [u32],
}

impl ElementLists<'_> {
    fn of(&self, e: usize) -> &[u32] {
        &self.dofs[self.ptr[e]..self.ptr[e + 1]]
    }
}

/// The nrows × ncols pattern whose column j holds, once and
/// sorted, every row of `rows` of each element with j among its `cols`
/// (two [`MULTIPLIER`]-flagged dofs excepted).
fn pattern(
    nrows: usize,
    ncols: usize,
    rows: ElementLists,
    cols: ElementLists,
) -> SymbolicSparseColMat<usize> {
    let n_elements = cols.ptr.len() - 1;
    // The elements of each column (a counting sort).
    index31(ncols);
    let mut col_start = vec![0usize; ncols + 1];
    for &d in cols.dofs {
        let j = (d & !MULTIPLIER) as usize;
        assert!(j < ncols, "an element dof outside the matrix");
        col_start[j + 1] += 1;
    }
    for j in 0..ncols {
        col_start[j + 1] += col_start[j];
    }
    // Column j's elements, each flagged when j is one of its multipliers.
    let mut next = col_start.clone();
    let mut col_elements = vec![0u32; cols.dofs.len()];
    for e in 0..n_elements {
        let element = index31(e);
        for &d in cols.of(e) {
            let j = (d & !MULTIPLIER) as usize;
            col_elements[next[j]] = element | (d & MULTIPLIER);
            next[j] += 1;
        }
    }
    drop(next);
    let mut col_ptr = Vec::with_capacity(ncols + 1);
    col_ptr.push(0usize);
    let mut row_idx: Vec<usize> = Vec::new();
    let mut seen = vec![u32::MAX; nrows];
    for j in 0..ncols {
        let (start, column) = (row_idx.len(), j as u32);
        for &tagged in &col_elements[col_start[j]..col_start[j + 1]] {
            let (e, j_multiplier) = ((tagged & !MULTIPLIER) as usize, tagged & MULTIPLIER != 0);
            for &d in rows.of(e) {
                let (i, i_multiplier) = ((d & !MULTIPLIER) as usize, d & MULTIPLIER != 0);
                assert!(i < nrows, "an element dof outside the matrix");
                if !(j_multiplier && i_multiplier) && seen[i] != column {
                    seen[i] = column;
                    row_idx.push(i);
                }
            }
        }
        row_idx[start..].sort_unstable();
        col_ptr.push(row_idx.len());
    }
    SymbolicSparseColMat::new_checked(nrows, ncols, col_ptr, None, row_idx)
}

/// Assembles ∫ form(u, v, x) over the mesh: rows are test dofs, columns trial dofs.
pub fn assemble_bilinear(
    test: &Space,
    trial: &Space,
    rule: &TriangleRule,
    form: impl Fn(&ShapeValue, &ShapeValue, &QuadPoint) -> f64,
) -> Triplets {
    let mut out = Triplets::new(test.n_dofs(), trial.n_dofs());
    out.reserve(test.mesh.n_triangles() * trial.element.n_local() * test.element.n_local());
    element_matrices(test, trial, rule, form, |rows, cols, local| {
        for (i, &r) in rows.iter().enumerate() {
            for (j, &c) in cols.iter().enumerate() {
                out.push(r, c, local[i][j]);
            }
        }
    });
    out
}

/// [`assemble_bilinear`] and then [`eliminate`], straight into compressed
/// columns ([`ElementMatrix`]: the pattern of the elements' free dofs, then
/// each element's block added), without triplets (at 1M vertices the
/// P1⊕B3 stiffness is 32M triplets, 512 MB, whose sort costs more than the
/// element loop). Rows are `test`'s free dofs (`rows`), columns `trial`'s
/// (`cols`); the fixed trial dofs' columns times `fixed_values` go to the
/// returned shift −A_free,fixed u_fixed.
pub fn assemble_bilinear_eliminated(
    test: &Space,
    trial: &Space,
    rule: &TriangleRule,
    form: impl Fn(&ShapeValue, &ShapeValue, &QuadPoint) -> f64,
    rows: &DofNumbering,
    cols: &DofNumbering,
    fixed_values: &[f64],
) -> (SparseColMat<usize, f64>, Vec<f64>) {
    let free_dofs = |space: &Space, numbering: &DofNumbering, t: usize, out: &mut Vec<usize>| {
        let (element, n) = space.element_dofs(t);
        out.extend(element[..n].iter().filter_map(|&d| numbering.free_index(d)));
    };
    let mut matrix = if std::ptr::eq(test, trial) && std::ptr::eq(rows, cols) {
        ElementMatrix::new(rows.n_free(), test.mesh.n_triangles(), |t, dofs| {
            free_dofs(test, rows, t, &mut dofs.coupled)
        })
    } else {
        ElementMatrix::rectangular(
            rows.n_free(),
            cols.n_free(),
            test.mesh.n_triangles(),
            |t, r, c| {
                free_dofs(test, rows, t, r);
                free_dofs(trial, cols, t, c);
            },
        )
    };
    let mut shift = vec![0.0; rows.n_free()];
    element_matrices(test, trial, rule, form, |test_dofs, trial_dofs, local| {
        let (mut free_rows, mut free_cols) = ([None; MAX_LOCAL], [None; MAX_LOCAL]);
        for (f, &d) in free_rows.iter_mut().zip(test_dofs) {
            *f = rows.free_index(d);
        }
        for (f, &d) in free_cols.iter_mut().zip(trial_dofs) {
            *f = cols.free_index(d);
        }
        let (free_rows, free_cols) = (
            &free_rows[..test_dofs.len()],
            &free_cols[..trial_dofs.len()],
        );
        matrix.add_block(free_rows, free_cols, |a, b| local[a][b]);
        for (j, &c) in trial_dofs.iter().enumerate() {
            if free_cols[j].is_none() {
                for (i, ri) in free_rows.iter().enumerate() {
                    if let Some(ri) = *ri {
                        shift[ri] -= local[i][j] * fixed_values[c];
                    }
                }
            }
        }
    });
    (matrix.into_sparse(), shift)
}

/// The P1 stiffness ∫ ∇φ_j·∇φ_i of `mesh` on the free vertices of
/// `numbering` (its dofs are the vertices), and the shift −K_free,fixed
/// u_fixed of `fixed_values`: [`assemble_bilinear_eliminated`] of the
/// Laplacian on P1, to round-off, built from the mesh's edges. K's pattern
/// is the free vertices' adjacency (one entry per edge and side, and the
/// diagonal), so each triangle adds its element matrix K_ij = d_i·d_j /
/// (4|T|) (d_i the edge opposite vertex i) at positions known per edge,
/// without searching its columns or building the pattern from element
/// lists. `reserve` entries more are allocated in the matrix's arrays, for
/// columns the caller appends (the membrane's bubbles) without copying them.
pub fn p1_stiffness(
    mesh: &Mesh,
    numbering: &DofNumbering,
    fixed_values: &[f64],
    reserve: usize,
) -> (SparseColMat<usize, f64>, Vec<f64>) {
    let free = |d: usize| numbering.free_index(d);
    let n = numbering.n_free();
    let free_edge = |[a, b]: [usize; 2]| Some((free(a)?, free(b)?));
    let mut col_ptr = Vec::with_capacity(n + 1 + reserve);
    col_ptr.push(0usize);
    col_ptr.resize(n + 1, 1);
    for &edge in &mesh.edges {
        if let Some((fa, fb)) = free_edge(edge) {
            col_ptr[fa + 1] += 1;
            col_ptr[fb + 1] += 1;
        }
    }
    for c in 0..n {
        col_ptr[c + 1] += col_ptr[c];
    }
    let nnz = col_ptr[n];
    // As `index31`: the memory guard refuses meshes far below 2³² entries.
    assert!(
        u32::try_from(nnz).is_ok(),
        "{nnz} entries: the P1 stiffness indexes its entries in 32 bits"
    );
    let mut rows = Vec::with_capacity(nnz + reserve);
    rows.resize(nnz, 0usize);
    let mut next = col_ptr[..n].to_vec();
    for (c, next_c) in next.iter_mut().enumerate() {
        rows[*next_c] = c;
        *next_c += 1;
    }
    for &edge in &mesh.edges {
        if let Some((fa, fb)) = free_edge(edge) {
            (rows[next[fa]], rows[next[fb]]) = (fb, fa);
            next[fa] += 1;
            next[fb] += 1;
        }
    }
    drop(next);
    for c in 0..n {
        rows[col_ptr[c]..col_ptr[c + 1]].sort_unstable();
    }
    // Positions in 32 bits (checked above): half the memory of usize.
    let position = |row: usize, col: usize| {
        let column = &rows[col_ptr[col]..col_ptr[col + 1]];
        let k = column
            .binary_search(&row)
            .expect("in the adjacency pattern");
        (col_ptr[col] + k) as u32
    };
    // Per edge [a, b]: the positions of (b, a) in a's column and (a, b) in b's.
    let edge_positions: Vec<[u32; 2]> = mesh
        .edges
        .iter()
        .map(|&edge| match free_edge(edge) {
            Some((fa, fb)) => [position(fb, fa), position(fa, fb)],
            None => [u32::MAX; 2],
        })
        .collect();
    let diagonal: Vec<u32> = (0..n).map(|c| position(c, c)).collect();
    let mut values = Vec::with_capacity(nnz + reserve);
    values.resize(nnz, 0.0);
    let mut shift = vec![0.0; n];
    for (t, (tri, edges)) in mesh.triangles.iter().zip(&mesh.triangle_edges).enumerate() {
        let p = tri.map(|v| mesh.vertices[v]);
        let d = [0, 1, 2].map(|i| {
            let (from, to) = (p[(i + 1) % 3], p[(i + 2) % 3]);
            [to[0] - from[0], to[1] - from[1]]
        });
        let scale = 0.25 / mesh.area(t).abs();
        for i in 0..3 {
            let Some(fi) = free(tri[i]) else { continue };
            for j in 0..3 {
                let k_ij = (d[i][0] * d[j][0] + d[i][1] * d[j][1]) * scale;
                if i == j {
                    values[diagonal[fi] as usize] += k_ij;
                    continue;
                }
                // The edge joining local vertices i and j is the one
                // opposite the third.
                let e = edges[3 - i - j];
                match free(tri[j]) {
                    // (fi, fj) lies in column fj.
                    Some(_) => {
                        let side = usize::from(mesh.edges[e][0] != tri[j]);
                        values[edge_positions[e][side] as usize] += k_ij;
                    }
                    None => shift[fi] -= k_ij * fixed_values[tri[j]],
                }
            }
        }
    }
    let symbolic = SymbolicSparseColMat::new_checked(n, n, col_ptr, None, rows);
    (SparseColMat::new(symbolic, values), shift)
}

/// ∫_T φ_k / |T| for each local basis function k of `element`, the same on
/// every straight triangle (the basis is a polynomial in the barycentric
/// coordinates): the reference element's means, from a rule exact for
/// its degree.
fn basis_means(element: Element) -> [f64; MAX_LOCAL] {
    let rule = TriangleRule::exact_for(element.degree());
    let mut means = [0.0; MAX_LOCAL];
    for (&point, &w) in rule.points.iter().zip(&rule.weights) {
        let basis = element.basis(point);
        for (m, v) in means.iter_mut().zip(&basis.values[..element.n_local()]) {
            *m += w * v;
        }
    }
    means
}

/// c ∫ φ_i for every dof i of `space`: the load of a constant source, each
/// triangle's share |T| times the basis means ([`basis_means`]), where
/// quadrature gives the same numbers to round-off.
pub fn assemble_constant_linear(space: &Space, c: f64) -> Vec<f64> {
    let means = basis_means(space.element);
    let n = space.element.n_local();
    let mut out = vec![0.0; space.n_dofs()];
    for t in 0..space.mesh.n_triangles() {
        let area = space.mesh.area(t);
        let (dofs, _) = space.element_dofs(t);
        for (&d, m) in dofs[..n].iter().zip(&means) {
            out[d] += c * area * m;
        }
    }
    out
}

/// The P0–`trial` mass matrix M_Tj = ∫_T φ_j with every triangle's row
/// (P0's dofs, all free) and the free trial dofs of `cols` as columns, and
/// −M_fixed u_fixed per row: a P0 multiplier's constraint rows. Each row is
/// |T| times the basis means ([`basis_means`]), written straight into
/// compressed columns: a column's rows are the triangles around its dof, in
/// order. [`assemble_bilinear_eliminated`] of the mass form gives the same
/// matrix to round-off, at 7 quadrature points per triangle.
pub fn assemble_p0_mass(
    trial: &Space,
    cols: &DofNumbering,
    fixed_values: &[f64],
) -> (SparseColMat<usize, f64>, Vec<f64>) {
    let mesh = trial.mesh;
    let (means, n) = (basis_means(trial.element), trial.element.n_local());
    let m = mesh.n_triangles();
    let mut col_ptr = vec![0usize; cols.n_free() + 1];
    for t in 0..m {
        let (dofs, _) = trial.element_dofs(t);
        for &d in &dofs[..n] {
            if let Some(c) = cols.free_index(d) {
                col_ptr[c + 1] += 1;
            }
        }
    }
    for c in 0..cols.n_free() {
        col_ptr[c + 1] += col_ptr[c];
    }
    let mut next = col_ptr[..cols.n_free()].to_vec();
    let mut rows = vec![0usize; col_ptr[cols.n_free()]];
    let mut values = vec![0.0; rows.len()];
    let mut shift = vec![0.0; m];
    for t in 0..m {
        let area = mesh.area(t);
        let (dofs, _) = trial.element_dofs(t);
        for (&d, mean) in dofs[..n].iter().zip(&means) {
            match cols.free_index(d) {
                Some(c) => {
                    (rows[next[c]], values[next[c]]) = (t, area * mean);
                    next[c] += 1;
                }
                None => shift[t] -= area * mean * fixed_values[d],
            }
        }
    }
    let symbolic = SymbolicSparseColMat::new_checked(m, cols.n_free(), col_ptr, None, rows);
    (SparseColMat::new(symbolic, values), shift)
}

/// Each triangle's element matrix of ∫ form(u, v, x), handed to `sink`
/// with the triangle's test (row) and trial (column) dofs.
fn element_matrices(
    test: &Space,
    trial: &Space,
    rule: &TriangleRule,
    form: impl Fn(&ShapeValue, &ShapeValue, &QuadPoint) -> f64,
    mut sink: impl FnMut(&[usize], &[usize], &[[f64; MAX_LOCAL]; MAX_LOCAL]),
) {
    let mesh = test.mesh;
    let (tab_u, tab_v) = (
        Tabulation::new(trial.element, rule),
        Tabulation::new(test.element, rule),
    );
    let (nu, nv) = (trial.element.n_local(), test.element.n_local());
    let same_element = test.element == trial.element;
    let mut local = [[0.0; MAX_LOCAL]; MAX_LOCAL];
    let (mut su, mut sv_buffer) = (
        [ShapeValue::default(); MAX_LOCAL],
        [ShapeValue::default(); MAX_LOCAL],
    );
    for t in 0..mesh.n_triangles() {
        let g = TriangleGeometry::new(mesh, t);
        local[..nv].iter_mut().for_each(|row| row[..nu].fill(0.0));
        for (q, p) in quad_points(&g, t, rule).enumerate() {
            tab_u.fill_shapes(&g, q, &mut su);
            let sv = if same_element {
                &su
            } else {
                tab_v.fill_shapes(&g, q, &mut sv_buffer);
                &sv_buffer
            };
            for i in 0..nv {
                for j in 0..nu {
                    local[i][j] += p.weight * form(&su[j], &sv[i], &p);
                }
            }
        }
        let (rows, _) = test.element_dofs(t);
        let (cols, _) = trial.element_dofs(t);
        sink(&rows[..nv], &cols[..nu], &local);
    }
}

/// ∫_T form(φ_k, φ_k) on each triangle T for the local basis function k of
/// `space` (an element's own dof, e.g. its bubble): one value per triangle.
pub fn element_diagonal(
    space: &Space,
    rule: &TriangleRule,
    form: impl Fn(&ShapeValue, &ShapeValue, &QuadPoint) -> f64,
    k: usize,
) -> Vec<f64> {
    let mesh = space.mesh;
    let tab = Tabulation::new(space.element, rule);
    let mut s = [ShapeValue::default(); MAX_LOCAL];
    (0..mesh.n_triangles())
        .map(|t| {
            let g = TriangleGeometry::new(mesh, t);
            quad_points(&g, t, rule)
                .enumerate()
                .map(|(q, p)| {
                    tab.fill_shapes(&g, q, &mut s);
                    p.weight * form(&s[k], &s[k], &p)
                })
                .sum()
        })
        .collect()
}

/// Assembles ∫ form(v, x) over the mesh, one entry per test dof.
pub fn assemble_linear(
    test: &Space,
    rule: &TriangleRule,
    form: impl Fn(&ShapeValue, &QuadPoint) -> f64,
) -> Vec<f64> {
    let mesh = test.mesh;
    let tab = Tabulation::new(test.element, rule);
    let n = test.element.n_local();
    let mut out = vec![0.0; test.n_dofs()];
    let mut s = [ShapeValue::default(); MAX_LOCAL];
    for t in 0..mesh.n_triangles() {
        let g = TriangleGeometry::new(mesh, t);
        let (dofs, _) = test.element_dofs(t);
        for (q, p) in quad_points(&g, t, rule).enumerate() {
            tab.fill_shapes(&g, q, &mut s);
            for i in 0..n {
                out[dofs[i]] += p.weight * form(&s[i], &p);
            }
        }
    }
    out
}

/// Integrates N functionals of F finite-element functions on one mesh (each
/// function's value and gradient at the point) over the mesh, in one pass
/// over the quadrature points: e.g. error norms against an exact solution,
/// which the integrand evaluates once per point for all of them. Each total
/// is the sum over the triangles, in their order, of the triangle's
/// Σ_q w_q integrand_q ([`integrate_each_triangle`]), whatever `threads`.
pub fn integrate_fields<const F: usize, const N: usize, E, I>(
    fields: [(&Space, &[f64]); F],
    rule: &TriangleRule,
    threads: usize,
    integrand: impl Fn() -> I + Sync,
) -> std::result::Result<[f64; N], E>
where
    E: Send,
    I: FnMut(&[ShapeValue; F], &QuadPoint) -> std::result::Result<[f64; N], E>,
{
    let mut totals = [0.0; N];
    for sum in integrate_each_triangle(fields, rule, threads, integrand)? {
        for j in 0..N {
            totals[j] += sum[j];
        }
    }
    Ok(totals)
}

/// Integrates a functional of one FE function (value and gradient at each point),
/// per triangle: e.g. a constraint row checked against an independent quadrature.
pub fn integrate_per_triangle(
    space: &Space,
    coefficients: &[f64],
    rule: &TriangleRule,
    integrand: impl Fn(&ShapeValue, &QuadPoint) -> f64 + Sync,
) -> Vec<f64> {
    let per_triangle = integrate_each_triangle([(space, coefficients)], rule, 1, || {
        |[value]: &[ShapeValue; 1], p: &QuadPoint| {
            Ok::<_, std::convert::Infallible>([integrand(value, p)])
        }
    });
    let Ok(per_triangle) = per_triangle;
    per_triangle.into_iter().map(|[v]| v).collect()
}

/// For every triangle, Σ_q w_q integrand_q of N functionals of F
/// finite-element functions on one mesh (each function's value and gradient
/// at the point). The triangles are split into `threads` contiguous ranges,
/// each integrated on its own thread with its own integrand (`integrand()`:
/// e.g. its own evaluator's scratch space); the sums do not depend on the
/// split. An error of the integrand ends the pass: the first in triangle order.
fn integrate_each_triangle<const F: usize, const N: usize, E, I>(
    fields: [(&Space, &[f64]); F],
    rule: &TriangleRule,
    threads: usize,
    integrand: impl Fn() -> I + Sync,
) -> std::result::Result<Vec<[f64; N]>, E>
where
    E: Send,
    I: FnMut(&[ShapeValue; F], &QuadPoint) -> std::result::Result<[f64; N], E>,
{
    let Some(mesh) = fields.first().map(|(space, _)| space.mesh) else {
        return Ok(Vec::new());
    };
    let tabulations = fields.map(|(space, _)| Tabulation::new(space.element, rule));
    // Triangle first + k's sum in sums[k].
    let integrate_range = |first: usize, sums: &mut [[f64; N]]| -> std::result::Result<(), E> {
        let mut integrand = integrand();
        for (k, sum) in sums.iter_mut().enumerate() {
            let t = first + k;
            let g = TriangleGeometry::new(mesh, t);
            let dofs = fields.map(|(space, _)| space.element_dofs(t));
            for (q, p) in quad_points(&g, t, rule).enumerate() {
                let mut values = [ShapeValue::default(); F];
                for (f, value) in values.iter_mut().enumerate() {
                    let (coefficients, (dofs, n)) = (fields[f].1, dofs[f]);
                    let s = tabulations[f].shapes(&g, q);
                    for i in 0..n {
                        let c = coefficients[dofs[i]];
                        value.value += c * s[i].value;
                        value.grad[0] += c * s[i].grad[0];
                        value.grad[1] += c * s[i].grad[1];
                    }
                }
                let v = integrand(&values, &p)?;
                for j in 0..N {
                    sum[j] += p.weight * v[j];
                }
            }
        }
        Ok(())
    };
    let n_triangles = mesh.n_triangles();
    let mut sums = vec![[0.0; N]; n_triangles];
    let per_thread = n_triangles.div_ceil(threads.max(1)).max(1);
    if per_thread >= n_triangles {
        integrate_range(0, &mut sums)?;
    } else {
        let integrate_range = &integrate_range;
        std::thread::scope(|scope| {
            let ranges: Vec<_> = sums
                .chunks_mut(per_thread)
                .enumerate()
                .map(|(k, range)| scope.spawn(move || integrate_range(k * per_thread, range)))
                .collect();
            // Joined in order: the first range's error is the first error.
            ranges
                .into_iter()
                .try_for_each(|r| r.join().expect("an integration thread panicked"))
        })?;
    }
    Ok(sums)
}

/// Lumped mass: the row sums of the mass matrix (for P1, |supp φ_i|/3).
pub fn lumped_mass(space: &Space, rule: &TriangleRule) -> Vec<f64> {
    assemble_linear(space, rule, |v, _| v.value)
}

/// Which global dofs are free (unknowns) and which are fixed (Dirichlet).
#[derive(Debug, Clone)]
pub struct DofNumbering {
    /// For each global dof, its index among the free dofs, or [`FIXED`]:
    /// 32 bits (held through a whole solve, one per dof).
    free_index: Vec<u32>,
    /// The free dofs in order.
    pub free_dofs: Vec<usize>,
}

/// [`DofNumbering`]'s mark of a fixed dof.
const FIXED: u32 = u32::MAX;

impl DofNumbering {
    /// # Panics
    /// With 2³² − 1 dofs or more (the memory guard refuses far fewer).
    pub fn from_fixed_mask(fixed: &[bool]) -> Self {
        assert!(
            u32::try_from(fixed.len()).is_ok_and(|n| n < FIXED),
            "{} dofs: a numbering holds 32-bit indices",
            fixed.len()
        );
        let mut free_index = vec![FIXED; fixed.len()];
        let mut free_dofs = Vec::with_capacity(fixed.iter().filter(|&&f| !f).count());
        for (d, &f) in fixed.iter().enumerate() {
            if !f {
                free_index[d] = free_dofs.len() as u32;
                free_dofs.push(d);
            }
        }
        DofNumbering {
            free_index,
            free_dofs,
        }
    }

    /// Dof d's index among the free dofs, or None if it is fixed.
    pub fn free_index(&self, d: usize) -> Option<usize> {
        match self.free_index[d] {
            FIXED => None,
            i => Some(i as usize),
        }
    }

    /// The numbering of the first `n` dofs, whose free ones are numbered
    /// before every other dof's.
    pub fn leading(&self, n: usize) -> DofNumbering {
        let free_dofs: Vec<usize> = self
            .free_dofs
            .iter()
            .copied()
            .take_while(|&d| d < n)
            .collect();
        debug_assert!(
            self.free_dofs[free_dofs.len()..].iter().all(|&d| d >= n),
            "the first n dofs' free ones first"
        );
        DofNumbering {
            free_index: self.free_index[..n].to_vec(),
            free_dofs,
        }
    }

    pub fn all_free(n: usize) -> Self {
        Self::from_fixed_mask(&vec![false; n])
    }

    pub fn n_free(&self) -> usize {
        self.free_dofs.len()
    }

    pub fn n_total(&self) -> usize {
        self.free_index.len()
    }

    pub fn restrict(&self, full: &[f64]) -> Vec<f64> {
        self.free_dofs.iter().map(|&d| full[d]).collect()
    }

    /// The interior groups of the free problem (static condensation): for
    /// each of the `n_triangles` triangles t, the free indices of the dofs
    /// `start + t`, one per bubble block starting at `start` (a bubble
    /// vanishes on the boundary, so only a block fixed as a whole drops
    /// out).
    pub fn interior_groups(&self, bubble_starts: &[usize], n_triangles: usize) -> InteriorGroups {
        InteriorGroups::from_groups((0..n_triangles).map(|t| {
            bubble_starts
                .iter()
                .filter_map(|&start| self.free_index(start + t))
                .collect()
        }))
    }

    /// The full vector: free values from `reduced`, fixed ones from `fixed_values`.
    pub fn extend(&self, reduced: &[f64], fixed_values: &[f64]) -> Vec<f64> {
        let mut full = fixed_values.to_vec();
        for (k, &d) in self.free_dofs.iter().enumerate() {
            full[d] = reduced[k];
        }
        full
    }
}

/// Homogeneous linear ties between free unknowns (deal.II's affine
/// constraints without inhomogeneity): each tied unknown ("slave") equals a
/// combination of others, x_s = Σ w_m x_m, which dof elimination cannot
/// state (u·n = 0 on a symmetry plane of oblique normal n). With T the map
/// from the independent unknowns y to all free ones, x = T y, the tied
/// problem is Tᵀ A T y = Tᵀ F, its constraint C T.
#[derive(Debug, Clone)]
pub struct LinearTies {
    /// For each free unknown: None if independent, else its combination of
    /// independent unknowns (free indices and weights).
    combination: Vec<Option<Vec<(usize, f64)>>>,
    /// For each free unknown, its index among the independent ones.
    independent: Vec<Option<usize>>,
}

impl LinearTies {
    /// `ties`: (slave, [(master, weight)]) over `n_free` free unknowns; a
    /// master is never itself a slave.
    pub fn new(n_free: usize, ties: Vec<(usize, Vec<(usize, f64)>)>) -> Self {
        let mut combination = vec![None; n_free];
        for (slave, masters) in ties {
            combination[slave] = Some(masters);
        }
        let mut independent = vec![None; n_free];
        let mut k = 0;
        for (i, c) in combination.iter().enumerate() {
            if c.is_none() {
                independent[i] = Some(k);
                k += 1;
            }
        }
        debug_assert!(combination
            .iter()
            .flatten()
            .flatten()
            .all(|&(m, _)| independent[m].is_some()));
        LinearTies {
            combination,
            independent,
        }
    }

    /// The number of independent unknowns.
    pub fn n_independent(&self) -> usize {
        self.independent.iter().flatten().count()
    }

    /// Row i of T: the independent unknowns free unknown i is made of.
    pub fn row(&self, i: usize) -> Vec<(usize, f64)> {
        match (&self.combination[i], self.independent[i]) {
            (Some(masters), _) => masters
                .iter()
                .map(|&(m, w)| (self.independent[m].expect("a master is independent"), w))
                .collect(),
            (None, Some(k)) => vec![(k, 1.0)],
            (None, None) => Vec::new(),
        }
    }

    /// The independent index of free unknown i (None for a slave).
    pub fn independent_index(&self, i: usize) -> Option<usize> {
        self.independent[i]
    }

    /// Tᵀ A T for a square A over the free unknowns (whole, not a triangle).
    pub fn congruence(&self, a: &SparseColMat<usize, f64>) -> SparseColMat<usize, f64> {
        let n = self.n_independent();
        let rows: Vec<Vec<(usize, f64)>> = (0..a.nrows()).map(|i| self.row(i)).collect();
        let mut t = Triplets::new(n, n);
        let m = a.as_ref();
        for j in 0..m.ncols() {
            for (i, v) in m.row_idx_of_col(j).zip(m.val_of_col(j)) {
                for &(p, wp) in &rows[i] {
                    for &(q, wq) in &rows[j] {
                        t.push(p, q, wp * v * wq);
                    }
                }
            }
        }
        t.into_sparse()
    }

    /// C T for a matrix C whose columns are the free unknowns.
    pub fn columns(&self, c: &SparseColMat<usize, f64>) -> SparseColMat<usize, f64> {
        let mut t = Triplets::new(c.nrows(), self.n_independent());
        let m = c.as_ref();
        for j in 0..m.ncols() {
            let row = self.row(j);
            for (i, v) in m.row_idx_of_col(j).zip(m.val_of_col(j)) {
                for &(q, w) in &row {
                    t.push(i, q, v * w);
                }
            }
        }
        t.into_sparse()
    }

    /// Tᵀ f for a vector over the free unknowns.
    pub fn transpose_times(&self, f: &[f64]) -> Vec<f64> {
        let mut out = vec![0.0; self.n_independent()];
        for (i, &fi) in f.iter().enumerate() {
            for (k, w) in self.row(i) {
                out[k] += w * fi;
            }
        }
        out
    }

    /// x = T y: every free unknown from the independent ones.
    pub fn expand(&self, y: &[f64]) -> Vec<f64> {
        (0..self.combination.len())
            .map(|i| self.row(i).iter().map(|&(k, w)| w * y[k]).sum())
            .collect()
    }

    /// y from x: the independent unknowns' values.
    pub fn independent_values(&self, x: &[f64]) -> Vec<f64> {
        x.iter()
            .zip(&self.independent)
            .filter_map(|(v, k)| k.map(|_| *v))
            .collect()
    }
}

/// Keeps the free rows and columns of a matrix. Returns the reduced matrix
/// and −A_free,fixed · fixed_values, the right-hand-side shift that lifts
/// non-homogeneous Dirichlet data.
pub fn eliminate(
    a: Triplets,
    rows: &DofNumbering,
    cols: &DofNumbering,
    fixed_values: &[f64],
) -> (Triplets, Vec<f64>) {
    let mut shift = vec![0.0; rows.n_free()];
    let mut entries = a.entries;
    // In place: the full matrix's allocation becomes the reduced one's.
    entries.retain_mut(|e| {
        let (r, c, v) = (e.0 as usize, e.1 as usize, e.2);
        let Some(ri) = rows.free_index(r) else {
            return false;
        };
        match cols.free_index(c) {
            Some(ci) => {
                // Free indices are below the full ones: 32 bits.
                *e = (ri as u32, ci as u32, v);
                true
            }
            None => {
                shift[ri] -= v * fixed_values[c];
                false
            }
        }
    });
    let reduced = Triplets {
        nrows: rows.n_free(),
        ncols: cols.n_free(),
        entries,
    };
    (reduced, shift)
}
