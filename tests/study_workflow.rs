//! `obstacle study --workflow snakemake`: the study as a Snakefile, run by
//! Snakemake (installed from PyPI by `.ci/install-deps.sh`), gives the
//! in-process study's tables; `--from-results` builds them from the files.
//!
//! Snakemake is `$OBSTACLE_SNAKEMAKE`, default `/opt/obstacle-venv/bin/snakemake`;
//! a missing Snakemake FAILS these tests, it is never skipped.

mod common;

use common::{assert_one_error, check_success, manifest_path, run_study};
use std::path::{Path, PathBuf};
use std::process::Command;

/// Where the tests find Snakemake (the venv `.ci/install-deps.sh` makes).
const DEFAULT_SNAKEMAKE: &str = "/opt/obstacle-venv/bin/snakemake";

/// A study of the disk (`name = "flow"`, `output.plots = []`) with the
/// given sweeps (TOML `[[sweep]]` tables) and extra `set` entries.
fn disk_study(dir: &Path, set: &str, sweeps: &str) -> PathBuf {
    let path = dir.join("study.toml");
    let text = format!(
        "name = \"flow\"\nscene = {:?}\nconvergence_plot = true\n\
         set = [\"solver.stop=kkt\", \"output.plots=[]\"{set}]\n{sweeps}",
        manifest_path("pipelines/scenes/obstacle-disk.toml")
            .display()
            .to_string()
    );
    std::fs::write(&path, text).unwrap();
    path
}

/// `obstacle study STUDY --out-dir OUT_DIR --workflow snakemake`, then
/// `snakemake -j 2` in OUT_DIR; panics when either fails.
fn run_workflow(study: &Path, out_dir: &Path) {
    let o = run_study(study, out_dir, &["--workflow", "snakemake"]);
    check_success("study --workflow snakemake", &o);
    assert!(out_dir.join("Snakefile").is_file(), "no Snakefile");
    let snakemake = std::env::var("OBSTACLE_SNAKEMAKE").unwrap_or(DEFAULT_SNAKEMAKE.into());
    let o = Command::new(&snakemake)
        .args(["-j", "2", "--quiet"])
        .current_dir(out_dir)
        .output()
        .unwrap_or_else(|e| {
            panic!(
                "cannot run Snakemake `{snakemake}` ({e}): install it with .ci/install-deps.sh \
                 or name it in OBSTACLE_SNAKEMAKE"
            )
        });
    check_success("snakemake -j 2", &o);
}

/// The in-process study and the same study through Snakemake give the same
/// Markdown table, CSV (but wall times) and convergence plots.
#[test]
fn snakemake_gives_the_in_process_table() {
    let dir = tempfile::tempdir().unwrap();
    let study = disk_study(
        dir.path(),
        ", \"solver.tol=1e-9\", \"solver.alpha=\\\"auto\\\"\"",
        "[[sweep]]\nkey = \"element\"\nvalues = [\"p1b-p0\", \"p2-p1\"]\n\
         [[sweep]]\nkey = \"mesh.n\"\nvalues = [4, 8]\n",
    );
    let serial = dir.path().join("serial");
    check_success("study", &run_study(&study, &serial, &[]));
    let flow = dir.path().join("flow");
    run_workflow(&study, &flow);
    let (md, csv) = common::study_tables(&serial, "flow");
    assert_eq!((md, csv.clone()), common::study_tables(&flow, "flow"));
    // Four runs, both elements, converged, each with a rate at n = 8.
    assert_eq!(csv.lines().count(), 4, "{csv}");
    assert_eq!(csv.matches(",true,OUT/flow-00").count(), 4, "{csv}");
    assert!(csv.contains("\"p2-p1\",8,"), "{csv}");
    for k in 0..2 {
        let plot = |d: &Path| std::fs::read(d.join(format!("flow-convergence-{k}.png"))).unwrap();
        assert!(plot(&serial) == plot(&flow), "convergence plot {k} differs");
    }
    // Each run's `obstacle solve` line is its rule's log.
    let log = std::fs::read_to_string(flow.join("flow-003.log")).unwrap();
    assert!(log.contains("converged: true"), "{log}");
}

/// A run that fails numerically (Uzawa with α = 100, far above the stability
/// bound 2/s_max ≈ 11.6) leaves `RUN.failed` with its error, the workflow
/// goes on, and the tables show the failure as the in-process study does.
#[test]
fn a_failed_run_leaves_a_marker_and_a_failed_row() {
    let dir = tempfile::tempdir().unwrap();
    let study = disk_study(
        dir.path(),
        ", \"mesh.n=4\", \"solver.tol=1e-8\"",
        "[[sweep]]\nkey = \"solver.alpha\"\nvalues = [\"auto\", 100.0]\n",
    );
    let serial = dir.path().join("serial");
    check_success("study", &run_study(&study, &serial, &[]));
    let flow = dir.path().join("flow");
    run_workflow(&study, &flow);
    let marker_file = flow.join("flow-001.failed");
    let marker = obstacle_fem::output::marker::read_marker(&marker_file).unwrap();
    assert!(std::fs::read_to_string(&marker_file)
        .unwrap()
        .starts_with(obstacle_fem::output::marker::HEADER));
    assert!(!flow.join("flow-001.h5").exists());
    assert!(!flow.join("flow-000.failed").exists());
    let (md, csv) = common::study_tables(&flow, "flow");
    assert_eq!(
        (md.clone(), csv.clone()),
        common::study_tables(&serial, "flow")
    );
    assert!(
        md.contains(&format!("- solver.alpha = 100.0: {}", marker.trim_end())),
        "{md}\n{marker}"
    );
    assert!(
        marker.contains("Uzawa") && marker.contains("diverged"),
        "{marker}"
    );
    let failed_row = csv.lines().nth(1).unwrap();
    assert!(
        failed_row.starts_with("100.0,") && failed_row.contains(",failed,"),
        "{csv}"
    );
}

/// `--from-results` without the runs' files names the first missing result;
/// `--workflow` refuses a study with a bad override before writing anything.
#[test]
fn missing_results_and_bad_overrides_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let study = disk_study(
        dir.path(),
        "",
        "[[sweep]]\nkey = \"mesh.n\"\nvalues = [4, 8]\n",
    );
    let out = dir.path().join("out");
    let o = run_study(&study, &out, &["--from-results"]);
    assert_one_error(
        &o,
        &[
            "flow-000.h5",
            "mesh.n=4",
            "no result file and no failure marker",
            "flow-000.failed",
        ],
        "from-results",
    );
    assert!(!out.join("flow.md").exists() && !out.join("flow.csv").exists());

    let bad = disk_study(
        dir.path(),
        "",
        "[[sweep]]\nkey = \"mesh.n\"\nvalues = [4, 0]\n",
    );
    let o = run_study(&bad, &out, &["--workflow", "snakemake"]);
    assert_one_error(
        &o,
        &["obstacle-disk.toml", "mesh.n"],
        "workflow with mesh.n = 0",
    );
    assert!(!out.join("Snakefile").exists());
}

/// `--from-results` refuses a result file left by another version of the
/// study (here: n = 4, 8 solved, then the study edited to n = 4, 6), naming
/// the file and the reason, and writes no table.
#[test]
fn a_stale_result_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let study = disk_study(
        dir.path(),
        "",
        "[[sweep]]\nkey = \"mesh.n\"\nvalues = [4, 8]\n",
    );
    check_success("in-process study", &run_study(&study, &out, &[]));
    std::fs::remove_file(out.join("flow.md")).unwrap();
    let edited = disk_study(
        dir.path(),
        "",
        "[[sweep]]\nkey = \"mesh.n\"\nvalues = [4, 6]\n",
    );
    let o = run_study(&edited, &out, &["--from-results"]);
    assert_one_error(
        &o,
        &["flow-001.h5", "another scene", "rerun the workflow"],
        "from-results on a stale result",
    );
    assert!(!out.join("flow.md").exists());
}

/// An out dir whose name holds Snakemake's wildcard braces runs as any
/// other: the Snakefile's params are taken literally, not as patterns.
#[test]
fn braces_in_the_out_dir_are_no_wildcards() {
    let dir = tempfile::tempdir().unwrap();
    let study = disk_study(
        dir.path(),
        ", \"mesh.n=4\"",
        "[[sweep]]\nkey = \"solver.tol\"\nvalues = [1e-6]\n",
    );
    let flow = dir.path().join("out{x}}{");
    run_workflow(&study, &flow);
    assert!(flow.join("flow-000.h5").is_file());
    let (md, _) = common::study_tables(&flow, "flow");
    assert_eq!(md.matches("| 0.000001 | ").count(), 1, "{md}");
}

/// `--workflow` again on the same out dir replaces the Snakefile and the
/// Slurm profile it wrote; a Snakefile or profile it did not write is
/// refused, naming the file, and nothing is written.
#[test]
fn the_workflow_files_are_replaced_but_no_others() {
    let dir = tempfile::tempdir().unwrap();
    let study = disk_study(
        dir.path(),
        ", \"mesh.n=4\"",
        "[[sweep]]\nkey = \"solver.tol\"\nvalues = [1e-6]\n",
    );
    let out = dir.path().join("out");
    for _ in 0..2 {
        check_success(
            "workflow",
            &run_study(&study, &out, &["--workflow", "snakemake"]),
        );
    }
    let profile = out.join("slurm/config.yaml");
    assert!(std::fs::read_to_string(&profile)
        .unwrap()
        .contains("executor: slurm"));
    for (file, text) in [
        (out.join("Snakefile"), "rule all:\n    input: []\n"),
        (profile, "executor: slurm\n"),
    ] {
        std::fs::write(&file, text).unwrap();
        let o = run_study(&study, &out, &["--workflow", "snakemake"]);
        let name = file.file_name().unwrap().to_str().unwrap();
        assert_one_error(
            &o,
            &[name, "is not an obstacle workflow file; not replacing it"],
            &format!("workflow over a foreign {name}"),
        );
        assert_eq!(std::fs::read_to_string(&file).unwrap(), text);
        std::fs::remove_file(&file).unwrap();
    }
}
