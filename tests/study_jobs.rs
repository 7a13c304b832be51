//! `obstacle study --jobs N`: runs N at a time, the same tables as serial.

mod common;

use common::{assert_one_error, check_success, manifest_path, run_obstacle};
use std::path::Path;

/// The membrane-convergence study shrunk to mesh.n = 4, 8, 16 (six runs).
fn small_study(dir: &Path, mesh_levels: &str) -> std::path::PathBuf {
    let path = dir.join("study.toml");
    let text = format!(
        "name = \"jobs\"\nscene = {:?}\nconvergence_plot = true\n\
         set = [\"solver.stop=kkt\", \"solver.tol=1e-10\", \"solver.alpha=\\\"auto\\\"\", \"output.plots=[]\"]\n\
         [[sweep]]\nkey = \"element\"\nvalues = [\"p1b-p0\", \"p2-p1\"]\n\
         [[sweep]]\nkey = \"mesh.n\"\nvalues = [{mesh_levels}]\n",
        manifest_path("pipelines/scenes/obstacle-disk.toml")
            .display()
            .to_string()
    );
    std::fs::write(&path, text).unwrap();
    path
}

/// `obstacle study STUDY --out-dir OUT_DIR --quiet --jobs JOBS`.
fn run_study(study: &Path, out_dir: &Path, jobs: &str) -> std::process::Output {
    common::run_study(study, out_dir, &["--jobs", jobs])
}

/// The study's Markdown table, CSV (but wall times, see
/// `common::study_tables`) and convergence plots from `--jobs N`.
fn study_outputs(study: &Path, out_dir: &Path, jobs: &str) -> (String, String, Vec<Vec<u8>>) {
    let o = run_study(study, out_dir, jobs);
    check_success(&format!("study --jobs {jobs}"), &o);
    let (md, csv) = common::study_tables(out_dir, "jobs");
    let plots = (0..2)
        .map(|k| std::fs::read(out_dir.join(format!("jobs-convergence-{k}.png"))).unwrap())
        .collect();
    (md, csv, plots)
}

/// Two runs at a time give the serial study's table, CSV (but wall times)
/// and plots, byte for byte, rows in the grid's order.
#[test]
fn two_jobs_give_the_serial_table() {
    let dir = tempfile::tempdir().unwrap();
    let study = small_study(dir.path(), "4, 8, 16");
    let serial = study_outputs(&study, &dir.path().join("serial"), "1");
    let parallel = study_outputs(&study, &dir.path().join("parallel"), "2");
    assert_eq!(serial.0, parallel.0);
    assert_eq!(serial.1, parallel.1);
    assert_eq!(serial.0.matches("| 16 |").count(), 2, "{}", serial.0);
    assert_eq!(serial.1.lines().count(), 6, "{}", serial.1);
    // Element and mesh level lead each CSV line (the element as TOML text).
    let first = serial.1.lines().next().unwrap();
    let last = serial.1.lines().last().unwrap();
    assert!(
        first.contains("p1b-p0") && first.split(',').nth(1) == Some("4"),
        "{first}"
    );
    assert!(
        last.contains("p2-p1") && last.split(',').nth(1) == Some("16"),
        "{last}"
    );
    assert!(serial.2 == parallel.2, "the convergence plots differ");
}

/// A run with a bad override stops the parallel study with its error (one
/// `error:` line naming the field), and no table is written.
#[test]
fn an_error_in_one_run_stops_a_parallel_study() {
    let dir = tempfile::tempdir().unwrap();
    let study = small_study(dir.path(), "4, 0, 8");
    let out_dir = dir.path().join("out");
    let o = run_study(&study, &out_dir, "2");
    assert_one_error(&o, &["obstacle-disk.toml", "mesh.n"], "mesh.n = 0");
    assert!(!out_dir.join("jobs.md").exists());
    assert!(!out_dir.join("jobs.csv").exists());
}

/// A study whose third run has a bad override (mesh.n = 0) fails before
/// any run, serial or parallel: the results of an earlier study in the same
/// folder stay as they were, byte for byte.
#[test]
fn a_bad_run_is_refused_before_any_result_is_replaced() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("out");
    let good = small_study(dir.path(), "4, 8");
    check_success("the first study", &run_study(&good, &out_dir, "1"));
    let results: Vec<Vec<u8>> = (0..4)
        .map(|i| std::fs::read(out_dir.join(format!("jobs-{i:03}.h5"))).unwrap())
        .collect();
    let bad = small_study(dir.path(), "4, 8, 0");
    for jobs in ["1", "2"] {
        let o = run_study(&bad, &out_dir, jobs);
        assert_one_error(&o, &["obstacle-disk.toml", "mesh.n"], "mesh.n = 0");
        for (i, before) in results.iter().enumerate() {
            let now = std::fs::read(out_dir.join(format!("jobs-{i:03}.h5"))).unwrap();
            assert!(now == *before, "--jobs {jobs}: jobs-{i:03}.h5 was replaced");
        }
    }
}

/// `--jobs 0` is refused by the command line.
#[test]
fn zero_jobs_are_refused() {
    let o = run_obstacle(&["study", "x.toml", "--jobs", "0"]);
    assert!(!o.status.success());
    assert!(common::text(&o).contains("--jobs"), "{}", common::text(&o));
}
