//! Static condensation: unknowns that couple only inside one group (the
//! bubbles of one triangle) are eliminated group by group with their small
//! dense block, and only the Schur complement on the remaining unknowns is
//! factorised. Purely algebraic: a group is a list of unknowns.
//!
//! With I the interior unknowns (block diagonal A_II, one block per group)
//! and R the rest,
//!
//! ```text
//!     S = A_RR − A_RI A_II⁻¹ A_IR,     S x_R = b_R − A_RI A_II⁻¹ b_I,
//!     x_I = A_II⁻¹ b_I − (A_II⁻¹ A_IR) x_R,
//! ```
//!
//! exact in exact arithmetic. Each group contributes a dense |R_g|×|R_g|
//! term to S, R_g being the remaining unknowns its rows and columns touch
//! (vertex and edge unknowns, and any multiplier row that reaches a bubble),
//! so S's pattern depends on A's pattern only: analysed once, refactorised
//! numerically for every matrix of that pattern. A symmetric A is read by
//! its lower triangle (it may be given so) and S is made as its lower
//! triangle: half of S, of its maps and of the Schur terms' work.

use crate::error::{Error, Result};
use faer::sparse::{SparseColMat, SymbolicSparseColMat};

use super::{column_halves, in_column_halves, MatrixKind};

/// The interior unknowns of a problem, one group per element (CSR): group
/// g is `indices[offsets[g]..offsets[g + 1]]`. A group's unknowns may
/// couple only with each other and with unknowns of no group.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct InteriorGroups {
    offsets: Vec<usize>,
    indices: Vec<usize>,
}

impl InteriorGroups {
    /// Groups from lists of unknowns; empty groups are dropped.
    pub fn from_groups<I: IntoIterator<Item = Vec<usize>>>(groups: I) -> Self {
        let (mut offsets, mut indices) = (vec![0], Vec::new());
        for g in groups.into_iter().filter(|g| !g.is_empty()) {
            indices.extend(g);
            offsets.push(indices.len());
        }
        // Held through a whole solve: without the growth's spare room.
        offsets.shrink_to_fit();
        indices.shrink_to_fit();
        InteriorGroups { offsets, indices }
    }

    /// Number of groups.
    pub fn len(&self) -> usize {
        self.offsets.len() - 1
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The unknowns of group g.
    pub fn group(&self, g: usize) -> &[usize] {
        &self.indices[self.offsets[g]..self.offsets[g + 1]]
    }

    /// The groups restricted to the unknowns below `end` (a leading block
    /// of the matrix).
    pub fn restricted_to(&self, end: usize) -> Self {
        Self::from_groups(
            (0..self.len()).map(|g| self.group(g).iter().copied().filter(|&i| i < end).collect()),
        )
    }

    /// Number of interior unknowns, all groups together.
    pub fn n_interior(&self) -> usize {
        self.indices.len()
    }
}

/// Local blocks whose 1-norm condition number (after equilibration) is
/// above this are refused: their inverse would have no correct digit.
const MAX_LOCAL_CONDITION: f64 = 1e15;

const NONE: usize = usize::MAX;

/// An index into A's or S's values in the plan's maps.
type Index = u32;

fn index(i: usize) -> Index {
    Index::try_from(i).expect("below Index::MAX (checked by the plan)")
}

/// What a matrix pattern and its groups give, computed once: the remaining
/// unknowns, each group's boundary R_g, the pattern of S and where every
/// entry of A goes.
pub(super) struct CondensationPlan {
    symmetric: bool,
    groups: InteriorGroups,
    /// Global index of S's unknown r.
    remaining: Vec<usize>,
    /// Per group, its boundary R_g as S indices (CSR over groups).
    boundary_offsets: Vec<usize>,
    boundary: Vec<usize>,
    /// Entries of A between remaining unknowns: (A value index, S value index).
    /// 32-bit, as the other maps: they are the plan's bulk (1.8 GB in
    /// 64-bit at the shell's n = 256, 67.7M entries of A).
    rest_entries: Vec<(Index, Index)>,
    /// Per group, (A value index, slot in the local (p+q)² column-major
    /// block, interior unknowns first), CSR over groups; of a symmetric A
    /// the lower triangle's entries, each filling its mirror slot too.
    local_offsets: Vec<usize>,
    local_entries: Vec<(Index, Index)>,
    /// Per group, the S value index of each of its q×q (column-major)
    /// Schur terms (symmetric: rows c.. of each column c only), CSR over
    /// groups (offsets Σ q², symmetric Σ q(q+1)/2).
    schur_offsets: Vec<usize>,
    schur_positions: Vec<Index>,
    /// Offsets of each group's A_II⁻¹ (Σ p²) and W = A_II⁻¹ A_IR (Σ p q).
    inverse_offsets: Vec<usize>,
    coupling_offsets: Vec<usize>,
    /// The kind of S.
    pub(super) schur_kind: MatrixKind,
}

/// The numeric elimination of every group of one matrix.
pub(super) struct LocalFactors {
    /// A_II⁻¹ per group, p×p row-major.
    inverse: Vec<f64>,
    /// W = A_II⁻¹ A_IR per group, p×q row-major.
    coupling: Vec<f64>,
    /// V = A_RI A_II⁻¹ per group, q×p row-major (only for a non-symmetric
    /// A; symmetric: V = Wᵀ).
    transposed_coupling: Option<Vec<f64>>,
}

impl CondensationPlan {
    /// Checks the groups against `a`'s pattern (every index in range and in
    /// one group only; no entry between two groups) and plans the
    /// condensation.
    pub(super) fn new(
        a: &SparseColMat<usize, f64>,
        groups: &InteriorGroups,
        kind: MatrixKind,
        what: &str,
    ) -> Result<(Self, SparseColMat<usize, f64>)> {
        let n = a.nrows();
        let fail = |field: String, reason: String| Error::numerical(what, &field, reason);
        let mut group_of = vec![NONE; n];
        for g in 0..groups.len() {
            if groups.group(g).len() > MAX_INLINE {
                return Err(fail(
                    format!("interior group {g}"),
                    format!(
                        "{} unknowns: at most {MAX_INLINE} per group (an element's interior)",
                        groups.group(g).len()
                    ),
                ));
            }
            for &i in groups.group(g) {
                if i >= n {
                    return Err(fail(
                        format!("interior group {g}"),
                        format!("unknown {i} is out of range (the matrix is {n}×{n})"),
                    ));
                }
                if group_of[i] != NONE {
                    return Err(fail(
                        format!("interior group {g}"),
                        format!("unknown {i} is already in interior group {}", group_of[i]),
                    ));
                }
                group_of[i] = g;
            }
        }
        // The plan's maps index values in 32 bits.
        let within_index = |field: &str, entries: usize| {
            match entries > Index::MAX as usize {
            true => Err(fail(
                field.to_string(),
                format!(
                    "{entries} entries: condensation indexes at most {} (solver.condense = false factorises A itself)",
                    Index::MAX
                ),
            )),
            false => Ok(()),
        }
        };
        within_index("matrix entries", a.val().len())?;
        let mut s_index = vec![NONE; n];
        let remaining: Vec<usize> = (0..n).filter(|&i| group_of[i] == NONE).collect();
        for (r, &i) in remaining.iter().enumerate() {
            s_index[i] = r;
        }
        let (col_ptr, row_idx) = (a.symbolic().col_ptr(), a.symbolic().row_idx());
        // A symmetric matrix is read by its lower triangle (as its LDLᵀ
        // reads S's), whether or not it stores the upper one.
        let symmetric = kind != MatrixKind::General;
        let read = |i: usize, j: usize| !symmetric || i >= j;
        // Boundaries, and the entries between two groups (an error).
        let mut boundaries: Vec<Vec<usize>> = vec![Vec::new(); groups.len()];
        for j in 0..n {
            for &i in row_idx[col_ptr[j]..col_ptr[j + 1]]
                .iter()
                .filter(|&&i| read(i, j))
            {
                match (group_of[i], group_of[j]) {
                    (NONE, NONE) => {}
                    (gi, NONE) => boundaries[gi].push(s_index[j]),
                    (NONE, gj) => boundaries[gj].push(s_index[i]),
                    (gi, gj) if gi != gj => {
                        return Err(fail(
                            format!("interior group {gj}"),
                            format!(
                                "its unknown {j} couples with unknown {i} of interior group {gi}: interior unknowns may couple only inside their group"
                            ),
                        ));
                    }
                    _ => {}
                }
            }
        }
        let mut boundary_offsets = vec![0];
        let mut boundary = Vec::new();
        for b in &mut boundaries {
            b.sort_unstable();
            b.dedup();
            boundary.extend_from_slice(b);
            boundary_offsets.push(boundary.len());
        }
        drop(boundaries);
        // The pattern of S: A_RR and a dense block per group boundary (of
        // a symmetric A, their lower triangles: S's index order is A's).
        let m = remaining.len();
        let mut columns: Vec<Vec<usize>> = vec![Vec::new(); m];
        for j in 0..n {
            if s_index[j] != NONE {
                let col = &mut columns[s_index[j]];
                col.extend(
                    row_idx[col_ptr[j]..col_ptr[j + 1]]
                        .iter()
                        .filter(|&&i| s_index[i] != NONE && read(i, j))
                        .map(|&i| s_index[i]),
                );
            }
        }
        let rows_of = |k: usize| if symmetric { k } else { 0 };
        for g in 0..groups.len() {
            let b = &boundary[boundary_offsets[g]..boundary_offsets[g + 1]];
            for (k, &c) in b.iter().enumerate() {
                columns[c].extend_from_slice(&b[rows_of(k)..]);
            }
        }
        // The plan's arrays are sized exactly: grown by doubling, their
        // spare capacity was ~0.15 GB at the shell's n = 256.
        for col in &mut columns {
            col.sort_unstable();
            col.dedup();
        }
        let mut s_col_ptr = Vec::with_capacity(m + 1);
        let mut s_row_idx = Vec::with_capacity(columns.iter().map(Vec::len).sum());
        s_col_ptr.push(0);
        for col in &mut columns {
            s_row_idx.extend_from_slice(col);
            s_col_ptr.push(s_row_idx.len());
            *col = Vec::new();
        }
        drop(columns);
        within_index("Schur complement entries", s_row_idx.len())?;
        let position = |r: usize, c: usize| -> usize {
            let rows = &s_row_idx[s_col_ptr[c]..s_col_ptr[c + 1]];
            s_col_ptr[c] + rows.binary_search(&r).expect("in the pattern of S")
        };
        // Where each entry of A goes.
        let rest = |i: usize, j: usize| read(i, j) && group_of[i] == NONE && group_of[j] == NONE;
        let n_rest = (0..n)
            .map(|j| {
                (col_ptr[j]..col_ptr[j + 1])
                    .filter(|&k| rest(row_idx[k], j))
                    .count()
            })
            .sum();
        let mut rest_entries = Vec::with_capacity(n_rest);
        let mut local_count = vec![0usize; groups.len() + 1];
        for j in 0..n {
            for k in col_ptr[j]..col_ptr[j + 1] {
                let i = row_idx[k];
                if !read(i, j) {
                    continue;
                }
                match (group_of[i], group_of[j]) {
                    (NONE, NONE) => {
                        rest_entries.push((index(k), index(position(s_index[i], s_index[j]))))
                    }
                    (NONE, g) | (g, _) => local_count[g + 1] += 1,
                }
            }
        }
        let mut local_offsets = local_count;
        for g in 0..groups.len() {
            local_offsets[g + 1] += local_offsets[g];
        }
        let mut local_entries = vec![(0, 0); local_offsets[groups.len()]];
        let mut next = local_offsets.clone();
        let local_index = |g: usize, i: usize| -> usize {
            if group_of[i] == g {
                groups
                    .group(g)
                    .iter()
                    .position(|&u| u == i)
                    .expect("in its group")
            } else {
                let b = &boundary[boundary_offsets[g]..boundary_offsets[g + 1]];
                groups.group(g).len() + b.binary_search(&s_index[i]).expect("on the boundary")
            }
        };
        for j in 0..n {
            for k in col_ptr[j]..col_ptr[j + 1] {
                let i = row_idx[k];
                let g = match (group_of[i], group_of[j]) {
                    _ if !read(i, j) => continue,
                    (NONE, NONE) => continue,
                    (NONE, g) | (g, _) => g,
                };
                let size = groups.group(g).len() + boundary_offsets[g + 1] - boundary_offsets[g];
                local_entries[next[g]] = (
                    index(k),
                    index(local_index(g, j) * size + local_index(g, i)),
                );
                next[g] += 1;
            }
        }
        let (mut schur_offsets, mut inverse_offsets, mut coupling_offsets) =
            (vec![0], vec![0], vec![0]);
        let n_terms = (0..groups.len())
            .map(|g| boundary_offsets[g + 1] - boundary_offsets[g])
            .map(|q| if symmetric { q * (q + 1) / 2 } else { q * q })
            .sum();
        let mut schur_positions = Vec::with_capacity(n_terms);
        for g in 0..groups.len() {
            let b = &boundary[boundary_offsets[g]..boundary_offsets[g + 1]];
            let (p, q) = (groups.group(g).len(), b.len());
            for (k, &c) in b.iter().enumerate() {
                for &r in &b[rows_of(k)..] {
                    schur_positions.push(index(position(r, c)));
                }
            }
            schur_offsets.push(schur_positions.len());
            inverse_offsets.push(inverse_offsets[g] + p * p);
            coupling_offsets.push(coupling_offsets[g] + p * q);
        }
        let schur_kind = match kind {
            MatrixKind::SymmetricSaddle { n_primal } => MatrixKind::SymmetricSaddle {
                n_primal: remaining.partition_point(|&i| i < n_primal),
            },
            other => other,
        };
        debug_assert_eq!(
            (rest_entries.len(), schur_positions.len()),
            (n_rest, n_terms)
        );
        let s_nnz = s_row_idx.len();
        // S's pattern is handed out: its one copy is S's own.
        let pattern = SymbolicSparseColMat::new_checked(m, m, s_col_ptr, None, s_row_idx);
        let plan = CondensationPlan {
            symmetric,
            groups: groups.clone(),
            remaining,
            boundary_offsets,
            boundary,
            rest_entries,
            local_offsets,
            local_entries,
            schur_offsets,
            schur_positions,
            inverse_offsets,
            coupling_offsets,
            schur_kind,
        };
        Ok((plan, SparseColMat::new(pattern, vec![0.0; s_nnz])))
    }

    /// The number of unknowns of S.
    pub(super) fn n_schur(&self) -> usize {
        self.remaining.len()
    }

    fn boundary_of(&self, g: usize) -> &[usize] {
        &self.boundary[self.boundary_offsets[g]..self.boundary_offsets[g + 1]]
    }

    /// Eliminates every group of `a` (which has the planned pattern) into
    /// S's values (on the pattern [`CondensationPlan::new`] handed out):
    /// returns the local factors. A singular or ill-conditioned local block
    /// is an error naming its group.
    pub(super) fn condense_into(
        &self,
        a: &SparseColMat<usize, f64>,
        s_values: &mut [f64],
        what: &str,
    ) -> Result<LocalFactors> {
        s_values.fill(0.0);
        self.add_remaining_entries(a, s_values);
        self.eliminate_into(a, s_values, what)
    }

    /// The value position in S of A's value `k`, when it lies between
    /// remaining unknowns (A_RR).
    pub(super) fn schur_position(&self, k: usize) -> Option<usize> {
        // rest_entries is in A's value order.
        let i = self
            .rest_entries
            .partition_point(|&(a, _)| (a as usize) < k);
        let &(a, pos) = self.rest_entries.get(i)?;
        (a as usize == k).then_some(pos as usize)
    }

    /// s += A_RR (on S's pattern).
    pub(super) fn add_remaining_entries(&self, a: &SparseColMat<usize, f64>, s_values: &mut [f64]) {
        let values = a.val();
        for &(k, pos) in &self.rest_entries {
            s_values[pos as usize] += values[k as usize];
        }
    }

    /// Eliminates every group: s −= A_RI A_II⁻¹ A_IR; returns the local
    /// factors.
    pub(super) fn eliminate_into(
        &self,
        a: &SparseColMat<usize, f64>,
        s_values: &mut [f64],
        what: &str,
    ) -> Result<LocalFactors> {
        let values = a.val();
        let mut inverse = vec![0.0; *self.inverse_offsets.last().expect("offsets")];
        let mut coupling = vec![0.0; *self.coupling_offsets.last().expect("offsets")];
        let mut transposed_coupling = (!self.symmetric).then(|| vec![0.0; coupling.len()]);
        let mut block = Vec::new();
        let mut scratch = DenseScratch::default();
        for g in 0..self.groups.len() {
            let (p, q) = (self.groups.group(g).len(), self.boundary_of(g).len());
            let size = p + q;
            block.clear();
            block.resize(size * size, 0.0);
            for &(k, slot) in &self.local_entries[self.local_offsets[g]..self.local_offsets[g + 1]]
            {
                let (slot, v) = (slot as usize, values[k as usize]);
                block[slot] += v;
                // A symmetric matrix's entry below the block's diagonal
                // fills its mirror too (only the lower triangle is read).
                let (c, r) = (slot / size, slot % size);
                if self.symmetric && r != c {
                    block[r * size + c] += v;
                }
            }
            let at = |r: usize, c: usize| block[c * size + r];
            let inv = &mut inverse[self.inverse_offsets[g]..self.inverse_offsets[g + 1]];
            scratch.invert(p, at, inv).map_err(|reason| {
                Error::numerical(
                    what,
                    &format!("interior group {g} (unknowns {:?})", self.groups.group(g)),
                    format!("its {p}×{p} block {reason}"),
                )
            })?;
            // W = A_II⁻¹ A_IR (p×q, row-major).
            let w = &mut coupling[self.coupling_offsets[g]..self.coupling_offsets[g + 1]];
            for i in 0..p {
                for c in 0..q {
                    w[i * q + c] = (0..p).map(|l| inv[i * p + l] * at(l, p + c)).sum();
                }
            }
            // S_RR −= A_RI W, column c as axpys of A_RI's contiguous
            // columns (the block is column-major): the same sums in the same
            // order as dot products, at a fraction of the time. Symmetric:
            // rows c.. of column c only (S is its lower triangle).
            let mut positions =
                &self.schur_positions[self.schur_offsets[g]..self.schur_offsets[g + 1]];
            scratch.term.resize(q, 0.0);
            for c in 0..q {
                let first = if self.symmetric { c } else { 0 };
                let (column_positions, rest) = positions.split_at(q - first);
                positions = rest;
                let term = &mut scratch.term[..q - first];
                term.fill(0.0);
                for l in 0..p {
                    let column = &block[l * size + p + first..l * size + size];
                    let w_lc = w[l * q + c];
                    term.iter_mut()
                        .zip(column)
                        .for_each(|(t, a)| *t += a * w_lc);
                }
                for (&position, t) in column_positions.iter().zip(term.iter()) {
                    s_values[position as usize] -= t;
                }
            }
            if let Some(v) = transposed_coupling.as_mut() {
                // V = A_RI A_II⁻¹ (q×p, row-major).
                let v = &mut v[self.coupling_offsets[g]..self.coupling_offsets[g + 1]];
                for r in 0..q {
                    for i in 0..p {
                        v[r * p + i] = (0..p).map(|l| at(p + r, l) * inv[l * p + i]).sum();
                    }
                }
            }
        }
        Ok(LocalFactors {
            inverse,
            coupling,
            transposed_coupling,
        })
    }

    /// The condensed right-hand side b_R − A_RI A_II⁻¹ b_I (transposed:
    /// of Aᵀ, b_R − A_IRᵀ A_II⁻ᵀ b_I). Many groups: on two threads (halves
    /// of about equal coupling entries, as [`CondensationPlan::recover`]),
    /// the second half's terms summed apart and subtracted at the end
    /// (groups share boundary unknowns). Measured on the shell's Newton
    /// matrix at n = 256 (the solves of its first five steps): 0.026 →
    /// 0.015 s per solve.
    pub(super) fn condense_rhs(
        &self,
        f: &LocalFactors,
        b: &[f64],
        transpose: bool,
        threads: usize,
    ) -> Vec<f64> {
        let mut rhs: Vec<f64> = self.remaining.iter().map(|&i| b[i]).collect();
        let n_groups = self.groups.len();
        let Some(split) = column_halves(&self.coupling_offsets, threads) else {
            self.subtract_interior_terms(f, b, transpose, 0..n_groups, &mut rhs);
            return rhs;
        };
        let n_remaining = rhs.len();
        std::thread::scope(|scope| {
            let second = scope.spawn(|| {
                let mut terms = vec![0.0; n_remaining];
                self.subtract_interior_terms(f, b, transpose, split..n_groups, &mut terms);
                terms
            });
            self.subtract_interior_terms(f, b, transpose, 0..split, &mut rhs);
            let terms = second.join().expect("the second thread");
            rhs.iter_mut().zip(&terms).for_each(|(r, t)| *r += t);
        });
        rhs
    }

    /// rhs −= (A_RI A_II⁻¹ b_I) of the groups `groups` (see
    /// [`CondensationPlan::condense_rhs`]).
    fn subtract_interior_terms(
        &self,
        f: &LocalFactors,
        b: &[f64],
        transpose: bool,
        groups: std::ops::Range<usize>,
        rhs: &mut [f64],
    ) {
        // V (q×p, row-major) for A of a non-symmetric matrix; else Wᵀ, read
        // from W (p×q, row-major).
        let v = f.transposed_coupling.as_ref().filter(|_| !transpose);
        let mut b_i = [0.0; MAX_INLINE];
        for g in groups {
            let interior = self.groups.group(g);
            if self.boundary_of(g).is_empty() {
                continue; // a triangle whose vertices are all fixed
            }
            let b_i = gather(interior, b, &mut b_i);
            self.interior_terms(f, v, g, b_i, |s, term| rhs[s] -= term);
        }
    }

    /// The terms of (A_RI A_II⁻¹ b_I) of group g, as `each(S index, term)`:
    /// one per boundary unknown from V's rows (`v`: V, q×p row-major, of a
    /// non-symmetric A), else one per interior and boundary unknown from W
    /// (p×q row-major, V = Wᵀ), each row of W in turn.
    fn interior_terms(
        &self,
        f: &LocalFactors,
        v: Option<&Vec<f64>>,
        g: usize,
        b_i: &[f64],
        mut each: impl FnMut(usize, f64),
    ) {
        let boundary = self.boundary_of(g);
        let (p, q) = (self.groups.group(g).len(), boundary.len());
        let range = self.coupling_offsets[g]..self.coupling_offsets[g + 1];
        match v {
            Some(v) => {
                for (row, &s) in v[range].chunks_exact(p).zip(boundary) {
                    each(s, dot(row, b_i));
                }
            }
            None => {
                for (row, &bi) in f.coupling[range].chunks_exact(q).zip(b_i) {
                    for (&w, &s) in row.iter().zip(boundary) {
                        each(s, w * bi);
                    }
                }
            }
        }
    }

    /// Sparse columns b of A (order n, entries (index, value)) condensed:
    /// per column b̃ = b_R − A_RI A_II⁻¹ b_I as S entries (ascending, summed)
    /// and A_II⁻¹ b_I as A entries (ascending). Only the groups a column
    /// touches are read (a multiplier's row of the constraint touches one
    /// triangle's bubbles).
    pub(super) fn condense_sparse(
        &self,
        f: &LocalFactors,
        columns: &[Vec<(usize, f64)>],
        n: usize,
    ) -> Vec<CondensedColumn> {
        let mut schur_index = vec![NONE; n];
        for (r, &i) in self.remaining.iter().enumerate() {
            schur_index[i] = r;
        }
        let mut group_of = vec![NONE; n];
        for g in 0..self.groups.len() {
            for &i in self.groups.group(g) {
                group_of[i] = g;
            }
        }
        let v = f.transposed_coupling.as_ref();
        let condense = |column: &Vec<(usize, f64)>| {
            let (mut remaining, mut interior, mut touched) = (Vec::new(), Vec::new(), Vec::new());
            for &(i, value) in column {
                if schur_index[i] != NONE {
                    remaining.push((schur_index[i], value));
                } else if group_of[i] != NONE {
                    touched.push(group_of[i]);
                }
            }
            touched.sort_unstable();
            touched.dedup();
            for g in touched {
                let indices = self.groups.group(g);
                let p = indices.len();
                let b_i: Vec<f64> = indices
                    .iter()
                    .map(|&u| column.iter().filter(|e| e.0 == u).map(|e| e.1).sum())
                    .collect();
                let inv = &f.inverse[self.inverse_offsets[g]..self.inverse_offsets[g + 1]];
                for (l, &u) in indices.iter().enumerate() {
                    interior.push((u, dot(&inv[l * p..(l + 1) * p], &b_i)));
                }
                self.interior_terms(f, v, g, &b_i, |r, term| remaining.push((r, -term)));
            }
            interior.sort_unstable_by_key(|e| e.0);
            CondensedColumn {
                remaining: summed(remaining),
                interior,
            }
        };
        columns.iter().map(condense).collect()
    }

    /// x from x_R (the solution of S, or Sᵀ) and the original b:
    /// x_I = A_II⁻¹ b_I − W x_R (transposed: A_II⁻ᵀ b_I − Vᵀ x_R), into b.
    /// The groups are independent (each reads its own b_I and x_R): many
    /// are recovered on two threads ([`in_column_halves`], halves of about
    /// equal coupling entries), each value the same sum as on one.
    pub(super) fn recover(
        &self,
        f: &LocalFactors,
        x_r: &[f64],
        b: &mut [f64],
        transpose: bool,
        threads: usize,
    ) {
        let v = f.transposed_coupling.as_ref().filter(|_| transpose);
        let b_read: &[f64] = b;
        // x_I of the groups `groups`, in their order (one block per half).
        let interior_values = |groups: std::ops::Range<usize>| {
            let offsets = &self.groups.offsets;
            let mut out = Vec::with_capacity(offsets[groups.end] - offsets[groups.start]);
            let (mut b_i, mut x_b) = ([0.0; MAX_INLINE], Vec::new());
            for g in groups {
                let (interior, boundary) = (self.groups.group(g), self.boundary_of(g));
                let (p, q) = (interior.len(), boundary.len());
                let inv = &f.inverse[self.inverse_offsets[g]..self.inverse_offsets[g + 1]];
                let range = self.coupling_offsets[g]..self.coupling_offsets[g + 1];
                let b_i = gather(interior, b_read, &mut b_i);
                x_b.clear();
                x_b.extend(boundary.iter().map(|&r| x_r[r]));
                for i in 0..p {
                    let (local, coupled) = match (transpose, v) {
                        (false, _) => (
                            dot(&inv[i * p..(i + 1) * p], b_i),
                            dot(&f.coupling[range.clone()][i * q..(i + 1) * q], &x_b),
                        ),
                        (true, v) => (
                            (0..p).map(|l| inv[l * p + i] * b_i[l]).sum(),
                            match v {
                                Some(v) => {
                                    (0..q).map(|r| v[range.start + r * p + i] * x_b[r]).sum()
                                }
                                None => dot(&f.coupling[range.clone()][i * q..(i + 1) * q], &x_b),
                            },
                        ),
                    };
                    out.push(local - coupled);
                }
            }
            vec![out]
        };
        let blocks = in_column_halves(
            &self.coupling_offsets,
            threads,
            interior_values,
            |mut a, b| {
                a.extend(b);
                a
            },
        );
        for (&u, &x) in self.groups.indices.iter().zip(blocks.iter().flatten()) {
            b[u] = x;
        }
        for (&i, &x) in self.remaining.iter().zip(x_r) {
            b[i] = x;
        }
    }
}

/// A sparse column of A condensed ([`CondensationPlan::condense_sparse`]).
pub(super) struct CondensedColumn {
    /// b̃ = b_R − A_RI A_II⁻¹ b_I, as (S index, value).
    pub(super) remaining: Vec<(usize, f64)>,
    /// A_II⁻¹ b_I, as (A index, value).
    pub(super) interior: Vec<(usize, f64)>,
}

/// Entries sorted by index, those of one index summed.
fn summed(mut entries: Vec<(usize, f64)>) -> Vec<(usize, f64)> {
    entries.sort_unstable_by_key(|e| e.0);
    let mut out: Vec<(usize, f64)> = Vec::with_capacity(entries.len());
    for (i, value) in entries {
        match out.last_mut() {
            Some((last, sum)) if *last == i => *sum += value,
            _ => out.push((i, value)),
        }
    }
    out
}

/// Unknowns per group at most: a group is one element's interior (the
/// shell's have 5 or 7), and its values are copied to the stack.
const MAX_INLINE: usize = 16;

/// b at `indices` (at most [`MAX_INLINE`], checked by the plan), copied
/// into `buffer`.
fn gather<'a>(indices: &[usize], b: &[f64], buffer: &'a mut [f64; MAX_INLINE]) -> &'a [f64] {
    assert!(
        indices.len() <= MAX_INLINE,
        "interior groups of at most {MAX_INLINE} unknowns (checked by the plan)"
    );
    for (slot, &i) in buffer.iter_mut().zip(indices) {
        *slot = b[i];
    }
    &buffer[..indices.len()]
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Buffers of the small dense inversions, reused across groups.
#[derive(Default)]
struct DenseScratch {
    /// One column of a group's Schur term A_RI W.
    term: Vec<f64>,
    lu: Vec<f64>,
    row_scale: Vec<f64>,
    col_scale: Vec<f64>,
    perm: Vec<usize>,
}

impl DenseScratch {
    /// The inverse of the p×p matrix `entry(r, c)` into `inverse`
    /// (row-major): equilibrated (three Ruiz sweeps, so that the condition
    /// check judges the block and not its units), LU with partial pivoting,
    /// then A⁻¹ = C (R A C)⁻¹ R. Err: why the block is refused.
    fn invert(
        &mut self,
        p: usize,
        entry: impl Fn(usize, usize) -> f64,
        inverse: &mut [f64],
    ) -> std::result::Result<(), String> {
        let (lu, rs, cs) = (&mut self.lu, &mut self.row_scale, &mut self.col_scale);
        lu.clear();
        lu.extend((0..p * p).map(|k| entry(k / p, k % p)));
        if let Some(k) = lu.iter().position(|v| !v.is_finite()) {
            return Err(format!("has a non-finite entry ({}, {})", k / p, k % p));
        }
        rs.clear();
        rs.resize(p, 1.0);
        cs.clear();
        cs.resize(p, 1.0);
        for _ in 0..3 {
            for (r, scale) in rs.iter_mut().enumerate() {
                let m = (0..p).fold(0.0f64, |m, c| m.max(lu[r * p + c].abs()));
                if m > 0.0 {
                    *scale /= m.sqrt();
                    (0..p).for_each(|c| lu[r * p + c] /= m.sqrt());
                }
            }
            for (c, scale) in cs.iter_mut().enumerate() {
                let m = (0..p).fold(0.0f64, |m, r| m.max(lu[r * p + c].abs()));
                if m > 0.0 {
                    *scale /= m.sqrt();
                    (0..p).for_each(|r| lu[r * p + c] /= m.sqrt());
                }
            }
        }
        let norm1 = (0..p)
            .map(|c| (0..p).map(|r| lu[r * p + c].abs()).sum::<f64>())
            .fold(0.0, f64::max);
        let perm = &mut self.perm;
        perm.clear();
        perm.extend(0..p);
        for k in 0..p {
            let pivot = (k..p)
                .max_by(|&a, &b| lu[a * p + k].abs().total_cmp(&lu[b * p + k].abs()))
                .expect("k < p");
            if lu[pivot * p + k] == 0.0 {
                return Err("is singular (a zero pivot in LU with partial pivoting)".into());
            }
            if pivot != k {
                for c in 0..p {
                    lu.swap(k * p + c, pivot * p + c);
                }
                perm.swap(k, pivot);
            }
            let d = lu[k * p + k];
            for r in k + 1..p {
                let factor = lu[r * p + k] / d;
                lu[r * p + k] = factor;
                for c in k + 1..p {
                    lu[r * p + c] -= factor * lu[k * p + c];
                }
            }
        }
        // Columns of the inverse of the scaled block: solve L U y = P e_c.
        let mut y = vec![0.0; p];
        for c in 0..p {
            for r in 0..p {
                let mut v = if perm[r] == c { 1.0 } else { 0.0 };
                for l in 0..r {
                    v -= lu[r * p + l] * y[l];
                }
                y[r] = v;
            }
            for r in (0..p).rev() {
                let mut v = y[r];
                for l in r + 1..p {
                    v -= lu[r * p + l] * y[l];
                }
                y[r] = v / lu[r * p + r];
            }
            // (R A C)⁻¹ column c → A⁻¹[r][c] = C_r y_r R_c.
            for r in 0..p {
                inverse[r * p + c] = cs[r] * y[r] * rs[c];
            }
        }
        let inverse_norm1 = (0..p)
            .map(|c| {
                (0..p)
                    .map(|r| (inverse[r * p + c] / (cs[r] * rs[c])).abs())
                    .sum::<f64>()
            })
            .fold(0.0, f64::max);
        let condition = norm1 * inverse_norm1;
        if !(condition.is_finite() && condition <= MAX_LOCAL_CONDITION) {
            return Err(format!(
                "is singular or nearly so (condition number {condition:.2e} after equilibration, above {MAX_LOCAL_CONDITION:.0e})"
            ));
        }
        Ok(())
    }
}
