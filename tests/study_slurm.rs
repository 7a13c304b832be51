//! `obstacle study --workflow snakemake` on a Slurm cluster: a one-node
//! cluster on this machine (`pipelines/slurm/local-cluster.sh`: munged,
//! slurmctld and slurmd of its own under a temporary folder, on free ports),
//! the study run by `snakemake --profile slurm` (the profile the study
//! writes: Snakemake's Slurm executor), each run one Slurm job.
//!
//! Needs root, Slurm and munge (Debian `slurm-wlm`, `munge`) and the executor
//! plugin in Snakemake's venv, all installed by `.ci/install-deps.sh`;
//! Snakemake is `$OBSTACLE_SNAKEMAKE`, default `/opt/obstacle-venv/bin/snakemake`.
//! A missing one FAILS this test, it is never skipped.

mod common;

use common::{check_success, manifest_path, run_study};
use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;
use std::time::Instant;

/// Where the test finds Snakemake (the venv `.ci/install-deps.sh` makes).
const DEFAULT_SNAKEMAKE: &str = "/opt/obstacle-venv/bin/snakemake";

/// The study: the disk at n = 4, 8, 16 converged by Uzawa at α = auto, and
/// the same levels at α = 100, far above the stability bound 2/s_max ≈ 11.6,
/// where Uzawa diverges. One thread per run, so that the node's 2 CPUs run
/// two jobs at a time.
const STUDY: &str = "name = \"flow\"\nscene = SCENE\nconvergence_plot = true\n\
    set = [\"solver.stop=kkt\", \"solver.tol=1e-8\", \"solver.threads=1\", \"output.plots=[]\"]\n\
    [[sweep]]\nkey = \"solver.alpha\"\nvalues = [\"auto\", 100.0]\n\
    [[sweep]]\nkey = \"mesh.n\"\nvalues = [4, 8, 16]\n";

/// Each rule's `mem_mb` and `threads` in the Snakefile, by rule name.
fn rule_resources(snakefile: &str) -> BTreeMap<String, (u64, u64)> {
    let mut rules = BTreeMap::new();
    let mut rule = None;
    let mut threads = 0;
    for line in snakefile.lines() {
        if let Some(name) = line.strip_prefix("rule run_") {
            rule = Some(format!("run_{}", name.trim_end_matches(':')));
        } else if let Some(t) = line.trim().strip_prefix("threads: ") {
            threads = t.parse().unwrap();
        } else if let Some(m) = line.trim().strip_prefix("mem_mb=") {
            let mem = m.trim_end_matches(',').parse().unwrap();
            rules.insert(rule.clone().expect("mem_mb in a run rule"), (mem, threads));
        }
    }
    rules
}

/// The Slurm job of each run: `slurm-logs/rule_run_NNN/JOBID.log`, one each.
fn job_ids(flow: &Path) -> BTreeMap<String, String> {
    let mut jobs = BTreeMap::new();
    for rule in std::fs::read_dir(flow.join("slurm-logs")).unwrap() {
        let rule = rule.unwrap();
        let name = rule.file_name().to_string_lossy().into_owned();
        let logs: Vec<String> = std::fs::read_dir(rule.path())
            .unwrap()
            .map(|f| f.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert_eq!(
            logs.len(),
            1,
            "{name}: one job log expected, found {logs:?}"
        );
        let id = logs[0].strip_suffix(".log").unwrap().to_string();
        jobs.insert(name.strip_prefix("rule_").unwrap().to_string(), id);
    }
    jobs
}

/// The study through Snakemake's Slurm executor on the local cluster gives
/// the in-process study's table, CSV (but wall times) and convergence plot;
/// each run was one Slurm job (`sacct` lists it, completed, with the CPUs,
/// memory and time limit of its rule and the profile); the diverging runs
/// are "failed" rows with their markers, and the workflow succeeds.
#[test]
fn a_study_on_slurm_gives_the_in_process_table() {
    let start = Instant::now();
    let dir = tempfile::tempdir().unwrap();
    let study = dir.path().join("study.toml");
    let scene = manifest_path("pipelines/scenes/obstacle-disk.toml");
    std::fs::write(
        &study,
        STUDY.replace("SCENE", &format!("{:?}", scene.display().to_string())),
    )
    .unwrap();
    let serial = dir.path().join("serial");
    check_success("in-process study", &run_study(&study, &serial, &[]));
    let flow = dir.path().join("flow");
    check_success(
        "study --workflow snakemake",
        &run_study(&study, &flow, &["--workflow", "snakemake"]),
    );
    assert!(flow.join("slurm/config.yaml").is_file(), "no Slurm profile");

    let cluster = dir.path().join("cluster");
    let snakemake = std::env::var("OBSTACLE_SNAKEMAKE").unwrap_or(DEFAULT_SNAKEMAKE.into());
    let o = Command::new("bash")
        .arg(manifest_path("pipelines/slurm/local-cluster.sh"))
        .arg(&cluster)
        .args([&snakemake, "--profile", "slurm"])
        .current_dir(&flow)
        .output()
        .unwrap_or_else(|e| panic!("cannot run bash ({e})"));
    check_success(
        &format!("{snakemake} --profile slurm on the local Slurm cluster"),
        &o,
    );

    // The tables and plots are the in-process study's.
    let (md, csv) = common::study_tables(&serial, "flow");
    assert_eq!((md, csv.clone()), common::study_tables(&flow, "flow"));
    let plot = |d: &Path| std::fs::read(d.join("flow-convergence-0.png")).unwrap();
    assert!(plot(&serial) == plot(&flow), "the convergence plot differs");
    // α = auto converges at every level; α = 100 fails, each with its marker.
    let rows: Vec<&str> = csv.lines().collect();
    assert_eq!(rows.len(), 6, "{csv}");
    for (i, row) in rows.iter().enumerate() {
        let marker = flow.join(format!("flow-{i:03}.failed"));
        if i < 3 {
            assert!(row.contains(",true,OUT/flow-00"), "run {i}: {row}");
            assert!(!marker.exists(), "run {i}: {}", marker.display());
        } else {
            assert!(
                row.starts_with("100.0,") && row.contains(",failed,"),
                "run {i}: {row}"
            );
            let error = obstacle_fem::output::marker::read_marker(&marker).unwrap();
            assert!(error.contains("diverged"), "run {i}: {error}");
        }
    }

    // Each run was one Slurm job, listed by sacct, with its rule's resources.
    let snakefile = std::fs::read_to_string(flow.join("Snakefile")).unwrap();
    let resources = rule_resources(&snakefile);
    let jobs = job_ids(&flow);
    assert_eq!(
        jobs.keys().collect::<Vec<_>>(),
        resources.keys().collect::<Vec<_>>(),
        "one Slurm job per run"
    );
    let o = Command::new("sacct")
        .args(["--completion", "--parsable2", "--noheader"])
        .args([
            "--format",
            "JobID,JobName,Partition,State,AllocCPUS,Timelimit,Elapsed,ExitCode",
        ])
        .env("SLURM_CONF", cluster.join("slurm.conf"))
        .output()
        .unwrap_or_else(|e| {
            panic!("cannot run sacct ({e}): install slurm-wlm (.ci/install-deps.sh)")
        });
    check_success("sacct --completion", &o);
    let sacct = String::from_utf8(o.stdout).unwrap();
    let records = std::fs::read_to_string(cluster.join("jobcomp.txt")).unwrap();
    for (rule, id) in &jobs {
        let (mem_mb, threads) = resources[rule];
        assert!(mem_mb > 512, "{rule}: mem_mb {mem_mb}");
        let line = sacct
            .lines()
            .find(|l| l.starts_with(&format!("{id}|")))
            .unwrap_or_else(|| panic!("{rule}: job {id} not listed by sacct:\n{sacct}"));
        let cells: Vec<&str> = line.split('|').collect();
        assert_eq!(
            (cells[2], cells[3], cells[4], cells[5], cells[7]),
            (
                "local",
                "COMPLETED",
                threads.to_string().as_str(),
                "60",
                "0:0"
            ),
            "{rule}: {line}"
        );
        // Slurm's completion record (what sacct read) holds the memory asked for.
        let record = records
            .lines()
            .find(|l| l.starts_with(&format!("JobId={id} ")))
            .unwrap();
        assert!(
            record.contains(&format!("Tres=cpu={threads},mem={mem_mb}M,")),
            "{rule}: {record}"
        );
    }
    eprintln!(
        "sacct --completion:\n{sacct}study on Slurm: {:.1} s in all",
        start.elapsed().as_secs_f64()
    );
}
