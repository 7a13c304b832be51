//! Issue 17: the peers' examples of `pipelines/scenes/peers/` (one test per
//! case), their numbers beside the peers' (docs/problems.md, "Peers").

mod common;

use common::{field, root_attr, solve_scene, solver_attr, text};
use obstacle_fem::output::{read_result, AttrValue, ResultFile};
use std::path::Path;

fn solved(dir: &Path, scene: &str, sets: &[&str]) -> ResultFile {
    let out = dir.join(format!("{}.h5", scene.replace('/', "-")));
    let o = solve_scene(scene, &out, sets);
    assert!(o.status.success(), "{scene}: {}", text(&o));
    let r = read_result(&out).unwrap();
    assert_eq!(
        solver_attr(&r, "converged"),
        &AttrValue::Bool(true),
        "{scene}"
    );
    r
}

fn int(r: &ResultFile, name: &str) -> i64 {
    match solver_attr(r, name) {
        AttrValue::I64(v) => *v,
        other => panic!("{name}: {other:?}"),
    }
}

fn float(r: &ResultFile, name: &str) -> f64 {
    match root_attr(r, name) {
        AttrValue::F64(v) => v,
        other => panic!("{name}: {other:?}"),
    }
}

/// deal.II step-41 on 64 × 64 squares: the staircase holds the membrane; our
/// active P1 multipliers (1170 of 65² at n = 64; 4747 of 129² at n = 128 in
/// `make peers`, deal.II's Q1 5399) are a contact fraction within 25 % of
/// deal.II's 5399/16641, and no multiplier sits on the lowest step
/// (deal.II: "the contact with the lower-most stair step disappears").
#[test]
fn deal_ii_step_41() {
    let dir = tempfile::tempdir().unwrap();
    let r = solved(dir.path(), "peers/step-41", &["mesh.n=64"]);
    let active = int(&r, "active");
    assert!((1160..=1180).contains(&active), "active {active}");
    let fraction = active as f64 / 65.0f64.powi(2);
    let deal_ii = 5399.0 / 16641.0;
    assert!(
        (fraction / deal_ii - 1.0).abs() < 0.25,
        "{fraction} vs {deal_ii}"
    );
    let lambda = field(&r, "lambda");
    let on_lowest_step = r
        .vertices
        .iter()
        .zip(lambda)
        .filter(|(p, l)| p[0] > 0.5 + 1e-9 && **l > 0.0)
        .count();
    assert_eq!(on_lowest_step, 0);
    // The membrane rests on the steps it touches: u = ψ at active vertices
    // (P2–P1 tests the constraint with hats, so u departs from ψ near a jump
    // of the staircase, up to 5e-3 within 4h of it; elsewhere less than 1e-3).
    let u = field(&r, "u");
    let phi = field(&r, "phi");
    let near_jump = |x: f64| {
        [-0.5, 0.0, 0.5]
            .iter()
            .any(|j| (x - j).abs() < 4.0 * 2.0 / 64.0 + 1e-9)
    };
    for (((l, u), p), x) in lambda.iter().zip(u).zip(phi).zip(&r.vertices) {
        if *l > 1e-6 {
            let tol = if near_jump(x[0]) { 1e-2 } else { 1e-3 };
            assert!((u - p).abs() < tol, "u {u} vs ψ {p} at {x:?}");
        }
    }
}

/// FreeFEM's variational-inequality tutorial (u ≤ 0.05, f = 1, 20 × 20): our
/// P2–P1 solution against FreeFEM's P1 one from the tutorial script itself,
/// vertex by vertex, and the contact sets' sizes (ours 37, FreeFEM's 45).
#[test]
fn freefem_variational_inequality_tutorial() {
    let dir = tempfile::tempdir().unwrap();
    let r = solved(dir.path(), "peers/freefem-vi", &[]);
    assert_eq!(int(&r, "active"), 37);
    let upper = field(&r, "lambda_upper");
    assert_eq!(upper.iter().filter(|&&l| l > 0.0).count(), 37);
    assert!(field(&r, "lambda_lower").iter().all(|&l| l == 0.0));
    let u = field(&r, "u");
    let max_u = u.iter().copied().fold(f64::MIN, f64::max);
    // The hat-tested constraint lets u pass g between vertices' means by
    // the discretisation error (0.05013 measured).
    assert!((max_u - 0.05).abs() < 2e-4, "max u {max_u}");

    let prefix = dir.path().join("vi");
    let (o, _) = common::run_freefem(
        "peers/vi.edp",
        &["-out".into(), prefix.display().to_string()],
    );
    common::check_success("freefem/peers/vi.edp", &o);
    let info = common::read_info(&prefix.with_extension("info.txt"));
    assert_eq!(info["iterations"], "6");
    assert_eq!(info["locked"].parse::<f64>().unwrap(), 45.0);
    let theirs = common::read_numbers(&prefix.with_extension("u.txt"));
    // Vertices on the same 21 × 21 grid: matched by coordinates.
    let key = |x: f64, y: f64| ((x * 20.0).round() as i64, (y * 20.0).round() as i64);
    let ours: std::collections::HashMap<(i64, i64), f64> = r
        .vertices
        .iter()
        .zip(u)
        .map(|(p, u)| (key(p[0], p[1]), *u))
        .collect();
    assert_eq!(theirs.len(), 3 * 441);
    let worst = theirs
        .chunks(3)
        .map(|c| (ours[&key(c[0], c[1])] - c[2]).abs())
        .fold(0.0, f64::max);
    // P1 against P2 on h = 0.05: the solutions differ by the discretisation
    // error (measured 1.3e-3 of max u = 0.05), not more.
    assert!(worst < 2e-3, "max vertex difference {worst:e}");
}

/// Bueler's ball obstacle (exact solution): errors and rates for both pairs
/// at n = 16, 32 (the full table to n = 64 is `make peers`).
#[test]
fn ball_obstacle_exact_solution() {
    let dir = tempfile::tempdir().unwrap();
    // (element, L² error at n = 32, H¹ error at n = 32, least L² and H¹ rates)
    for (element, l2_32, h1_32, l2_rate, h1_rate) in [
        ("p1b-p0", 7.212e-3, 1.266e-1, 1.9, 0.9),
        ("p2-p1", 1.394e-3, 3.286e-2, 2.5, 1.3),
    ] {
        let e = |n: i64| {
            let r = solved(
                dir.path(),
                "peers/ball",
                &[&format!("element={element}"), &format!("mesh.n={n}")],
            );
            (float(&r, "error_l2_u"), float(&r, "error_h1_u"))
        };
        let ((l2_16, h1_16), (l2, h1)) = (e(16), e(32));
        assert!((l2 / l2_32 - 1.0).abs() < 0.01, "{element}: L² {l2:e}");
        assert!((h1 / h1_32 - 1.0).abs() < 0.01, "{element}: H¹ {h1:e}");
        let rate = |coarse: f64, fine: f64| (coarse / fine).log2();
        assert!(
            rate(l2_16, l2) > l2_rate,
            "{element}: L² rate {}",
            rate(l2_16, l2)
        );
        assert!(
            rate(h1_16, h1) > h1_rate,
            "{element}: H¹ rate {}",
            rate(h1_16, h1)
        );
    }
}

/// The two-sided peer scene as shipped: both bounds active (the left half
/// touches ψ₂, the right half ψ₁), 267 active multipliers at n = 16.
#[test]
fn two_sided_case() {
    let dir = tempfile::tempdir().unwrap();
    let r = solved(dir.path(), "peers/two-sided", &[]);
    assert_eq!(int(&r, "active"), 267);
    let centroid_x = |t: &[usize; 3]| (0..3).map(|k| r.vertices[t[k]][0]).sum::<f64>() / 3.0;
    for (name, left) in [("lambda_upper", true), ("lambda_lower", false)] {
        let values = field(&r, name);
        let active: Vec<f64> = r
            .triangles
            .iter()
            .zip(values)
            .filter(|(_, l)| **l > 0.0)
            .map(|(t, _)| centroid_x(t))
            .collect();
        assert!(active.len() > 50, "{name}: {}", active.len());
        assert!(
            active.iter().all(|&x| (x < 0.0) == left),
            "{name} on its half"
        );
    }
}
