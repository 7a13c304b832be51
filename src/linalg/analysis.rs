//! The analysis phase: what depends on a matrix's pattern only. The
//! fill-reducing orderings (AMD, or the multipliers after their primal
//! neighbours), faer's symbolic factorisations, the pattern a factoriser
//! checks each matrix against ([`AnalysedPattern`]), and the matrix's
//! pattern in the factor's order ([`OrderedPattern`]), made once per
//! analysis.

use super::kernels::{in_two_halves, two_threads, PARALLEL_ENTRIES};
use super::tree_ldlt::TreeSchedule;
use super::{MatrixKind, Solves};
use crate::error::{Error, Result};
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::perm::PermRef;
use faer::sparse::linalg::amd;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, SymbolicCholesky, SymbolicCholeskyRaw, SymmetricOrdering,
};
use faer::sparse::linalg::solvers::{SymbolicLlt, SymbolicLu};
use faer::sparse::{
    FaerError, SparseColMat, SparseColMatRef, SymbolicSparseColMat, SymbolicSparseColMatRef,
};
use faer::Side;
use std::sync::Arc;
/// The symbolic LU analysis of `a`'s pattern.
pub(super) fn lu_analysis(a: &SparseColMat<usize, f64>, what: &str) -> Result<SymbolicAnalysis> {
    SymbolicLu::try_new(a.symbolic())
        .map(SymbolicAnalysis::Lu)
        .map_err(|e| Error::numerical(what, "LU (symbolic)", format!("{e:?}")))
}

/// The symbolic analysis of a factorisation, by kind.
pub(super) enum SymbolicAnalysis {
    Lu(SymbolicLu<usize>),
    Ldlt {
        analysis: LdltAnalysis,
        n_primal: usize,
        /// The order it was analysed for ([`Solves`]).
        order: Solves,
    },
    Llt(SymbolicLlt<usize>),
}

/// What every numeric LDLᵀ of one pattern reads.
pub(super) struct LdltAnalysis {
    pub(super) symbolic: Arc<SymbolicCholesky<usize>>,
    /// The two threads' split of a supernodal analysis ([`two_threads`]).
    pub(super) schedule: Option<Arc<TreeSchedule>>,
    /// Where the matrix's entries go in that order.
    pub(super) ordered: OrderedPattern,
}

/// The pattern a [`ReusableFactorization`] was analysed for, as its
/// refactorisations check it: kept whole when a condensed factorisation's
/// refinement reads A's values on it (a general matrix), else only its
/// fingerprint. The copy was the largest avoidable array of the shell's
/// active set at n = 256 (75M row indices of the Newton matrix, 0.6 GB).
pub(super) enum AnalysedPattern {
    Kept(Arc<SymbolicSparseColMat<usize>>),
    /// Order and a 64-bit hash of the column lengths and row indices:
    /// a different pattern passes only on a hash collision (the check is
    /// against calling with the wrong matrix, not against an adversary).
    Fingerprint {
        nrows: usize,
        ncols: usize,
        hash: u64,
    },
}

impl AnalysedPattern {
    pub(super) fn of(a: &SparseColMat<usize, f64>, kind: MatrixKind, threads: usize) -> Self {
        match kind {
            MatrixKind::General => AnalysedPattern::Kept(Arc::new(pattern_of(a))),
            _ => AnalysedPattern::Fingerprint {
                nrows: a.nrows(),
                ncols: a.ncols(),
                hash: pattern_hash(a, threads),
            },
        }
    }

    /// Whether `a` has the pattern (compared column by column when kept:
    /// no copy of `a`'s pattern, which is as large as A's values).
    pub(super) fn matches(&self, a: &SparseColMat<usize, f64>, threads: usize) -> bool {
        match self {
            AnalysedPattern::Kept(pattern) => {
                a.nrows() == pattern.nrows()
                    && a.ncols() == pattern.ncols()
                    && (0..a.ncols()).all(|j| {
                        a.symbolic().row_idx_of_col_raw(j) == pattern.row_idx_of_col_raw(j)
                    })
            }
            &AnalysedPattern::Fingerprint { nrows, ncols, hash } => {
                a.nrows() == nrows && a.ncols() == ncols && pattern_hash(a, threads) == hash
            }
        }
    }

    pub(super) fn nrows(&self) -> usize {
        match self {
            AnalysedPattern::Kept(pattern) => pattern.nrows(),
            AnalysedPattern::Fingerprint { nrows, .. } => *nrows,
        }
    }
}

/// A 64-bit hash of `a`'s pattern: every column's length and the first
/// half of the row indices (column by column), then the second half
/// ([`PatternHasher`]); the halves hash on two threads when factorisations
/// have two ([`two_threads`]) and the pattern is large: the hash is the
/// same either way.
pub(super) fn pattern_hash(a: &SparseColMat<usize, f64>, threads: usize) -> u64 {
    let s = a.symbolic();
    let mut first = PatternHasher::default();
    for j in 0..a.ncols() {
        first.push(s.row_idx_of_col_raw(j).len());
    }
    let rows: std::borrow::Cow<'_, [usize]> = match s.col_nnz() {
        // Compressed: the row indices are one slice.
        None => std::borrow::Cow::Borrowed(&s.row_idx()[..s.col_ptr()[a.ncols()]]),
        Some(_) => (0..a.ncols())
            .flat_map(|j| s.row_idx_of_col_raw(j).iter().copied())
            .collect(),
    };
    let (head, tail) = rows.split_at(rows.len() / 2);
    let hash_tail = || {
        let mut h = PatternHasher::default();
        h.extend(tail);
        h.finish()
    };
    let tail_hash = match two_threads(threads) && rows.len() >= PARALLEL_ENTRIES {
        true => std::thread::scope(|scope| {
            let tail_hash = scope.spawn(hash_tail);
            first.extend(head);
            tail_hash.join().expect("the pattern hash's second thread")
        }),
        false => {
            first.extend(head);
            hash_tail()
        }
    };
    PatternHasher::step(first.finish(), tail_hash as usize)
}

/// FxHash's multiply-rotate step dealt round-robin to four independent
/// chains: one chain waits for a multiply per value (the shell's n = 128
/// Newton matrix: 37 ms of every Newton step with the entry check), four
/// run at memory speed. The hash depends on the sequence only, not on how
/// it is cut into `extend` calls.
#[derive(Default)]
pub(super) struct PatternHasher {
    pub(super) lanes: [u64; 4],
    pub(super) pushed: usize,
}

impl PatternHasher {
    pub(super) fn step(h: u64, x: usize) -> u64 {
        (h.rotate_left(5) ^ x as u64).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95)
    }

    pub(super) fn push(&mut self, x: usize) {
        let lane = self.pushed % 4;
        self.lanes[lane] = Self::step(self.lanes[lane], x);
        self.pushed += 1;
    }

    pub(super) fn extend(&mut self, values: &[usize]) {
        let head = ((4 - self.pushed % 4) % 4).min(values.len());
        values[..head].iter().for_each(|&x| self.push(x));
        let mut blocks = values[head..].chunks_exact(4);
        for block in &mut blocks {
            for (lane, &x) in self.lanes.iter_mut().zip(block) {
                *lane = Self::step(*lane, x);
            }
        }
        self.pushed += 4 * ((values.len() - head) / 4);
        blocks.remainder().iter().for_each(|&x| self.push(x));
    }

    pub(super) fn finish(&self) -> u64 {
        let mixed = self.lanes.iter().fold(0, |h, &l| Self::step(h, l as usize));
        Self::step(mixed, self.pushed)
    }
}

/// The pattern of `a` in compact form.
pub(super) fn pattern_of(a: &SparseColMat<usize, f64>) -> SymbolicSparseColMat<usize> {
    let s = a.symbolic();
    let mut col_ptr = Vec::with_capacity(a.ncols() + 1);
    let mut row_idx = Vec::with_capacity(a.val().len());
    col_ptr.push(0);
    for j in 0..a.ncols() {
        row_idx.extend(s.row_idx_of_col(j));
        col_ptr.push(row_idx.len());
    }
    SymbolicSparseColMat::new_checked(a.nrows(), a.ncols(), col_ptr, None, row_idx)
}

/// The LDLᵀ analysis in the ordering `solves` asks for, with its two
/// threads' schedule when supernodal and this thread factorises on two
/// ([`two_threads`]).
pub(super) fn ldlt_analysis(
    a: &SparseColMat<usize, f64>,
    n_primal: usize,
    solves: Solves,
    what: &str,
    threads: usize,
) -> Result<SymbolicAnalysis> {
    let symbolic = analyze_symmetric(a, n_primal, solves, what)?;
    let schedule = match symbolic.raw() {
        SymbolicCholeskyRaw::Supernodal(raw) if two_threads(threads) => {
            TreeSchedule::new(raw).map(Arc::new)
        }
        _ => None,
    };
    let ordered = OrderedPattern::new(&symbolic, a, n_primal, schedule.is_some());
    Ok(SymbolicAnalysis::Ldlt {
        analysis: LdltAnalysis {
            symbolic: Arc::new(symbolic),
            schedule,
            ordered,
        },
        n_primal,
        order: solves,
    })
}

/// The symbolic LDLᵀ analysis in the ordering `solves` asks for.
pub(super) fn analyze_symmetric(
    a: &SparseColMat<usize, f64>,
    n_primal: usize,
    solves: Solves,
    what: &str,
) -> Result<SymbolicCholesky<usize>> {
    let fail = |e: FaerError| Error::numerical(what, "LDLᵀ (symbolic)", format!("{e:?}"));
    match solves {
        Solves::Few => factorize_symbolic_cholesky(
            a.symbolic(),
            Side::Lower,
            SymmetricOrdering::Amd,
            Default::default(),
        ),
        Solves::Many => {
            let (fwd, inv) = multipliers_after_neighbours(a, n_primal).map_err(fail)?;
            factorize_symbolic_cholesky(
                a.symbolic(),
                Side::Lower,
                SymmetricOrdering::Custom(PermRef::new_checked(&fwd, &inv, a.nrows())),
                Default::default(),
            )
        }
    }
    .map_err(fail)
}

/// The AMD order of the symmetric pattern with every multiplier (index ≥
/// n_primal) moved right after the last of its primal neighbours: its
/// pivot is then the nonzero local Schur complement −b K⁻¹ bᵀ instead of 0.
/// Returns (forward, inverse), `forward[new] = old`.
pub(super) fn multipliers_after_neighbours(
    a: &SparseColMat<usize, f64>,
    n_primal: usize,
) -> std::result::Result<(Vec<usize>, Vec<usize>), FaerError> {
    let n = a.nrows();
    let (mut fwd, mut inv) = (vec![0usize; n], vec![0usize; n]);
    let mut buffer =
        MemBuffer::try_new(amd::order_maybe_unsorted_scratch::<usize>(n, a.val().len()))
            .map_err(|_| FaerError::OutOfMemory)?;
    amd::order_maybe_unsorted(
        &mut fwd,
        &mut inv,
        a.symbolic(),
        Default::default(),
        MemStack::new(&mut buffer),
    )?;
    // The AMD position of each multiplier's last primal neighbour, from
    // the entries of either triangle (the matrix may be its lower one).
    let mut last: Vec<Option<usize>> = vec![None; n];
    for j in 0..n {
        for i in a.symbolic().row_idx_of_col(j) {
            let (multiplier, primal) = match (i < n_primal, j < n_primal) {
                (true, false) => (j, i),
                (false, true) => (i, j),
                _ => continue,
            };
            last[multiplier] = last[multiplier].max(Some(inv[primal]));
        }
    }
    // Sort key: (position of the last primal neighbour, after the primal
    // unknown at that position, own AMD position).
    let mut order: Vec<(usize, bool, usize, usize)> = (0..n)
        .map(|j| match j < n_primal {
            true => (inv[j], false, inv[j], j),
            false => (last[j].unwrap_or(inv[j]), true, inv[j], j),
        })
        .collect();
    order.sort_unstable();
    for (new, &(_, _, _, old)) in order.iter().enumerate() {
        fwd[new] = old;
        inv[old] = new;
    }
    Ok((fwd, inv))
}

/// The pattern of P A Pᵀ as the numeric factorisation of a symbolic
/// analysis reads it (in its order P, on its side: supernodal lower,
/// simplicial upper; from A's lower triangle), and the signs in that order.
/// Computed once per analysis: each factorisation then only scatters
/// A's values (a counting sort of S's pattern per Newton step took 4.8 s
/// of the shell's n = 256 active set, 17 steps).
pub(super) struct OrderedPattern {
    /// P A Pᵀ's pattern, rows unsorted within a column: in each column the
    /// entries in the order A's columns give them.
    pub(super) pattern: SymbolicSparseColMat<usize>,
    /// The inverse order: `inverse[old] = new`.
    pub(super) inverse: Vec<usize>,
    /// Whether P A Pᵀ is read by its upper triangle (simplicial).
    pub(super) upper: bool,
    /// Per entry of P A Pᵀ, the position of its value in A: kept for the
    /// two threads' factorisation, which reads A's values through it
    /// ([`OrderedPattern::entries`]) instead of a scaled copy.
    pub(super) source: Option<Vec<u32>>,
    /// The signs of the regularisation in the order P.
    pub(super) signs: Vec<i8>,
}

impl OrderedPattern {
    /// The pattern of `a` (n_primal positive signs, then negative) in the
    /// order of `symbolic`, with the positions of A's values when `sources`
    /// (and they fit 32 bits).
    pub(super) fn new(
        symbolic: &SymbolicCholesky<usize>,
        a: &SparseColMat<usize, f64>,
        n_primal: usize,
        sources: bool,
    ) -> Self {
        let n = a.nrows();
        let (forward, inverse): (Vec<usize>, Vec<usize>) = match symbolic.perm() {
            Some(perm) => (perm.arrays().0.to_vec(), perm.arrays().1.to_vec()),
            None => ((0..n).collect(), (0..n).collect()),
        };
        let upper = matches!(symbolic.raw(), SymbolicCholeskyRaw::Simplicial(_));
        let mut ordered = OrderedPattern {
            pattern: SymbolicSparseColMat::new_checked(n, n, vec![0; n + 1], None, Vec::new()),
            inverse,
            upper,
            source: None,
            signs: forward
                .iter()
                .map(|&i| if i < n_primal { 1 } else { -1 })
                .collect(),
        };
        let mut counts = vec![0usize; n + 1];
        ordered.for_each_entry(a, |_, (_, c)| counts[c + 1] += 1);
        for c in 0..n {
            counts[c + 1] += counts[c];
        }
        let mut next = counts[..n].to_vec();
        let mut row_idx = vec![0; counts[n]];
        let sources = sources && a.val().len() <= u32::MAX as usize;
        let mut source = vec![0u32; if sources { counts[n] } else { 0 }];
        ordered.for_each_entry(a, |k, (r, c)| {
            row_idx[next[c]] = r;
            if sources {
                source[next[c]] = k as u32;
            }
            next[c] += 1;
        });
        ordered.pattern = SymbolicSparseColMat::new_unsorted_checked(n, n, counts, None, row_idx);
        ordered.source = sources.then_some(source);
        ordered
    }

    /// `visit(k, (row, column))` for every entry k of A's lower triangle,
    /// (row, column) its place in P A Pᵀ on the side read; A's columns in
    /// order.
    pub(super) fn for_each_entry(
        &self,
        a: &SparseColMat<usize, f64>,
        mut visit: impl FnMut(usize, (usize, usize)),
    ) {
        let (col_ptr, row_idx) = (a.symbolic().col_ptr(), a.symbolic().row_idx());
        for j in 0..a.ncols() {
            let pj = self.inverse[j];
            for k in col_ptr[j]..col_ptr[j + 1] {
                let i = row_idx[k];
                if i < j {
                    continue;
                }
                let pi = self.inverse[i];
                let place = match self.upper {
                    false => (pi.max(pj), pi.min(pj)),
                    true => (pi.min(pj), pi.max(pj)),
                };
                visit(k, place);
            }
        }
    }

    /// P (D A D) Pᵀ read through the positions of A's values (None
    /// without them): its entries are v (d_i d_j) as in
    /// [`OrderedPattern::equilibrated`], made where they are read; `norm`:
    /// the largest |v (d_i d_j)| when known.
    pub(super) fn entries<'a>(
        &'a self,
        a: &'a SparseColMat<usize, f64>,
        scale: &[f64],
        norm: Option<f64>,
        threads: usize,
    ) -> Option<OrderedEntries<'a>> {
        let source = self.source.as_deref()?;
        Some(OrderedEntries {
            pattern: self.pattern.as_ref(),
            source,
            values: a.val(),
            norm: norm.unwrap_or_else(|| equilibrated_norm(a, scale, threads)),
            scale: self.in_order(scale),
        })
    }

    /// `scale` in the order P.
    pub(super) fn in_order(&self, scale: &[f64]) -> Vec<f64> {
        let mut ordered = vec![0.0; scale.len()];
        for (&new, &d) in self.inverse.iter().zip(scale) {
            ordered[new] = d;
        }
        ordered
    }

    /// P (D A D) Pᵀ's values, A of this pattern, D = diag(`scale`): each
    /// entry v (d_i d_j), as faer's permutation and a scaling gave them.
    pub(super) fn equilibrated(
        &self,
        a: &SparseColMat<usize, f64>,
        scale: &[f64],
    ) -> OrderedMatrix<'_> {
        let (values, scale) = (a.val(), self.in_order(scale));
        let mut next = self.pattern.col_ptr()[..a.ncols()].to_vec();
        let mut ordered = vec![0.0; self.pattern.row_idx().len()];
        let mut norm = 0.0f64;
        // A's columns in order, as the pattern was made.
        self.for_each_entry(a, |k, (r, c)| {
            let v = values[k] * (scale[r] * scale[c]);
            ordered[next[c]] = v;
            next[c] += 1;
            norm = norm.max(v.abs());
        });
        OrderedMatrix {
            pattern: self,
            values: ordered,
            norm,
        }
    }
}

/// P (D A D) Pᵀ's values as a numeric factorisation reads them, on their
/// [`OrderedPattern`].
pub(super) struct OrderedMatrix<'p> {
    pub(super) pattern: &'p OrderedPattern,
    pub(super) values: Vec<f64>,
    /// max |v| of the values.
    pub(super) norm: f64,
}

impl OrderedMatrix<'_> {
    pub(super) fn as_ref(&self) -> SparseColMatRef<'_, usize, f64> {
        SparseColMatRef::new(self.pattern.pattern.as_ref(), &self.values)
    }
}

/// P (D A D) Pᵀ without a copy ([`OrderedPattern::entries`]): entry t
/// (row i, column j of the pattern) is `values[source[t]] scale[i]
/// scale[j]`.
pub(super) struct OrderedEntries<'a> {
    pub(super) pattern: SymbolicSparseColMatRef<'a, usize>,
    pub(super) source: &'a [u32],
    pub(super) values: &'a [f64],
    /// D in the order P.
    pub(super) scale: Vec<f64>,
    /// max |v| of the entries.
    pub(super) norm: f64,
}

/// max |v (d_i d_j)| over A's lower triangle, D = diag(`scale`): the
/// largest entry of D A D, on two threads as the equilibration.
pub(super) fn equilibrated_norm(
    a: &SparseColMat<usize, f64>,
    scale: &[f64],
    threads: usize,
) -> f64 {
    let (col_ptr, row_idx, values) = (a.symbolic().col_ptr(), a.symbolic().row_idx(), a.val());
    let largest = |columns: std::ops::Range<usize>| {
        let mut norm = 0.0f64;
        for j in columns {
            let dj = scale[j];
            for k in col_ptr[j]..col_ptr[j + 1] {
                let i = row_idx[k];
                if i >= j {
                    norm = norm.max((values[k] * (scale[i] * dj)).abs());
                }
            }
        }
        norm
    };
    in_two_halves(a, threads, largest, f64::max)
}
