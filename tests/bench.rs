//! Smoke test of `obstacle bench run` on tiny meshes (a few seconds): every
//! case runs in its own child process, the table, CSV and plots are written,
//! and the floor and both tolerances are there. No timing is asserted.

mod common;

use common::{field, root_attr};
use obstacle_fem::bench::extrapolate_iterations;
use obstacle_fem::output::read_result;
use std::process::Command;

#[test]
fn bench_runs_on_tiny_meshes() {
    let dir = tempfile::tempdir().unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_obstacle"))
        .args(["bench", "run", "pipelines/bench/tiny.toml", "--out-dir"])
        .arg(dir.path())
        .env("CI", "1")
        .output()
        .expect("the obstacle binary runs");
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{out}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(out.contains("linear solve (floor)"), "{out}");
    assert!(out.contains("### Targets"), "{out}");
    let csv = std::fs::read_to_string(dir.path().join("tiny.csv")).unwrap();
    let lines: Vec<&str> = csv.lines().skip(1).collect();
    // 2 levels × 2 methods × 2 tolerances, all converged, with a peak
    // memory, less Uzawa at level 4: left out of its levels, it has no row
    // (neither a time nor a bound).
    assert_eq!(lines.len(), 6, "{csv}");
    let uzawa_at_4 = |l: &&str| {
        let cells: Vec<&str> = l.split(',').collect();
        cells[1] == "4" && cells[3] == "uzawa"
    };
    assert!(!lines.iter().any(uzawa_at_4), "{csv}");
    for l in &lines {
        let cells: Vec<&str> = l.split(',').collect();
        assert_eq!(cells[5], "converged", "{l}");
        let mb: f64 = cells[10].parse().unwrap();
        assert!(mb > 0.0, "{l}");
    }
    for tol in ["1e-6", "1e-10"] {
        assert!(dir.path().join(format!("tiny-disk-{tol}.png")).is_file());
    }
}

/// A run that `max_iter` ends inside the active set's interior-point start
/// (as the bench's re-runs to a looser tolerance do) says so in its BENCH
/// line (`interior_iterate`, which the table shows as †); a run that PDAS
/// finishes does not. The interior iterate's λ is positive on every
/// triangle, but its result file puts in contact only the set the interior
/// point predicts: on this shell (n = 16) after three steps, the final
/// answer's 4 triangles, with the same contact area.
#[test]
fn a_run_ended_inside_the_interior_point_is_marked() {
    let mut contact_sets = Vec::new();
    for (max_iter, interior) in [(4, true), (50, false)] {
        let dir = tempfile::tempdir().unwrap();
        let o = Command::new(env!("CARGO_BIN_EXE_obstacle"))
            .args(["bench", "case", "pipelines/scenes/naghdi-hypar.toml"])
            .args(["--set", "solver.method=active-set", "--set"])
            .arg(format!("solver.max_iter={max_iter}"))
            .args(["--set", "output.plots=[]", "--out"])
            .arg(dir.path().join("shell.h5"))
            .env("CI", "1")
            .output()
            .expect("the obstacle binary runs");
        let out = String::from_utf8_lossy(&o.stdout);
        assert!(o.status.success(), "{out}");
        assert!(
            out.contains(&format!("interior_iterate={interior}")),
            "max_iter {max_iter}: {out}"
        );
        let result = read_result(&dir.path().join("shell.h5")).unwrap();
        let positive = field(&result, "lambda")
            .iter()
            .filter(|&&l| l > 0.0)
            .count();
        let contact = field(&result, "contact").to_vec();
        let in_contact = contact.iter().filter(|&&c| c == 1.0).count();
        let triangles = result.triangles.len();
        match interior {
            true => assert_eq!(positive, triangles, "an interior iterate"),
            false => assert_eq!(positive, in_contact, "a complementary answer"),
        }
        assert_eq!(in_contact, 4, "max_iter {max_iter}");
        contact_sets.push((contact, root_attr(&result, "contact_area")));
    }
    assert_eq!(contact_sets[0], contact_sets[1]);
}

#[test]
fn extrapolation_of_a_linear_rate() {
    // kkt_k = 0.5^k: 1e-6 is reached at k = log2(1e6) ≈ 19.93.
    let kkt: Vec<f64> = (1..=10).map(|k| 0.5f64.powi(k)).collect();
    let k = extrapolate_iterations(&kkt, 1e-6).unwrap();
    assert!((k - 1e6f64.log2()).abs() < 1e-9, "{k}");
    assert!(extrapolate_iterations(&[1.0, 1.0, 1.0, 1.0], 1e-6).is_none());
}

#[test]
fn every_bench_configuration_loads() {
    for entry in std::fs::read_dir("pipelines/bench").unwrap() {
        let path = entry.unwrap().path();
        if path.extension().and_then(|e| e.to_str()) == Some("toml") {
            let cfg = obstacle_fem::bench::BenchConfig::load(&path)
                .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            for p in &cfg.problem {
                let scene = path.parent().unwrap().join(&p.scene);
                obstacle_fem::scene::Scene::load(&scene, &p.set)
                    .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            }
        }
    }
}
