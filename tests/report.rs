//! Report pages (issue 15, item 3): `obstacle report RESULT.h5` holds the run's
//! numbers as the file has them and shows every plot beside it, which headless
//! Chromium (Debian `chromium`) must load; `obstacle index` links every table,
//! figure and result. The Chromium test fails, never skips, when chromium is
//! missing: `.ci/install-deps.sh` installs it.

mod common;
use common::{assert_one_error, check_success, run_obstacle, solve_scene, solver_attr};
use obstacle_fem::output::{read_result, AttrValue};
use std::path::Path;
use std::process::Command;

/// Solves the disk scene (h = 0.4, its plots u, lambda, contact, history) into `dir/disk.h5`.
fn solve_disk(dir: &Path) -> std::path::PathBuf {
    let result = dir.join("disk.h5");
    check_success(
        "solve",
        &solve_scene("obstacle-disk", &result, &["mesh.h=0.4"]),
    );
    result
}

/// The page's title after Chromium loaded `page` with a script that counts
/// the images loaded (`complete` and a natural width): "loaded K of N".
fn images_loaded_in_chromium(page: &Path, profile: &Path) -> String {
    let html = std::fs::read_to_string(page).unwrap();
    let script = "<script>window.addEventListener('load', () => { const all = [...document.images]; \
        document.title = 'loaded ' + all.filter(i => i.complete && i.naturalWidth > 0).length + ' of ' + all.length; });</script>";
    let checked = page.with_file_name("chromium-check.html");
    std::fs::write(
        &checked,
        html.replace("</body>", &format!("{script}</body>")),
    )
    .unwrap();
    let out = Command::new("chromium")
        .args(["--headless", "--disable-gpu", "--no-sandbox", "--virtual-time-budget=10000"])
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg("--dump-dom")
        .arg(format!("file://{}", checked.display()))
        .output()
        .unwrap_or_else(|e| {
            panic!("chromium (Debian package chromium, installed by .ci/install-deps.sh) cannot run: {e}")
        });
    check_success("chromium --dump-dom", &out);
    let dom = String::from_utf8_lossy(&out.stdout);
    let title = dom
        .split_once("<title>")
        .and_then(|(_, t)| t.split_once("</title>"))
        .map(|(t, _)| t.to_string());
    title.unwrap_or_else(|| panic!("no <title> in Chromium's DOM:\n{dom}"))
}

#[test]
fn report_holds_the_runs_numbers_and_chromium_loads_every_plot() {
    let dir = tempfile::tempdir().unwrap();
    let result = solve_disk(dir.path());
    let o = run_obstacle(&["report", result.to_str().unwrap()]);
    check_success("report", &o);
    let page = dir.path().join("disk.html");
    let html = std::fs::read_to_string(&page).unwrap();

    // The numbers as the file has them (AttrValue's text, strings unquoted).
    let file = read_result(&result).unwrap();
    for name in [
        "iterations",
        "kkt",
        "converged",
        "stop_reason",
        "penetration",
        "complementarity",
    ] {
        let value = match solver_attr(&file, name) {
            AttrValue::Str(s) => s.clone(),
            v => v.to_string(),
        };
        let row = format!("<tr><th>{name}</th><td>{value}</td></tr>");
        assert!(html.contains(&row), "no row {row} in the page");
    }
    let AttrValue::I64(iterations) = solver_attr(&file, "iterations") else {
        panic!("iterations is no integer")
    };
    assert!(*iterations > 0);
    assert!(
        html.contains("<tr><th>triangles</th><td>62</td></tr>"),
        "mesh counts"
    );
    assert!(
        html.contains("<tr><th>model</th><td>membrane</td></tr>"),
        "model"
    );
    assert!(
        html.contains("<tr><th>contact_radius</th>"),
        "key number contact_radius"
    );
    // The scene as run, escaped.
    assert!(
        html.contains("name = &quot;obstacle-disk&quot;"),
        "scene text"
    );

    // One <img> per plot, relative src, in PlotKind order.
    let imgs: Vec<&str> = html
        .split("<img src=\"")
        .skip(1)
        .map(|s| s.split('"').next().unwrap())
        .collect();
    assert_eq!(
        imgs,
        [
            "disk.u.png",
            "disk.lambda.png",
            "disk.contact.png",
            "disk.history.png"
        ]
    );

    let profile = tempfile::tempdir().unwrap();
    assert_eq!(
        images_loaded_in_chromium(&page, profile.path()),
        "loaded 4 of 4"
    );
    // The check sees a broken image: one plot removed, three of four load.
    std::fs::remove_file(dir.path().join("disk.lambda.png")).unwrap();
    assert_eq!(
        images_loaded_in_chromium(&page, profile.path()),
        "loaded 3 of 4"
    );
}

#[test]
fn index_links_every_table_figure_and_result_with_one_line_each() {
    let build = tempfile::tempdir().unwrap();
    let results = build.path().join("results");
    let studies = build.path().join("studies").join("sub");
    std::fs::create_dir_all(&results).unwrap();
    std::fs::create_dir_all(&studies).unwrap();
    let result = solve_disk(&results);
    check_success(
        "report",
        &run_obstacle(&["report", result.to_str().unwrap()]),
    );
    std::fs::write(
        studies.join("my-study.md"),
        "## A study of <things>\n\n| a |\n",
    )
    .unwrap();
    std::fs::write(studies.join("my-study.csv"), "a\n1\n").unwrap();
    std::fs::write(studies.join("membrane-thesis.csv"), "a\n1\n").unwrap();
    std::fs::write(studies.join("my-study-003.h5"), "").unwrap();
    std::fs::write(studies.join("my-study-convergence-0.png"), "").unwrap();
    // A run under way (hidden staging folder) and other files are not listed.
    std::fs::create_dir_all(results.join(".x.obstacle-tmp-1-abc")).unwrap();
    std::fs::write(results.join(".x.obstacle-tmp-1-abc").join("x.h5"), "").unwrap();

    let o = run_obstacle(&["index", build.path().to_str().unwrap()]);
    check_success("index", &o);
    let html = std::fs::read_to_string(build.path().join("index.html")).unwrap();
    for line in [
        "<li><a href=\"results/disk.h5\">disk.h5</a> (<a href=\"results/disk.html\">report</a>): result</li>",
        "<li><a href=\"results/disk.u.png\">disk.u.png</a>: figure u of disk</li>",
        "<li><a href=\"results/disk.history.png\">disk.history.png</a>: figure history of disk</li>",
        "<li><a href=\"studies/sub/my-study.md\">my-study.md</a>: table: A study of &lt;things&gt;</li>",
        "<li><a href=\"studies/sub/my-study.csv\">my-study.csv</a>: table: A study of &lt;things&gt;</li>",
        "<li><a href=\"studies/sub/my-study-003.h5\">my-study-003.h5</a>: result 003 of: A study of &lt;things&gt;</li>",
        "<li><a href=\"studies/sub/my-study-convergence-0.png\">my-study-convergence-0.png</a>: figure convergence-0 of: A study of &lt;things&gt;</li>",
        "<li><a href=\"studies/sub/membrane-thesis.csv\">membrane-thesis.csv</a>: table: membrane, both pairs, h = 0.8 … 0.1, α = 0.9, 1.9, auto (thesis Tables 5.1–5.4)</li>",
    ] {
        assert!(html.contains(line), "no line {line} in the index:\n{html}");
    }
    assert_eq!(
        html.matches("<li>").count(),
        10,
        "4 plots, 1 result, 3 tables, a study's run and plot: {html}"
    );
    assert!(!html.contains("obstacle-tmp"), "a staging folder is listed");
    // `make` twice: both pages are rewritten over the previous run's.
    for args in [
        vec!["report", result.to_str().unwrap()],
        vec!["index", build.path().to_str().unwrap()],
    ] {
        check_success("a second report/index over the first", &run_obstacle(&args));
    }
    assert!(
        !html.contains("disk.xdmf"),
        "only tables, figures and results are listed"
    );
}

#[test]
fn report_refuses_a_missing_result_and_a_page_not_ending_in_html() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("none.h5");
    let o = run_obstacle(&["report", missing.to_str().unwrap()]);
    assert_one_error(&o, &["none.h5"], "missing result");
    let result = solve_disk(dir.path());
    let page = dir.path().join("page.txt");
    let o = run_obstacle(&[
        "report",
        result.to_str().unwrap(),
        "--out",
        page.to_str().unwrap(),
    ]);
    assert_one_error(&o, &["page.txt", ".html"], "page name");
    assert!(!page.exists());
    // The result itself is never the page.
    let o = run_obstacle(&[
        "report",
        result.to_str().unwrap(),
        "--out",
        result.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(read_result(&result).is_ok(), "the result file was replaced");
}

/// A result whose name holds `#`, `?`, `%` and a space, its page in another
/// folder given relative to the working folder: every plot link is relative
/// to the page and percent-encoded, and Chromium loads all four plots.
#[test]
fn report_links_are_relative_to_the_page_and_percent_encoded() {
    let dir = tempfile::tempdir().unwrap();
    let results = dir.path().join("res");
    std::fs::create_dir(&results).unwrap();
    let result = results.join("d#1?%x y.h5");
    check_success(
        "solve",
        &solve_scene("obstacle-disk", &result, &["mesh.h=0.4"]),
    );
    // Result and page given relative to the working folder, which is not
    // the page's: only a link relative to the page finds the plots.
    let o = Command::new(env!("CARGO_BIN_EXE_obstacle"))
        .args(["report", "../res/d#1?%x y.h5", "--out", "p.html"])
        .current_dir(dir.path().join("res"))
        .output()
        .unwrap();
    check_success("report in res/ onto res/p.html", &o);
    let o = Command::new(env!("CARGO_BIN_EXE_obstacle"))
        .args(["report", "res/d#1?%x y.h5", "--out", "pages/p.html"])
        .current_dir(dir.path())
        .output()
        .unwrap();
    check_success("report onto pages/p.html", &o);
    let page = dir.path().join("pages").join("p.html");
    let html = std::fs::read_to_string(&page).unwrap();
    for plot in ["u", "lambda", "contact", "history"] {
        let src = format!("<img src=\"../res/d%231%3F%25x%20y.{plot}.png\"");
        assert!(html.contains(&src), "no {src} in the page:\n{html}");
    }
    let profile = tempfile::tempdir().unwrap();
    assert_eq!(
        images_loaded_in_chromium(&page, profile.path()),
        "loaded 4 of 4"
    );
    let beside = std::fs::read_to_string(results.join("p.html")).unwrap();
    assert!(beside.contains("<img src=\"d%231%3F%25x%20y.u.png\""));
}

/// `obstacle index` over a build folder holding FIFOs (one where a study's
/// title is read, one named like a result) lists the regular files, skips
/// the FIFOs and never opens one: it ends, well within 60 s.
#[test]
fn index_skips_fifos_and_never_blocks() {
    use wait_timeout::ChildExt as _;
    let build = tempfile::tempdir().unwrap();
    let studies = build.path().join("studies");
    std::fs::create_dir_all(&studies).unwrap();
    std::fs::write(studies.join("piped-000.h5"), "").unwrap();
    for fifo in ["piped.md", "fifo.h5"] {
        let o = Command::new("mkfifo")
            .arg(studies.join(fifo))
            .output()
            .unwrap();
        check_success("mkfifo", &o);
    }
    let mut child = Command::new(env!("CARGO_BIN_EXE_obstacle"))
        .args(["index", build.path().to_str().unwrap()])
        .stdout(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let Some(status) = child
        .wait_timeout(std::time::Duration::from_secs(60))
        .unwrap()
    else {
        child.kill().unwrap();
        child.wait().unwrap();
        panic!("obstacle index blocked on a FIFO");
    };
    assert!(status.success());
    let html = std::fs::read_to_string(build.path().join("index.html")).unwrap();
    assert!(
        html.contains("<li><a href=\"studies/piped-000.h5\">piped-000.h5</a>: result</li>"),
        "{html}"
    );
    assert!(
        !html.contains("fifo.h5") && !html.contains("piped.md"),
        "{html}"
    );
}
