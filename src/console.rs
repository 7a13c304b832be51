//! What the commands print on standard output (tables, summary lines),
//! through [`out!`](crate::out) and [`outln!`](crate::outln) instead of
//! `print!`/`println!`, which panic when stdout cannot be written.
//!
//! A reader that went away (EPIPE: `obstacle info FILE | head -1`) ends
//! the process as SIGPIPE would end a C program, quietly with status 141
//! (128 + SIGPIPE), after removing the temporaries registered for cleanup
//! (the same as on SIGINT/SIGTERM). Rust ignores SIGPIPE, so the signal
//! itself never comes; the failed write is the only sign. Any other write
//! error (a full disk under a redirection) is an `error:` line and status 1.

use std::io::Write as _;

/// The exit status of `solve` for a run stopped by `solver.max_iter` before
/// it converged or met the scene's stop rule (its result is written and
/// records `converged = false`, `stop_reason = "max_iter"`). 0 is success,
/// 1 an error (bad input, a numerical failure, a usage error).
pub const NOT_CONVERGED_STATUS: u8 = 2;

/// The exit status of a command whose output reader went away: 128 + SIGPIPE.
pub const BROKEN_PIPE_STATUS: i32 = 128 + 13;

/// Writes `args` to stdout (locked, flushed); see the module documentation
/// for what a failed write does.
pub fn write_stdout(args: std::fmt::Arguments) {
    let mut stdout = std::io::stdout().lock();
    if let Err(e) = stdout.write_fmt(args).and_then(|()| stdout.flush()) {
        if e.kind() == std::io::ErrorKind::BrokenPipe {
            crate::output::transaction::exit_after_cleanup(BROKEN_PIPE_STATUS);
        }
        eprintln!("error: cannot write to standard output: {e}");
        crate::output::transaction::exit_after_cleanup(1);
    }
}

/// `print!` to stdout through [`write_stdout`].
#[macro_export]
macro_rules! out {
    ($($arg:tt)*) => {
        $crate::console::write_stdout(format_args!($($arg)*))
    };
}

/// `println!` to stdout through [`write_stdout`].
#[macro_export]
macro_rules! outln {
    () => {
        $crate::console::write_stdout(format_args!("\n"))
    };
    ($($arg:tt)*) => {
        $crate::console::write_stdout(format_args!("{}\n", format_args!($($arg)*)))
    };
}
