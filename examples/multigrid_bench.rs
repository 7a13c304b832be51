//! `make multigrid-bench`: the multigrid V-cycle and MG-preconditioned CG
//! beside the sparse direct solver on the P1 Laplacian (Poisson on the unit
//! square, f = 1, u = 0 on the boundary) at N × N vertices, N − 1 = 8 · 2^k
//! (meshes/rectangle.geo's 8 × 8 grid refined k times).
//!
//! Usage: `multigrid_bench [N ...]` (default 129 257 513 1025). Each solver
//! at each size runs in a child process of this binary (`--case N mg|direct`)
//! so that its peak RSS is its own; the parent prints one Markdown table.

use obstacle_fem::gmsh::run_gmsh;
use obstacle_fem::guards::peak_rss_kb;
use obstacle_fem::linalg::{factor_once, LinearOptions, MatrixKind, Solves, SystemPattern};
use obstacle_fem::mesh::{Hierarchy, Mesh};
use obstacle_fem::multigrid::{
    p1_load, p1_stiffness, pcg, Multigrid, MultigridOptions, P1Levels, Smoother,
};
#[path = "common/child_case.rs"]
mod child_case;

use child_case::child_output;
use std::collections::BTreeMap;
use std::path::Path;
use std::time::Instant;

/// Relative residual ‖b − A x‖₂/‖b‖₂ both iterative solvers stop at.
const RTOL: f64 = 1e-10;
/// Cells per side of the coarsest mesh.
const COARSE: usize = 8;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.first().map(String::as_str) == Some("--case") {
        let n: usize = args[1].parse().expect("--case N METHOD");
        return run_case(n, &args[2]);
    }
    let sizes: Vec<usize> = match args.is_empty() {
        true => vec![129, 257, 513, 1025],
        false => args.iter().map(|a| a.parse().expect("sizes N")).collect(),
    };
    let exe = std::env::current_exe().expect("own path");
    println!(
        "| vertices | levels | V(1,1) cycles | mean / max contraction | Jacobi ω = 4/5 cycles (contraction) | \
         PCG iterations | hierarchy + assembly s | MG setup s | V-cycles s | PCG s | MG peak MB | \
         direct s | direct peak MB | direct / (MG setup + PCG) |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for n in sizes {
        let case = |method: &str| -> BTreeMap<String, String> {
            let args = ["--case".to_string(), n.to_string(), method.to_string()];
            child_output(&exe, &args, &format!("{method} at {n}"))
        };
        let (mg, direct) = (case("mg"), case("direct"));
        let f = |m: &BTreeMap<String, String>, k: &str| -> f64 { m[k].parse().unwrap() };
        println!(
            "| {n}² | {} | {} | {:.3} / {:.3} | {} ({:.2}) | {} | {:.2} | {:.2} | {:.2} | {:.2} | {:.0} | {:.2} | {:.0} | {:.1}× |",
            mg["levels"],
            mg["cycles"],
            f(&mg, "mean_contraction"),
            f(&mg, "max_contraction"),
            mg["jacobi_cycles"],
            f(&mg, "jacobi_contraction"),
            mg["pcg_iterations"],
            f(&mg, "hierarchy_s") + f(&mg, "assembly_s"),
            f(&mg, "setup_s"),
            f(&mg, "vcycle_s"),
            f(&mg, "pcg_s"),
            f(&mg, "peak_mb"),
            f(&direct, "solve_s"),
            f(&direct, "peak_mb"),
            f(&direct, "solve_s") / (f(&mg, "setup_s") + f(&mg, "pcg_s")),
        );
    }
}

/// One solver at one size; prints `key=value` pairs.
fn run_case(n: usize, method: &str) {
    assert!(
        n > COARSE && (n - 1).is_multiple_of(COARSE) && ((n - 1) / COARSE).is_power_of_two(),
        "N − 1 must be {COARSE} · 2^k"
    );
    let refinements = ((n - 1) / COARSE).trailing_zeros() as usize;
    let dir = tempfile::tempdir().expect("temporary directory");
    let coarse = coarse_mesh(dir.path());
    let t = Instant::now();
    let hierarchy = Hierarchy::detected(coarse, refinements).expect("hierarchy");
    let levels = P1Levels::new(&hierarchy, None).expect("prolongations");
    let hierarchy_s = t.elapsed().as_secs_f64();
    let numbering = &levels.numberings[refinements];
    let t = Instant::now();
    let a = p1_stiffness(hierarchy.finest(), numbering);
    let b = p1_load(hierarchy.finest(), numbering, 1.0);
    let assembly_s = t.elapsed().as_secs_f64();
    print!(
        "levels={} unknowns={} hierarchy_s={hierarchy_s} assembly_s={assembly_s} ",
        refinements + 1,
        b.len()
    );
    match method {
        "mg" => {
            let t = Instant::now();
            let prolongations = levels.prolongations;
            let mg = Multigrid::new(&a, &prolongations, MultigridOptions::default())
                .expect("multigrid setup");
            let setup_s = t.elapsed().as_secs_f64();
            let t = Instant::now();
            let mut x = vec![0.0; b.len()];
            let report = mg.solve(&b, &mut x, RTOL, 100);
            let vcycle_s = t.elapsed().as_secs_f64();
            assert!(report.converged, "{report:?}");
            let t = Instant::now();
            let mut y = vec![0.0; b.len()];
            let cg = pcg(&a, &b, &mut y, |r, z| mg.precondition(r, z), RTOL, 100, 1);
            let pcg_s = t.elapsed().as_secs_f64();
            assert!(cg.converged, "{cg:?}");
            let peak_mb = peak_rss_kb().unwrap_or(0) as f64 / 1024.0;
            // Damped Jacobi in the same cycle, for the choice of smoother.
            let jacobi = MultigridOptions {
                smoother: Smoother::Jacobi { omega: 0.8 },
                ..MultigridOptions::default()
            };
            let mg_j = Multigrid::new(&a, &prolongations, jacobi).expect("setup");
            let mut z = vec![0.0; b.len()];
            let jr = mg_j.solve(&b, &mut z, RTOL, 200);
            print!(
                "setup_s={setup_s} cycles={} mean_contraction={} max_contraction={} vcycle_s={vcycle_s} \
                 pcg_iterations={} pcg_s={pcg_s} peak_mb={peak_mb} jacobi_cycles={} jacobi_contraction={}",
                report.cycles,
                report.mean_contraction(),
                report.max_contraction(),
                cg.iterations,
                jr.cycles,
                jr.mean_contraction()
            );
        }
        "direct" => {
            let t = Instant::now();
            let f = factor_once(
                SystemPattern {
                    matrix: &a,
                    kind: MatrixKind::SymmetricPositiveDefinite,
                    solves: Solves::Few,
                    interior: None,
                    what: "P1 Laplacian",
                },
                &LinearOptions::default(),
            )
            .expect("factorisation");
            let mut x = b.clone();
            f.solve_in_place(&mut x);
            let solve_s = t.elapsed().as_secs_f64();
            let peak_mb = peak_rss_kb().unwrap_or(0) as f64 / 1024.0;
            print!("solve_s={solve_s} peak_mb={peak_mb}");
        }
        other => panic!("unknown method {other} (mg or direct)"),
    }
    println!();
}

/// meshes/rectangle.geo, the unit square in COARSE × COARSE cells.
fn coarse_mesh(dir: &Path) -> Mesh {
    let geo = Path::new(env!("CARGO_MANIFEST_DIR")).join("meshes/rectangle.geo");
    let msh = dir.join("coarse.msh");
    run_gmsh(&geo, &msh, &[("n".into(), COARSE as f64)]).expect("gmsh");
    Mesh::read_msh(&msh).expect("coarse mesh")
}
