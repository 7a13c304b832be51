//! External programs (gmsh, FreeFem++) run with a time limit: a `.geo` that
//! loops or a script that never ends must not hang a run forever.
//!
//! The wait is `wait-timeout`'s (a well-kept crate, already in the tree via
//! proptest): it blocks on the child's exit with a deadline (SIGCHLD on
//! Unix) instead of polling `try_wait` in a sleep loop, which would either
//! burn CPU or add up to one polling period to every run.

use std::io::Read;
use std::process::{Command, Output, Stdio};
use std::time::Duration;
use wait_timeout::ChildExt;

/// Environment variable: the limit in seconds on each gmsh and FreeFem++ run.
pub const TIMEOUT_VAR: &str = "OBSTACLE_TOOL_TIMEOUT";

/// The default limit: generous, far above any run of the thesis or the
/// benchmarks (the largest FreeFEM benchmark takes about a minute).
pub const DEFAULT_TIMEOUT_SECONDS: f64 = 600.0;

/// Why a subprocess gave no output.
#[derive(Debug)]
pub enum RunError {
    /// It could not be started (not found, not executable, ...).
    Spawn(std::io::Error),
    /// It ran past the limit (seconds) and was killed.
    TimedOut(f64),
    /// `OBSTACLE_TOOL_TIMEOUT` is not a positive number of seconds.
    BadLimit(String),
}

impl RunError {
    /// The reason, naming the program and the limit.
    pub fn describe(&self, program: &str) -> String {
        match self {
            RunError::Spawn(e) => format!("cannot run {program}: {e}"),
            RunError::TimedOut(limit) => format!(
                "{program} did not finish within {limit} s and was killed (the limit is {TIMEOUT_VAR}, default {DEFAULT_TIMEOUT_SECONDS} s)"
            ),
            RunError::BadLimit(v) => format!(
                "{TIMEOUT_VAR} = `{v}` is not a positive number of seconds"
            ),
        }
    }
}

/// The limit from [`TIMEOUT_VAR`], else [`DEFAULT_TIMEOUT_SECONDS`].
pub fn timeout_seconds() -> std::result::Result<f64, RunError> {
    match std::env::var(TIMEOUT_VAR) {
        Err(_) => Ok(DEFAULT_TIMEOUT_SECONDS),
        Ok(v) => match v.trim().parse::<f64>() {
            Ok(s) if s.is_finite() && s > 0.0 && s < 1e9 => Ok(s),
            _ => Err(RunError::BadLimit(v)),
        },
    }
}

/// Runs `command` to completion with its output captured, as
/// `Command::output` does, but kills it after [`timeout_seconds`].
pub fn output_with_timeout(command: &mut Command) -> std::result::Result<Output, RunError> {
    let limit = timeout_seconds()?;
    let mut child = command
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(RunError::Spawn)?;
    // Both pipes are drained while waiting, or a chatty child blocks on a
    // full pipe and looks hung.
    let drain = |pipe: Option<Box<dyn Read + Send>>| {
        std::thread::spawn(move || {
            let mut bytes = Vec::new();
            if let Some(mut p) = pipe {
                let _ = p.read_to_end(&mut bytes);
            }
            bytes
        })
    };
    let stdout = drain(
        child
            .stdout
            .take()
            .map(|p| Box::new(p) as Box<dyn Read + Send>),
    );
    let stderr = drain(
        child
            .stderr
            .take()
            .map(|p| Box::new(p) as Box<dyn Read + Send>),
    );
    let status = match child
        .wait_timeout(Duration::from_secs_f64(limit))
        .map_err(RunError::Spawn)?
    {
        Some(status) => status,
        None => {
            let _ = child.kill();
            let _ = child.wait();
            return Err(RunError::TimedOut(limit));
        }
    };
    Ok(Output {
        status,
        stdout: stdout.join().unwrap_or_default(),
        stderr: stderr.join().unwrap_or_default(),
    })
}
