//! The adaptive loop (issue 14, docs/formulation.md §8) on the disk with its
//! exact solution: the estimator is reliable and efficient (effectivity index
//! η / ‖∇(u − u_h)‖ within [1, 10] at every step, both pairs), positive on every
//! triangle; the loop stops on its target; every step reads back; bad
//! `[adapt]` input gets one clear error.

mod common;

use common::{assert_effectivity_per_step, field, root_attr, run_obstacle, solve_scene, text};
use obstacle_fem::output::{numeric_attr, read_result, read_steps, AttrValue, ResultFile};
use obstacle_fem::scene::Scene;
use std::path::Path;

const SCENE: &str = "obstacle-disk-adapt";

fn attr(step: &ResultFile, name: &str) -> f64 {
    numeric_attr(&step.data.root_attrs, name).unwrap_or_else(|| panic!("no attribute {name}"))
}

/// Runs the adaptive disk scene with `sets`; its steps read back.
fn adaptive_steps(out: &Path, sets: &[&str]) -> Vec<ResultFile> {
    let o = solve_scene(SCENE, out, sets);
    assert!(o.status.success(), "{}", text(&o));
    read_steps(out).unwrap()
}

/// Effectivity in [1, 10] at every step, for P1⊕B3–P0 and P2–P1; η_T > 0 on
/// every triangle; dofs grow; the root holds the last step; `obstacle info`
/// lists every step.
#[test]
fn effectivity_index_within_1_and_10_at_every_step() {
    let dir = tempfile::tempdir().unwrap();
    for element in ["p1b-p0", "p2-p1"] {
        let out = dir.path().join(format!("{element}.h5"));
        let set = format!("element=\"{element}\"");
        let steps = adaptive_steps(&out, &[&set, "adapt.max_dofs=6000"]);
        assert!(steps.len() >= 4, "{element}: {} steps", steps.len());
        assert_effectivity_per_step(element, &steps);
        let mut dofs = 0.0;
        for (k, step) in steps.iter().enumerate() {
            let eta = attr(step, "estimator");
            let indicators = field(step, "estimator");
            assert_eq!(indicators.len(), step.triangles.len());
            let total = indicators.iter().map(|e| e * e).sum::<f64>().sqrt();
            assert!((total - eta).abs() <= 1e-12 * eta, "{total} vs {eta}");
            assert_eq!(attr(step, "adapt_step"), k as f64);
            assert!(attr(step, "n_dofs") > dofs, "{element}: dofs do not grow");
            dofs = attr(step, "n_dofs");
        }
        let root = read_result(&out).unwrap();
        let last = steps.last().unwrap();
        assert_eq!(root.triangles, last.triangles);
        assert_eq!(
            root_attr(&root, "adapt_steps"),
            AttrValue::I64(steps.len() as i64)
        );
        let AttrValue::Str(stop) = root_attr(&root, "adapt_stop") else {
            panic!("adapt_stop is not a string")
        };
        assert!(stop.starts_with("max_dofs"), "{stop}");
        let info = run_obstacle(&["info", out.to_str().unwrap()]);
        let info = text(&info);
        assert!(
            info.contains(&format!("adaptive steps: {}", steps.len())),
            "{info}"
        );
        for k in 0..steps.len() {
            assert!(
                info.contains(&format!("\n| {k} | ")),
                "info lacks step {k}: {info}"
            );
        }
        // The XDMF plays the steps: one grid per step in a temporal collection.
        let xdmf = std::fs::read_to_string(out.with_extension("xdmf")).unwrap();
        assert!(xdmf.contains("CollectionType=\"Temporal\""));
        assert_eq!(xdmf.matches("<Time Value=").count(), steps.len());
        assert!(xdmf.contains(&format!("/steps/{:03}/fields/estimator", steps.len() - 1)));
    }
}

/// The loop stops once η ≤ target_error (and not before), and after
/// max_steps solves; a plain solve asked for the "estimator" plot writes the
/// field and the figure.
#[test]
fn the_loop_stops_on_its_target() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("target.h5");
    let steps = adaptive_steps(&out, &["adapt.target_error=0.3"]);
    let etas: Vec<f64> = steps.iter().map(|s| attr(s, "estimator")).collect();
    assert!(*etas.last().unwrap() <= 0.3, "{etas:?}");
    assert!(etas[..etas.len() - 1].iter().all(|&e| e > 0.3), "{etas:?}");
    let AttrValue::Str(stop) = root_attr(&read_result(&out).unwrap(), "adapt_stop") else {
        panic!("adapt_stop is not a string")
    };
    assert!(stop.starts_with("target_error"), "{stop}");

    let out = dir.path().join("steps.h5");
    let steps = adaptive_steps(&out, &["adapt.max_steps=2"]);
    assert_eq!(steps.len(), 2);

    let out = dir.path().join("plain.h5");
    let o = solve_scene(
        "obstacle-disk",
        &out,
        &["mesh.n=8", "output.plots=[\"estimator\"]"],
    );
    assert!(o.status.success(), "{}", text(&o));
    let r = read_result(&out).unwrap();
    assert_eq!(field(&r, "estimator").len(), r.triangles.len());
    assert!(out.with_extension("estimator.png").is_file());
    assert!(read_steps(&out).unwrap().is_empty());
}

/// Each bad `[adapt]` gets an error naming the scene file, the key and the reason.
#[test]
fn bad_adapt_input_gets_clear_errors() {
    let path = common::manifest_path(&format!("pipelines/scenes/{SCENE}.toml"));
    let text = std::fs::read_to_string(&path).unwrap();
    let cases: [(&str, &str, &str); 9] = [
        ("adapt.theta=0", "adapt.theta", "(0, 1]"),
        ("adapt.theta=1.5", "adapt.theta", "(0, 1]"),
        ("adapt.max_steps=0", "adapt.max_steps", "between 1 and 100"),
        ("adapt.target_error=-1", "adapt.target_error", "> 0"),
        ("adapt.max_dofs=0", "adapt.max_dofs", "≥ 1"),
        ("adapt.marking=\"maximum\"", "adapt.marking", "dorfler"),
        ("adapt.sweeps=3", "adapt", "sweeps"),
        ("solver.nested=true", "adapt", "nested"),
        ("mesh.file=\"disk.msh\"", "adapt", "mesh.geo"),
    ];
    for (set, key, reason) in cases {
        let e = Scene::from_text(&text, &path, &[set.to_string()]).unwrap_err();
        let message = e.to_string();
        println!("{set}: {message}");
        assert!(message.contains(&path.display().to_string()), "{message}");
        assert!(
            message.contains(key) && message.contains(reason),
            "{set}: {message}"
        );
    }
}

/// The two-sided case (`peers/two-sided`, issue 17) through the adaptive
/// loop: each bound enters the estimator with its own multiplier (the
/// residual sees λ₁ − λ₂), η_T > 0 and finite on every triangle, and the
/// loop refines (dofs grow) while both bounds stay in contact.
#[test]
fn two_sided_obstacles_are_estimated_and_adapted() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("two-sided.h5");
    let o = solve_scene(
        "peers/two-sided",
        &out,
        &[
            "mesh.n=8",
            "adapt.marking=\"dorfler\"",
            "adapt.max_steps=3",
            "adapt.theta=0.5",
        ],
    );
    assert!(o.status.success(), "{}", text(&o));
    let steps = read_steps(&out).unwrap();
    assert_eq!(steps.len(), 3);
    for (k, step) in steps.iter().enumerate() {
        let eta = field(step, "estimator");
        assert!(
            eta.iter().all(|e| e.is_finite() && *e > 0.0),
            "step {k}: η_T"
        );
        for bound in ["lambda_lower", "lambda_upper"] {
            let active = field(step, bound).iter().filter(|&&l| l > 0.0).count();
            assert!(active > 0, "step {k}: no {bound} contact");
        }
        if k > 0 {
            assert!(
                step.triangles.len() > steps[k - 1].triangles.len(),
                "step {k} did not refine"
            );
        }
    }
}
