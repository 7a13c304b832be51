//! The membrane obstacle problem on the unit disk against its exact solution
//! (docs/formulation.md §1): convergence rates, contact radius, KKT measures of the
//! converged discrete solution, divergence detection. Runs the whole
//! pipeline (gmsh → assembly → Uzawa → HDF5) through the library.
//!
//! Expected rates, and why: the exact solution is C^{1,1} (u'' jumps at the
//! free boundary r = a), so u ∈ H^{5/2−ε}. For P1⊕B3 (piecewise linear plus
//! bubbles) the approximation order caps the rates at h in H¹ and h² in L².
//! For P2 the regularity and the polygonal boundary (chords at distance
//! O(h²) from the circle) cap H¹ at h^{3/2}; in L² we observe about h^{2.2}.
//! The tests assert least-squares slopes over the finer levels with a margin
//! for the unstructured meshes: P1⊕B3 L² ≥ 1.8, H¹ ≥ 0.88; P2 L² ≥ 2.0, H¹ ≥ 1.3.

use obstacle_fem::output::{numeric_attr, read_result, AttrValue};
use obstacle_fem::pipeline::RunSummary;
use obstacle_fem::run::run_scene;
use obstacle_fem::scene::Scene;
use obstacle_fem::Error;
use std::path::{Path, PathBuf};

const SCENE: &str = "pipelines/scenes/obstacle-disk.toml";
/// The exact contact radius: 1.3 − 2a² + 4a² ln a = 0.
const A_EXACT: f64 = 0.539_279_199_476;

fn run(dir: &Path, name: &str, overrides: &[&str]) -> Result<RunSummary, Error> {
    let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    let scene = Scene::load(Path::new(SCENE), &o)?;
    run_scene(&scene, &dir.join(format!("{name}.h5")), false)
}

/// Least-squares slope of log e against log h.
fn slope(points: &[(f64, f64)]) -> f64 {
    let n = points.len() as f64;
    let (xs, ys): (Vec<f64>, Vec<f64>) = points.iter().map(|(h, e)| (h.ln(), e.ln())).unzip();
    let (mx, my) = (xs.iter().sum::<f64>() / n, ys.iter().sum::<f64>() / n);
    let sxy: f64 = xs.iter().zip(&ys).map(|(x, y)| (x - mx) * (y - my)).sum();
    let sxx: f64 = xs.iter().map(|x| (x - mx) * (x - mx)).sum();
    sxy / sxx
}

/// Solves on four mesh levels (4, 8, 16, 32 points per quarter circle) to
/// KKT ≤ 1e-9 and checks rates, contact radius and the KKT measures.
fn convergence(element: &str, min_l2: f64, min_h1: f64) {
    let dir = tempfile::tempdir().unwrap();
    let mut levels = Vec::new();
    for n in [4, 8, 16, 32] {
        let s = run(
            dir.path(),
            &format!("{element}-{n}"),
            &[
                &format!("element={element}"),
                &format!("mesh.n={n}"),
                "solver.tol=1e-9",
                "solver.alpha=\"auto\"",
            ],
        )
        .unwrap();
        assert!(
            s.converged,
            "{element} n={n}: not converged, kkt {:.3e}",
            s.measures.kkt
        );
        assert!(s.measures.kkt <= 1e-9);
        levels.push(s);
    }
    let errors: Vec<_> = levels
        .iter()
        .map(|s| s.errors.expect("the scene asks for errors"))
        .collect();
    for (s, e) in levels.iter().zip(&errors) {
        eprintln!(
            "{element}: h {:.4} dofs {} iterations {} L² {:.4e} H¹ {:.4e} a_h {:.5}",
            s.h, s.n_dofs, s.iterations, e.l2, e.h1, e.contact_radius
        );
        assert!((e.exact_contact_radius - A_EXACT).abs() < 1e-11);
        // The contact radius converges like h (measured: |a_h − a| ≤ 0.1 h … 0.05 h).
        assert!(
            (e.contact_radius - A_EXACT).abs() <= 0.2 * s.h,
            "{element}: contact radius {} at h = {}",
            e.contact_radius,
            s.h
        );
    }
    let finest = errors.last().unwrap();
    assert!(
        (finest.contact_radius - A_EXACT).abs() < 4e-3,
        "finest a_h = {}",
        finest.contact_radius
    );
    for w in errors.windows(2) {
        assert!(
            w[1].l2 < w[0].l2 && w[1].h1 < w[0].h1,
            "{element}: errors must decrease"
        );
    }
    // Slopes over the three finer levels (the coarsest, h ≈ 0.5, is pre-asymptotic).
    let l2: Vec<_> = levels
        .iter()
        .zip(&errors)
        .skip(1)
        .map(|(s, e)| (s.h, e.l2))
        .collect();
    let h1: Vec<_> = levels
        .iter()
        .zip(&errors)
        .skip(1)
        .map(|(s, e)| (s.h, e.h1))
        .collect();
    let (r_l2, r_h1) = (slope(&l2), slope(&h1));
    eprintln!("{element}: L² rate {r_l2:.2}, H¹ rate {r_h1:.2}");
    assert!(r_l2 >= min_l2, "{element}: L² rate {r_l2:.2} < {min_l2}");
    assert!(r_h1 >= min_h1, "{element}: H¹ rate {r_h1:.2} < {min_h1}");
    assert!(
        r_l2 <= 3.0 && r_h1 <= 2.0,
        "rates above what the elements can give: suspicious"
    );
}

#[test]
fn p1b_p0_converges_at_the_expected_rates() {
    convergence("p1b-p0", 1.8, 0.88);
}

#[test]
fn p2_p1_converges_at_the_expected_rates() {
    convergence("p2-p1", 2.0, 1.3);
}

/// The result file of a converged run satisfies the KKT conditions of docs/formulation.md §4
/// to the requested tolerance, read back from the HDF5 contract.
#[test]
fn converged_solution_satisfies_kkt_in_the_result_file() {
    let dir = tempfile::tempdir().unwrap();
    for element in ["p1b-p0", "p2-p1"] {
        let tol = 1e-10;
        let s = run(
            dir.path(),
            element,
            &[
                &format!("element={element}"),
                "mesh.n=8",
                &format!("solver.tol={tol}"),
            ],
        )
        .unwrap();
        let file = read_result(&s.result_file).unwrap();
        let attr = |name: &str| {
            file.data
                .solver_attrs
                .iter()
                .find(|(n, _)| n == name)
                .map(|(_, v)| v.clone())
                .unwrap_or_else(|| panic!("missing /solver attribute {name}"))
        };
        assert_eq!(attr("converged"), AttrValue::Bool(true));
        assert_eq!(attr("stop_reason"), AttrValue::Str("kkt".into()));
        let AttrValue::F64(kkt) = attr("kkt") else {
            panic!()
        };
        assert!(kkt <= tol);
        let field = |name: &str| {
            file.data
                .fields
                .iter()
                .find(|f| f.name == name)
                .unwrap()
                .values
                .clone()
        };
        let (lambda, gap, u) = (field("lambda"), field("gap_mean"), field("u"));
        let scale = u.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(0.7);
        let lambda_max = lambda.iter().cloned().fold(0.0, f64::max);
        assert!(lambda.iter().all(|&l| l >= 0.0), "λ ≥ 0");
        assert!(
            gap.iter().all(|&g| g >= -tol * scale),
            "no penetration beyond tol"
        );
        let complementarity = lambda
            .iter()
            .zip(&gap)
            .fold(0.0f64, |m, (l, g)| m.max((l * g).abs()));
        assert!(
            complementarity <= tol * scale * lambda_max,
            "complementarity {complementarity:e}"
        );
        // λ ≈ 8 inside the contact zone (its exact value), on average.
        let active: Vec<f64> = lambda.iter().cloned().filter(|&l| l > 0.0).collect();
        let mean = active.iter().sum::<f64>() / active.len() as f64;
        assert!(
            (mean - 8.0).abs() < 1.5,
            "{element}: mean λ on the contact set {mean}"
        );
        // Dof counts: P1⊕B3 = Nv + Nt, P2 = Nv + Ne.
        let u_dofs = &file.data.dofs.iter().find(|(n, _)| n == "u").unwrap().1;
        let expected = match element {
            "p1b-p0" => file.vertices.len() + file.triangles.len(),
            _ => file.vertices.len() + file.edges.as_ref().expect("/mesh/edges for P2").len(),
        };
        assert_eq!(u_dofs.len(), expected);
        assert_eq!(
            lambda.len(),
            if element == "p1b-p0" {
                file.triangles.len()
            } else {
                file.vertices.len()
            }
        );
    }
}

/// α above the stability bound 2/s_max (≈ 11.6 in the mean form here) is
/// reported as divergence, with the bound, and writes no result file.
#[test]
fn uzawa_above_the_stability_bound_is_reported_as_diverging() {
    let dir = tempfile::tempdir().unwrap();
    for alpha in ["30.0", "24.0"] {
        let out: PathBuf = dir.path().join(format!("diverging-{alpha}.h5"));
        let err = run(
            dir.path(),
            &format!("diverging-{alpha}"),
            &["mesh.n=8", &format!("solver.alpha={alpha}")],
        )
        .expect_err("must diverge");
        let msg = err.to_string();
        assert!(matches!(err, Error::Numerical { .. }), "{msg}");
        assert!(
            msg.contains("diverged at iteration") && msg.contains("2/s_max"),
            "{msg}"
        );
        assert!(!out.exists(), "no result file for a failed run");
        eprintln!("{msg}");
    }
    // Just below the bound it converges.
    let s = run(dir.path(), "stable", &["mesh.n=8", "solver.alpha=11.0"]).unwrap();
    assert!(s.converged);
    let bound = 2.0 / s.spectrum.unwrap().s_max;
    assert!(bound > 11.0 && bound < 12.5, "stability bound {bound}");
}

/// The thesis criterion can stop the run; the KKT measures are recorded anyway
/// and decide `converged`.
#[test]
fn thesis_stop_rule_records_both_criteria() {
    let dir = tempfile::tempdir().unwrap();
    let s = run(
        dir.path(),
        "thesis",
        &[
            "mesh.h=0.4",
            "solver.alpha=1.9",
            "solver.stop=thesis",
            "solver.thesis_tol=1e-5",
            "solver.max_iter=3000",
        ],
    )
    .unwrap();
    assert_eq!(s.stop_reason, "thesis");
    assert!(s.last_dual_step < 1e-5);
    assert!(s.measures.kkt > 0.0 && s.measures.kkt.is_finite());
    // With α = 1.9 the thesis criterion stops long before the KKT measures are small.
    assert!(!s.converged, "kkt {:.3e}", s.measures.kkt);
}

/// Without an obstacle the scene is one linear solve (no multiplier, no iteration),
/// and same input gives bit-identical results.
#[test]
fn no_obstacle_is_one_linear_solve_and_runs_are_reproducible() {
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(SCENE).unwrap();
    let free = text.split("[obstacle]").next().unwrap().to_string()
        + "[solver]\nmethod = \"uzawa\"\n[output]\nerrors = false\n";
    let scene = Scene::from_text(&free, Path::new(SCENE), &["mesh.n=8".into()]).unwrap();
    let s = run_scene(&scene, &dir.path().join("free.h5"), false).unwrap();
    assert_eq!((s.iterations, s.stop_reason.as_str()), (1, "linear"));
    assert!(s.measures.stationarity < 1e-12);
    let file = read_result(&s.result_file).unwrap();
    assert!(file.data.fields.iter().all(|f| f.name != "lambda"));
    let simulated = file
        .data
        .root_attrs
        .iter()
        .find(|(n, _)| n == "simulated")
        .unwrap();
    assert_eq!(simulated.1, AttrValue::Str("load,dirichlet".into()));
    // u = g(1 − r²)/4 = r² − 1 at the centre vertex: −1 up to the discretisation error.
    let u_min = file.data.fields[0]
        .values
        .iter()
        .cloned()
        .fold(f64::INFINITY, f64::min);
    assert!((u_min + 1.0).abs() < 0.02, "u(0) = {u_min}");

    let a = run(dir.path(), "a", &["mesh.n=8"]).unwrap();
    let b = run(dir.path(), "b", &["mesh.n=8"]).unwrap();
    let (fa, fb) = (
        read_result(&a.result_file).unwrap(),
        read_result(&b.result_file).unwrap(),
    );
    let bits = |f: &obstacle_fem::output::ResultFile| -> Vec<u64> {
        f.data
            .dofs
            .iter()
            .flat_map(|(_, v)| v.iter().map(|x| x.to_bits()))
            .collect()
    };
    assert_eq!(bits(&fa), bits(&fb));
}

/// The run summary carries what `/solver` records of the solver's run (its
/// wall and factorisation times, Uzawa's α and Lanczos estimate), so that
/// bench and study need not re-read the file just written.
#[test]
fn the_summary_carries_the_solver_times_and_step() {
    let dir = tempfile::tempdir().unwrap();
    let s = run(dir.path(), "summary", &["mesh.n=8", "output.plots=[]"]).unwrap();
    let file = read_result(&s.result_file).unwrap();
    let attr = |name: &str| numeric_attr(&file.data.solver_attrs, name).unwrap();
    assert_eq!(s.solver_seconds, attr("wall_seconds"));
    assert_eq!(s.factor_seconds, attr("factor_seconds"));
    assert_eq!(s.solve_seconds, s.solver_seconds - s.factor_seconds);
    assert!(s.factor_seconds <= s.solver_seconds && s.solver_seconds <= s.wall_seconds);
    assert_eq!(s.alpha, Some(attr("alpha")));
    let spectrum = s.spectrum.expect("Uzawa's estimate");
    assert_eq!(spectrum.s_max, attr("s_max_estimate"));
    assert_eq!(spectrum.s_min, attr("s_min_ritz"));
}
