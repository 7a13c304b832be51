//! The Cartesian Naghdi shell (docs/formulation.md §2): dof count of the thesis mesh, the
//! free (no contact) thesis hyperbolic paraboloid (KKT residuals at round-off,
//! mirror symmetries, the contact data C, g at that solution), the penalty ρ
//! over the thesis' range (1 … 1e9, with the ψ block rescaled for LU), and
//! the clamped flat plate against the Kirchhoff and
//! Reissner–Mindlin centre deflections (convergence for a thick plate, shear
//! locking for a thin one).

mod common;

use obstacle_fem::assembly::{integrate_per_triangle, mat_vec, norm2, norm_inf, DofNumbering};
use obstacle_fem::linalg::{factorize_checked, MatrixKind, Solves};
use obstacle_fem::mesh::Mesh;
use obstacle_fem::models::naghdi::forms::{
    assemble_shell, balanced_tangency_scale, obstacle_at_vertices, rigid_plane_constraint,
    scale_tangency_multiplier, ShellLayout, N_COMPONENTS,
};
use obstacle_fem::models::naghdi::geometry::{Chart, Material};
use obstacle_fem::quadrature::TriangleRule;
use obstacle_fem::solvers::uzawa::solve_linear;
use obstacle_fem::solvers::SolveReport;
use obstacle_fem::space::{Element, Space};
use std::time::Instant;

const R: f64 = 50.0 * std::f64::consts::SQRT_2;

fn thesis_material() -> Material {
    Material {
        young: 2.85e4,
        poisson: 0.4,
        thickness: 0.8,
    }
}

/// The clamped shell without contact, solved once.
struct FreeSolution {
    /// Full coefficient vector: 7 blocks of Nv + Nt (clamped dofs are 0).
    full: Vec<f64>,
    report: SolveReport,
    numbering: DofNumbering,
    /// ‖BU‖ relative to ‖F‖ + ‖x‖ (the KKT measure's convention).
    tangency_rel: f64,
    /// ‖BU‖ relative to ‖|B||U|‖ (its own cancellation scale), after the
    /// plain LU solve and after one step of iterative refinement.
    tangency_cancellation: [f64; 2],
}

/// Assembles and solves the clamped shell without contact.
fn solve_free(
    mesh: &Mesh,
    chart: &Chart,
    material: &Material,
    rho: f64,
    load: [f64; 3],
) -> FreeSolution {
    let (problem, numbering) = assemble_shell(mesh, chart, material, rho, load, None);
    let start = Instant::now();
    let f = factorize_checked(&problem.matrix, problem.kind, Solves::Few, "shell").unwrap();
    let report = solve_linear(&problem, &f, start.elapsed().as_secs_f64(), 1).unwrap();
    let layout = ShellLayout::new(mesh);
    let full = numbering.extend(&report.x, &vec![0.0; layout.n_total()]);
    let np = problem.n_primal;
    let abs_matrix = {
        let mut m = problem.matrix.clone();
        m.val_mut().iter_mut().for_each(|v| *v = v.abs());
        m
    };
    let cancellation = |x: &[f64]| {
        let ax = mat_vec(&problem.matrix, x);
        let abs_x: Vec<f64> = x.iter().map(|v| v.abs()).collect();
        let scale = mat_vec(&abs_matrix, &abs_x);
        norm2(&ax[np..]) / norm2(&scale[np..]).max(f64::MIN_POSITIVE)
    };
    // One step of iterative refinement: x + A⁻¹(F − A x).
    let mut refined = report.x.clone();
    let ax = mat_vec(&problem.matrix, &refined);
    let mut r: Vec<f64> = problem.rhs.iter().zip(&ax).map(|(b, a)| b - a).collect();
    f.solve_in_place(&mut r);
    refined.iter_mut().zip(&r).for_each(|(a, b)| *a += b);
    let tangency_rel = report.measures.tangency / (norm2(&problem.rhs) + norm2(&report.x));
    FreeSolution {
        full,
        tangency_cancellation: [cancellation(&report.x), cancellation(&refined)],
        tangency_rel,
        report,
        numbering,
    }
}

/// The structured diamond {|x| + |y| < 50√2} with n subdivisions per side.
fn diamond_mesh(n: usize) -> Mesh {
    let dir = tempfile::tempdir().unwrap();
    common::diamond(dir.path(), n).1
}

/// For each scalar P1⊕B3 dof (vertex, then triangle bubble), the dof at the
/// mirrored position: vertices matched by coordinates, bubbles by centroids.
fn mirror_map(mesh: &Mesh, map: impl Fn([f64; 2]) -> [f64; 2]) -> Vec<usize> {
    let tol = 1e-9 * R;
    let centroid = |t: &[usize; 3]| {
        let p = t.map(|v| mesh.vertices[v]);
        [
            (p[0][0] + p[1][0] + p[2][0]) / 3.0,
            (p[0][1] + p[1][1] + p[2][1]) / 3.0,
        ]
    };
    let points: Vec<[f64; 2]> = mesh
        .vertices
        .iter()
        .copied()
        .chain(mesh.triangles.iter().map(centroid))
        .collect();
    // A centroid is never a vertex: a point maps to one of its own kind.
    common::mirror_map(&points, map, tol)
}

fn centre_vertex(mesh: &Mesh) -> usize {
    mesh.vertices
        .iter()
        .position(|x| x[0].abs() < 1e-9 && x[1].abs() < 1e-9)
        .expect("(0, 0) is a vertex for even n")
}

fn range(v: &[f64]) -> (f64, f64) {
    v.iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
            (a.min(x), b.max(x))
        })
}

#[test]
fn thesis_dof_count() {
    let mesh = diamond_mesh(16);
    assert_eq!(mesh.n_vertices(), 289);
    assert_eq!(mesh.n_triangles(), 512);
    let layout = ShellLayout::new(&mesh);
    assert_eq!(layout.n_scalar(), 801);
    assert_eq!(layout.n_total(), N_COMPONENTS * 801);
    assert_eq!(layout.thesis_dof_count(), 6119);
    // Clamped everywhere: 64 boundary vertices × 7 fields are eliminated.
    let (problem, numbering) = assemble_shell(
        &mesh,
        &Chart::Plate { height: 0.0 },
        &thesis_material(),
        1e3,
        [0.0, 0.0, -0.25],
        None,
    );
    assert_eq!(numbering.n_free(), 7 * (801 - 64));
    assert_eq!(problem.n_primal, 6 * (801 - 64));
    assert_eq!(problem.matrix.nrows(), numbering.n_free());
    assert_eq!(
        problem.kind,
        MatrixKind::SymmetricSaddle {
            n_primal: 6 * (801 - 64)
        }
    );
    assert!(problem.constraint.is_none());
    // The contact constraint adds one P0 multiplier per triangle.
    let c = rigid_plane_constraint(
        &mesh,
        &Chart::Plate { height: 0.0 },
        &thesis_material(),
        &numbering,
    );
    assert_eq!(c.matrix.nrows(), 512);
    assert_eq!(c.matrix.ncols(), numbering.n_free());
    assert_eq!(
        numbering.n_total() + c.obstacle.len(),
        6119,
        "docs/formulation.md §2: 7·(289 + 512) + 512"
    );
}

/// The thesis hypar (docs/formulation.md §2) without the rigid plane, on the thesis mesh.
#[test]
fn free_hypar() {
    let start = Instant::now();
    let mesh = diamond_mesh(16);
    let chart = Chart::HyperbolicParaboloid { r: R, offset: 1.4 };
    let material = thesis_material();
    let sol = solve_free(&mesh, &chart, &material, 1e3, [0.0, 0.0, -0.25]);
    let layout = ShellLayout::new(&mesh);
    let nv = mesh.n_vertices();
    let comp = |c: usize| layout.component(&sol.full, c);
    let (u3_min, u3_max) = range(&comp(2)[..nv]);
    let m = &sol.report.measures;
    println!(
        "free hypar 16×16: u3 ∈ [{u3_min:.5}, {u3_max:.5}] (thesis contact run: [−1.09, 0.029]); \
         u1 ∈ [{:.3e}, {:.3e}], u2 ∈ [{:.3e}, {:.3e}]",
        range(&comp(0)[..nv]).0,
        range(&comp(0)[..nv]).1,
        range(&comp(1)[..nv]).0,
        range(&comp(1)[..nv]).1,
    );
    println!(
        "  stationarity {:.2e} (rel. ‖F‖), ‖BU‖ {:.2e} = {:.2e} of ‖F‖+‖x‖; \
         ‖BU‖/‖|B||U|‖ {:.2e}, after one refinement step {:.2e}",
        m.stationarity,
        m.tangency,
        sol.tangency_rel,
        sol.tangency_cancellation[0],
        sol.tangency_cancellation[1],
    );
    assert!(m.stationarity < 1e-10, "stationarity {:e}", m.stationarity);
    assert!(sol.tangency_rel < 1e-10, "tangency {:e}", sol.tangency_rel);
    // BU = 0 holds to round-off of B's own entries once the LU solve is refined.
    assert!(sol.tangency_cancellation[1] < 1e-12);

    // The rigid plane at this free solution: the shell goes through it.
    let c = rigid_plane_constraint(&mesh, &chart, &material, &sol.numbering);
    let cx = mat_vec(&c.matrix, &sol.report.x);
    let min_gap = (0..cx.len())
        .map(|t| (cx[t] - c.obstacle[t]) / c.weights[t])
        .fold(f64::INFINITY, f64::min);
    // C U against an independent quadrature of ∫_T (u3 − ε/2 r3) dx.
    let space = Space::new(&mesh, Element::P1Bubble);
    let rule = TriangleRule::exact_for(5);
    let normal_displacement: Vec<f64> = comp(2)
        .iter()
        .zip(comp(5))
        .map(|(u3, r3)| u3 - 0.5 * material.thickness * r3)
        .collect();
    let direct = integrate_per_triangle(&space, &normal_displacement, &rule, |v, _| v.value);
    for t in 0..mesh.n_triangles() {
        assert!((cx[t] - direct[t]).abs() < 1e-12 * c.weights[t]);
    }
    // Φ at the vertices (docs/formulation.md §2): −1 at the origin, ≈ −2e-4 at the clamped
    // corners (0, ±R), ≈ −2 at (±R, 0); g_T/|T| is the mean
    // of its P1 interpolant over T.
    let phi = obstacle_at_vertices(&mesh, &chart, &material);
    let at = |p: [f64; 2]| {
        mesh.vertices
            .iter()
            .position(|x| (x[0] - p[0]).abs() < 1e-9 && (x[1] - p[1]).abs() < 1e-9)
            .unwrap()
    };
    assert!((phi[at([0.0, 0.0])] + 1.0).abs() < 1e-14);
    for corner in [[0.0, R], [0.0, -R]] {
        assert!((-1e-3..0.0).contains(&phi[at(corner)]), "Φ{corner:?}");
    }
    assert!((phi[at([R, 0.0])] + 2.0).abs() < 1e-3);
    assert!(phi.iter().all(|&p| p <= 1e-14), "thesis (2.2): Φ ≤ 0");
    for (t, tri) in mesh.triangles.iter().enumerate() {
        let mean = (phi[tri[0]] + phi[tri[1]] + phi[tri[2]]) / 3.0;
        assert!((c.obstacle[t] / c.weights[t] - mean).abs() < 1e-14);
        assert!((c.weights[t] - mesh.area(t)).abs() < 1e-12 * mesh.area(t));
    }
    let centre = centre_vertex(&mesh);
    println!(
        "  u3(0,0) = {:.5}, r3(0,0) = {:.2e}, min mean gap {min_gap:.4} (< 0: penetration)",
        comp(2)[centre],
        comp(5)[centre]
    );
    assert!(min_gap < 0.0);
    assert!(u3_min < -1.09, "the free shell goes below the contact run");

    // Mirror symmetries x → −x and y → −y (vertices and bubbles).
    let scale = (0..6).map(|c| norm_inf(comp(c))).fold(0.0, f64::max);
    let mx = mirror_map(&mesh, |x| [-x[0], x[1]]);
    let my = mirror_map(&mesh, |x| [x[0], -x[1]]);
    let mut worst: f64 = 0.0;
    // (component, parity under x → −x, parity under y → −y)
    for (c, px, py) in [(0, -1.0, 1.0), (1, 1.0, -1.0), (2, 1.0, 1.0)] {
        let u = comp(c);
        for d in 0..layout.n_scalar() {
            let ex = (u[d] - px * u[mx[d]]).abs();
            let ey = (u[d] - py * u[my[d]]).abs();
            worst = worst.max(ex.max(ey));
            assert!(
                ex.max(ey) <= 1e-9 * scale,
                "u{} dof {d}: {} vs mirrors {} (x), {} (y)",
                c + 1,
                u[d],
                u[mx[d]],
                u[my[d]]
            );
        }
    }
    println!(
        "  worst mirror defect {:.2e} of max|U|; {:.2} s",
        worst / scale,
        start.elapsed().as_secs_f64()
    );
}

/// The penalty ρ of a_ρ over the thesis' range (Table 5.8: 1 … 1e9), with the
/// tangency multiplier rescaled so that LU copes with ρ = 1e9. The discrete
/// U depends on ρ: BU = 0 only makes r_h·a3 orthogonal to P1⊕B3, not zero,
/// so a large ρ adds stiffness.
#[test]
fn hypar_penalty_rho() {
    let mesh = diamond_mesh(16);
    let chart = Chart::HyperbolicParaboloid { r: R, offset: 1.4 };
    let material = thesis_material();
    let load = [0.0, 0.0, -0.25];
    let mut u_rho1: Option<Vec<f64>> = None;
    for rho in [1.0, 1e3, 1e6, 1e9] {
        let (mut problem, _) = assemble_shell(&mesh, &chart, &material, rho, load, None);
        let sigma = balanced_tangency_scale(&problem);
        scale_tangency_multiplier(&mut problem, sigma);
        let f =
            factorize_checked(&problem.matrix, problem.kind, Solves::Few, "scaled shell").unwrap();
        let report = solve_linear(&problem, &f, 0.0, 1).unwrap();
        let np = problem.n_primal;
        let u = &report.x[..np];
        let bu = report.measures.tangency / sigma;
        let u_scale = norm_inf(u);
        let reference = u_rho1.get_or_insert_with(|| u.to_vec());
        let change = u
            .iter()
            .zip(reference.iter())
            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        println!(
            "ρ = {rho:e}, σ = {sigma:.2e}: stationarity {:.1e}, ‖BU‖ {bu:.1e}, \
             max|U − U(ρ=1)| = {:.2e} of max|U|",
            report.measures.stationarity,
            change / u_scale
        );
        assert!(report.measures.stationarity < 1e-9);
        assert!(bu < 1e-14 * u_scale);
        if rho == 1e3 {
            // The same U as the unscaled problem.
            let plain = solve_free(&mesh, &chart, &material, rho, load);
            let d = plain.report.x[..np]
                .iter()
                .zip(u)
                .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
            assert!(d < 1e-9 * u_scale, "scaled vs unscaled: {d:e}");
            assert!(change < 1e-5 * u_scale);
        }
    }
}

/// Kirchhoff centre deflection of a clamped square plate of side a under
/// uniform pressure q: w = 0.00126532 q a⁴/D, D = Eε³/(12(1−ν²))
/// (Timoshenko & Woinowsky-Krieger, Table 35; independent of ν).
fn kirchhoff_clamped_square(q: f64, side: f64, material: &Material) -> f64 {
    let (e, nu, t) = (material.young, material.poisson, material.thickness);
    let d = e * t.powi(3) / (12.0 * (1.0 - nu * nu));
    0.00126532 * q * side.powi(4) / d
}

/// Centre deflection w = −u3(0, 0) of the clamped plate on the n×n diamond
/// (side 100) under pressure q, relative to Kirchhoff.
fn plate_ratio(n: usize, thickness: f64) -> f64 {
    let q = 1.0;
    let material = Material {
        young: 2.85e4,
        poisson: 0.4,
        thickness,
    };
    let mesh = diamond_mesh(n);
    let sol = solve_free(
        &mesh,
        &Chart::Plate { height: 0.0 },
        &material,
        1e3,
        [0.0, 0.0, -q],
    );
    let layout = ShellLayout::new(&mesh);
    let w = -layout.component(&sol.full, 2)[centre_vertex(&mesh)];
    w / kirchhoff_clamped_square(q, 100.0, &material)
}

/// The clamped flat plate (the model reduces to Reissner–Mindlin with shear
/// factor κ = 1: 2εE/(1+ν) δ·δ = εμ|∇u3 + r|²). Thick plate, span/thickness
/// 10: the Reissner–Mindlin centre deflection is w_RM ≈ 1.18 w_K (the usual
/// benchmark value 0.00150 q a⁴/D for ν = 0.3, κ = 5/6, whose shear part
/// scales with ε²/(6κ(1−ν)): 3.5/3.6 of it for ν = 0.4, κ = 1; our own
/// meshes extrapolate to ≈ 1.186). Thin plate, span/thickness 100 and 125
/// (the thesis' ε = 0.8): the equal-order P1⊕B3 element shear-locks.
#[test]
fn clamped_plate() {
    let start = Instant::now();
    let rm_thick = 1.18;
    let thick: Vec<(usize, f64)> = [16, 32, 64].map(|n| (n, plate_ratio(n, 10.0))).to_vec();
    for (n, r) in &thick {
        println!(
            "plate ε = 10 (span/ε = 10), n = {n}: w/w_K = {r:.4}, w/w_RM = {:.4}",
            r / rm_thick
        );
    }
    let thin: Vec<(f64, usize, f64)> = [(1.0, 16), (1.0, 32), (0.8, 16), (0.8, 32)]
        .map(|(t, n)| (t, n, plate_ratio(n, t)))
        .to_vec();
    for (t, n, r) in &thin {
        println!(
            "plate ε = {t} (span/ε = {:.0}), n = {n}: w/w_K = {r:.4} (w_RM ≈ w_K here: locking)",
            100.0 / t
        );
    }
    println!("clamped plate test: {:.2} s", start.elapsed().as_secs_f64());
    // Thick: the deflection grows under refinement towards w_RM, within 5% on 64×64.
    assert!(thick.windows(2).all(|p| p[1].1 > p[0].1));
    let finest = thick.last().unwrap().1;
    assert!(
        (finest / rm_thick - 1.0).abs() < 0.05,
        "thick plate on 64×64: w/w_RM = {}",
        finest / rm_thick
    );
    assert!(finest > 1.0, "the thick plate is softer than Kirchhoff");
    // Thin: locked, far stiffer than Kirchhoff (≈ Reissner–Mindlin) on these meshes.
    for (t, n, r) in &thin {
        assert!(*r < 0.5, "ε = {t}, n = {n}: w/w_K = {r} shows no locking");
        let thick_same_mesh = thick.iter().find(|(m, _)| m == n).unwrap().1;
        assert!(*r < thick_same_mesh);
    }
}
