//! The child process of a benchmark case: `obstacle bench case …` solves one
//! case and prints its `BENCH key=value …` line (times, iterations, peak RSS
//! per phase); the parent starts it with a time limit and reads that line.

use crate::error::Result;
use crate::guards::peak_rss_kb;
use crate::linalg::{analyse, Solves, SystemPattern};
use crate::pipeline::scene_mesh_in_temp;
use crate::run::run_scene;
use crate::scene::Scene;
use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

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
pub(super) const RSS_PHASES: [&str; 4] = ["meshing", "assembly", "factorisation", "solve"];

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

pub(super) type Fields = BTreeMap<String, String>;

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

pub(super) fn num(f: &Fields, k: &str) -> f64 {
    f.get(k).and_then(|v| v.parse().ok()).unwrap_or(f64::NAN)
}

/// Runs `obstacle bench case …` and waits at most `limit`.
pub(super) fn child(
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
