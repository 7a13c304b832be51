//! Benchmarks and work–precision studies (issue 5): `obstacle bench …`.
//!
//! * `obstacle bench run CONFIG` (`make bench`, `make scale`): each
//!   (problem, mesh level, method, tolerance) is solved in a **child process**
//!   (`obstacle bench case …`, the same binary) so that its peak memory is its
//!   own: the child reads `VmHWM` from `/proc/self/status` when it is done
//!   (peak resident set of the whole process: mesh, assembly, solve, result
//!   file) and prints one `BENCH key=value …` line. Per mesh level the *floor*
//!   is measured too: one factorisation + one solve of the system matrix
//!   without contact (`A x = F`, the matrix every contact solver starts
//!   from). Times are the solver's own wall time (`/solver/wall_seconds`:
//!   factorisations + iterations; meshing, assembly and output excluded);
//!   `total` is the child's wall time for everything.
//!
//!   The cap: a method's run at the tightest tolerance gets `solver.max_iter`
//!   = what fits in `cap_seconds` by a calibration from the floor (one solve
//!   per iteration for the iterative methods, one factorisation per Newton
//!   step for active-set). A run that stops on `max_iter` is *capped*: its
//!   measured time is a lower bound of the time to the tolerance (shown as
//!   `>t`), and the linear rate of its last KKT measures gives an
//!   *estimate* of the iterations still needed (shown separately). A looser
//!   tolerance is read from the same run when the KKT measure first falls
//!   below it at the last iteration (same run, same numbers); otherwise it
//!   is run on its own (the iterations are then known). Such a re-run of
//!   the active set that ends inside its interior-point start is marked †:
//!   its iterate meets the measure but is interior, not complementary. A
//!   method capped at one level is not run at the finer ones (`>cap`,
//!   times grow with n).
//!   A hard kill at 3·cap + 120 s guards against a bad calibration.
//!
//! * `obstacle bench study …` (`make study`): work–precision. Runs study
//!   files (sweeps of element, method, mesh level and tolerance) in process,
//!   measures errors (disk: against the exact solution; shell: against a
//!   reference run on a finer mesh via [`crate::transfer`]) against the
//!   solver's wall time, and writes log–log plots and a Markdown report.
//!
//! Here: the driver [`run_bench`] and its [`BenchRow`]s; `config` is the
//! TOML, `child` the child's side and the `BENCH` line between the two,
//! `table` the tables, CSV and plots, `work_precision` `bench study`.

mod child;
mod config;
mod table;
mod work_precision;

pub use child::{extrapolate_iterations, run_case, MIN_ITERATIONS_FOR_ESTIMATE};
pub use config::{BenchConfig, BenchMethod, BenchProblem, CapRelative};
pub use table::{bench_csv, bench_markdown, phase_rss_markdown, targets, PhaseRss};
pub use work_precision::{balance, work_precision, WpPoint};

use child::{child, num, Fields};
use table::{bench_plots, write};

use crate::error::{Error, Result};
use crate::output::OutputTransaction;
use std::path::Path;
use std::time::Duration;

/// One measured (or skipped) cell of the benchmark.
#[derive(Debug, Clone, Default)]
pub struct BenchRow {
    pub problem: String,
    pub level: String,
    pub n_dofs: usize,
    pub method: String,
    pub tol: f64,
    /// "converged", "capped" (lower bound), "not run" (capped at a coarser level),
    /// "killed", "failed".
    pub status: String,
    pub iterations: Option<usize>,
    pub seconds: f64,
    pub factor_seconds: f64,
    pub total_seconds: f64,
    pub peak_rss_mb: f64,
    pub kkt: f64,
    pub floor_seconds: f64,
    /// Capped runs: estimated seconds to the tolerance (linear rate of the KKT history).
    pub estimate_seconds: Option<f64>,
    /// The run ended inside the interior-point start: its answer is an
    /// interior iterate, not a complementary pair
    /// ([`crate::pipeline::RunSummary::ended_in_interior_point`]).
    pub interior: bool,
    pub note: String,
}

/// Runs the benchmark; prints and writes the table, CSV and plots.
pub fn run_bench(cfg: &BenchConfig, config_path: &Path, out_dir: &Path) -> Result<Vec<BenchRow>> {
    std::fs::create_dir_all(out_dir)
        .map_err(|e| Error::output(out_dir, format!("cannot create: {e}")))?;
    let runs_dir = out_dir.join("runs");
    std::fs::create_dir_all(&runs_dir)
        .map_err(|e| Error::output(&runs_dir, format!("cannot create: {e}")))?;
    let base = config_path.parent().unwrap_or(Path::new("."));
    let mut tols = cfg.tolerances.clone();
    tols.sort_by(|a, b| b.total_cmp(a)); // loosest first
    let tightest = *tols.last().expect("validated");
    let mut rows: Vec<BenchRow> = Vec::new();
    let mut floors: Vec<(String, String, usize, f64, f64)> = Vec::new();
    let mut phase_rss: Vec<PhaseRss> = Vec::new();
    for p in &cfg.problem {
        let scene = base.join(&p.scene);
        let mut capped_methods: Vec<String> = Vec::new();
        for level in &p.levels {
            let level_s = level.to_string();
            let mut set = p.set.clone();
            set.push(format!("{}={}", p.key, level_s));
            let stem = format!("{}-{}-{}", cfg.name, p.label, level_s.replace('"', ""));
            // The floor.
            let out = runs_dir.join(format!("{stem}-linear.h5"));
            let floor = child(&scene, &set, &out, true, &[], Duration::from_secs(3600));
            let (floor_s, floor_factor, floor_solve, n_dofs, floor_mem) = match &floor {
                Ok(f) => (
                    num(f, "seconds"),
                    num(f, "factor_seconds"),
                    num(f, "solve_seconds"),
                    num(f, "n_dofs") as usize,
                    num(f, "peak_rss_kb") / 1024.0,
                ),
                Err(e) => {
                    eprintln!("{stem}: the linear solve failed: {e}");
                    (f64::NAN, f64::NAN, f64::NAN, 0, f64::NAN)
                }
            };
            let assembly_mem = floor
                .as_ref()
                .map_or(f64::NAN, |f| num(f, "rss_kb_assembly") / 1024.0);
            eprintln!(
                "{} {}={}: floor {:.3} s (factor {:.3}, solve {:.4}), {} dofs, {:.0} MB ({:.0} MB after assembly)",
                p.label, p.key, level_s, floor_s, floor_factor, floor_solve, n_dofs, floor_mem, assembly_mem
            );
            floors.push((p.label.clone(), level_s.clone(), n_dofs, floor_s, floor_mem));
            if let Ok(f) = &floor {
                phase_rss.push(PhaseRss::new(&p.label, &level_s, "linear solve (floor)", f));
            }
            for m in &cfg.method {
                if p.methods.as_ref().is_some_and(|ms| !ms.contains(&m.label)) {
                    continue;
                }
                let row0 = BenchRow {
                    problem: p.label.clone(),
                    level: level_s.clone(),
                    n_dofs,
                    method: m.label.clone(),
                    floor_seconds: floor_s,
                    seconds: f64::NAN,
                    factor_seconds: f64::NAN,
                    total_seconds: f64::NAN,
                    peak_rss_mb: f64::NAN,
                    kkt: f64::NAN,
                    ..Default::default()
                };
                let mut cap = m.cap_seconds.unwrap_or(cfg.cap_seconds);
                if let Some(rel) = &m.cap_relative {
                    let reference = rows.iter().find(|r| {
                        r.problem == p.label
                            && r.level == level_s
                            && r.method == rel.method
                            && r.tol == rel.tol
                            && r.status == "converged"
                    });
                    match reference {
                        Some(r) => cap = rel.factor * r.seconds,
                        None => eprintln!(
                            "  {}: no converged {} run at {:e} to scale the cap by; cap {cap} s",
                            m.label, rel.method, rel.tol
                        ),
                    }
                }
                if capped_methods.contains(&m.label) {
                    for &tol in &tols {
                        rows.push(BenchRow {
                            tol,
                            status: "not run".into(),
                            seconds: cap,
                            note: "capped at a coarser level".into(),
                            ..row0.clone()
                        });
                    }
                    continue;
                }
                // A level left out of the method's levels has no row: it
                // was not measured, so it is neither a time nor a bound.
                let excluded = p
                    .method_levels
                    .get(&m.label)
                    .is_some_and(|ls| !ls.iter().any(|l| l.to_string() == level_s));
                if excluded {
                    continue;
                }
                let mut mset = set.clone();
                mset.extend(m.set.iter().cloned());
                mset.extend(p.method_set.get(&m.label).cloned().unwrap_or_default());
                mset.push("solver.stop=kkt".into());
                // The cap as an iteration budget (calibrated on the floor).
                let per_iter = if m.iteration_cost == "factor" {
                    1.3 * floor_factor.max(1e-4) + floor_solve.max(1e-5)
                } else if m.cap_relative.is_some() {
                    // Err on the long side: the run must reach the cap.
                    0.8 * floor_solve.max(1e-5)
                } else {
                    1.5 * floor_solve.max(1e-5)
                };
                let setup = if m.iteration_cost == "factor" {
                    0.0
                } else {
                    floor_factor + 50.0 * floor_solve
                };
                let budget = if per_iter.is_finite() {
                    (((cap - setup) / per_iter).floor()).clamp(1.0, 1e8) as usize
                } else {
                    100_000
                };
                let run = |tol: f64, max_iter: usize, tag: &str| {
                    let mut s = mset.clone();
                    s.push(format!("solver.tol={tol:e}"));
                    s.push(format!("solver.max_iter={max_iter}"));
                    let out = runs_dir.join(format!("{stem}-{}-{tag}.h5", m.label));
                    child(
                        &scene,
                        &s,
                        &out,
                        false,
                        &tols,
                        Duration::from_secs_f64(3.0 * cap + 120.0),
                    )
                };
                let tight = run(tightest, budget, "tight");
                let fields = match tight {
                    Ok(f) => f,
                    Err(e) => {
                        let killed = e.starts_with("killed");
                        eprintln!("  {}: {e}", m.label);
                        for &tol in &tols {
                            rows.push(BenchRow {
                                tol,
                                status: if killed { "killed" } else { "failed" }.into(),
                                seconds: if killed { 3.0 * cap + 120.0 } else { f64::NAN },
                                note: e.clone(),
                                ..row0.clone()
                            });
                        }
                        if killed {
                            capped_methods.push(m.label.clone());
                        }
                        continue;
                    }
                };
                phase_rss.push(PhaseRss::new(&p.label, &level_s, &m.label, &fields));
                let iterations = num(&fields, "iterations") as usize;
                let converged = fields.get("converged").map(String::as_str) == Some("true");
                let t_iter = {
                    let s = num(&fields, "seconds");
                    let fs = num(&fields, "factor_seconds");
                    if m.iteration_cost == "factor" {
                        s / iterations.max(1) as f64
                    } else {
                        (s - fs) / iterations.max(1) as f64
                    }
                };
                let measured = |f: &Fields, tol: f64, status: &str| BenchRow {
                    tol,
                    status: status.into(),
                    iterations: Some(num(f, "iterations") as usize),
                    seconds: num(f, "seconds"),
                    factor_seconds: num(f, "factor_seconds"),
                    total_seconds: num(f, "total_seconds"),
                    peak_rss_mb: num(f, "peak_rss_kb") / 1024.0,
                    kkt: num(f, "kkt"),
                    interior: f.get("interior_iterate").map(String::as_str) == Some("true"),
                    ..row0.clone()
                };
                if !converged && m.skip_after_cap {
                    capped_methods.push(m.label.clone());
                }
                for &tol in &tols {
                    let first = fields
                        .get(&format!("first_{tol:e}"))
                        .and_then(|v| v.parse::<usize>().ok());
                    let row = if tol == tightest || (first == Some(iterations) && converged) {
                        let mut r =
                            measured(&fields, tol, if converged { "converged" } else { "capped" });
                        if !converged {
                            r.estimate_seconds = fields
                                .get(&format!("estimate_{tol:e}"))
                                .and_then(|v| v.parse::<f64>().ok())
                                .map(|k| {
                                    let fs = num(&fields, "factor_seconds");
                                    fs + k * t_iter
                                });
                        }
                        r
                    } else if let Some(k) = first {
                        // Reached inside the tight run: rerun to exactly there.
                        match run(tol, k, "loose") {
                            Ok(f) => {
                                let ok = f.get("converged").map(String::as_str) == Some("true");
                                measured(&f, tol, if ok { "converged" } else { "capped" })
                            }
                            Err(e) => BenchRow {
                                tol,
                                status: "failed".into(),
                                note: e,
                                ..row0.clone()
                            },
                        }
                    } else {
                        // Not reached before the cap: lower bound and estimate.
                        let mut r = measured(&fields, tol, "capped");
                        r.estimate_seconds = fields
                            .get(&format!("estimate_{tol:e}"))
                            .and_then(|v| v.parse::<f64>().ok())
                            .map(|k| num(&fields, "factor_seconds") + k * t_iter);
                        r
                    };
                    eprintln!(
                        "  {:<18} tol {:.0e}: {:<9} {:>7} it  {:>9.3} s  {:>7.0} MB  kkt {:.1e}",
                        m.label,
                        tol,
                        row.status,
                        row.iterations.map_or("-".into(), |k| k.to_string()),
                        row.seconds,
                        row.peak_rss_mb,
                        row.kkt
                    );
                    rows.push(row);
                }
            }
        }
    }
    let md = bench_markdown(cfg, &rows, &floors) + &phase_rss_markdown(&phase_rss, tightest);
    crate::out!("{md}");
    // The table, CSV and plots appear together (the runs' files are each their own).
    let outputs = OutputTransaction::new(out_dir, &cfg.name, &[config_path.to_path_buf()])?;
    let table = |ext: &str| outputs.stage(&out_dir.join(format!("{}.{ext}", cfg.name)));
    write(&table("md")?, &md)?;
    write(&table("csv")?, &bench_csv(&rows))?;
    let plots = bench_plots(cfg, &rows, &floors, &outputs)?;
    outputs.commit()?;
    for f in plots {
        crate::outln!("plot: {}", f.display());
    }
    Ok(rows)
}
