//! The benchmarks' child processes: each case runs in its own process (its
//! peak RSS its own) and prints `key=value` pairs on one line.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

/// Runs `exe` with `args` and returns the `key=value` pairs it printed;
/// panics naming `what` and the child's error output when it fails.
pub fn child_output(exe: &Path, args: &[String], what: &str) -> BTreeMap<String, String> {
    let out = Command::new(exe).args(args).output().expect("run a case");
    assert!(
        out.status.success(),
        "{what}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout)
        .split_whitespace()
        .filter_map(|kv| kv.split_once('='))
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect()
}
