//! Report pages (issues 15 and 46): `obstacle report RESULT.h5` shows the run's
//! status first, its numbers with meaningful digits and every plot beside it,
//! which headless Chromium (Debian `chromium`) must load; `obstacle index`
//! gives every run's status (a failed run as failed, with its reason), every
//! study table rendered from its CSV, every figure as a thumbnail, and a
//! report page per run. The Chromium tests fail, never skip, when chromium
//! is missing: `.ci/install-deps.sh` installs it.

mod common;
use common::{assert_one_error, check_success, run_obstacle, solve_scene, solver_attr};
use obstacle_fem::numbers::meaningful;
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

/// The page's title after Chromium loaded `page` with `script` (run on the
/// window's `load` event, setting `document.title`).
fn title_in_chromium(page: &Path, profile: &Path, script: &str) -> String {
    let html = std::fs::read_to_string(page).unwrap();
    let script = format!("<script>window.addEventListener('load', () => {{ {script} }});</script>");
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

/// The images Chromium loaded (`complete` and a natural width) on `page`:
/// "loaded K of N".
fn images_loaded_in_chromium(page: &Path, profile: &Path) -> String {
    title_in_chromium(
        page,
        profile,
        "const all = [...document.images]; \
         document.title = 'loaded ' + all.filter(i => i.complete && i.naturalWidth > 0).length + ' of ' + all.length;",
    )
}

/// A screenshot of `page` by headless Chromium into `png`: a PNG of the
/// window's size.
fn screenshot(page: &Path, profile: &Path, png: &Path) {
    let out = Command::new("chromium")
        .args([
            "--headless",
            "--disable-gpu",
            "--no-sandbox",
            "--hide-scrollbars",
        ])
        .args(["--window-size=1280,1600", "--virtual-time-budget=10000"])
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg(format!("--screenshot={}", png.display()))
        .arg(format!("file://{}", page.display()))
        .output()
        .unwrap();
    check_success("chromium --screenshot", &out);
    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(png).unwrap()));
    let info = decoder.read_info().unwrap().info().clone();
    assert_eq!((info.width, info.height), (1280, 1600), "screenshot size");
}

/// Whether `text` holds a number written with more than 6 decimals (a raw
/// f64 such as `0.30936923800000005`).
fn has_raw_float(text: &str) -> bool {
    let b = text.as_bytes();
    (0..b.len())
        .any(|i| b[i] == b'.' && b[i + 1..].iter().take_while(|c| c.is_ascii_digit()).count() > 6)
}

#[test]
fn report_shows_the_status_first_and_the_numbers_rounded_and_chromium_loads_every_plot() {
    let dir = tempfile::tempdir().unwrap();
    let result = solve_disk(dir.path());
    let o = run_obstacle(&["report", result.to_str().unwrap()]);
    check_success("report", &o);
    let page = dir.path().join("disk.html");
    let html = std::fs::read_to_string(&page).unwrap();

    // The status comes first, before any table.
    let status = html.find(
        "<p class=\"status converged\" id=\"status\"><strong>converged</strong>: KKT measure ",
    );
    let first_table = html.find("<table");
    assert!(
        status.is_some() && status < first_table,
        "no status line before the tables:\n{html}"
    );
    // The numbers with meaningful digits, grouped.
    let file = read_result(&result).unwrap();
    for (name, group) in [
        ("kkt", "KKT measures"),
        ("penetration", "KKT measures"),
        ("complementarity", "KKT measures"),
        ("stability_bound", "Solver"),
        ("tol", "Solver"),
    ] {
        let AttrValue::F64(v) = solver_attr(&file, name) else {
            panic!("{name} is no number")
        };
        let row = format!(
            "<span class=\"key\">{name}</span></th><td>{}</td></tr>",
            meaningful(*v, 4)
        );
        let at = html
            .find(&row)
            .unwrap_or_else(|| panic!("no row {row} in the page"));
        let heading = html[..at].rfind("<h2>").unwrap();
        assert!(
            html[heading..].starts_with(&format!("<h2>{group}</h2>")),
            "{name} not under {group}"
        );
    }
    let AttrValue::I64(iterations) = solver_attr(&file, "iterations") else {
        panic!("iterations is no integer")
    };
    assert!(html.contains(&format!(
        "<tr><th>iterations</th><td>{iterations}</td></tr>"
    )));
    assert!(html.contains(&format!("after {iterations} iterations</p>")));
    assert!(html.contains("<span class=\"key\">wall_seconds</span></th><td>"));
    assert!(
        html.contains(" ms</td>") || html.contains(" s</td>"),
        "times with their unit"
    );
    assert!(
        html.contains("<tr><th>triangles</th><td>62</td></tr>"),
        "mesh counts"
    );
    assert!(
        html.contains("<tr><th>model</th><td>membrane</td></tr>"),
        "model"
    );
    assert!(
        html.contains("<span class=\"key\">contact_radius</span>"),
        "key number contact_radius"
    );
    for group in [
        "Problem",
        "Mesh",
        "Solver",
        "KKT measures",
        "Timing",
        "Memory",
        "Plots",
    ] {
        assert!(
            html.contains(&format!("<h2>{group}</h2>")),
            "no group {group}"
        );
    }
    // The numbers the page prints (the scene below is the file's text).
    let numbers = &html[..html.find("<h2>Scene as run</h2>").unwrap()];
    assert!(
        !has_raw_float(numbers),
        "a raw float in the page:\n{numbers}"
    );
    assert!(!numbers.contains(">-0<"), "-0 in the page");
    // The scene as run, escaped (askama: `"` as `&#34;`).
    assert!(
        html.contains("name = &#34;obstacle-disk&#34;"),
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

/// A study over the disk (n = 8) whose first run diverges (α = 30, above the
/// stability bound ≈ 11.6) and whose second converges, in `build/studies`;
/// the disk with its plots in `build/results`.
fn build_with_a_failed_run(build: &Path) {
    let results = build.join("results");
    let studies = build.join("studies");
    std::fs::create_dir_all(&results).unwrap();
    solve_disk(&results);
    let scene = common::manifest_path("pipelines/scenes/obstacle-disk.toml");
    let study = build.join("alpha-sweep.toml");
    std::fs::write(
        &study,
        format!(
            "name = \"alpha-sweep\"\ntitle = \"Disk: α above and below the <stability> bound\"\n\
             scene = {:?}\nset = [\"mesh.n=8\", \"output.plots=[]\"]\n\
             [[sweep]]\nkey = \"solver.alpha\"\nvalues = [30.0, 11.0]\n",
            scene.display().to_string()
        ),
    )
    .unwrap();
    let o = run_obstacle(&[
        "study",
        study.to_str().unwrap(),
        "--out-dir",
        studies.to_str().unwrap(),
        "--quiet",
    ]);
    check_success("study with a diverging run", &o);
    check_success("index", &run_obstacle(&["index", build.to_str().unwrap()]));
}

/// The failed run of a study: its marker, its line and table row marked
/// failed with the reason, its report page saying so first.
#[test]
fn a_failed_run_shows_as_failed_in_the_index_and_its_report() {
    let build = tempfile::tempdir().unwrap();
    build_with_a_failed_run(build.path());
    let studies = build.path().join("studies");
    assert!(
        studies.join("alpha-sweep-000.failed").is_file(),
        "no failure marker"
    );
    assert!(!studies.join("alpha-sweep-000.h5").exists());
    let html = std::fs::read_to_string(build.path().join("index.html")).unwrap();
    assert!(
        html.contains("<p class=\"status failed\" id=\"status\"><strong>3 runs: 2 converged, 1 failed</strong></p>"),
        "overall status:\n{html}"
    );
    assert!(html.contains("<li><span class=\"badge failed\">failed</span> <a href=\"studies/alpha-sweep-000.html\">alpha-sweep-000 (Disk: α above and below the &#60;stability&#62; bound: solver.alpha = 30.0)</a></li>"), "{html}");
    // The run's line: failed, with the reason.
    let line = html
        .split("<tr class=\"failed\">")
        .find(|l| {
            l.contains(
                "<td class=\"name\"><a href=\"studies/alpha-sweep-000.html\">alpha-sweep-000</a>",
            )
        })
        .unwrap_or_else(|| panic!("no failed line of alpha-sweep-000:\n{html}"));
    let line = line.split("</tr>").next().unwrap();
    assert!(line.contains("diverged at iteration"), "{line}");
    // The table row: failed, linked to the report page.
    assert!(
        html.contains("<tr class=\"failed\"><td><span class=\"badge failed\">failed</span></td><td class=\"num\">30</td>"),
        "the table's failed row:\n{html}"
    );
    let page = std::fs::read_to_string(studies.join("alpha-sweep-000.html")).unwrap();
    let status = page.find("<p class=\"status failed\" id=\"status\"><strong>failed</strong>: ");
    assert!(status.is_some(), "{page}");
    assert!(page.contains("diverged at iteration"), "{page}");
    let converged = std::fs::read_to_string(studies.join("alpha-sweep-001.html")).unwrap();
    assert!(converged.contains("<p class=\"status converged\" id=\"status\">"));

    // A rerun that converges removes the marker: the run is no longer failed.
    std::fs::remove_file(studies.join("alpha-sweep-000.failed")).unwrap();
    check_success(
        "index",
        &run_obstacle(&["index", build.path().to_str().unwrap()]),
    );
    let html = std::fs::read_to_string(build.path().join("index.html")).unwrap();
    assert!(
        html.contains("<strong>2 runs: 2 converged</strong>"),
        "{html}"
    );
}

/// Headless Chromium on the index and a report page: the status line, the
/// rendered tables and their rows, every image loaded; and screenshots.
#[test]
fn chromium_shows_the_index_and_a_report_with_status_tables_and_images() {
    let build = tempfile::tempdir().unwrap();
    build_with_a_failed_run(build.path());
    let profile = tempfile::tempdir().unwrap();
    let index = build.path().join("index.html");
    let summary = "const imgs = [...document.images]; \
        const loaded = imgs.filter(i => i.complete && i.naturalWidth > 0).length; \
        const tables = [...document.querySelectorAll('table.study')]; \
        const rows = tables.map(t => t.rows.length - 1).join('+'); \
        const failed = document.querySelectorAll('table.study tr.failed').length; \
        const status = document.getElementById('status').innerText; \
        document.title = status + ' | tables ' + tables.length + ' (' + rows + ' rows, ' + failed + ' failed)' + ' | images ' + loaded + ' of ' + imgs.length;";
    assert_eq!(
        title_in_chromium(&index, profile.path(), summary),
        "3 runs: 2 converged, 1 failed | tables 1 (2 rows, 1 failed) | images 4 of 4"
    );
    let report = build.path().join("results").join("disk.html");
    let status = "const imgs = [...document.images]; \
        const loaded = imgs.filter(i => i.complete && i.naturalWidth > 0).length; \
        const status = document.getElementById('status'); \
        const top = status.getBoundingClientRect().top < document.querySelector('table').getBoundingClientRect().top; \
        document.title = status.className + ' | ' + (top ? 'first' : 'below') + ' | ' + document.querySelectorAll('h2').length + ' sections | images ' + loaded + ' of ' + imgs.length;";
    assert_eq!(
        title_in_chromium(&report, profile.path(), status),
        "status converged | first | 8 sections | images 4 of 4"
    );
    let failed = build.path().join("studies").join("alpha-sweep-000.html");
    let first_word = "document.title = document.getElementById('status').className + ': ' + document.querySelector('#status strong').innerText;";
    assert_eq!(
        title_in_chromium(&failed, profile.path(), first_word),
        "status failed: failed"
    );
    for (page, png) in [(&index, "index.png"), (&report, "report.png")] {
        screenshot(page, profile.path(), &build.path().join(png));
    }
}

#[test]
fn index_lists_every_run_table_and_figure_with_one_line_each() {
    let build = tempfile::tempdir().unwrap();
    let results = build.path().join("results");
    let studies = build.path().join("studies").join("sub");
    std::fs::create_dir_all(&results).unwrap();
    std::fs::create_dir_all(&studies).unwrap();
    solve_disk(&results);
    std::fs::write(
        studies.join("my-study.md"),
        "## A study of <things>\n\n| a |\n",
    )
    .unwrap();
    std::fs::write(
        studies.join("my-study.csv"),
        "mesh.h,iterations,kkt,converged,result_file\n0.4,26133,0.30936923800000005,true,x/my-study-003.h5\n",
    )
    .unwrap();
    std::fs::write(studies.join("membrane-thesis.csv"), "a\n-0.0\n").unwrap();
    std::fs::write(studies.join("my-study-003.h5"), "").unwrap();
    std::fs::write(studies.join("my-study-convergence-0.png"), "").unwrap();
    // A run under way (hidden staging folder) and other files are not listed.
    std::fs::create_dir_all(results.join(".x.obstacle-tmp-1-abc")).unwrap();
    std::fs::write(results.join(".x.obstacle-tmp-1-abc").join("x.h5"), "").unwrap();

    let o = run_obstacle(&["index", build.path().to_str().unwrap()]);
    check_success("index", &o);
    let html = std::fs::read_to_string(build.path().join("index.html")).unwrap();
    for part in [
        // Runs: status, report page, result file.
        "<tr class=\"converged\"><td><span class=\"badge converged\"",
        "<a href=\"results/disk.html\">disk</a> <a class=\"note\" href=\"results/disk.h5\">.h5</a>",
        "<a href=\"studies/sub/my-study-003.html\">my-study-003</a>",
        "<span class=\"badge unreadable\"",
        // Tables from the CSV: headings as the Markdown names them, numbers
        // with meaningful digits, integers exact, the run's report linked.
        "<h3 id=\"table-membrane-thesis\">membrane, both pairs, h = 0.8 … 0.1, α = 0.9, 1.9, auto (thesis Tables 5.1–5.4)</h3>",
        "<h3 id=\"table-my-study\">A study of &#60;things&#62;</h3>",
        "<th>iter</th><th>KKT</th>",
        "<td class=\"num\">0.4</td><td class=\"num\">26133</td><td class=\"num\">0.3094</td><td>yes</td><td><a href=\"studies/sub/my-study-003.html\">my-study-003</a></td>",
        "<td class=\"num\">0</td>",
        // Figures as thumbnails linking to their full size.
        "<figure><a href=\"results/disk.u.png\"><img src=\"results/disk.u.png\" alt=\"figure u of disk\"></a>",
        "<img src=\"studies/sub/my-study-convergence-0.png\" alt=\"figure convergence-0 of: A study of &#60;things&#62;\">",
    ] {
        assert!(html.contains(part), "no {part} in the index:\n{html}");
    }
    // The thesis table comes first, whatever the file order.
    assert!(html.find("table-membrane-thesis") < html.find("table-my-study"));
    assert_eq!(
        html.matches("<figure>").count(),
        5,
        "4 plots and a study's: {html}"
    );
    assert_eq!(html.matches("<table class=\"study\">").count(), 2, "{html}");
    assert!(!html.contains("obstacle-tmp"), "a staging folder is listed");
    assert!(
        !html.contains("disk.xdmf"),
        "only tables, figures and runs are listed"
    );
    // A report page beside every run, the unreadable one included.
    let page = std::fs::read_to_string(results.join("disk.html")).unwrap();
    assert!(
        page.contains("<a href=\"../index.html\">all outputs</a>"),
        "{page}"
    );
    assert!(studies.join("my-study-003.html").is_file());
    // `make` twice: every page is rewritten over the previous run's.
    check_success(
        "a second index over the first",
        &run_obstacle(&["index", build.path().to_str().unwrap()]),
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
        html.contains("<a href=\"studies/piped-000.html\">piped-000</a> <a class=\"note\" href=\"studies/piped-000.h5\">.h5</a>"),
        "{html}"
    );
    assert!(
        !html.contains("fifo.h5") && !html.contains("piped.md"),
        "{html}"
    );
}
