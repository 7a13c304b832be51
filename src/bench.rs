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

use crate::adapt::{adaptive_points, compare_markdown, compare_runs, CurvePoint};
use crate::error::{Error, Result};
use crate::guards::peak_rss_kb;
use crate::linalg::{analyse, Solves, SystemPattern};
use crate::output::{read_result, OutputTransaction};
use crate::pipeline::scene_mesh_in_temp;
use crate::plot;
use crate::run::run_scene;
use crate::scene::{read_toml_file, Scene};
use crate::study::{run_study, Study, StudyRow};
use crate::transfer::relative_errors;
use serde::Deserialize;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

// ---------------------------------------------------------------------------
// Configuration

/// A benchmark configuration (`pipelines/bench/*.toml`).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BenchConfig {
    pub name: String,
    /// Seconds per run for the iterative methods (Uzawa, …).
    pub cap_seconds: f64,
    /// Tolerances of the relative KKT measure, loosest first.
    pub tolerances: Vec<f64>,
    pub method: Vec<BenchMethod>,
    pub problem: Vec<BenchProblem>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BenchMethod {
    pub label: String,
    /// Overrides selecting the method, e.g. ["solver.method=active-set"].
    pub set: Vec<String>,
    /// This method's cap (default: the configuration's).
    pub cap_seconds: Option<f64>,
    /// Cost of one iteration in floors: "solve" (one solve with the fixed
    /// factorisation) or "factor" (a refactorisation, active-set).
    #[serde(default = "default_cost")]
    pub iteration_cost: String,
    /// Once capped at a level, report the finer levels as `>cap` without
    /// running them (default true).
    #[serde(default = "default_true")]
    pub skip_after_cap: bool,
    /// Cap relative to another method measured before at the same level:
    /// cap = factor × its time to `tol` (e.g. 1000 × active-set to 1e-6), so
    /// a capped run proves "at least factor× slower" directly.
    pub cap_relative: Option<CapRelative>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CapRelative {
    pub method: String,
    pub factor: f64,
    pub tol: f64,
}

fn default_true() -> bool {
    true
}

fn default_cost() -> String {
    "solve".into()
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BenchProblem {
    pub label: String,
    /// Scene file, relative to the configuration file.
    pub scene: String,
    /// Overrides for every run of this problem.
    #[serde(default)]
    pub set: Vec<String>,
    /// The level key (default "mesh.n") and its values.
    #[serde(default = "default_key")]
    pub key: String,
    pub levels: Vec<toml::Value>,
    /// Extra overrides per method label, e.g. uzawa = ["solver.alpha=0.01"].
    #[serde(default)]
    pub method_set: BTreeMap<String, Vec<String>>,
    /// Methods run on this problem (default: all).
    pub methods: Option<Vec<String>>,
    /// Levels per method label (default: all levels). The others get no
    /// row, unless the method was capped at a coarser level: then they are
    /// "not run" with the cap as their lower bound, like every level after
    /// a capped one.
    #[serde(default)]
    pub method_levels: BTreeMap<String, Vec<toml::Value>>,
}

fn default_key() -> String {
    "mesh.n".into()
}

impl BenchConfig {
    pub fn load(path: &Path) -> Result<BenchConfig> {
        let err = |field: &str, reason: String| Error::Scene {
            file: path.to_path_buf(),
            field: field.into(),
            reason,
        };
        let cfg: BenchConfig = read_toml_file(path)?;
        if cfg.tolerances.is_empty()
            || cfg
                .tolerances
                .iter()
                .any(|t| t.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater))
        {
            return Err(err("tolerances", "at least one, all > 0".into()));
        }
        if cfg.cap_seconds.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            return Err(err("cap_seconds", "must be > 0".into()));
        }
        // Each of these becomes part of a file name.
        crate::names::check_name(&cfg.name).map_err(|reason| err("name", reason))?;
        for p in &cfg.problem {
            crate::names::check_name(&p.label)
                .map_err(|reason| err("problem.label", format!("`{}` {reason}", p.label)))?;
        }
        for m in &cfg.method {
            crate::names::check_name(&m.label)
                .map_err(|reason| err("method.label", format!("`{}` {reason}", m.label)))?;
            if m.iteration_cost != "solve" && m.iteration_cost != "factor" {
                return Err(err(
                    "method.iteration_cost",
                    format!("`{}`: \"solve\" or \"factor\"", m.iteration_cost),
                ));
            }
        }
        Ok(cfg)
    }
}

// ---------------------------------------------------------------------------
// The child process

/// One case; returns the `key=value` fields of its `BENCH` line.
pub fn run_case(
    scene_path: &Path,
    set: &[String],
    out: &Path,
    linear: bool,
    tols: &[f64],
) -> Result<String> {
    let start = Instant::now();
    let scene = Scene::load(scene_path, set)?;
    let mut f: Vec<(String, String)> = Vec::new();
    if linear {
        let mesh = scene_mesh_in_temp(&scene)?;
        push_phase_rss(&mut f, "meshing");
        let (system, problem) = crate::pipeline::assembled(&scene, &mesh)?;
        // Peak RSS so far: meshing and assembly (coordinate triplets) alone.
        push_phase_rss(&mut f, "assembly");
        // One factorisation and the one checked solve of A x = F …
        let t = Instant::now();
        let pattern = SystemPattern {
            matrix: &problem.matrix,
            kind: problem.kind,
            solves: Solves::Few,
            interior: problem.interior.as_ref(),
            what: "system matrix",
        };
        let mut factorizer = analyse(pattern, &crate::pipeline::linear_options(&scene.solver))?;
        let analyze = t.elapsed().as_secs_f64();
        let (factorization, _, _) = factorizer.factor_and_solve(&problem.matrix, &problem.rhs)?;
        let factor_and_solve = t.elapsed().as_secs_f64();
        push_phase_rss(&mut f, "factorisation");
        // … and one more solve, timed alone (the iteration-cost calibration).
        let t = Instant::now();
        let mut x = problem.rhs.clone();
        factorization.solve_in_place(&mut x);
        let solve = t.elapsed().as_secs_f64();
        let factor = (factor_and_solve - solve).max(0.0);
        f.push(("n_dofs".into(), system.n_dofs().to_string()));
        f.push(("n_unknowns".into(), problem.n().to_string()));
        f.push(("n_multipliers".into(), problem.n_multipliers().to_string()));
        f.push(("factor_seconds".into(), format!("{factor:e}")));
        // Of it, the symbolic analysis (with condensation: the plan and S's).
        f.push(("analyze_seconds".into(), format!("{analyze:e}")));
        let counts = factorizer.counts();
        f.push((
            "factorized_order".into(),
            counts.factorized_order.to_string(),
        ));
        // More than one analysis: the factorisation took a fallback.
        f.push((
            "symbolic_analyses".into(),
            counts.symbolic_analyses.to_string(),
        ));
        f.push(("solve_seconds".into(), format!("{solve:e}")));
        f.push(("seconds".into(), format!("{factor_and_solve:e}")));
    } else {
        let s = run_scene(&scene, out, false)?;
        f.push(("n_dofs".into(), s.n_dofs.to_string()));
        f.push(("iterations".into(), s.iterations.to_string()));
        f.push(("converged".into(), s.converged.to_string()));
        f.push(("stop".into(), s.stop_reason.clone()));
        f.push(("kkt".into(), format!("{:e}", s.measures.kkt)));
        f.push((
            "interior_iterate".into(),
            s.ended_in_interior_point().to_string(),
        ));
        f.push(("seconds".into(), format!("{:e}", s.solver_seconds)));
        f.push(("factor_seconds".into(), format!("{:e}", s.factor_seconds)));
        for (phase, mb) in &s.peak_rss_mb {
            f.push((format!("rss_kb_{phase}"), format!("{:.0}", mb * 1024.0)));
        }
        let kkt = s.history.column("kkt").unwrap_or(&[]);
        for &tol in tols {
            let first = kkt.iter().position(|&v| v <= tol).map(|k| k + 1);
            f.push((
                format!("first_{tol:e}"),
                first.map_or("-".into(), |k| k.to_string()),
            ));
            // An estimate only from a long enough history (short ones are
            // still in their fast initial phase).
            if first.is_none() && kkt.len() >= MIN_ITERATIONS_FOR_ESTIMATE {
                if let Some(k) = extrapolate_iterations(kkt, tol) {
                    f.push((format!("estimate_{tol:e}"), format!("{k:e}")));
                }
            }
        }
    }
    f.push((
        "total_seconds".into(),
        format!("{:e}", start.elapsed().as_secs_f64()),
    ));
    f.push((
        "peak_rss_kb".into(),
        peak_rss_kb().map_or("-".into(), |v| v.to_string()),
    ));
    Ok(f.iter()
        .map(|(k, v)| format!("{k}={v}"))
        .collect::<Vec<_>>()
        .join(" "))
}

/// The peak RSS so far as the field `rss_kb_<phase>` of the `BENCH` line.
fn push_phase_rss(f: &mut Vec<(String, String)>, phase: &str) {
    if let Some(kb) = peak_rss_kb() {
        f.push((format!("rss_kb_{phase}"), kb.to_string()));
    }
}

/// The phases whose peak RSS a child reports, in order (the floor's
/// factorisation, a contact run's solve).
const RSS_PHASES: [&str; 4] = ["meshing", "assembly", "factorisation", "solve"];

/// Capped runs shorter than this give no estimate of the time to the tolerance.
pub const MIN_ITERATIONS_FOR_ESTIMATE: usize = 1000;

/// Iterations to reach `tol` when the KKT history keeps the linear rate of
/// its second half: K + ln(tol/kkt_K)/ln ρ, ρ = (kkt_K/kkt_{K/2})^{1/(K−K/2)}.
/// None when there is no decrease.
pub fn extrapolate_iterations(kkt: &[f64], tol: f64) -> Option<f64> {
    let k = kkt.len();
    if k < 4 {
        return None;
    }
    let (a, b) = (kkt[k / 2], kkt[k - 1]);
    if !(a > 0.0 && b > 0.0 && b < a) {
        return None;
    }
    let rho = (b / a).ln() / (k - 1 - k / 2) as f64;
    Some(k as f64 + (tol / b).ln() / rho)
}

// ---------------------------------------------------------------------------
// The driver

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

type Fields = BTreeMap<String, String>;

fn parse_line(stdout: &str) -> Option<Fields> {
    let line = stdout.lines().rev().find(|l| l.starts_with("BENCH "))?;
    Some(
        line["BENCH ".len()..]
            .split_whitespace()
            .filter_map(|kv| kv.split_once('='))
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect(),
    )
}

fn num(f: &Fields, k: &str) -> f64 {
    f.get(k).and_then(|v| v.parse().ok()).unwrap_or(f64::NAN)
}

/// Runs `obstacle bench case …` and waits at most `limit`.
fn child(
    scene: &Path,
    set: &[String],
    out: &Path,
    linear: bool,
    tols: &[f64],
    limit: Duration,
) -> std::result::Result<Fields, String> {
    let exe = std::env::current_exe().map_err(|e| format!("current_exe: {e}"))?;
    let mut cmd = Command::new(exe);
    cmd.arg("bench")
        .arg("case")
        .arg(scene)
        .arg("--out")
        .arg(out);
    for s in set {
        cmd.arg("--set").arg(s);
    }
    if linear {
        cmd.arg("--linear");
    }
    if !tols.is_empty() {
        let t: Vec<String> = tols.iter().map(|t| format!("{t:e}")).collect();
        cmd.arg("--tols").arg(t.join(","));
    }
    let stdout_path = out.with_extension("stdout");
    let stderr_path = out.with_extension("stderr");
    let so = std::fs::File::create(&stdout_path).map_err(|e| e.to_string())?;
    let se = std::fs::File::create(&stderr_path).map_err(|e| e.to_string())?;
    let mut proc = cmd
        .stdout(Stdio::from(so))
        .stderr(Stdio::from(se))
        .spawn()
        .map_err(|e| format!("cannot start the child: {e}"))?;
    let start = Instant::now();
    let status = loop {
        if let Some(s) = proc.try_wait().map_err(|e| e.to_string())? {
            break s;
        }
        if start.elapsed() > limit {
            let _ = proc.kill();
            let _ = proc.wait();
            return Err(format!("killed after {:.0} s", limit.as_secs_f64()));
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let stdout = std::fs::read_to_string(&stdout_path).unwrap_or_default();
    let stderr = std::fs::read_to_string(&stderr_path).unwrap_or_default();
    if !status.success() {
        let msg = stderr
            .lines()
            .rev()
            .find(|l| l.starts_with("error"))
            .unwrap_or("failed")
            .to_string();
        return Err(msg);
    }
    parse_line(&stdout).ok_or_else(|| "no BENCH line".to_string())
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

fn write(path: &Path, text: &str) -> Result<()> {
    crate::output::write_text_atomically(path, text)
}

/// Seconds with three significant digits.
fn secs(t: f64) -> String {
    if !t.is_finite() {
        "–".into()
    } else if t >= 100.0 {
        format!("{t:.0}")
    } else if t >= 0.01 {
        format!("{:.*}", (2.0 - t.log10().floor()).max(0.0) as usize, t)
    } else {
        format!("{t:.2e}")
    }
}

fn fmt_time(r: &BenchRow) -> String {
    match r.status.as_str() {
        "converged" => secs(r.seconds),
        "capped" | "killed" | "not run" => format!(">{}", secs(r.seconds)),
        _ => "failed".into(),
    }
}

/// Marks the iterations of a run that ended inside the interior-point start.
const INTERIOR_MARK: &str = "†";

/// The table: one row per (problem, level, method), the tolerances side by side.
pub fn bench_markdown(
    cfg: &BenchConfig,
    rows: &[BenchRow],
    floors: &[(String, String, usize, f64, f64)],
) -> String {
    let mut tols: Vec<f64> = cfg.tolerances.clone();
    tols.sort_by(|a, b| b.total_cmp(a));
    let mut md = format!(
        "## Benchmark `{}`: time to the relative KKT measure (cap {} s per run unless stated)\n\n",
        cfg.name, cfg.cap_seconds
    );
    md.push_str("Times: solver wall time (factorisations + iterations), seconds; `>t`: capped (lower bound); est.: extrapolated from the KKT rate of the capped run. Memory: peak RSS (VmHWM) of the child process of the run. ×floor: time / (one factorisation + one solve without contact).\n\n");
    let mut head = vec!["problem", "level", "dofs", "method"]
        .into_iter()
        .map(String::from)
        .collect::<Vec<_>>();
    for t in &tols {
        head.push(format!("it ({t:.0e})"));
        head.push(format!("time ({t:.0e})"));
        head.push(format!("×floor ({t:.0e})"));
        head.push(format!("MB ({t:.0e})"));
    }
    head.push("est. time (loosest)".into());
    let _ = writeln!(md, "| {} |", head.join(" | "));
    let _ = writeln!(md, "|{}", "---|".repeat(head.len()));
    for (prob, level, dofs, floor, mem) in floors {
        let _ = writeln!(
            md,
            "| {prob} | {level} | {dofs} | **linear solve (floor)** | 1 | {} | 1 | {mem:.0} |{}",
            secs(*floor),
            " | | | |".repeat(tols.len() - 1) + " |"
        );
        let methods: Vec<String> = cfg.method.iter().map(|m| m.label.clone()).collect();
        for m in &methods {
            let cells: Vec<&BenchRow> = tols
                .iter()
                .filter_map(|t| {
                    rows.iter().find(|r| {
                        &r.problem == prob && &r.level == level && &r.method == m && r.tol == *t
                    })
                })
                .collect();
            if cells.is_empty() {
                continue;
            }
            let mut line = vec![prob.clone(), level.clone(), dofs.to_string(), m.clone()];
            for r in &cells {
                line.push(r.iterations.map_or("–".into(), |k| {
                    match (r.status == "converged", r.interior) {
                        (true, false) => k.to_string(),
                        (true, true) => format!("{k}{INTERIOR_MARK}"),
                        (false, _) => format!(">{k}"),
                    }
                }));
                line.push(fmt_time(r));
                let ratio = r.seconds / r.floor_seconds;
                line.push(if r.status == "converged" {
                    format!("{ratio:.1}")
                } else if ratio.is_finite() {
                    format!(">{ratio:.0}")
                } else {
                    "–".into()
                });
                line.push(if r.peak_rss_mb.is_finite() {
                    format!("{:.0}", r.peak_rss_mb)
                } else {
                    "–".into()
                });
            }
            line.push(
                cells
                    .first()
                    .and_then(|r| r.estimate_seconds)
                    .map_or("".into(), |e| format!("~{e:.3e}")),
            );
            let _ = writeln!(md, "| {} |", line.join(" | "));
        }
    }
    if rows.iter().any(|r| r.interior) {
        let _ = writeln!(
            md,
            "\n{INTERIOR_MARK}: the run (a re-run with `max_iter` at the step where the tightest run first met this tolerance) ended inside the active set's interior-point start: its iterate meets the tolerance by the KKT measure but is interior (λ > 0 on every constraint), not a complementary pair, whose finish takes the tighter run's PDAS steps (docs/work-precision.md)."
        );
    }
    md.push_str(&targets(cfg, rows));
    md
}

/// Peak RSS of one child at the end of each phase (MB, `RSS_PHASES` order;
/// NaN for a phase the child does not have).
pub struct PhaseRss {
    pub problem: String,
    pub level: String,
    pub method: String,
    pub mb: [f64; RSS_PHASES.len()],
}

impl PhaseRss {
    fn new(problem: &str, level: &str, method: &str, f: &Fields) -> Self {
        PhaseRss {
            problem: problem.into(),
            level: level.into(),
            method: method.into(),
            mb: RSS_PHASES.map(|phase| num(f, &format!("rss_kb_{phase}")) / 1024.0),
        }
    }
}

/// The memory table: peak RSS so far at the end of each phase, per child.
pub fn phase_rss_markdown(rows: &[PhaseRss], tightest: f64) -> String {
    let mut md = format!(
        "\n### Peak RSS per phase (MB; VmHWM at the end of each phase, so each column includes the ones before; contact runs at tol {tightest:.0e}, nested levels inside `solve`)\n\n| problem | level | run | {} |\n|---|---|---|{}\n",
        RSS_PHASES.join(" | "),
        "---|".repeat(RSS_PHASES.len())
    );
    for r in rows {
        let cells: Vec<String> =
            r.mb.iter()
                .map(|v| {
                    if v.is_finite() {
                        format!("{v:.0}")
                    } else {
                        "–".into()
                    }
                })
                .collect();
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} |",
            r.problem,
            r.level,
            r.method,
            cells.join(" | ")
        );
    }
    md
}

/// The issue's targets, checked on the rows.
pub fn targets(cfg: &BenchConfig, rows: &[BenchRow]) -> String {
    let mut md = String::from("\n### Targets\n\n");
    let tightest = cfg.tolerances.iter().copied().fold(f64::INFINITY, f64::min);
    let as_rows: Vec<&BenchRow> = rows
        .iter()
        .filter(|r| r.method == "active-set" && r.tol == tightest)
        .collect();
    if !as_rows.is_empty() {
        let _ = writeln!(
            md,
            "1. active-set to {tightest:.0e} within 10× the linear solve at every size:"
        );
        let mut all = true;
        for r in &as_rows {
            let ratio = r.seconds / r.floor_seconds;
            let ok = r.status == "converged" && ratio <= 10.0;
            all &= ok;
            let _ = writeln!(
                md,
                "   - {} {}: {}{:.1}× ({} iterations, {} s vs floor {} s, {} of it in factorisations) — {}",
                r.problem,
                r.level,
                if r.status == "converged" { "" } else { ">" },
                ratio,
                r.iterations.map_or("?".into(), |k| k.to_string()),
                secs(r.seconds),
                secs(r.floor_seconds),
                if r.factor_seconds.is_finite() {
                    format!("{:.0}%", 100.0 * r.factor_seconds / r.seconds)
                } else {
                    "–".into()
                },
                if ok { "met" } else { "NOT met" }
            );
        }
        let _ = writeln!(md, "   - overall: {}", if all { "met" } else { "NOT met" });
    }
    let loose = 1e-6;
    {
        let prob = "shell";
        let find = |m: &str| {
            rows.iter()
                .find(|r| r.problem == prob && r.level == "64" && r.method == m && r.tol == loose)
        };
        if let (Some(a), Some(u)) = (find("active-set"), find("uzawa")) {
            let ratio = u.seconds / a.seconds;
            let est = u.estimate_seconds.map(|e| e / a.seconds);
            let _ = writeln!(
                md,
                "2. active-set ≥ 1000× faster than thesis Uzawa (α = 0.01) to 1e-6 at {prob} n = 64: Uzawa {} s, active-set {} s: ratio {}{ratio:.1}{}{} — {}",
                fmt_time(u),
                fmt_time(a),
                if u.status == "converged" { "" } else { "> " },
                if a.status == "converged" { "" } else { " (active-set capped too)" },
                est.map_or(String::new(), |e| format!(" (estimated from the KKT rate: ~{e:.0})")),
                if u.status == "converged" && a.status == "converged" {
                    if ratio >= 1000.0 { "met" } else { "NOT met" }
                } else if ratio >= 1000.0 {
                    "met (lower bound)"
                } else if est.is_some_and(|e| e >= 1000.0) {
                    "met by the estimate only (the lower bound is below 1000)"
                } else {
                    "not shown"
                }
            );
        }
    }
    md
}

pub fn bench_csv(rows: &[BenchRow]) -> String {
    let mut csv = String::from("problem,level,n_dofs,method,tol,status,iterations,seconds,factor_seconds,total_seconds,peak_rss_mb,kkt,floor_seconds,ratio_to_floor,estimate_seconds,note\n");
    for r in rows {
        let _ = writeln!(
            csv,
            "{},{},{},{},{:e},{},{},{:e},{:e},{:e},{:.1},{:e},{:e},{:e},{},{}",
            r.problem,
            r.level,
            r.n_dofs,
            r.method,
            r.tol,
            r.status,
            r.iterations.map_or(String::new(), |k| k.to_string()),
            r.seconds,
            r.factor_seconds,
            r.total_seconds,
            r.peak_rss_mb,
            r.kkt,
            r.floor_seconds,
            r.seconds / r.floor_seconds,
            r.estimate_seconds
                .map_or(String::new(), |e| format!("{e:e}")),
            match r.interior {
                true => format!("interior iterate {}", r.note)
                    .trim_end()
                    .replace(',', ";"),
                false => r.note.replace(',', ";"),
            }
        );
    }
    csv
}

/// Time against the level, log–log, one figure per (problem, tolerance): a
/// curve per method (converged runs only) and the floor.
fn bench_plots(
    cfg: &BenchConfig,
    rows: &[BenchRow],
    floors: &[(String, String, usize, f64, f64)],
    outputs: &OutputTransaction,
) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    let problems: Vec<String> = cfg.problem.iter().map(|p| p.label.clone()).collect();
    for prob in &problems {
        for &tol in &cfg.tolerances {
            let mut series: Vec<(String, Vec<(f64, f64)>)> = cfg
                .method
                .iter()
                .map(|m| {
                    let pts = rows
                        .iter()
                        .filter(|r| {
                            &r.problem == prob
                                && r.method == m.label
                                && r.tol == tol
                                && r.status == "converged"
                        })
                        .filter_map(|r| r.level.parse::<f64>().ok().map(|n| (n, r.seconds)))
                        .collect();
                    (m.label.clone(), pts)
                })
                .filter(|(_, p): &(String, Vec<(f64, f64)>)| !p.is_empty())
                .collect();
            series.push((
                "linear solve (floor)".into(),
                floors
                    .iter()
                    .filter(|f| &f.0 == prob)
                    .filter_map(|f| f.1.parse::<f64>().ok().map(|n| (n, f.3)))
                    .collect(),
            ));
            let path = outputs
                .folder()
                .join(format!("{}-{prob}-{tol:.0e}.png", cfg.name));
            plot::plot_convergence(
                &outputs.stage(&path)?,
                &series,
                "n (mesh level)",
                "solver wall time [s]",
                &format!("{prob}: time to KKT ≤ {tol:.0e} (converged runs)"),
                &[],
            )?;
            files.push(path);
        }
    }
    Ok(files)
}

// ---------------------------------------------------------------------------
// Work–precision

/// The error measures of a study run, by name.
type ErrorsOf<'a> = dyn FnMut(&StudyRow) -> Result<Vec<(String, f64)>> + 'a;

/// One point of a work–precision diagram.
#[derive(Debug, Clone)]
pub struct WpPoint {
    pub element: String,
    pub method: String,
    pub level: String,
    pub tol: f64,
    pub seconds: f64,
    pub iterations: usize,
    /// (measure, error)
    pub errors: Vec<(String, f64)>,
}

fn label(row: &StudyRow, key: &str) -> Option<String> {
    row.labels
        .iter()
        .find(|(k, _)| k == key)
        .map(|(_, v)| v.trim_matches('"').to_string())
}

fn study_scene_value(study: &Study, study_path: &Path, key: &str) -> Option<String> {
    let scene = Scene::load(
        &study_path
            .parent()
            .unwrap_or(Path::new("."))
            .join(&study.scene),
        &study.set,
    )
    .ok()?;
    match key {
        "element" => Some(scene.element.name().to_string()),
        "solver.method" => Some(scene.solver.method.name().to_string()),
        _ => None,
    }
}

fn study_points(path: &Path, out_dir: &Path, errors: &mut ErrorsOf) -> Result<Vec<WpPoint>> {
    let study = Study::load(path)?;
    eprintln!("study {} ({} runs)", study.name, study.runs().len());
    let rows = run_study(path, out_dir, false, 1)?;
    let element0 = study_scene_value(&study, path, "element").unwrap_or_default();
    let method0 = study_scene_value(&study, path, "solver.method").unwrap_or_default();
    let mut pts = Vec::new();
    for row in rows.iter() {
        if row.failure.is_some() {
            eprintln!("  failed: {:?}", row.failure);
            continue;
        }
        let tol = label(row, "solver.tol")
            .and_then(|t| t.parse().ok())
            .unwrap_or(f64::NAN);
        pts.push(WpPoint {
            element: label(row, "element").unwrap_or_else(|| element0.clone()),
            method: label(row, "solver.method").unwrap_or_else(|| method0.clone()),
            level: label(row, "mesh.n").unwrap_or_default(),
            tol,
            seconds: row.summary.solver_seconds,
            iterations: row.summary.iterations,
            errors: errors(row)?,
        });
    }
    Ok(pts)
}

/// `make study`: work–precision diagrams and the algebraic/discretisation balance.
pub fn work_precision(
    exact: &[PathBuf],
    against: &[PathBuf],
    adapt: &[PathBuf],
    reference: Option<&Path>,
    fields: &[String],
    out_dir: &Path,
) -> Result<()> {
    std::fs::create_dir_all(out_dir)
        .map_err(|e| Error::output(out_dir, format!("cannot create: {e}")))?;
    let runs = out_dir.join("runs");
    let inputs: Vec<PathBuf> = exact
        .iter()
        .chain(against)
        .chain(adapt)
        .cloned()
        .chain(reference.map(Path::to_path_buf))
        .collect();
    // The report, its CSV and its figures appear together.
    let outputs = OutputTransaction::new(out_dir, "work-precision", &inputs)?;
    let mut md = String::from("# Work–precision: what accuracy costs in time\n\nGenerated by `make study` (`obstacle bench study`). Time: the solver's wall time (factorisations + iterations; meshing, assembly and output excluded), one run per point. Points: mesh level × solver tolerance (relative KKT measure).\n");
    let mut csv = String::from("part,element,method,level,tol,seconds,iterations,measure,error\n");
    let mut parts: Vec<(String, Vec<WpPoint>)> = Vec::new();
    let mut disk = Vec::new();
    for p in exact {
        disk.extend(study_points(p, &runs, &mut |row: &StudyRow| {
            let s = &row.summary;
            Ok(s.errors
                .map(|e| {
                    vec![
                        ("L2 u".to_string(), e.l2),
                        ("H1 u".to_string(), e.h1),
                        (
                            "contact radius".to_string(),
                            (e.contact_radius - e.exact_contact_radius).abs(),
                        ),
                    ]
                })
                .unwrap_or_default())
        })?);
    }
    if !disk.is_empty() {
        parts.push(("disk (errors against the exact solution)".into(), disk));
    }
    if let Some(r) = reference {
        let rows = run_study(r, &runs, false, 1)?;
        match rows.iter().find(|r| r.failure.is_none()) {
            None => {
                let why: Vec<String> = rows.iter().filter_map(|r| r.failure.clone()).collect();
                eprintln!("the reference run failed: {}", why.join("; "));
                let _ = writeln!(
                    md,
                    "\nThe shell reference run failed ({}): no shell errors.",
                    why.join("; ")
                );
            }
            Some(rrow) => {
                let ref_path = rrow.summary.result_file.clone();
                let ref_file = read_result(&ref_path)?;
                let _ = writeln!(
                    md,
                    "\nShell reference: {} ({} dofs, h = {:.3}, {} iterations, KKT {:.1e}, {:.1} s).",
                    ref_path.display(),
                    rrow.summary.n_dofs,
                    rrow.summary.h,
                    rrow.summary.iterations,
                    rrow.summary.measures.kkt,
                    rrow.summary.solver_seconds
                );
                let mut shell = Vec::new();
                for p in against {
                    shell.extend(study_points(p, &runs, &mut |row: &StudyRow| {
                        let f = read_result(&row.summary.result_file)?;
                        let e = relative_errors(
                            (&f, &row.summary.result_file),
                            (&ref_file, &ref_path),
                            fields,
                        )?;
                        Ok(group_components(&e))
                    })?);
                }
                if !shell.is_empty() {
                    parts.push((
                        "shell (relative L² errors against the reference)".into(),
                        shell,
                    ));
                }
            }
        }
    }
    for (k, (title, pts)) in parts.iter().enumerate() {
        let tag = if k == 0 && !exact.is_empty() {
            "disk"
        } else {
            "shell"
        };
        let _ = writeln!(md, "\n## {title}\n");
        let measures: Vec<String> = pts
            .first()
            .map(|p| p.errors.iter().map(|(n, _)| n.clone()).collect())
            .unwrap_or_default();
        for p in pts {
            for (m, e) in &p.errors {
                let _ = writeln!(
                    csv,
                    "{tag},{},{},{},{:e},{:e},{},{m},{e:e}",
                    p.element, p.method, p.level, p.tol, p.seconds, p.iterations
                );
            }
        }
        let mut curves: Vec<(String, String)> = Vec::new();
        for p in pts {
            let c = (p.element.clone(), p.method.clone());
            if !curves.contains(&c) {
                curves.push(c);
            }
        }
        for (mi, measure) in measures.iter().enumerate() {
            let series: Vec<(String, Vec<(f64, f64)>)> = curves
                .iter()
                .map(|(el, me)| {
                    (
                        format!("{el} {me}"),
                        pts.iter()
                            .filter(|p| &p.element == el && &p.method == me)
                            .map(|p| (p.seconds, p.errors[mi].1))
                            .collect(),
                    )
                })
                .collect();
            let file = format!("wp-{tag}-{}.png", measure.replace([' ', '/'], "_"));
            plot::plot_convergence(
                &outputs.stage(&out_dir.join(&file))?,
                &series,
                "solver wall time [s]",
                &format!("error: {measure}"),
                &format!("{tag}: {measure} error vs time"),
                &[],
            )?;
            let _ = writeln!(md, "![{measure}]({file})\n");
        }
        // Every point.
        let _ = writeln!(
            md,
            "| element | method | n | tol | iter | time [s] | {} |",
            measures.join(" | ")
        );
        let _ = writeln!(md, "|{}", "---|".repeat(6 + measures.len()));
        for p in pts {
            let errs: Vec<String> = p.errors.iter().map(|(_, e)| format!("{e:.3e}")).collect();
            let _ = writeln!(
                md,
                "| {} | {} | {} | {:.0e} | {} | {:.4} | {} |",
                p.element,
                p.method,
                p.level,
                p.tol,
                p.iterations,
                p.seconds,
                errs.join(" | ")
            );
        }
        md.push_str(&balance(pts, &measures));
    }
    for scene in adapt {
        adaptive_curves(scene, &runs, out_dir, &outputs, &mut md, &mut csv)?;
    }
    write(&outputs.stage(&out_dir.join("report.md"))?, &md)?;
    write(&outputs.stage(&out_dir.join("work-precision.csv"))?, &csv)?;
    outputs.commit()?;
    crate::outln!("{md}");
    crate::outln!("report: {}", out_dir.join("report.md").display());
    Ok(())
}

/// The membrane pairs `make study` runs each `[adapt]` scene with.
const ADAPT_PAIRS: [&str; 2] = ["p1b-p0", "p2-p1"];

/// `make study`'s adaptive part for one `[adapt]` scene: both pairs, the
/// adaptive loop beside the uniform levels ([`crate::adapt::compare_runs`]);
/// one figure per case and axis (H¹ error against dofs, against the whole
/// wall time: meshing, remeshing and transfer included), the tables and the
/// time to the finest uniform error.
fn adaptive_curves(
    scene_path: &Path,
    runs: &Path,
    out_dir: &Path,
    outputs: &OutputTransaction,
    md: &mut String,
    csv: &mut String,
) -> Result<()> {
    let mut name = String::new();
    let mut curves: Vec<(String, Vec<CurvePoint>)> = Vec::new();
    let mut tables = String::new();
    for pair in ADAPT_PAIRS {
        let overrides = [format!("element=\"{pair}\""), "output.plots=[]".to_string()];
        let scene = Scene::load(scene_path, &overrides)?;
        eprintln!("adaptive vs uniform: {} ({pair})", scene.name);
        let (rows, uniform) = compare_runs(&scene, runs)?;
        tables.push_str(&compare_markdown(
            &format!("{}-{pair}", scene.name),
            &rows,
            &uniform,
        ));
        let adaptive = adaptive_points(&rows);
        for (kind, pts) in [("adaptive", &adaptive), ("uniform", &uniform)] {
            // The level column holds the dofs.
            for (dofs, error, seconds) in pts.iter() {
                let _ = writeln!(
                    csv,
                    "adapt-{},{pair},{kind},{dofs},,{seconds:e},,H1 u,{error:e}",
                    scene.name
                );
            }
        }
        curves.push((format!("{pair} adaptive"), adaptive));
        curves.push((format!("{pair} uniform"), uniform));
        name = scene.name;
    }
    let _ = writeln!(
        md,
        "\n## {name}: adaptive vs uniform (H¹ error of u)\n\nTime here: the whole run's wall time (meshing, assembly, solve; adaptive: every step so far, estimate, remeshing and transfer included). Uniform: `mesh.n` = {:?}.\n",
        crate::adapt::UNIFORM_LEVELS
    );
    type Pick = fn(&CurvePoint) -> (f64, f64);
    let axes: [(&str, &str, Pick); 2] = [
        ("dofs", "dofs", |p| (p.0, p.1)),
        (
            "time",
            "wall seconds (meshing, remeshing and transfer included)",
            |p| (p.2, p.1),
        ),
    ];
    for (axis, x_label, pick) in axes {
        let series: Vec<(String, Vec<(f64, f64)>)> = curves
            .iter()
            .map(|(label, pts)| (label.clone(), pts.iter().map(pick).collect()))
            .collect();
        let file = format!("adapt-{name}.{axis}.png");
        plot::plot_convergence(
            &outputs.stage(&out_dir.join(&file))?,
            &series,
            x_label,
            "H¹ error",
            &format!("{name}: adaptive vs uniform"),
            if axis == "dofs" { &[-0.5, -1.0] } else { &[] },
        )?;
        let _ = writeln!(md, "![{name} against {axis}]({file})\n");
    }
    md.push_str(&tables);
    Ok(())
}

/// Shell components grouped as the issue asks: u_β (u1, u2), u3, r, ψ, λ
/// (vector components combined as the root of the sum of squares).
fn group_components(e: &[(String, f64)]) -> Vec<(String, f64)> {
    let get = |names: &[&str]| -> Option<f64> {
        let v: Vec<f64> = e
            .iter()
            .filter(|(n, _)| names.contains(&n.as_str()))
            .map(|(_, x)| *x)
            .collect();
        (!v.is_empty()).then(|| v.iter().map(|x| x * x).sum::<f64>().sqrt())
    };
    let mut out = Vec::new();
    for (name, parts) in [
        ("u_beta", &["u1", "u2"][..]),
        ("u3", &["u3"][..]),
        ("r", &["r1", "r2", "r3", "r"][..]),
        ("psi", &["psi"][..]),
        ("lambda", &["lambda"][..]),
    ] {
        if let Some(x) = get(parts) {
            out.push((name.to_string(), x));
        }
    }
    out
}

/// Per (element, method, level): the loosest tolerance whose errors are all
/// within 5% of the tightest tolerance's, and the time it saves.
pub fn balance(pts: &[WpPoint], measures: &[String]) -> String {
    let mut md = String::from("\n### Algebraic vs discretisation error\n\nPer (element, solver, level): the loosest tolerance whose errors (every measure) are within 5% of those at the tightest tolerance, and its time against the tightest.\n\n| element | method | n | tightest tol | its time [s] | loosest sufficient tol | its time [s] | saved |\n|---|---|---|---|---|---|---|---|\n");
    let mut keys: Vec<(String, String, String)> = Vec::new();
    for p in pts {
        let k = (p.element.clone(), p.method.clone(), p.level.clone());
        if !keys.contains(&k) {
            keys.push(k);
        }
    }
    for (el, me, lv) in keys {
        let mut group: Vec<&WpPoint> = pts
            .iter()
            .filter(|p| p.element == el && p.method == me && p.level == lv)
            .collect();
        group.sort_by(|a, b| a.tol.total_cmp(&b.tol)); // tightest first
        let Some(tight) = group.first() else { continue };
        let ok = |p: &WpPoint| {
            p.errors
                .iter()
                .zip(&tight.errors)
                .all(|((_, e), (_, t))| (e - t).abs() <= 0.05 * t.abs().max(1e-300))
        };
        // The loosest tolerance such that it and every tighter one are fine.
        let mut best = *tight;
        for p in &group {
            if ok(p) {
                best = p;
            } else {
                break;
            }
        }
        let _ = writeln!(
            md,
            "| {el} | {me} | {lv} | {:.0e} | {:.4} | {:.0e} | {:.4} | {:.0}% |",
            tight.tol,
            tight.seconds,
            best.tol,
            best.seconds,
            100.0 * (1.0 - best.seconds / tight.seconds)
        );
    }
    let _ = measures;
    md
}
