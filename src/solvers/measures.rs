//! The measures every solver reports (docs/formulation.md §4), and the per-iteration history.

use super::ContactProblem;
use crate::linalg::{mat_t_vec, mat_vec, norm2, norm_inf};
use crate::solvers::DualNorm;

/// KKT measures of an iterate (x, λ). Absolute values, and the relative
/// ones that the tolerance applies to.
#[derive(Debug, Clone, Copy, Default)]
pub struct KktMeasures {
    /// max_i max(0, −ḡ_i).
    pub penetration: f64,
    /// min_i λ_i (≥ 0 by construction of the projected methods).
    pub dual_min: f64,
    /// max_i |λ_i ḡ_i|.
    pub complementarity: f64,
    /// ‖A x − F − Cᵀλ‖ over the primal rows, relative to max(‖F‖, ‖A x‖, ‖Cᵀλ‖).
    pub stationarity: f64,
    /// ‖(A x − F)‖ over the equality-multiplier rows (‖B U‖), absolute.
    pub tangency: f64,
    /// Number of multipliers with λ_i > 0.
    pub active: usize,
    /// The scale of gaps: max(‖ḡ(0)‖∞ = ‖g_i/w_i‖∞, ‖x_primal‖∞,
    /// max_i |λ_i| S̃_ii), the last the mean gap the contact force λ_i
    /// alone opens ([`jacobi_dual_diagonal`]): a body resting on a zero
    /// obstacle has g = 0 and x = 0, and without it the gaps' round-off
    /// would be measured against x's.
    pub gap_scale: f64,
    /// The largest relative measure: penetration/gap_scale,
    /// max(0, −dual_min)/‖λ‖∞, complementarity/(‖λ‖∞ gap_scale),
    /// stationarity, tangency/(‖F‖ + ‖x‖). This is what `tol` bounds.
    pub kkt: f64,
}

/// Computes the measures of (x, λ) for a problem. `cx` is C x when the
/// caller already has it (Uzawa does: it needs it for the step); A x is
/// computed on `threads`.
pub fn kkt_measures(
    problem: &ContactProblem,
    x: &[f64],
    lambda: &[f64],
    cx: Option<&[f64]>,
    threads: usize,
) -> KktMeasures {
    kkt_measures_with(
        problem,
        x,
        lambda,
        Products {
            cx,
            ..Products::default()
        },
        threads,
    )
}

/// Products of an iterate (x, λ) its solver has at hand, and the
/// problem's compliance S̃: the measures take them instead of computing
/// them again (the same functions, so the same numbers). None: computed
/// here.
#[derive(Debug, Clone, Copy, Default)]
pub struct Products<'a> {
    /// A x.
    pub ax: Option<&'a [f64]>,
    /// C x.
    pub cx: Option<&'a [f64]>,
    /// Cᵀ λ.
    pub ct_lambda: Option<&'a [f64]>,
    /// S̃_ii of [`jacobi_dual_diagonal`], the same for every iterate of a
    /// solve (and not computable while the active set holds A).
    pub compliance: Option<&'a [f64]>,
}

/// [`kkt_measures`] with the products the caller has (those it has not
/// computed on `threads`).
pub fn kkt_measures_with(
    problem: &ContactProblem,
    x: &[f64],
    lambda: &[f64],
    products: Products,
    threads: usize,
) -> KktMeasures {
    let n_primal = problem.n_primal;
    let cx = products.cx;
    let computed_ax;
    let ax = match products.ax {
        Some(ax) => ax,
        None => {
            computed_ax = problem.product(x, threads);
            &computed_ax
        }
    };
    // The scale of stationarity: the largest of its three terms ‖F‖, ‖A x‖,
    // ‖Cᵀλ‖ (primal rows), so a zero load (the obstacle alone pushes) is
    // not divided by ‖F‖ = 0; equal to ‖F‖ whenever the load dominates.
    let mut force_scale = norm2(&ax[..n_primal]).max(norm2(&problem.rhs[..n_primal]));
    let mut m = KktMeasures::default();
    let x_scale = norm_inf(&x[..n_primal]);
    let f_norm = norm2(&problem.rhs[..n_primal]).max(f64::MIN_POSITIVE);
    let mut computed_ct = None;
    if let Some(c) = &problem.constraint {
        let ct_lambda = match products.ct_lambda {
            Some(v) => v,
            None => computed_ct.insert(mat_t_vec(&c.matrix, lambda)),
        };
        force_scale = force_scale.max(norm2(&ct_lambda[..n_primal.min(ct_lambda.len())]));
        let computed;
        let cx = match cx {
            Some(cx) => cx,
            None => {
                computed = mat_vec(&c.matrix, x);
                &computed
            }
        };
        let obstacle_scale = c
            .obstacle
            .iter()
            .zip(&c.weights)
            .fold(0.0f64, |s, (g, w)| s.max((g / w).abs()));
        let computed_compliance;
        let compliance = match products.compliance {
            Some(v) => v,
            None => {
                computed_compliance = jacobi_dual_diagonal(problem);
                &computed_compliance
            }
        };
        let contact_gap = lambda
            .iter()
            .zip(compliance)
            .fold(0.0f64, |s, (l, c)| s.max((l * c).abs()));
        m.gap_scale = obstacle_scale
            .max(x_scale)
            .max(contact_gap)
            .max(f64::MIN_POSITIVE);
        let lambda_scale = norm_inf(lambda).max(f64::MIN_POSITIVE);
        m.dual_min = f64::INFINITY;
        for i in 0..lambda.len() {
            let gap = c.mean_gap(cx, i);
            m.penetration = m.penetration.max(-gap);
            m.complementarity = m.complementarity.max((lambda[i] * gap).abs());
            m.dual_min = m.dual_min.min(lambda[i]);
            if lambda[i] > 0.0 {
                m.active += 1;
            }
        }
        if lambda.is_empty() {
            m.dual_min = 0.0;
        }
        m.kkt = (m.penetration / m.gap_scale)
            .max((-m.dual_min).max(0.0) / lambda_scale)
            .max(m.complementarity / (lambda_scale * m.gap_scale));
    } else {
        m.gap_scale = x_scale;
    }
    // A x − F − Cᵀλ, row by row (not stored): its primal rows' norm is
    // stationarity, the equality rows' tangency.
    let ct_lambda = products.ct_lambda.or(computed_ct.as_deref());
    let residual_norm = |rows: std::ops::Range<usize>| {
        rows.map(|i| {
            let r = ax[i] - problem.rhs[i];
            let r = match ct_lambda {
                Some(ct) if i < ct.len() => r - ct[i],
                _ => r,
            };
            r * r
        })
        .sum::<f64>()
        .sqrt()
    };
    m.stationarity = residual_norm(0..n_primal) / force_scale.max(f64::MIN_POSITIVE);
    m.tangency = residual_norm(n_primal..ax.len().min(problem.rhs.len()));
    let tangency_rel = m.tangency / (f_norm + norm2(x));
    m.kkt = m.kkt.max(m.stationarity).max(tangency_rel);
    m
}

/// S̃_ii = (1/w_i) Σ_j C_ij² / |A_jj|: the diagonal of the mean-form dual
/// operator W⁻¹ C A⁻¹ Cᵀ with A replaced by its diagonal (0 where C's row
/// meets no nonzero diagonal entry), the mean gap a unit multiplier λ_i
/// opens on its own: the gap scale of the measures and the active set's
/// rule c_i = 1/S̃_ii.
pub fn jacobi_dual_diagonal(problem: &ContactProblem) -> Vec<f64> {
    let Some(c) = problem.constraint.as_ref() else {
        return Vec::new();
    };
    let a = &problem.matrix;
    let diag: Vec<f64> = (0..a.ncols())
        .map(|j| {
            a.symbolic()
                .row_idx_of_col(j)
                .zip(a.val_of_col(j))
                .filter(|(r, _)| *r == j)
                .map(|(_, v)| v.abs())
                .sum()
        })
        .collect();
    let mut s = vec![0.0; c.obstacle.len()];
    for j in 0..c.matrix.ncols() {
        if diag[j] == 0.0 {
            continue;
        }
        for (i, v) in c
            .matrix
            .symbolic()
            .row_idx_of_col(j)
            .zip(c.matrix.val_of_col(j))
        {
            s[i] += v * v / diag[j];
        }
    }
    s.iter_mut().zip(&c.weights).for_each(|(si, w)| *si /= w);
    s
}

/// ‖λ^{k+1} − λ^k‖ in the chosen norm (L²: Σ w_i Δλ_i², the L²(Ω) norm of the
/// multiplier function through its Riesz weights).
pub fn dual_step_norm(new: &[f64], old: &[f64], weights: &[f64], norm: DualNorm) -> f64 {
    match norm {
        DualNorm::Inf => new
            .iter()
            .zip(old)
            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs())),
        DualNorm::L2 => new
            .iter()
            .zip(old)
            .zip(weights)
            .map(|((a, b), w)| w * (a - b) * (a - b))
            .sum::<f64>()
            .sqrt(),
    }
}

/// Per-iteration measures, as named columns (written to `/solver/history`).
#[derive(Debug, Clone, Default)]
pub struct History {
    pub columns: Vec<(String, Vec<f64>)>,
}

/// The columns every solver's history starts with ([`History::for_solver`]).
pub const KKT_COLUMNS: [&str; 8] = [
    "iteration",
    "dual_step",
    "penetration",
    "dual_min",
    "complementarity",
    "stationarity",
    "tangency",
    "kkt",
];

impl History {
    /// A history with the [`KKT_COLUMNS`] followed by the solver's own.
    pub fn for_solver(extra: &[&str]) -> Self {
        let names: Vec<&str> = KKT_COLUMNS.iter().chain(extra).copied().collect();
        History::with_columns(&names)
    }

    /// Appends one row of a [`History::for_solver`] history: iteration k,
    /// the dual step, the measures, then the solver's own values.
    pub fn push_iteration(&mut self, k: usize, dual_step: f64, m: &KktMeasures, extra: &[f64]) {
        let mut row = vec![
            k as f64,
            dual_step,
            m.penetration,
            m.dual_min,
            m.complementarity,
            m.stationarity,
            m.tangency,
            m.kkt,
        ];
        row.extend_from_slice(extra);
        self.push(&row);
    }

    pub fn with_columns(names: &[&str]) -> Self {
        History {
            columns: names.iter().map(|n| (n.to_string(), Vec::new())).collect(),
        }
    }

    /// Appends one row; `values` in column order.
    pub fn push(&mut self, values: &[f64]) {
        debug_assert_eq!(values.len(), self.columns.len());
        for ((_, col), v) in self.columns.iter_mut().zip(values) {
            col.push(*v);
        }
    }

    pub fn len(&self) -> usize {
        self.columns.first().map_or(0, |(_, c)| c.len())
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn column(&self, name: &str) -> Option<&[f64]> {
        self.columns
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, c)| c.as_slice())
    }
}
