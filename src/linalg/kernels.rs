//! The sparse kernels the factorisations, their checks and the solvers
//! share: products (a symmetric matrix by its lower triangle too), norms,
//! entry filters, and the split of a large matrix's columns between two
//! threads.

use super::MatrixKind;
use faer::sparse::{SparseColMat, SparseColMatRef, SymbolicSparseColMat, Triplet};
use std::ops::Range;

/// The threads of the supernodal LDLᵀ factorisations and of the large
/// kernels (products, equilibration, entry checks, pattern fingerprints):
/// 1 (or 0) faer's sequential factorisation; 2 or more two threads on the
/// elimination tree (`tree_ldlt`), whose one-column solves use the same
/// split. Passed to each kernel by its caller, from [`LinearOptions`]
/// (`solver.threads`). Cholesky and LU are sequential: faer's own threads
/// lost on this 2-core machine (docs/work-precision.md, "Two threads on
/// the elimination tree").
pub(super) fn two_threads(threads: usize) -> bool {
    threads >= 2
}

/// `first()` here and `second()` on a second thread when `threads` allows
/// two, else one after the other; a panic of the second thread goes on
/// here.
pub fn beside<A, B: Send>(
    threads: usize,
    first: impl FnOnce() -> A,
    second: impl FnOnce() -> B + Send,
) -> (A, B) {
    if !two_threads(threads) {
        let a = first();
        return (a, second());
    }
    std::thread::scope(|scope| {
        let second = scope.spawn(second);
        let a = first();
        let b = second
            .join()
            .unwrap_or_else(|panic| std::panic::resume_unwind(panic));
        (a, b)
    })
}

/// Vectors of at least this many entries are worked on in two halves,
/// [0, n/2) and [n/2, n) ([`cut`]): on two threads when the caller allows
/// two, else one after the other. Sums add the two halves' sums, so the
/// numbers are the same on one thread or two. At 2¹⁶ entries a half takes
/// about 0.1 ms per pass, a second thread's start and join some 30 µs.
pub(crate) const HALVES_FROM: usize = 1 << 16;

/// Where the loops over a vector of n entries cut it: n/2, or n (not cut)
/// below [`HALVES_FROM`].
pub(crate) fn cut(n: usize) -> usize {
    match n >= HALVES_FROM {
        true => n / 2,
        false => n,
    }
}

/// `work(offset, part)` on `out[..m]` (offset 0) and `out[m..]` (offset
/// m), on two threads when `threads` allows two and the second part is not
/// empty; the parts' results combined in that order.
pub(crate) fn on_halves<T: Send, R: Send>(
    threads: usize,
    out: &mut [T],
    m: usize,
    work: impl Fn(usize, &mut [T]) -> R + Sync,
    combine: impl FnOnce(R, R) -> R,
) -> R {
    let (first, second) = out.split_at_mut(m);
    let threads = if second.is_empty() { 1 } else { threads };
    let (a, b) = beside(threads, || work(0, first), || work(m, second));
    combine(a, b)
}

/// [`on_halves`] over two slices of one length, both cut at m.
pub(crate) fn on_paired_halves<A: Send, B: Send, R: Send>(
    threads: usize,
    a: &mut [A],
    b: &mut [B],
    m: usize,
    work: impl Fn(usize, &mut [A], &mut [B]) -> R + Sync,
    combine: impl FnOnce(R, R) -> R,
) -> R {
    let (a_first, a_second) = a.split_at_mut(m);
    let (b_first, b_second) = b.split_at_mut(m);
    let threads = if a_second.is_empty() { 1 } else { threads };
    let (first, second) = beside(
        threads,
        || work(0, a_first, b_first),
        || work(m, a_second, b_second),
    );
    combine(first, second)
}

/// `out[i] = value(i)` for every i, in the halves of `out` ([`cut`]) on
/// `threads`.
pub(crate) fn each_in_halves<T: Send>(
    threads: usize,
    out: &mut [T],
    value: impl Fn(usize) -> T + Sync,
) {
    let m = cut(out.len());
    let part = |offset: usize, part: &mut [T]| {
        for (k, o) in part.iter_mut().enumerate() {
            *o = value(offset + k);
        }
    };
    on_halves(threads, out, m, part, |_, _| ());
}

/// `part` over [0, m) and [m, n) (m = [`cut`]), the two results combined
/// in that order.
pub(crate) fn over_halves<R: Send>(
    threads: usize,
    n: usize,
    part: impl Fn(Range<usize>) -> R + Sync,
    combine: impl FnOnce(R, R) -> R,
) -> R {
    let m = cut(n);
    let threads = if m == n { 1 } else { threads };
    let (a, b) = beside(threads, || part(0..m), || part(m..n));
    combine(a, b)
}

/// Σ `part(range)` over the halves ([`over_halves`]).
pub(crate) fn sum_halves(
    threads: usize,
    n: usize,
    part: impl Fn(Range<usize>) -> f64 + Sync,
) -> f64 {
    over_halves(threads, n, part, |a, b| a + b)
}

/// How a matrix given to this module is stored. Every factorisation of a
/// symmetric kind reads the lower triangle only (`Side::Lower`), so a
/// symmetric matrix may be given by its lower triangle alone (no stored
/// entry above the diagonal); its products then imply the upper one. Half
/// the memory: the active set's Newton matrix is given so.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Storage {
    Whole,
    LowerTriangle,
}

impl Storage {
    /// A matrix of a symmetric kind without an entry above the diagonal is
    /// its lower triangle; anything else is whole (a general matrix always).
    /// Read from each column's first row: rows are sorted within a column
    /// (faer's checked constructors and its triplet assembly sort them),
    /// so one look per column serves instead of a pass over every entry
    /// (each product with the problem's A asks).
    pub(super) fn of(a: SparseColMatRef<'_, usize, f64>, kind: MatrixKind) -> Self {
        let symbolic = a.symbolic();
        let lower = kind != MatrixKind::General
            && (0..a.ncols()).all(|j| symbolic.row_idx_of_col(j).next().is_none_or(|i| i >= j));
        debug_assert!(
            !lower || (0..a.ncols()).all(|j| symbolic.row_idx_of_col(j).all(|i| i >= j)),
            "row indices sorted within each column"
        );
        match lower {
            true => Storage::LowerTriangle,
            false => Storage::Whole,
        }
    }

    /// y = A x (a large lower triangle on `threads`).
    pub(super) fn product(
        self,
        a: SparseColMatRef<'_, usize, f64>,
        x: &[f64],
        threads: usize,
    ) -> Vec<f64> {
        let s = a.symbolic();
        match self {
            Storage::Whole => mat_vec_ref(a, x),
            Storage::LowerTriangle => lower_product(s.col_ptr(), s.row_idx(), a.val(), x, threads),
        }
    }

    /// |A| |x| (entries' absolute values).
    pub(super) fn absolute_product(
        self,
        a: SparseColMatRef<'_, usize, f64>,
        x: &[f64],
    ) -> Vec<f64> {
        let (s, values) = (a.symbolic(), a.val());
        let mut y = vec![0.0; a.nrows()];
        for (j, &xj) in x.iter().enumerate() {
            for k in s.col_ptr()[j]..s.col_ptr()[j + 1] {
                let (i, v) = (s.row_idx()[k], values[k].abs());
                y[i] += v * xj.abs();
                // The implied upper entry (j, i).
                if self == Storage::LowerTriangle && i > j {
                    y[j] += v * x[i].abs();
                }
            }
        }
        y
    }

    /// r = b − A x.
    pub(super) fn residual(
        self,
        a: SparseColMatRef<'_, usize, f64>,
        x: &[f64],
        b: &[f64],
        threads: usize,
    ) -> Vec<f64> {
        difference(b, &self.product(a, x, threads))
    }

    /// The matrix with both triangles (the lower triangle and its mirror),
    /// for LU, which reads every entry.
    pub(super) fn whole(
        self,
        a: &SparseColMat<usize, f64>,
    ) -> std::borrow::Cow<'_, SparseColMat<usize, f64>> {
        if self == Storage::Whole {
            return std::borrow::Cow::Borrowed(a);
        }
        let mut entries = Vec::with_capacity(2 * a.val().len());
        for j in 0..a.ncols() {
            for (i, &v) in a.symbolic().row_idx_of_col(j).zip(a.val_of_col(j)) {
                entries.push(Triplet::new(i, j, v));
                if i != j {
                    entries.push(Triplet::new(j, i, v));
                }
            }
        }
        let whole = SparseColMat::try_new_from_triplets(a.nrows(), a.ncols(), &entries)
            .expect("indices of a valid matrix");
        std::borrow::Cow::Owned(whole)
    }
}

/// A index stored in a column's row list (usize, or u32 where memory counts).
pub(super) trait RowIndex: Copy {
    fn get(self) -> usize;
}

impl RowIndex for usize {
    fn get(self) -> usize {
        self
    }
}

impl RowIndex for u32 {
    fn get(self) -> usize {
        self as usize
    }
}

/// y = A x for a symmetric A given by its lower triangle (CSC): each entry
/// below the diagonal is read once, for both of its places; entries above
/// the diagonal (there are none in this storage) would be ignored. A large
/// matrix on two threads ([`in_column_halves`]): the columns from j on
/// reach rows ≥ j only, so the second half sums into y[split..] alone,
/// added to the first half's y at the end (one sum per entry more than
/// in order: y agrees with the one-thread product to round-off).
pub(super) fn lower_product<R: RowIndex + Sync>(
    col_ptr: &[usize],
    rows: &[R],
    values: &[f64],
    x: &[f64],
    threads: usize,
) -> Vec<f64> {
    let n = x.len();
    // y[columns.start..] of the columns `columns`.
    let part = |columns: std::ops::Range<usize>| {
        let from = columns.start;
        let mut y = vec![0.0; n - from];
        for j in columns {
            let (range, xj) = (col_ptr[j]..col_ptr[j + 1], x[j]);
            let mut upper = 0.0;
            for (&i, &v) in rows[range.clone()].iter().zip(&values[range]) {
                let i = i.get();
                if i > j {
                    y[i - from] += v * xj;
                    upper += v * x[i];
                } else if i == j {
                    upper += v * xj;
                }
            }
            y[j - from] += upper;
        }
        y
    };
    in_column_halves(&col_ptr[..=n], threads, part, |mut first, second| {
        let from = n - second.len();
        first[from..]
            .iter_mut()
            .zip(&second)
            .for_each(|(a, b)| *a += b);
        first
    })
}

/// r = b − A x.
pub fn residual(a: &SparseColMat<usize, f64>, x: &[f64], b: &[f64]) -> Vec<f64> {
    difference(b, &mat_vec(a, x))
}

/// b − a.
pub(super) fn difference(b: &[f64], a: &[f64]) -> Vec<f64> {
    b.iter().zip(a).map(|(p, q)| p - q).collect()
}

/// Index of the first non-finite entry of `v`, if any.
pub fn first_non_finite(v: &[f64]) -> Option<usize> {
    // Blocks without an early exit (they vectorise), then the position.
    const BLOCK: usize = 256;
    let block = v
        .chunks(BLOCK)
        .position(|c| c.iter().fold(false, |bad, x| bad | !x.is_finite()))?;
    let start = block * BLOCK;
    v[start..]
        .iter()
        .position(|x| !x.is_finite())
        .map(|k| start + k)
}

/// a_jj of a matrix whose rows are sorted within each column (0 where not
/// stored).
pub(super) fn diagonal_entry(a: SparseColMatRef<'_, usize, f64>, j: usize) -> f64 {
    diagonal_position(a.symbolic().row_idx_of_col_raw(j), j).map_or(0.0, |p| a.val_of_col(j)[p])
}

/// Where row j is in column j's sorted `rows`: first in a lower triangle's.
pub(super) fn diagonal_position<R: RowIndex>(rows: &[R], j: usize) -> Option<usize> {
    match rows.first().map(|r| r.get()) == Some(j) {
        true => Some(0),
        false => rows.binary_search_by(|r| r.get().cmp(&j)).ok(),
    }
}

/// Matrices (and factors) with at least this many entries are checked,
/// equilibrated and solved with on two threads when factorisations have
/// two ([`two_threads`]).
pub(super) const PARALLEL_ENTRIES: usize = 1 << 20;

/// `work` over all of `a`'s columns: on two threads (each about half the
/// entries, the results combined) when factorisations have two and `a` is
/// large, else at once.
pub(super) fn in_two_halves<R: Send>(
    a: &SparseColMat<usize, f64>,
    threads: usize,
    work: impl Fn(std::ops::Range<usize>) -> R + Sync,
    combine: impl FnOnce(R, R) -> R,
) -> R {
    in_column_halves(a.symbolic().col_ptr(), threads, work, combine)
}

/// [`in_two_halves`] for the columns of a compressed pattern given by its
/// column pointers (`col_ptr[n]` = its number of entries).
pub(super) fn in_column_halves<R: Send>(
    col_ptr: &[usize],
    threads: usize,
    work: impl Fn(std::ops::Range<usize>) -> R + Sync,
    combine: impl FnOnce(R, R) -> R,
) -> R {
    let n = col_ptr.len() - 1;
    let Some(split) = column_halves(col_ptr, threads) else {
        return work(0..n);
    };
    let (first, second) = beside(threads, || work(0..split), || work(split..n));
    combine(first, second)
}

/// Where [`in_column_halves`] splits the columns of `col_ptr` (the
/// first column of the second half), or None when it works on one thread.
pub(super) fn column_halves(col_ptr: &[usize], threads: usize) -> Option<usize> {
    let n = col_ptr.len() - 1;
    let nnz = col_ptr[n];
    (two_threads(threads) && nnz >= PARALLEL_ENTRIES)
        .then(|| col_ptr.partition_point(|&p| p < nnz / 2).min(n))
}

/// y = A x.
pub fn mat_vec(a: &SparseColMat<usize, f64>, x: &[f64]) -> Vec<f64> {
    mat_vec_ref(a.as_ref(), x)
}

/// y = A x for a matrix of `kind` as this module reads it: a symmetric one
/// given by its lower triangle implies the upper one (`Storage`), a large
/// one multiplied on `threads` ([`two_threads`]).
pub fn product(
    a: &SparseColMat<usize, f64>,
    kind: MatrixKind,
    x: &[f64],
    threads: usize,
) -> Vec<f64> {
    Storage::of(a.as_ref(), kind).product(a.as_ref(), x, threads)
}

/// The lower triangle of `a` (its entries on and below the diagonal), made
/// in `a`'s own arrays: a symmetric matrix's storage that every
/// factorisation and [`product`] reads, at half the memory (the shell's A
/// at n = 256: 1.07 GB whole, 0.53 GB lower).
pub fn into_lower_triangle(a: SparseColMat<usize, f64>) -> SparseColMat<usize, f64> {
    let n = a.nrows();
    retain_entries(a, n, n, |i, j| i >= j)
}

/// The `nrows` × `ncols` matrix of the entries (i, j) of `a` with j <
/// `ncols` and `keep(i, j)` (each kept i < `nrows`), made in `a`'s own
/// arrays (entries only move towards the front; the arrays shrink to
/// fit): no second copy of `a` at any time.
pub fn retain_entries(
    a: SparseColMat<usize, f64>,
    nrows: usize,
    ncols: usize,
    keep: impl Fn(usize, usize) -> bool,
) -> SparseColMat<usize, f64> {
    let (symbolic, mut values) = a.into_parts();
    let (_, _, mut col_ptr, col_nnz, mut row_idx) = symbolic.into_parts();
    let mut kept = 0;
    for j in 0..ncols {
        let range = match &col_nnz {
            Some(nnz) => col_ptr[j]..col_ptr[j] + nnz[j],
            None => col_ptr[j]..col_ptr[j + 1],
        };
        col_ptr[j] = kept;
        for k in range {
            if keep(row_idx[k], j) {
                debug_assert!(row_idx[k] < nrows, "a kept row inside the result");
                (row_idx[kept], values[kept]) = (row_idx[k], values[k]);
                kept += 1;
            }
        }
    }
    col_ptr.truncate(ncols + 1);
    col_ptr[ncols] = kept;
    col_ptr.shrink_to_fit();
    row_idx.truncate(kept);
    values.truncate(kept);
    row_idx.shrink_to_fit();
    values.shrink_to_fit();
    let symbolic = SymbolicSparseColMat::new_checked(nrows, ncols, col_ptr, None, row_idx);
    SparseColMat::new(symbolic, values)
}

/// y = A x for a borrowed matrix.
pub(super) fn mat_vec_ref(a: SparseColMatRef<'_, usize, f64>, x: &[f64]) -> Vec<f64> {
    let mut y = vec![0.0; a.nrows()];
    let (cp, ri, val) = (a.symbolic().col_ptr(), a.symbolic().row_idx(), a.val());
    for j in 0..a.ncols() {
        let xj = x[j];
        if xj != 0.0 {
            for k in cp[j]..cp[j + 1] {
                y[ri[k]] += val[k] * xj;
            }
        }
    }
    y
}

/// y = Aᵀ x.
pub fn mat_t_vec(a: &SparseColMat<usize, f64>, x: &[f64]) -> Vec<f64> {
    let (cp, ri, val) = (a.symbolic().col_ptr(), a.symbolic().row_idx(), a.val());
    (0..a.ncols())
        .map(|j| (cp[j]..cp[j + 1]).map(|k| val[k] * x[ri[k]]).sum())
        .collect()
}

/// max |x_i|.
pub fn norm_inf(x: &[f64]) -> f64 {
    x.iter().fold(0.0, |m, v| m.max(v.abs()))
}

/// (Σ x_i²)^(1/2).
pub fn norm2(x: &[f64]) -> f64 {
    x.iter().map(|v| v * v).sum::<f64>().sqrt()
}
