//! `make shell-multigrid-bench`: multigrid-preconditioned CG beside the
//! sparse direct solver on the shell's linear system (docs/solvers.md,
//! "Multigrid for the shell"): the thesis' hyperbolic paraboloid without its
//! obstacle (pipelines/scenes/naghdi-hypar-free.toml) with the `p2b-psri`
//! element, whose matrix is symmetric positive definite, for thicknesses t
//! from thick to thin (t/L = 1e-1 … 1e-4, L = 100 the side of the diamond)
//! on meshes/diamond.geo's 4 × 4 grid refined to N × N cells (N = 4 · 2^k).
//!
//! Multigrid: [`P2FieldLevels`] (P2 prolongation per field; the coarser levels
//! P2 alone, the finest level's bubbles smoothed only), Galerkin coarse
//! operators, V(1,1) with symmetric Gauss–Seidel in Cuthill–McKee order
//! (`MultigridOptions::default`), one thread; PCG from 0 to
//! ‖b − Ax‖₂ ≤ 1e-8 ‖b‖₂, at most 500 iterations. Direct: the matrix's
//! lower triangle factorised through the seam as the pipeline's one linear
//! solve does (`Solves::Few`, two threads).
//!
//! Usage: `shell_multigrid_bench [--thickness T,T,...] [--smoothing K]
//! [N ...]` (default N = 16 32 64, T = 10,1,0.1,0.01, K = 1: V(K,K)-cycles).
//! Each method at each case runs in a child process of this binary
//! (`--case N T K mg|direct`) so that its peak RSS is its own; the parent
//! prints one Markdown table.

use obstacle_fem::gmsh::run_gmsh;
use obstacle_fem::guards::peak_rss_kb;
use obstacle_fem::linalg::{factor_once, LinearOptions, MatrixKind, Solves, SystemPattern};
use obstacle_fem::mesh::{BoundaryGeometry, Hierarchy, Mesh};
use obstacle_fem::models::naghdi::system::{field_prolongations, NaghdiSystem};
use obstacle_fem::models::ModelSystem;
use obstacle_fem::multigrid::{pcg, Multigrid, MultigridOptions};
use obstacle_fem::scene::Scene;
use obstacle_fem::solvers::ContactProblem;
#[path = "common/child_case.rs"]
mod child_case;

use child_case::child_output;
use std::collections::BTreeMap;
use std::path::Path;
use std::time::Instant;

/// Relative residual ‖b − A x‖₂/‖b‖₂ PCG stops at.
const RTOL: f64 = 1e-8;
/// PCG's iteration cap.
const MAX_ITER: usize = 500;
/// Cells per side of the coarsest mesh.
const COARSE: usize = 4;
/// The span of the shell (the side of the diamond), for t/L.
const SPAN: f64 = 100.0;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.first().map(String::as_str) == Some("--case") {
        let usage = "--case N T K METHOD";
        let n: usize = args[1].parse().expect(usage);
        let t: f64 = args[2].parse().expect(usage);
        let smoothing: usize = args[3].parse().expect(usage);
        return run_case(n, t, smoothing, &args[4]);
    }
    let mut thicknesses = vec![10.0, 1.0, 0.1, 0.01];
    let mut smoothing = 1;
    let mut sizes = Vec::new();
    let mut rest = args.iter();
    while let Some(a) = rest.next() {
        match a.as_str() {
            "--thickness" => {
                let list = rest.next().expect("--thickness T,T,...");
                thicknesses = list
                    .split(',')
                    .map(|t| t.parse().expect("a thickness"))
                    .collect();
            }
            "--smoothing" => {
                smoothing = rest
                    .next()
                    .and_then(|k| k.parse().ok())
                    .expect("--smoothing K");
            }
            n => sizes.push(n.parse::<usize>().expect("sizes N")),
        }
    }
    if sizes.is_empty() {
        sizes = vec![16, 32, 64];
    }
    let exe = std::env::current_exe().expect("own path");
    println!("Multigrid: V({smoothing},{smoothing})-cycles.\n");
    println!(
        "| t | t/L | N | levels | unknowns | PCG iterations | PCG residual | MG setup s | \
         PCG s | MG peak MB | direct s | direct residual | direct peak MB | \
         direct / (MG setup + PCG) |"
    );
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for &t in &thicknesses {
        for &n in &sizes {
            let case = |method: &str| -> BTreeMap<String, String> {
                let args = ["--case", &n.to_string(), &t.to_string()]
                    .into_iter()
                    .map(String::from)
                    .chain([smoothing.to_string(), method.to_string()])
                    .collect::<Vec<_>>();
                child_output(&exe, &args, &format!("{method} at N = {n}, t = {t}"))
            };
            let (mg, direct) = (case("mg"), case("direct"));
            let f = |m: &BTreeMap<String, String>, k: &str| -> f64 { m[k].parse().unwrap() };
            let iterations = match mg["converged"].as_str() {
                "true" => mg["pcg_iterations"].clone(),
                _ => format!("no convergence in {}", mg["pcg_iterations"]),
            };
            println!(
                "| {t} | {:.0e} | {n} | {} | {} | {iterations} | {:.1e} | {:.2} | {:.2} | {:.0} | \
                 {:.2} | {:.0e} | {:.0} | {:.2}× |",
                t / SPAN,
                mg["levels"],
                mg["unknowns"],
                f(&mg, "relative_residual"),
                f(&mg, "setup_s"),
                f(&mg, "pcg_s"),
                f(&mg, "peak_mb"),
                f(&direct, "solve_s"),
                f(&direct, "relative_residual"),
                f(&direct, "peak_mb"),
                f(&direct, "solve_s") / (f(&mg, "setup_s") + f(&mg, "pcg_s")),
            );
        }
    }
}

/// One method at one size and thickness; prints `key=value` pairs.
fn run_case(n: usize, thickness: f64, smoothing: usize, method: &str) {
    assert!(
        n > COARSE && n.is_multiple_of(COARSE) && (n / COARSE).is_power_of_two(),
        "N must be {COARSE} · 2^k, k ≥ 1"
    );
    let refinements = (n / COARSE).trailing_zeros() as usize;
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let scene = Scene::load(
        &root.join("pipelines/scenes/naghdi-hypar-free.toml"),
        &[
            "element=\"p2b-psri\"".to_string(),
            format!("shell.thickness={thickness}"),
            format!("mesh.n={COARSE}"),
        ],
    )
    .expect("scene");
    let dir = tempfile::tempdir().expect("temporary directory");
    let msh = dir.path().join("coarse.msh");
    run_gmsh(
        &root.join("meshes/diamond.geo"),
        &msh,
        &[("n".into(), COARSE as f64)],
    )
    .expect("gmsh");
    let coarse = Mesh::read_msh(&msh).expect("coarse mesh");
    let t0 = Instant::now();
    let hierarchy =
        Hierarchy::new(coarse, refinements, BoundaryGeometry::straight()).expect("hierarchy");
    let finest = NaghdiSystem::setup(hierarchy.finest(), &scene).expect("shell setup");
    let problem = finest.assemble().expect("assembly");
    let assembly_s = t0.elapsed().as_secs_f64();
    assert_eq!(problem.kind, MatrixKind::SymmetricPositiveDefinite);
    assert_eq!(problem.n(), finest.numbering.n_free(), "no tied unknowns");
    print!(
        "levels={} unknowns={} entries_per_row={} assembly_s={assembly_s} ",
        refinements + 1,
        problem.n(),
        problem.matrix.val().len() as f64 / problem.n() as f64
    );
    match method {
        "mg" => run_multigrid(&hierarchy, &scene, finest, problem, smoothing),
        "direct" => run_direct(problem),
        other => panic!("unknown method {other} (mg or direct)"),
    }
    println!();
}

fn run_multigrid(
    hierarchy: &Hierarchy,
    scene: &Scene,
    finest: NaghdiSystem,
    problem: ContactProblem,
    smoothing: usize,
) {
    let t = Instant::now();
    let coarser: Vec<NaghdiSystem> = hierarchy.levels[..hierarchy.n_levels() - 1]
        .iter()
        .map(|m| NaghdiSystem::setup(m, scene).expect("shell setup"))
        .collect();
    let systems: Vec<&NaghdiSystem> = coarser.iter().chain([&finest]).collect();
    let shell_levels = field_prolongations(hierarchy, &systems).expect("prolongations");
    let mg = Multigrid::new(
        &problem.matrix,
        &shell_levels.prolongations,
        MultigridOptions {
            pre: smoothing,
            post: smoothing,
            ..MultigridOptions::default()
        },
    )
    .expect("multigrid setup");
    let setup_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let mut x = vec![0.0; problem.rhs.len()];
    let cg = pcg(
        &problem.matrix,
        &problem.rhs,
        &mut x,
        |r, z| mg.precondition(r, z),
        RTOL,
        MAX_ITER,
        1,
    );
    let pcg_s = t.elapsed().as_secs_f64();
    let peak_mb = peak_rss_kb().unwrap_or(0) as f64 / 1024.0;
    print!(
        "sizes={:?} setup_s={setup_s} pcg_iterations={} converged={} relative_residual={} \
         pcg_s={pcg_s} peak_mb={peak_mb}",
        mg.sizes(),
        cg.iterations,
        cg.converged,
        cg.relative_residual
    );
}

fn run_direct(mut problem: ContactProblem) {
    problem.store_lower_triangle();
    let t = Instant::now();
    let options = LinearOptions::default();
    let f = factor_once(
        SystemPattern {
            matrix: &problem.matrix,
            kind: problem.kind,
            solves: Solves::Few,
            interior: None,
            what: "shell stiffness",
        },
        &options,
    )
    .expect("factorisation");
    let mut x = problem.rhs.clone();
    f.solve_in_place(&mut x);
    let solve_s = t.elapsed().as_secs_f64();
    let peak_mb = peak_rss_kb().unwrap_or(0) as f64 / 1024.0;
    let ax = problem.product(&x, options.threads);
    let norm = |v: &[f64]| v.iter().map(|a| a * a).sum::<f64>().sqrt();
    let r: Vec<f64> = ax.iter().zip(&problem.rhs).map(|(a, b)| b - a).collect();
    print!(
        "solve_s={solve_s} peak_mb={peak_mb} relative_residual={}",
        norm(&r) / norm(&problem.rhs)
    );
}
