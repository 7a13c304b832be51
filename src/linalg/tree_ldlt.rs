//! The numeric supernodal LDLᵀ with its elimination tree split between
//! two threads.
//!
//! faer's `factorize_supernodal_numeric_ldlt` is left-looking: it visits
//! the supernodes in order, and its `Par` reaches only the dense kernels
//! inside each one, so on this 2-core machine two threads lost (most
//! supernodes are small). Disjoint subtrees of the supernodal elimination
//! tree, though, never read each other's columns: here two threads factor
//! two sets of subtrees of about equal work ([`TreeSchedule`]), then the
//! supernodes above them (the top of the tree) are factored in order, the
//! updates each receives from its descendants split between the two (and
//! a wide one's dense LDLᵀ too, [`Shape::finish_on_two_threads`]). Each
//! supernode is computed as faer does it (same layout, same updates from
//! the same descendants, faer's dense LDLᵀ with the signed
//! regularisation), so faer's solves read the result; the descendants'
//! updates go through a gathered product instead of faer's crate-private
//! scatter kernel, and a wide top supernode's pivots are taken in blocks,
//! so values agree with faer's to round-off. One-column
//! solves run on the same split ([`solve_in_place`]), bit for bit faer's.
//! A matrix that differs from the last one factorised only in some columns
//! needs only the supernodes holding them and their ancestors computed
//! again ([`TreeSchedule::changed_supernodes`]): the rest of the factor
//! stays, bit for bit what a whole factorisation would give.

use super::OrderedEntries;
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::ldlt::factor::{
    cholesky_in_place, cholesky_in_place_scratch, LdltError, LdltRegularization,
};
use faer::linalg::matmul::triangular::{self, BlockStructure};
use faer::linalg::matmul::{matmul, matmul_with_conj};
use faer::linalg::triangular_solve::{
    solve_unit_lower_triangular_in_place, solve_unit_lower_triangular_in_place_with_conj,
    solve_unit_upper_triangular_in_place_with_conj,
};
use faer::reborrow::{Reborrow, ReborrowMut};
use faer::sparse::linalg::cholesky::supernodal::SymbolicSupernodalCholesky;
use faer::{Accum, Conj, MatMut, MatRef, Par};

/// Which supernodes each thread factors, and from which descendants every
/// supernode takes its updates.
#[derive(Debug)]
pub struct TreeSchedule {
    /// Per supernode: the thread (0, 1) whose subtrees hold it, or [`TOP`].
    owner: Vec<u8>,
    /// The supernodes above the subtrees, ascending.
    top: Vec<usize>,
    /// Descendants updating supernode s: `updates[update_ptr[s]..update_ptr[s + 1]]`,
    /// ascending (the order of faer's `row_major`).
    update_ptr: Vec<usize>,
    updates: Vec<usize>,
    /// The supernode of each column.
    supernode_of: Vec<usize>,
    /// Per supernode of a thread, where the rows of top supernodes begin
    /// in its pattern (they come after its own subtree's: ancestors in
    /// postorder).
    top_rows_from: Vec<usize>,
    /// Per supernode: its parent in the supernodal elimination tree
    /// (after it), or `usize::MAX` for a root.
    parent: Vec<usize>,
    /// Per supernode, the multiply–adds of factorising it: its
    /// descendants' updates and its dense LDLᵀ with the rows below.
    factor_work: Vec<f64>,
}

/// Subtrees are split off the top of the tree while that lowers the
/// estimated time max(bin) + top (in flops: Σ over columns of the column
/// count squared, the updates a column sends counted with it).
const MAX_SPLITS: usize = 64;
/// Update products with at least this many rows in the supernode compute
/// only the lower triangle of that block: faer's triangular product costs
/// more per call, and below it the whole block was faster (shell active
/// set, `obstacle bench case`, three runs each: n = 16 0.0282–0.0292 s
/// against 0.0306–0.0318 s triangular everywhere; n = 128 5.49–5.58 against
/// 5.69–5.72 s; n = 256 38.0 against 38.9 s).
const TRIANGLE_FROM: usize = 32;
/// A top supernode this wide or wider takes its dense LDLᵀ on two threads
/// ([`Shape::finish_on_two_threads`]), in blocks of [`TOP_BLOCK`] columns.
const TWO_THREAD_PIVOTS_FROM: usize = 512;
/// Columns per block there: the products of the update have 128 as their
/// inner size, and a block's own pivots (one thread) stay a small part.
const TOP_BLOCK: usize = 128;
/// The owner of a supernode above the subtrees.
const TOP: u8 = 2;

impl TreeSchedule {
    /// `None` when a supernode's parent does not come after it (then
    /// faer's own factorisation serves).
    pub fn new(symbolic: &SymbolicSupernodalCholesky<usize>) -> Option<Self> {
        let n_super = symbolic.n_supernodes();
        let (begin, end) = (symbolic.supernode_begin(), symbolic.supernode_end());
        let (pattern_ptr, rows) = (symbolic.col_ptr_for_row_idx(), symbolic.row_idx());
        let mut supernode_of = vec![0usize; symbolic.nrows()];
        for s in 0..n_super {
            supernode_of[begin[s]..end[s]].fill(s);
        }
        // Parent (the supernode of the first off-diagonal row), own work.
        let mut parent = vec![usize::MAX; n_super];
        let mut work = vec![0.0f64; n_super];
        for s in 0..n_super {
            let (w, below) = (end[s] - begin[s], pattern_ptr[s + 1] - pattern_ptr[s]);
            work[s] = (0..w).map(|k| ((w + below - k) as f64).powi(2)).sum();
            if below > 0 {
                parent[s] = supernode_of[rows[pattern_ptr[s]]];
                if parent[s] <= s {
                    return None;
                }
            }
        }
        let own = work.clone();
        let mut children: Vec<Vec<usize>> = vec![Vec::new(); n_super];
        for s in 0..n_super {
            if parent[s] != usize::MAX {
                work[parent[s]] += work[s];
                children[parent[s]].push(s);
            }
        }
        // Split off the top: always the heaviest subtree of the frontier.
        let mut frontier: Vec<usize> = (0..n_super).filter(|&s| parent[s] == usize::MAX).collect();
        let mut top: Vec<usize> = Vec::new();
        let mut top_work = 0.0;
        let mut best: Option<(f64, Vec<usize>, Vec<usize>)> = None;
        for _ in 0..MAX_SPLITS {
            frontier.sort_by(|x, y| work[*y].total_cmp(&work[*x]));
            let time = top_work + balanced(&frontier, &work).0;
            if best.as_ref().is_none_or(|(t, ..)| time < *t) {
                best = Some((time, frontier.clone(), top.clone()));
            }
            let heaviest = frontier[0];
            if children[heaviest].is_empty() {
                break;
            }
            frontier.remove(0);
            top.push(heaviest);
            top_work += own[heaviest];
            frontier.extend(children[heaviest].iter().copied());
        }
        let (_, frontier, mut top) = best?;
        let assignment = balanced(&frontier, &work).1;
        let mut owner = vec![TOP; n_super];
        for (&root, &bin) in frontier.iter().zip(&assignment) {
            let mut stack = vec![root];
            while let Some(s) = stack.pop() {
                owner[s] = bin as u8;
                stack.extend(children[s].iter().copied());
            }
        }
        top.sort_unstable();
        // The descendants updating each supernode (faer's row_major).
        let mut counts = vec![0usize; n_super + 1];
        let touched = |mut visit: Box<dyn FnMut(usize, usize) + '_>| {
            for d in 0..n_super {
                let mut last = usize::MAX;
                for &r in &rows[pattern_ptr[d]..pattern_ptr[d + 1]] {
                    let s = supernode_of[r];
                    if s != last {
                        visit(s, d);
                        last = s;
                    }
                }
            }
        };
        touched(Box::new(|s, _| counts[s + 1] += 1));
        for s in 0..n_super {
            counts[s + 1] += counts[s];
        }
        let mut next = counts.clone();
        let mut updates = vec![0usize; counts[n_super]];
        touched(Box::new(|s, d| {
            updates[next[s]] = d;
            next[s] += 1;
        }));
        let top_rows_from = (0..n_super)
            .map(|s| {
                let pattern = &rows[pattern_ptr[s]..pattern_ptr[s + 1]];
                pattern.partition_point(|&r| owner[supernode_of[r]] != TOP)
            })
            .collect();
        let factor_work = (0..n_super)
            .map(|s| {
                let shape = Shape::of(symbolic, s);
                let (w, below) = (shape.ncols as f64, (shape.nrows - shape.ncols) as f64);
                let updates = &updates[counts[s]..counts[s + 1]];
                w * w * (w / 3.0 + below)
                    + updates.iter().map(|&d| shape.update_work(d)).sum::<f64>()
            })
            .collect();
        Some(TreeSchedule {
            owner,
            top,
            update_ptr: counts,
            updates,
            supernode_of,
            top_rows_from,
            parent,
            factor_work,
        })
    }

    /// The estimated multiply–adds of a whole factorisation.
    pub fn whole_work(&self) -> f64 {
        self.factor_work.iter().sum()
    }

    /// Which supernodes a matrix that differs from the last one factorised
    /// only in the entries of `changed_columns` (in the analysis' order)
    /// must factorise anew: those holding such a column and their
    /// ancestors (every other supernode reads only columns that did not
    /// change, from descendants that did not either). Returns the flags
    /// and their fraction of the estimated work.
    pub fn changed_supernodes(
        &self,
        changed_columns: impl Iterator<Item = usize>,
    ) -> (Vec<bool>, f64) {
        let n_super = self.parent.len();
        let mut changed = vec![false; n_super];
        for c in changed_columns {
            changed[self.supernode_of[c]] = true;
        }
        // Parents come after their children: one ascending pass.
        for s in 0..n_super {
            if changed[s] && self.parent[s] != usize::MAX {
                changed[self.parent[s]] = true;
            }
        }
        let total = self.whole_work();
        let again: f64 = (0..n_super)
            .filter(|&s| changed[s])
            .map(|s| self.factor_work[s])
            .sum();
        (changed, if total > 0.0 { again / total } else { 1.0 })
    }

    fn updates_of(&self, s: usize) -> &[usize] {
        &self.updates[self.update_ptr[s]..self.update_ptr[s + 1]]
    }
}

/// The subtrees (heaviest first) in two bins, greedily: (the heavier
/// bin's work, each subtree's bin).
fn balanced(frontier: &[usize], work: &[f64]) -> (f64, Vec<usize>) {
    let mut bins = [0.0f64; 2];
    let assignment = frontier
        .iter()
        .map(|&s| {
            let b = if bins[0] <= bins[1] { 0 } else { 1 };
            bins[b] += work[s];
            b
        })
        .collect();
    (bins[0].max(bins[1]), assignment)
}

/// What every supernode's factorisation reads.
struct Inputs<'a> {
    symbolic: &'a SymbolicSupernodalCholesky<usize>,
    schedule: &'a TreeSchedule,
    a_lower: &'a OrderedEntries<'a>,
    regularization: &'a LdltRegularization<'a, f64>,
}

/// One thread's scratch: the global-to-local row map, the gathered
/// product and the dense LDLᵀ's stack.
struct Workspace {
    global_to_local: Vec<usize>,
    scaled: Vec<f64>,
    product: Vec<f64>,
    /// A descendant's rows (from the supernode's first column on) as local rows.
    local_rows: Vec<usize>,
    stack: MemBuffer,
}

/// `v` at least `len` long (new entries zero; old ones kept).
fn grow(v: &mut Vec<f64>, len: usize) {
    if v.len() < len {
        v.resize(len, 0.0);
    }
}

impl Workspace {
    fn new(symbolic: &SymbolicSupernodalCholesky<usize>) -> Self {
        let (begin, end) = (symbolic.supernode_begin(), symbolic.supernode_end());
        let widest = (0..symbolic.n_supernodes())
            .map(|s| end[s] - begin[s])
            .max()
            .unwrap_or(0);
        Workspace {
            global_to_local: vec![usize::MAX; symbolic.nrows()],
            scaled: Vec::new(),
            product: Vec::new(),
            local_rows: Vec::new(),
            stack: MemBuffer::new(cholesky_in_place_scratch::<f64>(
                widest,
                Par::Seq,
                Default::default(),
            )),
        }
    }
}

/// The numeric LDLᵀ of `a_lower` (in the symbolic analysis' order, lower
/// triangle) into `values` (faer's supernodal layout): two threads on the
/// subtrees of `schedule`, then the top supernodes in order, each with its
/// descendants' updates split between the two. With `only`, just the
/// supernodes it flags: `values` then holds the factor of a matrix that
/// differs from `a_lower` only in columns of flagged supernodes, with the
/// same regularisation ([`TreeSchedule::changed_supernodes`]), and the
/// others are kept as they are (the same operations on the same values:
/// the factor is the whole factorisation's bit for bit). Returns the
/// number of regularised pivots in the supernodes factorised.
pub fn factorize(
    values: &mut [f64],
    a_lower: &OrderedEntries<'_>,
    regularization: &LdltRegularization<'_, f64>,
    symbolic: &SymbolicSupernodalCholesky<usize>,
    schedule: &TreeSchedule,
    only: Option<&[bool]>,
) -> Result<usize, LdltError> {
    assert_eq!(values.len(), symbolic.len_val());
    let inputs = Inputs {
        symbolic,
        schedule,
        a_lower,
        regularization,
    };
    let value_ptr = symbolic.col_ptr_for_val();
    let again = |s: usize| only.is_none_or(|flags| flags[s]);
    // Each supernode's block of `values`, handed to the thread that owns it.
    let n_super = symbolic.n_supernodes();
    let mut blocks: [Vec<Option<&mut [f64]>>; 2] = [
        std::iter::repeat_with(|| None).take(n_super).collect(),
        std::iter::repeat_with(|| None).take(n_super).collect(),
    ];
    let mut rest: &mut [f64] = values;
    for s in 0..n_super {
        let (block, tail) = std::mem::take(&mut rest).split_at_mut(value_ptr[s + 1] - value_ptr[s]);
        if let Some(mine) = blocks.get_mut(schedule.owner[s] as usize) {
            mine[s] = Some(block);
        }
        rest = tail;
    }
    let [first, second] = blocks;
    let run_bin = |mut mine: Vec<Option<&mut [f64]>>| -> Result<usize, LdltError> {
        let mut ws = Workspace::new(symbolic);
        let mut count = 0;
        for s in 0..n_super {
            let (done, from_s) = mine.split_at_mut(s);
            let Some(ls) = from_s[0].as_deref_mut().filter(|_| again(s)) else {
                continue;
            };
            ls.fill(0.0);
            let block = |d: usize| -> &[f64] {
                done[d]
                    .as_deref()
                    .expect("a descendant in the same subtree")
            };
            count += factor_supernode(&inputs, s, ls, &block, &mut ws)?;
        }
        Ok(count)
    };
    let (a, b) = std::thread::scope(|scope| {
        let other = scope.spawn(|| run_bin(second));
        let mine = run_bin(first);
        (
            mine,
            other
                .join()
                .expect("the second factorisation thread panicked"),
        )
    });
    let mut count = a? + b?;
    let mut workspaces = [Workspace::new(symbolic), Workspace::new(symbolic)];
    let mut scratch = Vec::new();
    for &s in schedule.top.iter().filter(|&&s| again(s)) {
        let (done, from_s) = values.split_at_mut(value_ptr[s]);
        let ls = &mut from_s[..value_ptr[s + 1] - value_ptr[s]];
        ls.fill(0.0);
        let done: &[f64] = done;
        let block = |d: usize| -> &[f64] { &done[value_ptr[d]..value_ptr[d + 1]] };
        count += factor_top_supernode(&inputs, s, ls, &block, &mut workspaces, &mut scratch)?;
    }
    Ok(count)
}

/// Supernode s, faer's left-looking step: A's columns, the updates of
/// its descendants, the dense LDLᵀ of its diagonal block, the solve for
/// the rows below, into `ls_values` (s's block of the factor); `block(d)`
/// is descendant d's (already factored).
fn factor_supernode<'b>(
    inputs: &Inputs<'_>,
    s: usize,
    ls_values: &mut [f64],
    block: &dyn Fn(usize) -> &'b [f64],
    ws: &mut Workspace,
) -> Result<usize, LdltError> {
    let shape = Shape::of(inputs.symbolic, s);
    shape.map_rows(&mut ws.global_to_local);
    let mut ls = shape.matrix(ls_values);
    shape.add_columns_of_a(inputs.a_lower, &ws.global_to_local, ls.rb_mut());
    let updates = inputs.schedule.updates_of(s);
    shape.add_updates(updates, block, ws, ls.rb_mut());
    shape.unmap_rows(&mut ws.global_to_local);
    shape.finish(inputs.regularization, ls, &mut ws.stack)
}

/// A top supernode: as [`factor_supernode`], its descendants' updates
/// split between two threads (the second sums its half in `scratch`).
fn factor_top_supernode<'b>(
    inputs: &Inputs<'_>,
    s: usize,
    ls_values: &mut [f64],
    block: &(dyn Fn(usize) -> &'b [f64] + Sync),
    workspaces: &mut [Workspace; 2],
    scratch: &mut Vec<f64>,
) -> Result<usize, LdltError> {
    let shape = Shape::of(inputs.symbolic, s);
    let [ws, other_ws] = workspaces;
    shape.map_rows(&mut ws.global_to_local);
    shape.map_rows(&mut other_ws.global_to_local);
    let mut ls = shape.matrix(ls_values);
    shape.add_columns_of_a(inputs.a_lower, &ws.global_to_local, ls.rb_mut());
    // Halves of about equal work: the heaviest update first into the
    // lighter half, each half then in faer's (ascending) order. (Taking
    // every other one left the root's halves at 25 and 17 ms, shell
    // n = 128; so they are 21 and 21 ms.)
    let mut by_work: Vec<(f64, usize)> = inputs
        .schedule
        .updates_of(s)
        .iter()
        .map(|&d| (shape.update_work(d), d))
        .collect();
    by_work.sort_by(|x, y| y.0.total_cmp(&x.0));
    let (mut mine, mut theirs) = (Vec::new(), Vec::new());
    let mut loads = [0.0f64; 2];
    for (work, d) in by_work {
        let half = usize::from(loads[1] < loads[0]);
        loads[half] += work;
        [&mut mine, &mut theirs][half].push(d);
    }
    mine.sort_unstable();
    theirs.sort_unstable();
    scratch.clear();
    scratch.resize(shape.nrows * shape.ncols, 0.0);
    std::thread::scope(|scope| {
        let (scratch, other_ws) = (&mut *scratch, &mut *other_ws);
        let helper = scope.spawn(move || {
            let partial = shape.matrix(scratch);
            shape.add_updates(&theirs, block, other_ws, partial);
        });
        shape.add_updates(&mine, block, ws, ls.rb_mut());
        helper
            .join()
            .expect("the second factorisation thread panicked");
    });
    for (l, p) in ls.rb_mut().col_iter_mut().zip(scratch.chunks(shape.nrows)) {
        for (l, p) in l.iter_mut().zip(p) {
            *l += p;
        }
    }
    shape.unmap_rows(&mut ws.global_to_local);
    shape.unmap_rows(&mut other_ws.global_to_local);
    match shape.ncols >= TWO_THREAD_PIVOTS_FROM {
        true => shape.finish_on_two_threads(inputs.regularization, ls, &mut ws.stack, scratch),
        false => shape.finish(inputs.regularization, ls, &mut ws.stack),
    }
}

/// Supernode s's columns and rows.
#[derive(Clone, Copy)]
struct Shape<'a> {
    start: usize,
    end: usize,
    ncols: usize,
    nrows: usize,
    pattern: &'a [usize],
    symbolic: &'a SymbolicSupernodalCholesky<usize>,
}

impl<'a> Shape<'a> {
    fn of(symbolic: &'a SymbolicSupernodalCholesky<usize>, s: usize) -> Self {
        let (begin, end) = (symbolic.supernode_begin(), symbolic.supernode_end());
        let (pattern_ptr, rows) = (symbolic.col_ptr_for_row_idx(), symbolic.row_idx());
        let pattern = &rows[pattern_ptr[s]..pattern_ptr[s + 1]];
        let ncols = end[s] - begin[s];
        Shape {
            start: begin[s],
            end: end[s],
            ncols,
            nrows: pattern.len() + ncols,
            pattern,
            symbolic,
        }
    }

    fn matrix<'m>(&self, values: &'m mut [f64]) -> MatMut<'m, f64> {
        MatMut::from_column_major_slice_mut(values, self.nrows, self.ncols)
    }

    /// Rows below the diagonal block → their local row.
    fn map_rows(&self, global_to_local: &mut [usize]) {
        for (i, &row) in self.pattern.iter().enumerate() {
            global_to_local[row] = i + self.ncols;
        }
    }

    fn unmap_rows(&self, global_to_local: &mut [usize]) {
        for &row in self.pattern {
            global_to_local[row] = usize::MAX;
        }
    }

    fn local_row(&self, row: usize, global_to_local: &[usize]) -> usize {
        if row < self.end {
            row - self.start
        } else {
            global_to_local[row]
        }
    }

    /// A's lower-triangle entries of the supernode's columns.
    fn add_columns_of_a(
        &self,
        a: &OrderedEntries<'_>,
        global_to_local: &[usize],
        mut ls: MatMut<'_, f64>,
    ) {
        let (col_ptr, row_idx) = (a.pattern.col_ptr(), a.pattern.row_idx());
        for j in self.start..self.end {
            let dj = a.scale[j];
            for t in col_ptr[j]..col_ptr[j + 1] {
                let i = row_idx[t];
                if i >= j {
                    let v = a.values[a.source[t] as usize] * (a.scale[i] * dj);
                    ls[(self.local_row(i, global_to_local), j - self.start)] += v;
                }
            }
        }
    }

    /// Descendant d's rows from this supernode's first column on: (d's
    /// pattern, d's width, where those rows start in the pattern, how
    /// many fall in this supernode's columns, how many there are).
    fn reach(&self, d: usize) -> (&'a [usize], usize, usize, usize, usize) {
        let symbolic = self.symbolic;
        let (begin, end) = (symbolic.supernode_begin(), symbolic.supernode_end());
        let (pattern_ptr, rows) = (symbolic.col_ptr_for_row_idx(), symbolic.row_idx());
        let d_pattern = &rows[pattern_ptr[d]..pattern_ptr[d + 1]];
        let from = d_pattern.partition_point(|&r| r < self.start);
        let mid = d_pattern[from..].partition_point(|&r| r < self.end);
        (
            d_pattern,
            end[d] - begin[d],
            from,
            mid,
            d_pattern.len() - from,
        )
    }

    /// Descendant d's update in multiply–adds: its product (from
    /// [`TRIANGLE_FROM`] rows on, the top block's lower triangle and the rows
    /// below it) and its scatter.
    fn update_work(&self, d: usize) -> f64 {
        let (_, d_ncols, _, mid, below) = self.reach(d);
        let entries = match mid < TRIANGLE_FROM {
            true => below * mid,
            false => (below - mid) * mid + mid * (mid + 1) / 2,
        };
        entries as f64 * (d_ncols + 1) as f64
    }

    /// Ls −= L_d D_d L_dᵀ (its lower part) for each descendant d.
    fn add_updates<'b>(
        &self,
        updates: &[usize],
        block: &dyn Fn(usize) -> &'b [f64],
        ws: &mut Workspace,
        mut ls: MatMut<'_, f64>,
    ) {
        for &d in updates {
            let (d_pattern, d_ncols, from, mid, below) = self.reach(d);
            let ld = MatRef::from_column_major_slice(block(d), d_pattern.len() + d_ncols, d_ncols);
            let ld_mid_bot = ld.subrows(d_ncols + from, below);
            let ld_mid = ld_mid_bot.subrows(0, mid);
            // W = L_mid D (mid × d_ncols), then P = L_mid_bot Wᵀ (below × mid),
            // from TRIANGLE_FROM rows on of its top mid × mid block only the
            // lower triangle (the one scattered: the whole block made the
            // root's updates, a square block, twice their work; numeric LDLᵀ
            // of the shell's S at n = 256 1.68 → 1.52 s); the buffers only
            // grow (every entry used is written first).
            grow(&mut ws.scaled, mid * d_ncols);
            let mut w =
                MatMut::from_column_major_slice_mut(&mut ws.scaled[..mid * d_ncols], mid, d_ncols);
            for k in 0..d_ncols {
                let dk = ld[(k, k)];
                for i in 0..mid {
                    w[(i, k)] = ld_mid[(i, k)] * dk;
                }
            }
            grow(&mut ws.product, below * mid);
            let mut p =
                MatMut::from_column_major_slice_mut(&mut ws.product[..below * mid], below, mid);
            let w = MatRef::from_column_major_slice(&ws.scaled[..mid * d_ncols], mid, d_ncols);
            if mid < TRIANGLE_FROM {
                let p = p.rb_mut();
                matmul(p, Accum::Replace, ld_mid_bot, w.transpose(), 1.0, Par::Seq);
            } else {
                lower_trapezoid_product(p.rb_mut(), Accum::Replace, ld_mid_bot, w.transpose(), 1.0);
            }
            ws.local_rows.clear();
            ws.local_rows.extend(
                d_pattern[from..]
                    .iter()
                    .map(|&r| self.local_row(r, &ws.global_to_local)),
            );
            // Scatter-subtract the lower part, column by column.
            let (nrows, mut values) = (self.nrows, ls.rb_mut());
            for jj in 0..mid {
                let col = ws.local_rows[jj];
                let target = values
                    .rb_mut()
                    .col_mut(col)
                    .try_as_col_major_mut()
                    .expect("contiguous")
                    .as_slice_mut();
                debug_assert_eq!(target.len(), nrows);
                let source = &ws.product[jj * below..(jj + 1) * below];
                for (&row, &v) in ws.local_rows[jj..].iter().zip(&source[jj..]) {
                    target[row] -= v;
                }
            }
        }
    }

    /// The dense LDLᵀ of the diagonal block (signed regularisation), the
    /// rows below solved and scaled by D⁻¹: faer's layout.
    fn finish(
        &self,
        reg: &LdltRegularization<'_, f64>,
        mut ls: MatMut<'_, f64>,
        stack: &mut MemBuffer,
    ) -> Result<usize, LdltError> {
        let (mut ls_top, mut ls_bot) = ls.rb_mut().split_at_row_mut(self.ncols);
        let count = self.pivots(reg, 0, ls_top.rb_mut(), stack)?;
        solve_unit_lower_triangular_in_place(
            ls_top.rb(),
            ls_bot.rb_mut().transpose_mut(),
            Par::Seq,
        );
        divide_columns_by_pivots(ls_top.rb(), ls_bot);
        Ok(count)
    }

    /// faer's dense LDLᵀ of the diagonal block of the supernode's columns
    /// from `first` on, `block` (its strictly upper part zeroed after):
    /// the number of regularised pivots.
    fn pivots(
        &self,
        reg: &LdltRegularization<'_, f64>,
        first: usize,
        mut block: MatMut<'_, f64>,
        stack: &mut MemBuffer,
    ) -> Result<usize, LdltError> {
        let (from, width) = (self.start + first, block.ncols());
        let count = match cholesky_in_place(
            block.rb_mut(),
            LdltRegularization {
                dynamic_regularization_signs: reg
                    .dynamic_regularization_signs
                    .map(|signs| &signs[from..from + width]),
                dynamic_regularization_delta: reg.dynamic_regularization_delta,
                dynamic_regularization_epsilon: reg.dynamic_regularization_epsilon,
            },
            Par::Seq,
            MemStack::new(stack),
            Default::default(),
        ) {
            Ok(info) => info.dynamic_regularization_count,
            Err(LdltError::ZeroPivot { index }) => {
                return Err(LdltError::ZeroPivot {
                    index: index + from,
                })
            }
        };
        for j in 0..width {
            for i in 0..j {
                block[(i, j)] = 0.0;
            }
        }
        Ok(count)
    }

    /// [`Shape::finish`] on two threads, right-looking in blocks of
    /// [`TOP_BLOCK`] columns: a block's pivots on this thread, then its rows
    /// below solved (and its L D rows in the supernode's columns kept in
    /// `wt`, row-major) in two halves, then the columns after it updated in
    /// two parts of about equal work. The same factor as
    /// [`Shape::finish`] to round-off: a wide top supernode's dense LDLᵀ was
    /// the one step of a factorisation on one thread.
    fn finish_on_two_threads(
        &self,
        reg: &LdltRegularization<'_, f64>,
        mut ls: MatMut<'_, f64>,
        stack: &mut MemBuffer,
        wt: &mut Vec<f64>,
    ) -> Result<usize, LdltError> {
        let (nrows, ncols) = (self.nrows, self.ncols);
        let mut count = 0;
        let mut k0 = 0;
        while k0 < ncols {
            let k1 = (k0 + TOP_BLOCK).min(ncols);
            let nb = k1 - k0;
            let (left, right) = ls.rb_mut().split_at_col_mut(k1);
            let (diagonal, mut panel) = left
                .subcols_mut(k0, nb)
                .subrows_mut(k0, nrows - k0)
                .split_at_row_mut(nb);
            let mut diagonal = diagonal;
            count += self.pivots(reg, k0, diagonal.rb_mut(), stack)?;
            let diagonal = diagonal.rb();
            // The rows below: L D (their rows in the supernode's columns
            // into wt), then L.
            let in_columns = ncols - k1;
            wt.clear();
            wt.resize(in_columns * nb, 0.0);
            let half = (nrows - k1) / 2;
            let (upper, lower) = panel.rb_mut().split_at_row_mut(half);
            let (wt_upper, wt_lower) = wt.split_at_mut(half.min(in_columns) * nb);
            let solve_rows = |mut rows: MatMut<'_, f64>, wt: &mut [f64]| {
                solve_unit_lower_triangular_in_place(
                    diagonal,
                    rows.rb_mut().transpose_mut(),
                    Par::Seq,
                );
                for (i, w) in wt.chunks_exact_mut(nb).enumerate() {
                    for (k, w) in w.iter_mut().enumerate() {
                        *w = rows[(i, k)];
                    }
                }
                divide_columns_by_pivots(diagonal, rows);
            };
            std::thread::scope(|scope| {
                scope.spawn(|| solve_rows(lower, wt_lower));
                solve_rows(upper, wt_upper);
            });
            // The columns after the block: −L (L D)ᵀ, lower part.
            let (l, wt) = (
                panel.rb(),
                MatRef::from_row_major_slice(&wt[..], in_columns, nb),
            );
            let split = equal_work_split(nrows - k1, in_columns);
            let (first, second) = right.split_at_col_mut(split);
            let update = |columns: MatMut<'_, f64>, c0: usize| {
                let (width, rows) = (columns.ncols(), nrows - k1 - c0);
                lower_trapezoid_product(
                    columns.subrows_mut(k1 + c0, rows),
                    Accum::Add,
                    l.subrows(c0, rows),
                    wt.subrows(c0, width).transpose(),
                    -1.0,
                );
            };
            std::thread::scope(|scope| {
                scope.spawn(|| update(second, split));
                update(first, 0);
            });
            k0 = k1;
        }
        Ok(count)
    }
}

/// dst (rows × width, rows ≥ width) ← dst + alpha · lhs rhs (or without dst
/// for `Accum::Replace`), only the lower triangle of its top width × width
/// block and every row below it: the part of a symmetric update that is
/// kept.
fn lower_trapezoid_product(
    dst: MatMut<'_, f64>,
    accum: Accum,
    lhs: MatRef<'_, f64>,
    rhs: MatRef<'_, f64>,
    alpha: f64,
) {
    let (width, rows) = (dst.ncols(), dst.nrows());
    let (top, below) = dst.split_at_row_mut(width);
    triangular::matmul(
        top,
        BlockStructure::TriangularLower,
        accum,
        lhs.subrows(0, width),
        BlockStructure::Rectangular,
        rhs,
        BlockStructure::Rectangular,
        alpha,
        Par::Seq,
    );
    matmul(
        below,
        accum,
        lhs.subrows(width, rows - width),
        rhs,
        alpha,
        Par::Seq,
    );
}

/// The rows below a supernode's diagonal block times D⁻¹ (its pivots).
fn divide_columns_by_pivots(diagonal: MatRef<'_, f64>, mut rows: MatMut<'_, f64>) {
    for j in 0..diagonal.ncols() {
        let d = diagonal[(j, j)].recip();
        for i in 0..rows.nrows() {
            rows[(i, j)] *= d;
        }
    }
}

/// Where to split `columns` trailing columns of a lower-trapezoidal
/// block of `rows` rows so both parts hold about as many entries (column
/// c holds rows − c).
fn equal_work_split(rows: usize, columns: usize) -> usize {
    let total: usize = (0..columns).map(|c| rows - c).sum();
    let mut sum = 0;
    for c in 0..columns {
        if 2 * sum >= total {
            return c;
        }
        sum += rows - c;
    }
    columns
}

/// Solves L D Lᵀ x = b in place for one column (x in the analysis'
/// order), `values` the factor in faer's supernodal layout: faer's
/// sequential solve, each supernode's steps the same operations on the
/// same values, so x is faer's bit for bit. Forward, the two threads'
/// subtrees on two threads: an update of a row of the top is kept in the
/// thread's log and applied afterwards in supernode order (with the top
/// supernodes' own steps), as faer's loop applies them; backward, the top
/// first, then the subtrees on two threads (they only read the top).
pub fn solve_in_place(
    symbolic: &SymbolicSupernodalCholesky<usize>,
    values: &[f64],
    schedule: &TreeSchedule,
    x: &mut [f64],
) {
    let n_super = symbolic.n_supernodes();
    let (begin, end) = (symbolic.supernode_begin(), symbolic.supernode_end());
    let factor = |s: usize| Supernode::of(symbolic, values, s);
    // Forward: the subtrees, each thread on its own columns.
    let mut logs: [Vec<f64>; 2] = Default::default();
    {
        let [first, second] = split_columns(x, begin, end, schedule).0;
        let forward_bin = |mut mine: Vec<Option<&mut [f64]>>, log: &mut Vec<f64>| {
            let mut tmp = Vec::new();
            for s in 0..n_super {
                let (head, ancestors) = mine.split_at_mut(s + 1);
                let Some(x_s) = head[s].as_deref_mut() else {
                    continue;
                };
                let supernode = factor(s);
                supernode.forward(x_s, &mut tmp);
                let split = schedule.top_rows_from[s];
                for (&r, t) in supernode.pattern[..split].iter().zip(&tmp) {
                    let a = schedule.supernode_of[r];
                    let x_a = ancestors[a - s - 1]
                        .as_deref_mut()
                        .expect("an ancestor in the same subtree");
                    x_a[r - begin[a]] -= t;
                }
                log.extend_from_slice(&tmp[split..supernode.pattern.len()]);
                supernode.divide_by_d(x_s);
            }
        };
        let [log_first, log_second] = &mut logs;
        std::thread::scope(|scope| {
            scope.spawn(|| forward_bin(second, log_second));
            forward_bin(first, log_first);
        });
    }
    // The top's rows in supernode order: the logged updates, the top's steps.
    let (mut read, mut tmp) = ([0usize; 2], Vec::new());
    for s in 0..n_super {
        let supernode = factor(s);
        match schedule.owner[s] {
            TOP => {
                let x_s = &mut x[begin[s]..end[s]];
                supernode.forward(x_s, &mut tmp);
                supernode.divide_by_d(x_s);
                for (&r, t) in supernode.pattern.iter().zip(&tmp) {
                    x[r] -= t;
                }
            }
            bin => {
                let bin = bin as usize;
                let top_rows = &supernode.pattern[schedule.top_rows_from[s]..];
                let logged = &logs[bin][read[bin]..read[bin] + top_rows.len()];
                for (&r, t) in top_rows.iter().zip(logged) {
                    x[r] -= t;
                }
                read[bin] += top_rows.len();
            }
        }
    }
    drop(logs);
    // Backward: the top (its ancestors are top), then the subtrees.
    for &s in schedule.top.iter().rev() {
        let supernode = factor(s);
        tmp.clear();
        tmp.extend(supernode.pattern.iter().map(|&r| x[r]));
        supernode.backward(&mut x[begin[s]..end[s]], &tmp);
    }
    let ([first, second], top) = split_columns(x, begin, end, schedule);
    let backward_bin = |mut mine: Vec<Option<&mut [f64]>>| {
        let mut tmp = Vec::new();
        for s in (0..n_super).rev() {
            let (head, ancestors) = mine.split_at_mut(s + 1);
            let Some(x_s) = head[s].as_deref_mut() else {
                continue;
            };
            let supernode = factor(s);
            tmp.clear();
            tmp.extend(supernode.pattern.iter().map(|&r| {
                let a = schedule.supernode_of[r];
                let x_a = match schedule.owner[a] {
                    TOP => top[a],
                    _ => ancestors[a - s - 1].as_deref(),
                };
                x_a.expect("an ancestor in the subtree or the top")[r - begin[a]]
            }));
            supernode.backward(x_s, &tmp);
        }
    };
    std::thread::scope(|scope| {
        scope.spawn(|| backward_bin(second));
        backward_bin(first);
    });
}

/// G = Yᵀ D⁻¹ Y for Y = L⁻¹ B: the forward sweep of sparse columns B
/// (`columns[c]`: (row, value) in the factor's order) and their products
/// through D, that is Bᵀ (L D Lᵀ)⁻¹ B. Column c reaches only the supernodes
/// on the paths from its rows to the root, so each supernode sweeps the
/// block of the columns that reach it (one triangular solve and one
/// product for all of them): the work is the paths', not the whole
/// factor's. The two threads' subtrees sweep apart, then each top
/// supernode splits its columns between the threads. `None` when that
/// work, estimated before any as the time of the two threads (the larger
/// subtree bin and half the top), exceeds `max_work` (in the units of the
/// factorisation's own estimate, its multiply–adds). Returns G r × r,
/// column-major.
pub fn forward_gram(
    symbolic: &SymbolicSupernodalCholesky<usize>,
    values: &[f64],
    schedule: &TreeSchedule,
    columns: &[Vec<(usize, f64)>],
    max_work: f64,
) -> Option<Vec<f64>> {
    GramSweep::new(symbolic, values, schedule, columns).run(max_work, GRAM_SPLIT_MIN_WORK)
}

/// A top supernode's sweep splits its columns between the two threads
/// from this many multiply–adds on (below it a thread costs more than it
/// saves).
const GRAM_SPLIT_MIN_WORK: f64 = 1e6;

/// The columns of a Gram sweep and the supernodes each reaches.
struct GramSweep<'a> {
    symbolic: &'a SymbolicSupernodalCholesky<usize>,
    values: &'a [f64],
    schedule: &'a TreeSchedule,
    columns: &'a [Vec<(usize, f64)>],
    /// The columns reaching each supernode, ascending.
    reaching: Vec<Vec<usize>>,
}

/// One thread's view of the supernodes' column blocks (its w rows × k
/// reaching columns each, column-major; empty until written), its part of
/// G, and the sweep's buffers.
struct GramBlocks {
    blocks: Vec<Vec<f64>>,
    gram: Vec<f64>,
    below_x: Vec<f64>,
    through_d: Vec<f64>,
    product: Vec<f64>,
}

impl<'a> GramSweep<'a> {
    fn new(
        symbolic: &'a SymbolicSupernodalCholesky<usize>,
        values: &'a [f64],
        schedule: &'a TreeSchedule,
        columns: &'a [Vec<(usize, f64)>],
    ) -> Self {
        let n_super = symbolic.n_supernodes();
        let mut reaching: Vec<Vec<usize>> = vec![Vec::new(); n_super];
        let mut mark = vec![usize::MAX; n_super];
        for (c, column) in columns.iter().enumerate() {
            for &(row, _) in column {
                let mut s = schedule.supernode_of[row];
                while s != usize::MAX && mark[s] != c {
                    mark[s] = c;
                    reaching[s].push(c);
                    s = schedule.parent[s];
                }
            }
        }
        GramSweep {
            symbolic,
            values,
            schedule,
            columns,
            reaching,
        }
    }

    fn width(&self, s: usize) -> usize {
        self.symbolic.supernode_end()[s] - self.symbolic.supernode_begin()[s]
    }

    /// Supernode s's multiply–adds for its k reaching columns: the
    /// triangular solve and the product below (k w (w + below)), and the
    /// k × k products through D (k² w).
    fn work(&self, s: usize) -> f64 {
        let pattern_ptr = self.symbolic.col_ptr_for_row_idx();
        let (k, w) = (self.reaching[s].len() as f64, self.width(s) as f64);
        let below = (pattern_ptr[s + 1] - pattern_ptr[s]) as f64;
        k * w * (w + below + k)
    }

    /// Column c's place among those reaching supernode s.
    fn slot(&self, s: usize, c: usize) -> usize {
        self.reaching[s]
            .binary_search(&c)
            .expect("a column reaches every ancestor of its rows")
    }

    fn run(&self, max_work: f64, split_min_work: f64) -> Option<Vec<f64>> {
        let (r, n_super) = (self.columns.len(), self.reaching.len());
        let owner = &self.schedule.owner;
        let (mut bin_work, mut top_work) = ([0.0f64; 2], 0.0);
        for s in 0..n_super {
            match owner[s] {
                TOP => top_work += self.work(s),
                bin => bin_work[bin as usize] += self.work(s),
            }
        }
        if bin_work[0].max(bin_work[1]) + top_work / 2.0 > max_work {
            return None;
        }
        // B's entries into the blocks of the supernodes holding their rows.
        let begin = self.symbolic.supernode_begin();
        let empty = || GramBlocks {
            blocks: vec![Vec::new(); n_super],
            gram: vec![0.0; r * r],
            below_x: Vec::new(),
            through_d: Vec::new(),
            product: Vec::new(),
        };
        let (mut top, mut bins) = (empty(), [empty(), empty()]);
        for (c, column) in self.columns.iter().enumerate() {
            for &(row, v) in column {
                let s = self.schedule.supernode_of[row];
                let own = match owner[s] {
                    TOP => &mut top,
                    bin => &mut bins[bin as usize],
                };
                let slot = self.slot(s, c);
                self.block(&mut own.blocks, s)[row - begin[s] + slot * self.width(s)] += v;
            }
        }
        // The subtrees on a thread each; what they send to the top is
        // summed into its blocks after.
        let [mut first, mut second] = bins;
        std::thread::scope(|scope| {
            scope.spawn(|| self.sweep_bin(1, &mut second));
            self.sweep_bin(0, &mut first);
        });
        for bin in [first, second] {
            for (s, block) in bin.blocks.into_iter().enumerate() {
                if owner[s] == TOP && !block.is_empty() {
                    let target = self.block(&mut top.blocks, s);
                    target.iter_mut().zip(&block).for_each(|(t, b)| *t += b);
                }
            }
            top.gram
                .iter_mut()
                .zip(&bin.gram)
                .for_each(|(g, b)| *g += b);
        }
        for &s in &self.schedule.top {
            let parts = match self.work(s) >= split_min_work {
                true => 2,
                false => 1,
            };
            self.sweep(s, &mut top, parts);
        }
        Some(top.gram)
    }

    /// Supernode s's block in `blocks`, zero-filled at first use.
    fn block<'b>(&self, blocks: &'b mut [Vec<f64>], s: usize) -> &'b mut Vec<f64> {
        let block = &mut blocks[s];
        if block.is_empty() {
            block.resize(self.width(s) * self.reaching[s].len(), 0.0);
        }
        block
    }

    /// The supernodes of subtree bin `bin`, ascending (descendants first).
    fn sweep_bin(&self, bin: u8, own: &mut GramBlocks) {
        for s in 0..self.reaching.len() {
            if self.schedule.owner[s] == bin {
                self.sweep(s, own, 1);
            }
        }
    }

    /// Supernode s: X_s ← L_s⁻¹ X_s, G += X_sᵀ D_s⁻¹ X_s on its reaching
    /// columns, and −L_below X_s into its ancestors' blocks; the columns
    /// split into `parts` (1 or 2) solved on a thread each.
    fn sweep(&self, s: usize, own: &mut GramBlocks, parts: usize) {
        let k = self.reaching[s].len();
        if k == 0 {
            return;
        }
        let supernode = Supernode::of(self.symbolic, self.values, s);
        let (w, n_below) = (supernode.l.ncols(), supernode.pattern.len());
        let mut x = std::mem::take(self.block(&mut own.blocks, s));
        let GramBlocks {
            blocks,
            gram,
            below_x,
            through_d,
            product,
        } = own;
        below_x.resize(n_below * k, 0.0);
        let half = match parts {
            2 if k >= 2 => k / 2,
            _ => k,
        };
        let (x_first, x_second) = x.split_at_mut(w * half);
        let (below_first, below_second) = below_x.split_at_mut(n_below * half);
        if half == k {
            supernode.forward_into(x_first, below_first);
        } else {
            std::thread::scope(|scope| {
                scope.spawn(|| supernode.forward_into(x_second, below_second));
                supernode.forward_into(x_first, below_first);
            });
        }
        through_d.clone_from(&x);
        supernode.divide_by_d(through_d);
        let x = MatRef::from_column_major_slice(&x, w, k);
        let gram_columns = |product: &mut [f64], from: usize, to: usize| {
            matmul(
                MatMut::from_column_major_slice_mut(product, k, to - from),
                Accum::Replace,
                x.transpose(),
                MatRef::from_column_major_slice(&through_d[w * from..w * to], w, to - from),
                1.0,
                Par::Seq,
            )
        };
        product.resize(k * k, 0.0);
        if half == k {
            gram_columns(product, 0, k);
        } else {
            let (p_first, p_second) = product.split_at_mut(k * half);
            std::thread::scope(|scope| {
                scope.spawn(|| gram_columns(p_second, half, k));
                gram_columns(p_first, 0, half);
            });
        }
        let r = self.columns.len();
        for (q, &cq) in self.reaching[s].iter().enumerate() {
            for (p, &cp) in self.reaching[s].iter().enumerate() {
                gram[cp + cq * r] += product[p + q * k];
            }
        }
        // The rows below: −L_below X_s into the ancestors' blocks. The
        // pattern is ascending, so each ancestor's rows are one run.
        let begin = self.symbolic.supernode_begin();
        let mut run_start = 0;
        while run_start < n_below {
            let a = self.schedule.supernode_of[supernode.pattern[run_start]];
            let run_end = run_start
                + supernode.pattern[run_start..]
                    .iter()
                    .take_while(|&&row| self.schedule.supernode_of[row] == a)
                    .count();
            let w_a = self.width(a);
            for (p, &c) in self.reaching[s].iter().enumerate() {
                let q = self.slot(a, c);
                let target = &mut self.block(blocks, a)[q * w_a..(q + 1) * w_a];
                for t in run_start..run_end {
                    target[supernode.pattern[t] - begin[a]] -= below_x[t + p * n_below];
                }
            }
            run_start = run_end;
        }
    }
}

/// x's columns by supernode: each thread's (mutable), and the top's.
#[allow(clippy::type_complexity)]
fn split_columns<'x>(
    x: &'x mut [f64],
    begin: &[usize],
    end: &[usize],
    schedule: &TreeSchedule,
) -> ([Vec<Option<&'x mut [f64]>>; 2], Vec<Option<&'x [f64]>>) {
    let n_super = begin.len();
    let none = || {
        std::iter::repeat_with(|| None)
            .take(n_super)
            .collect::<Vec<_>>()
    };
    let (mut bins, mut top) = ([none(), none()], vec![None; n_super]);
    let mut rest = x;
    for s in 0..n_super {
        let (columns, tail) = std::mem::take(&mut rest).split_at_mut(end[s] - begin[s]);
        match schedule.owner[s] {
            TOP => top[s] = Some(&*columns),
            bin => bins[bin as usize][s] = Some(columns),
        }
        rest = tail;
    }
    (bins, top)
}

/// One supernode's factor block (faer's layout: the unit lower diagonal
/// block with D on its diagonal, then the rows of its pattern).
struct Supernode<'a> {
    l: MatRef<'a, f64>,
    pattern: &'a [usize],
}

impl<'a> Supernode<'a> {
    fn of(symbolic: &'a SymbolicSupernodalCholesky<usize>, values: &'a [f64], s: usize) -> Self {
        let shape = Shape::of(symbolic, s);
        let value_ptr = symbolic.col_ptr_for_val();
        Supernode {
            l: MatRef::from_column_major_slice(
                &values[value_ptr[s]..value_ptr[s + 1]],
                shape.nrows,
                shape.ncols,
            ),
            pattern: shape.pattern,
        }
    }

    /// x_s ← L_s⁻¹ x_s and tmp ← L_below x_s (faer's forward step), for
    /// the columns x_s holds (column-major, the supernode's width each).
    fn forward(&self, x_s: &mut [f64], tmp: &mut Vec<f64>) {
        tmp.resize(self.pattern.len() * (x_s.len() / self.l.ncols()), 0.0);
        self.forward_into(x_s, tmp);
    }

    /// [`Supernode::forward`] into `below`, of the pattern's length times
    /// x_s's columns.
    fn forward_into(&self, x_s: &mut [f64], below_x: &mut [f64]) {
        let ncols = self.l.ncols();
        let k = x_s.len() / ncols;
        let (diagonal, below) = self.l.split_at_row(ncols);
        let mut x_s = MatMut::from_column_major_slice_mut(x_s, ncols, k);
        solve_unit_lower_triangular_in_place_with_conj(diagonal, Conj::No, x_s.rb_mut(), Par::Seq);
        let product = MatMut::from_column_major_slice_mut(below_x, below.nrows(), k);
        matmul_with_conj(
            product,
            Accum::Replace,
            below,
            Conj::No,
            x_s.rb(),
            Conj::No,
            1.0,
            Par::Seq,
        );
    }

    /// x_s ← D⁻¹ x_s, as faer multiplies by each pivot's reciprocal, for
    /// the columns x_s holds.
    fn divide_by_d(&self, x_s: &mut [f64]) {
        for column in x_s.chunks_exact_mut(self.l.ncols()) {
            for (k, v) in column.iter_mut().enumerate() {
                *v *= self.l[(k, k)].recip();
            }
        }
    }

    /// x_s ← L_s⁻ᵀ (x_s − L_belowᵀ x_pattern) (faer's backward step).
    fn backward(&self, x_s: &mut [f64], x_pattern: &[f64]) {
        let ncols = self.l.ncols();
        let (diagonal, below) = self.l.split_at_row(ncols);
        let mut x_s = MatMut::from_column_major_slice_mut(x_s, ncols, 1);
        let gathered = MatRef::from_column_major_slice(x_pattern, below.nrows(), 1);
        matmul_with_conj(
            x_s.rb_mut(),
            Accum::Add,
            below.transpose(),
            Conj::Yes,
            gathered,
            Conj::No,
            -1.0,
            Par::Seq,
        );
        solve_unit_upper_triangular_in_place_with_conj(
            diagonal.transpose(),
            Conj::Yes,
            x_s,
            Par::Seq,
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::sparse::linalg::cholesky::{
        factorize_symbolic_cholesky, supernodal, CholeskySymbolicParams, SymbolicCholesky,
        SymbolicCholeskyRaw, SymmetricOrdering,
    };
    use faer::sparse::linalg::SupernodalThreshold;
    use faer::sparse::{SparseColMat, Triplet};
    use faer::Side;

    /// A k×k grid's 5-point Laplacian (+ a shift) bordered by multipliers,
    /// each coupling three neighbouring nodes with a −ε diagonal: its lower
    /// triangle and the number of primal unknowns.
    fn grid_saddle(k: usize) -> (SparseColMat<usize, f64>, usize) {
        let node = |i: usize, j: usize| i * k + j;
        let mut lower = Vec::new();
        for i in 0..k {
            for j in 0..k {
                lower.push(Triplet::new(node(i, j), node(i, j), 4.5));
                if i + 1 < k {
                    lower.push(Triplet::new(node(i + 1, j), node(i, j), -1.0));
                }
                if j + 1 < k {
                    lower.push(Triplet::new(node(i, j + 1), node(i, j), -1.0));
                }
            }
        }
        let mut m = k * k;
        for i in (0..k - 1).step_by(3) {
            for j in (0..k - 1).step_by(2) {
                for (c, w) in [
                    (node(i, j), 1.0),
                    (node(i + 1, j), 0.5),
                    (node(i, j + 1), 0.25),
                ] {
                    lower.push(Triplet::new(m, c, w));
                }
                lower.push(Triplet::new(m, m, -1e-3));
                m += 1;
            }
        }
        (
            SparseColMat::try_new_from_triplets(m, m, &lower).unwrap(),
            k * k,
        )
    }

    /// [`grid_saddle`]`(k)`, its supernodal AMD analysis and the two
    /// threads' split of its tree.
    fn analysed_grid_saddle(
        k: usize,
    ) -> (
        SparseColMat<usize, f64>,
        usize,
        SymbolicCholesky<usize>,
        TreeSchedule,
    ) {
        let (a, n_primal) = grid_saddle(k);
        let symbolic = supernodal_amd(&a);
        let schedule = TreeSchedule::new(supernodal_part(&symbolic))
            .expect("parents come after their children");
        (a, n_primal, symbolic, schedule)
    }

    /// The AMD analysis of `a`, supernodal whatever its size.
    fn supernodal_amd(a: &SparseColMat<usize, f64>) -> SymbolicCholesky<usize> {
        factorize_symbolic_cholesky(
            a.symbolic(),
            Side::Lower,
            SymmetricOrdering::Amd,
            CholeskySymbolicParams {
                supernodal_flop_ratio_threshold: SupernodalThreshold::FORCE_SUPERNODAL,
                ..Default::default()
            },
        )
        .unwrap()
    }

    /// The tests' signed regularisation (δ = 1e-12, ε = 1e-14).
    fn test_regularization(signs: &[i8]) -> LdltRegularization<'_, f64> {
        LdltRegularization {
            dynamic_regularization_signs: Some(signs),
            dynamic_regularization_delta: 1e-12,
            dynamic_regularization_epsilon: 1e-14,
        }
    }

    fn supernodal_part(symbolic: &SymbolicCholesky<usize>) -> &SymbolicSupernodalCholesky<usize> {
        let SymbolicCholeskyRaw::Supernodal(raw) = symbolic.raw() else {
            panic!("forced supernodal")
        };
        raw
    }

    /// A factorisation of the supernodes that changed multiplier diagonals
    /// reach, over the factor of the last matrix, is the whole
    /// factorisation of the new one bit for bit; it computes part of the
    /// work only, and the supernodes it keeps do differ from a factor of
    /// a matrix changed everywhere.
    #[test]
    fn refactorising_the_changed_supernodes_equals_the_whole_factorisation() {
        let (a, n_primal, symbolic, schedule) = analysed_grid_saddle(60);
        let (n, raw) = (a.nrows(), supernodal_part(&symbolic));
        let pattern = super::super::analysis::OrderedPattern::new(&symbolic, &a, n_primal, true);
        let regularization = test_regularization(&pattern.signs);
        let ones = vec![1.0; n];
        let whole = |a: &SparseColMat<usize, f64>| {
            let entries = pattern.entries(a, &ones, None, 2).expect("positions kept");
            let mut values = vec![f64::NAN; raw.len_val()];
            factorize(&mut values, &entries, &regularization, raw, &schedule, None).unwrap();
            values
        };
        // The multiplier diagonal (−1e-3) changed in the rows `rows`.
        let changed = |rows: &[usize], value: f64| {
            let mut b = a.clone();
            let (col_ptr, row_idx) = (
                a.symbolic().col_ptr().to_vec(),
                a.symbolic().row_idx().to_vec(),
            );
            for &i in rows {
                let k = (col_ptr[i]..col_ptr[i + 1])
                    .find(|&k| row_idx[k] == i)
                    .unwrap();
                b.val_mut()[k] = value;
            }
            b
        };
        let last = whole(&a);
        let rows = [n_primal, n_primal + 100, n - 1];
        let next = changed(&rows, -2e-3);
        let columns = rows.iter().map(|&i| pattern.inverse[i]);
        let (only, fraction) = schedule.changed_supernodes(columns);
        assert!(fraction > 0.0 && fraction < 0.9, "{fraction}");
        assert!(only.iter().any(|&f| !f) && only.iter().any(|&f| f));
        let mut partial = last.clone();
        let entries = pattern.entries(&next, &ones, None, 2).unwrap();
        factorize(
            &mut partial,
            &entries,
            &regularization,
            raw,
            &schedule,
            Some(&only),
        )
        .unwrap();
        let differing = |a: &[f64], b: &[f64]| {
            a.iter()
                .zip(b)
                .filter(|(x, y)| x.to_bits() != y.to_bits())
                .count()
        };
        assert_eq!(differing(&partial, &whole(&next)), 0);
        // The kept supernodes matter: with every multiplier changed, the
        // whole factor differs from the partial one.
        let all: Vec<usize> = (n_primal..n).collect();
        assert!(differing(&partial, &whole(&changed(&all, -2e-3))) > 0);
    }

    /// The forward sweeps of sparse columns over the paths they reach give
    /// Bᵀ (L D Lᵀ)⁻¹ B as whole solves do (to 1e-12 of its largest entry),
    /// for unit columns on multipliers and primal unknowns, a column with
    /// several rows and two sharing a row, with the top's supernodes on one
    /// thread or split between two; beyond the work bound, none.
    #[test]
    fn forward_sweeps_of_sparse_columns_give_their_inverse_products() {
        let (a, n_primal, symbolic, schedule) = analysed_grid_saddle(60);
        let (n, raw) = (a.nrows(), supernodal_part(&symbolic));
        let pattern = super::super::analysis::OrderedPattern::new(&symbolic, &a, n_primal, true);
        let entries = pattern.entries(&a, &vec![1.0; n], None, 2).unwrap();
        let regularization = test_regularization(&pattern.signs);
        let mut values = vec![f64::NAN; raw.len_val()];
        factorize(&mut values, &entries, &regularization, raw, &schedule, None).unwrap();
        let columns: Vec<Vec<(usize, f64)>> = vec![
            vec![(n_primal + 3, 1.0)],
            vec![(n - 1, 1.0)],
            vec![(17, 1.0)],
            vec![(5, 0.5), (n_primal / 2, -2.0), (n - 7, 1.5)],
            vec![(5, 1.0), (1200, 0.25)],
        ];
        let r = columns.len();
        let mut expected = vec![0.0; r * r];
        for (q, column_q) in columns.iter().enumerate() {
            let mut x = vec![0.0; n];
            for &(i, v) in column_q {
                x[i] += v;
            }
            solve_in_place(raw, &values, &schedule, &mut x);
            for (p, column_p) in columns.iter().enumerate() {
                expected[p + q * r] = column_p.iter().map(|&(i, v)| v * x[i]).sum();
            }
        }
        let scale = super::super::norm_inf(&expected);
        // Every top supernode on one thread, and each split in two.
        let sweep = GramSweep::new(raw, &values, &schedule, &columns);
        for split_min_work in [f64::INFINITY, 0.0] {
            let gram = sweep.run(f64::INFINITY, split_min_work).unwrap();
            let worst = super::super::norm_inf(&super::super::difference(&expected, &gram));
            assert!(
                worst <= 1e-12 * scale,
                "G differs by {worst:e} (scale {scale:e}, split from {split_min_work:e})"
            );
        }
        // A path is a small part of the factor; every column's path, more.
        let one = vec![columns[0].clone()];
        assert!(
            forward_gram(raw, &values, &schedule, &one, 0.05 * schedule.whole_work()).is_some()
        );
        let every: Vec<Vec<(usize, f64)>> = (0..n).map(|i| vec![(i, 1.0)]).collect();
        assert!(forward_gram(raw, &values, &schedule, &every, schedule.whole_work()).is_none());
    }

    /// Two threads on the tree give faer's supernodal factor to round-off
    /// (AMD order, signed regularisation), with every supernode in exactly
    /// one bin or the top, both bins used; and faer's solve bit for bit.
    #[test]
    fn tree_factorisation_and_solve_equal_faers() {
        let (a, n_primal, symbolic, schedule) = analysed_grid_saddle(60);
        let (n, raw) = (a.nrows(), supernodal_part(&symbolic));
        for bin in 0..2u8 {
            assert!(schedule.owner.contains(&bin), "bin {bin} empty");
        }
        let tops = schedule.owner.iter().filter(|&&o| o == TOP).count();
        assert!(tops > 0 && tops == schedule.top.len());
        assert!(schedule.top.iter().all(|&s| schedule.owner[s] == TOP));
        let pattern = super::super::analysis::OrderedPattern::new(&symbolic, &a, n_primal, true);
        let ordered = pattern.equilibrated(&a, &vec![1.0; n]);
        let entries = pattern
            .entries(&a, &vec![1.0; n], None, 2)
            .expect("positions kept");
        let regularization = test_regularization(&pattern.signs);
        let mut faers = vec![0.0; raw.len_val()];
        let mut buffer = MemBuffer::new(supernodal::factorize_supernodal_numeric_ldlt_scratch::<
            usize,
            f64,
        >(raw, Par::Seq, Default::default()));
        supernodal::factorize_supernodal_numeric_ldlt(
            &mut faers,
            ordered.as_ref(),
            regularization,
            raw,
            Par::Seq,
            MemStack::new(&mut buffer),
            Default::default(),
        )
        .unwrap();
        let mut ours = vec![f64::NAN; raw.len_val()];
        factorize(&mut ours, &entries, &regularization, raw, &schedule, None).unwrap();
        let scale = super::super::norm_inf(&faers);
        let worst = super::super::norm_inf(&super::super::difference(&faers, &ours));
        assert!(
            worst <= 1e-13 * scale,
            "factor values differ by {worst:e} (scale {scale:e})"
        );
        // The two-thread solve is faer's, bit for bit, on the same factor.
        let b: Vec<f64> = (0..n).map(|i| ((i * 7919) % 101) as f64 - 50.0).collect();
        let mut faer_x = b.clone();
        let mut buffer = MemBuffer::new(faer::linalg::temp_mat_scratch::<f64>(n, 1));
        supernodal::SupernodalLdltRef::new(raw, &ours).solve_in_place_with_conj(
            Conj::No,
            MatMut::from_column_major_slice_mut(&mut faer_x, n, 1),
            Par::Seq,
            MemStack::new(&mut buffer),
        );
        let mut tree_x = b;
        solve_in_place(raw, &ours, &schedule, &mut tree_x);
        let differing = faer_x.iter().zip(&tree_x).filter(|(f, t)| f != t).count();
        assert_eq!(
            differing, 0,
            "the solves differ in {differing} of {n} entries"
        );
    }

    /// A wide supernode's dense LDLᵀ on two threads is the one-thread
    /// finish to round-off: a quasi-definite diagonal block (positive
    /// primal, negative multiplier pivots, one pivot regularised) with rows
    /// below, TOP_BLOCK-unaligned, so every block and both splits are used.
    #[test]
    fn two_thread_pivots_equal_the_one_thread_finish() {
        let (ncols, below, n_primal) = (2 * TOP_BLOCK + 77, 150, 2 * TOP_BLOCK + 10);
        let nrows = ncols + below;
        // Entries from a fixed linear congruential sequence in [-0.5, 0.5).
        let mut state = 12345u64;
        let mut next = move || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let mut block = vec![0.0; nrows * ncols];
        for j in 0..ncols {
            for i in j..nrows {
                let v = next();
                block[i + j * nrows] = match (i == j, j < n_primal, i < n_primal) {
                    (true, true, _) => 40.0 + v,
                    (true, false, _) => -(40.0 + v),
                    (false, _, true) | (false, false, false) => 0.1 * v,
                    (false, true, false) => v,
                };
            }
        }
        // One primal unknown decoupled with a zero diagonal: its pivot is
        // regularised (faer counts the positive ones).
        let tiny = n_primal - 5;
        for j in 0..tiny {
            block[tiny + j * nrows] = 0.0;
        }
        for i in tiny..nrows {
            block[i + tiny * nrows] = 0.0;
        }
        let (a, _) = grid_saddle(4);
        let symbolic = supernodal_amd(&a);
        let mut signs = vec![1i8; ncols];
        signs[n_primal..].fill(-1);
        let regularization = test_regularization(&signs);
        let pattern: Vec<usize> = (ncols..nrows).collect();
        let shape = Shape {
            start: 0,
            end: ncols,
            ncols,
            nrows,
            pattern: &pattern,
            symbolic: supernodal_part(&symbolic),
        };
        let mut stack = MemBuffer::new(cholesky_in_place_scratch::<f64>(
            ncols,
            Par::Seq,
            Default::default(),
        ));
        let mut one = block.clone();
        let count_one = shape
            .finish(&regularization, shape.matrix(&mut one), &mut stack)
            .unwrap();
        let mut two = block;
        let count_two = shape
            .finish_on_two_threads(
                &regularization,
                shape.matrix(&mut two),
                &mut stack,
                &mut Vec::new(),
            )
            .unwrap();
        assert_eq!((count_one, count_two), (1, 1), "regularised pivots");
        let scale = super::super::norm_inf(&one);
        let worst = super::super::norm_inf(&super::super::difference(&one, &two));
        assert!(
            worst <= 1e-13 * scale,
            "the factors differ by {worst:e} (scale {scale:e})"
        );
    }
}
