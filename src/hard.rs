//! The hard cases (issue 6): scenes under `pipelines/scenes/hard/` where
//! shells and contact are hard (thin shells, extreme penalties and steps,
//! contact extremes, bad meshes, other charts), each with its expected
//! outcome, and the table `obstacle hard` (`make hard`) prints: case,
//! expected and actual outcome, iterations, KKT measures, a condition
//! estimate of the factorised matrix, time. See `docs/hard-cases.md`.

use crate::assembly::{mat_vec, norm2, Triplets};
use crate::error::{Error, Result};
use crate::linalg::{factor_once, Factors, MatrixKind, Solves, SystemPattern};
use crate::pipeline::{scene_mesh_in_temp, setup_model, RunSummary};
use crate::run::run_scene;
use crate::scene::Scene;
use crate::solvers::ContactProblem;
use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

/// What a hard case must do.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Expect {
    /// Solved; with an obstacle, converged to the scene's KKT tolerance.
    Converged,
    /// Fails with an error whose message contains this text.
    Error(&'static str),
}

/// The hard cases: scene file stem under `pipelines/scenes/hard/` and outcome.
pub const CASES: &[(&str, Expect)] = &[
    ("thin-0.8-free", Expect::Converged),
    ("thin-0.08-free", Expect::Converged),
    ("thin-0.008-free", Expect::Converged),
    ("thin-0.0008-free", Expect::Converged),
    ("thin-0.8-contact", Expect::Converged),
    ("thin-0.08-contact", Expect::Converged),
    ("thin-0.008-contact", Expect::Converged),
    ("thin-0.0008-contact", Expect::Converged),
    ("thin-plate-0.8-free", Expect::Converged),
    ("thin-plate-0.008-free", Expect::Converged),
    ("rho-0", Expect::Converged),
    ("rho-0-split", Expect::Error("not coercive")),
    ("rho-1", Expect::Converged),
    ("rho-1e6", Expect::Converged),
    ("rho-1e12", Expect::Converged),
    ("alpha-0.5", Expect::Converged),
    ("alpha-0.99", Expect::Converged),
    ("alpha-1.01", Expect::Error("diverged")),
    ("alpha-2", Expect::Error("diverged")),
    ("contact-no-load", Expect::Converged),
    ("contact-huge-load", Expect::Converged),
    ("contact-touching", Expect::Converged),
    ("contact-resting", Expect::Converged),
    ("contact-infeasible", Expect::Error("infeasible")),
    ("mesh-graded", Expect::Converged),
    ("mesh-aniso", Expect::Converged),
    ("mesh-perturbed", Expect::Converged),
    ("mesh-large", Expect::Converged),
    ("chart-plate", Expect::Converged),
    ("chart-cylinder", Expect::Converged),
    ("chart-kink", Expect::Converged),
];

/// One row of the hard-case table.
#[derive(Debug, Clone)]
pub struct HardRow {
    pub case: String,
    pub expect: Expect,
    /// The run's summary, or its error message.
    pub outcome: std::result::Result<RunSummary, String>,
    /// Estimate of the 2-norm condition number of the factorised matrix.
    pub condition: Option<f64>,
    /// The same for the primal block K_ρ of a saddle-point matrix (the
    /// stiffness of a_ρ), or the reason its Cholesky factorisation failed:
    /// a_ρ is coercive exactly when this is a finite number.
    pub primal_condition: Option<std::result::Result<f64, String>>,
    pub seconds: f64,
}

impl HardRow {
    /// Did the case do what it must?
    pub fn as_expected(&self) -> bool {
        match (&self.outcome, self.expect) {
            (Ok(s), Expect::Converged) => s.converged,
            (Err(m), Expect::Error(text)) => m.contains(text),
            _ => false,
        }
    }
}

/// Estimate of κ₂(A) = |λ|max / |λ|min of the symmetric matrix A: 40 steps
/// of power iteration on A and on A⁻¹ (one solve each, with the existing
/// factorisation) from a fixed start vector. Both are lower bounds that
/// converge from below, so the estimate is a lower bound on κ₂.
pub fn condition_estimate(
    a: &faer::sparse::SparseColMat<usize, f64>,
    factorization: &dyn Factors,
) -> f64 {
    let n = a.nrows();
    let start: Vec<f64> = (0..n)
        .map(|i| 1.0 + 0.5 * ((i * 2654435761usize) % 1000) as f64 / 1000.0)
        .collect();
    let power = |apply: &dyn Fn(&mut Vec<f64>)| -> f64 {
        let mut v = start.clone();
        let mut estimate = 0.0;
        for _ in 0..40 {
            let norm = norm2(&v);
            if norm == 0.0 || !norm.is_finite() {
                return f64::INFINITY;
            }
            v.iter_mut().for_each(|x| *x /= norm);
            apply(&mut v);
            estimate = norm2(&v);
        }
        estimate
    };
    let largest = power(&|v: &mut Vec<f64>| *v = mat_vec(a, v));
    let inverse = power(&|v: &mut Vec<f64>| factorization.solve_in_place(v));
    largest * inverse
}

/// The leading n_primal × n_primal block of A (K_ρ of [[K_ρ, Bᵀ], [B, 0]]).
fn primal_block(problem: &ContactProblem) -> faer::sparse::SparseColMat<usize, f64> {
    let np = problem.n_primal;
    let a = &problem.matrix;
    let symbolic = a.symbolic();
    let (col_ptr, row_idx, values) = (symbolic.col_ptr(), symbolic.row_idx(), a.val());
    let mut t = Triplets::new(np, np);
    for j in 0..np {
        for k in col_ptr[j]..col_ptr[j + 1] {
            if row_idx[k] < np {
                t.push(row_idx[k], j, values[k]);
            }
        }
    }
    t.into_sparse()
}

/// Condition estimates of a scene's matrix and, for a saddle-point matrix,
/// of its primal block K_ρ (see [`HardRow::primal_condition`]).
pub type Conditions = (f64, Option<std::result::Result<f64, String>>);

/// Mesh, assemble and factorise a scene's matrix as the pipeline does (the
/// mesh in a temporary folder: the run writes it beside its result), and
/// estimate its condition number, and that of K_ρ.
pub fn scene_condition(scene: &Scene) -> Result<Conditions> {
    let mesh = scene_mesh_in_temp(scene)?;
    let system = setup_model(scene, &mesh)?;
    let problem: ContactProblem = system.assemble()?;
    let what = problem.kind.describe();
    let linear = crate::pipeline::linear_options(&scene.solver);
    let a = &problem.matrix;
    // The estimate multiplies by A whole: the factors of A as it is.
    fn pattern<'a>(
        matrix: &'a faer::sparse::SparseColMat<usize, f64>,
        kind: MatrixKind,
        what: &'a str,
    ) -> SystemPattern<'a> {
        SystemPattern {
            matrix,
            kind,
            solves: Solves::Many,
            interior: None,
            what,
        }
    }
    let f = factor_once(pattern(a, problem.kind, what), &linear)?;
    let kappa = condition_estimate(a, f.as_ref());
    let primal = (problem.n_primal < problem.n()).then(|| {
        let k = primal_block(&problem);
        let kind = MatrixKind::SymmetricPositiveDefinite;
        factor_once(pattern(&k, kind, "K_ρ (a_ρ)"), &linear)
            .map(|f| condition_estimate(&k, f.as_ref()))
            .map_err(|e| e.to_string())
    });
    Ok((kappa, primal))
}

/// Runs one hard case: the scene `dir/<case>.toml` with `overrides`, result
/// files in `out_dir`.
pub fn run_case(
    dir: &Path,
    case: &str,
    expect: Expect,
    overrides: &[String],
    out_dir: &Path,
) -> HardRow {
    let start = Instant::now();
    let mut condition = None;
    let mut primal_condition = None;
    let outcome = (|| -> Result<RunSummary> {
        let scene = Scene::load(&dir.join(format!("{case}.toml")), overrides)?;
        std::fs::create_dir_all(out_dir)
            .map_err(|e| Error::output(out_dir, format!("cannot create the folder: {e}")))?;
        let (kappa, primal) = scene_condition(&scene)?;
        condition = Some(kappa);
        primal_condition = primal;
        run_scene(&scene, &out_dir.join(format!("{case}.h5")), false)
    })()
    .map_err(|e| e.to_string());
    HardRow {
        case: case.to_string(),
        expect,
        outcome,
        condition,
        primal_condition,
        seconds: start.elapsed().as_secs_f64(),
    }
}

/// Runs every case of [`CASES`]; `extra` adds overrides per case (e.g. a
/// larger mesh for `mesh-large`).
pub fn run_all(dir: &Path, out_dir: &Path, extra: &[(String, String)]) -> Vec<HardRow> {
    CASES
        .iter()
        .map(|&(case, expect)| {
            let overrides: Vec<String> = extra
                .iter()
                .filter(|(c, _)| c == case || c == "*")
                .map(|(_, o)| o.clone())
                .collect();
            let row = run_case(dir, case, expect, &overrides, out_dir);
            eprintln!(
                "{case}: {} ({:.1} s)",
                if row.as_expected() {
                    "as expected"
                } else {
                    "UNEXPECTED"
                },
                row.seconds
            );
            row
        })
        .collect()
}

/// The Markdown table of the rows.
pub fn table(rows: &[HardRow]) -> String {
    let mut s = String::from(
        "| case | expected | outcome | ok | iterations | KKT | penetration | complementarity | stationarity | κ₂ estimate | κ₂(K_ρ) | u3 min | contact area | dofs | time (s) |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    let e = |x: f64| format!("{x:.2e}");
    for r in rows {
        let expected = match r.expect {
            Expect::Converged => "converged".to_string(),
            Expect::Error(t) => format!("error: {t}"),
        };
        let ok = if r.as_expected() { "yes" } else { "**NO**" };
        let kappa = r.condition.map_or("–".into(), e);
        let kappa_k = match &r.primal_condition {
            None => "–".into(),
            Some(Ok(k)) => e(*k),
            Some(Err(_)) => "singular".into(),
        };
        match &r.outcome {
            Ok(sm) => {
                let m = &sm.measures;
                let outcome = if sm.stop_reason == "linear" {
                    "solved (linear)".to_string()
                } else if sm.converged {
                    "converged".to_string()
                } else {
                    format!("not converged ({})", sm.stop_reason)
                };
                let _ = writeln!(
                    s,
                    "| {} | {expected} | {outcome} | {ok} | {} | {} | {} | {} | {} | {kappa} | {kappa_k} | {} | {} | {} | {:.2} |",
                    r.case,
                    sm.iterations,
                    e(m.kkt),
                    e(m.penetration),
                    e(m.complementarity),
                    e(m.stationarity),
                    sm.attr("u3_min").map_or("–".into(), |v| format!("{v:.4e}")),
                    sm.attr("contact_area")
                        .map_or("–".into(), |v| format!("{:.1}", v + 0.0)),
                    sm.n_dofs,
                    r.seconds
                );
            }
            Err(msg) => {
                let short: String = msg.chars().take(160).collect();
                let short = short.replace('|', "\\|");
                let _ = writeln!(
                    s,
                    "| {} | {expected} | error: {short}{} | {ok} | – | – | – | – | – | {kappa} | {kappa_k} | – | – | – | {:.2} |",
                    r.case,
                    if msg.chars().count() > 160 { "…" } else { "" },
                    r.seconds
                );
            }
        }
    }
    s
}

/// `obstacle hard [DIR] [--set CASE:KEY=VALUE]... [--out-dir DIR]`: runs every
/// case (CASE `*`: the override applies to all), prints the table, writes it to `<out_dir>/hard.md`; an error when a
/// case does not do what it must.
pub fn command(dir: &Path, out_dir: &Path, set: &[String]) -> Result<()> {
    // One error for a missing folder, not one failed row per case.
    if !dir.is_dir() {
        return Err(Error::Scene {
            file: dir.to_path_buf(),
            field: "(folder)".into(),
            reason: "no such folder of hard cases (default: pipelines/scenes/hard)".into(),
        });
    }
    let mut extra = Vec::new();
    for s in set {
        let (case, o) = s.split_once(':').ok_or_else(|| Error::Scene {
            file: dir.to_path_buf(),
            field: s.clone(),
            reason: "a hard-case override is CASE:KEY=VALUE, e.g. mesh-large:mesh.n=96".into(),
        })?;
        if case != "*" && !CASES.iter().any(|(c, _)| *c == case) {
            return Err(Error::Scene {
                file: dir.to_path_buf(),
                field: s.clone(),
                reason: format!("no hard case `{case}`"),
            });
        }
        extra.push((case.to_string(), o.to_string()));
    }
    let rows = run_all(dir, out_dir, &extra);
    let md = table(&rows);
    crate::out!("{md}");
    let path = out_dir.join("hard.md");
    crate::output::write_text_atomically(&path, &md)?;
    let bad: Vec<&str> = rows
        .iter()
        .filter(|r| !r.as_expected())
        .map(|r| r.case.as_str())
        .collect();
    if bad.is_empty() {
        Ok(())
    } else {
        Err(Error::numerical(
            "hard cases",
            "outcome",
            format!("not as expected: {}", bad.join(", ")),
        ))
    }
}
