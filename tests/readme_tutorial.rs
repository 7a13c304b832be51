//! The README's tutorial ("A first tour") as a newcomer runs it: every file
//! it shows is written and every command it shows is run, in a scratch copy
//! of the repository's layout, with this build's binary as `obstacle` and
//! `make` pointed at it. A command that fails fails the test.

use std::path::{Path, PathBuf};
use std::process::Command;

const BEGIN: &str = "<!-- tutorial: begin";
const END: &str = "<!-- tutorial: end -->";

/// The fenced blocks of the tutorial: (info string, body).
fn tutorial_blocks(readme: &str) -> Vec<(String, String)> {
    let start = readme
        .find(BEGIN)
        .expect("README has the tutorial's begin marker");
    let end = readme
        .find(END)
        .expect("README has the tutorial's end marker");
    let mut blocks = Vec::new();
    let mut lines = readme[start..end].lines();
    while let Some(line) = lines.next() {
        if let Some(info) = line.strip_prefix("```") {
            let body: Vec<&str> = lines
                .by_ref()
                .take_while(|l| !l.starts_with("```"))
                .collect();
            blocks.push((info.trim().to_string(), body.join("\n") + "\n"));
        }
    }
    blocks
}

#[test]
fn the_readme_tutorial_runs_as_written() {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    let readme = std::fs::read_to_string(repo.join("README.md")).unwrap();
    let blocks = tutorial_blocks(&readme);
    let dir = tempfile::tempdir().unwrap();
    for entry in ["pipelines", "meshes", "freefem", "Makefile", ".ci"] {
        std::os::unix::fs::symlink(repo.join(entry), dir.path().join(entry)).unwrap();
    }
    let bin = PathBuf::from(env!("CARGO_BIN_EXE_obstacle"));
    let path = format!(
        "{}:{}",
        bin.parent().unwrap().display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let (mut files, mut commands) = (0, 0);
    for (info, body) in &blocks {
        let mut words = info.split_whitespace();
        match (words.next(), words.next()) {
            (Some("toml"), Some(file)) => {
                std::fs::write(dir.path().join(file), body).unwrap();
                files += 1;
            }
            (Some("sh"), None) => {
                for line in body.lines().filter(|l| !l.trim().is_empty()) {
                    // `make` builds with cargo and runs target/release/obstacle:
                    // here the binary under test, already built.
                    let line = if line.starts_with("make ") {
                        format!("{line} BIN={} CARGO=true", bin.display())
                    } else {
                        line.to_string()
                    };
                    let out = Command::new("sh")
                        .arg("-c")
                        .arg(&line)
                        .current_dir(dir.path())
                        .env("PATH", &path)
                        .output()
                        .unwrap();
                    assert!(
                        out.status.success(),
                        "`{line}` failed:\n{}{}",
                        String::from_utf8_lossy(&out.stdout),
                        String::from_utf8_lossy(&out.stderr)
                    );
                    commands += 1;
                }
            }
            _ => {}
        }
    }
    assert_eq!(
        (files, commands),
        (1, 5),
        "the tutorial's files and commands"
    );
    for produced in [
        "build/results/my-disk.h5",
        "build/results/my-disk.html",
        "build/results/spherical-cap-contact.h5",
        "build/freefem/my-disk.h5",
    ] {
        assert!(dir.path().join(produced).is_file(), "{produced}");
    }
}
