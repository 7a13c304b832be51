//! Extreme eigenvalues of the dual operator S = D⁻¹ C A⁻¹ Cᵀ by Lanczos,
//! reusing the one factorisation of A (one solve per step).
//!
//! D is the Riesz map of the dual step: the weights W for the mean form,
//! the identity for the integral form (docs/formulation.md §3). S is self-adjoint in the
//! D inner product, so Lanczos runs on D^{-1/2} C A⁻¹ Cᵀ D^{-1/2}.
//! Uzawa with a fixed step converges for 0 < α < 2/s_max.

use super::ContactProblem;
use crate::linalg::Factors;
use crate::linalg::{mat_t_vec, mat_vec};
use crate::solvers::StepForm;

/// Ritz estimates of the extreme eigenvalues of S.
#[derive(Debug, Clone, Copy)]
pub struct SpectrumEstimate {
    /// Largest Ritz value: converges fast and from below.
    pub s_max: f64,
    /// Smallest Ritz value: only an upper bound on s_min after few steps.
    pub s_min: f64,
    pub steps: usize,
}

/// Runs `steps` Lanczos steps with full reorthogonalisation.
pub fn estimate_dual_spectrum(
    problem: &ContactProblem,
    factorization: &dyn Factors,
    step_form: StepForm,
    steps: usize,
) -> Option<SpectrumEstimate> {
    let c = problem.constraint.as_ref()?;
    let m = c.obstacle.len();
    if m == 0 {
        return None;
    }
    let scale: Vec<f64> = match step_form {
        StepForm::Mean => c.weights.iter().map(|w| 1.0 / w.sqrt()).collect(),
        StepForm::Integral => vec![1.0; m],
    };
    let apply = |v: &[f64]| -> Vec<f64> {
        let z: Vec<f64> = v.iter().zip(&scale).map(|(a, s)| a * s).collect();
        let mut x = mat_t_vec(&c.matrix, &z);
        factorization.solve_in_place(&mut x);
        let y = mat_vec(&c.matrix, &x);
        y.iter().zip(&scale).map(|(a, s)| a * s).collect()
    };
    let steps = steps.min(m).max(1);
    // A deterministic start vector with all components present.
    let mut q: Vec<f64> = (0..m)
        .map(|i| 1.0 + 0.5 * ((i * 2654435761usize) % 1000) as f64 / 1000.0)
        .collect();
    normalise(&mut q);
    let mut basis: Vec<Vec<f64>> = vec![q];
    let (mut alphas, mut betas) = (Vec::new(), Vec::new());
    for k in 0..steps {
        let mut w = apply(&basis[k]);
        let a = dot(&w, &basis[k]);
        alphas.push(a);
        // Full reorthogonalisation (twice is enough) keeps the Ritz values clean.
        for _ in 0..2 {
            for b in &basis {
                let p = dot(&w, b);
                w.iter_mut().zip(b).for_each(|(wi, bi)| *wi -= p * bi);
            }
        }
        let beta = dot(&w, &w).sqrt();
        if k + 1 == steps || beta <= 1e-14 * a.abs().max(f64::MIN_POSITIVE) {
            break;
        }
        betas.push(beta);
        w.iter_mut().for_each(|wi| *wi /= beta);
        basis.push(w);
    }
    let n = alphas.len();
    let t = nalgebra::DMatrix::from_fn(n, n, |i, j| {
        if i == j {
            alphas[i]
        } else if i + 1 == j {
            betas[i]
        } else if j + 1 == i {
            betas[j]
        } else {
            0.0
        }
    });
    let eig = nalgebra::SymmetricEigen::new(t).eigenvalues;
    let s_max = eig.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    let s_min = eig.iter().cloned().fold(f64::INFINITY, f64::min);
    Some(SpectrumEstimate {
        s_max,
        s_min,
        steps: n,
    })
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

fn normalise(v: &mut [f64]) {
    let n = dot(v, v).sqrt();
    v.iter_mut().for_each(|x| *x /= n);
}
