//! `obstacle solve --failure-marker FILE`, for workflow engines: a run that
//! fails numerically writes its error to FILE (in its own output
//! transaction) instead of failing, and a run that succeeds removes a FILE
//! left by an earlier failure. FILE is the command's own only when it is a
//! marker, recognised by its first line ([`HEADER`]): any other file there
//! is refused before the run, never removed or replaced, and so is a marker
//! path that is an input of the run or a file the run writes (the result
//! and the files named after it: `RESULT.xdmf`, `.msh`, plots).

use super::transaction::{check_marker_target, is_output_extension};
use super::OutputTransaction;
use crate::error::{Error, Result};
use std::path::{Path, PathBuf};

/// The first line of every failure marker.
pub use super::transaction::MARKER_HEADER as HEADER;

/// A failure marker path, checked against the run it belongs to.
pub struct FailureMarker {
    path: PathBuf,
    inputs: Vec<PathBuf>,
}

impl FailureMarker {
    /// The marker at `path` of the run writing `result` from `inputs`:
    /// refused when it is the result, a file named after it with an
    /// extension obstacle writes, an input, or an existing file that is no
    /// marker (or a folder, a FIFO, ...).
    pub fn new(path: &Path, result: &Path, inputs: &[PathBuf]) -> Result<FailureMarker> {
        let refuse = |reason: &str| {
            Error::output(
                path,
                format!("{reason}: refused as the failure marker (--failure-marker)"),
            )
        };
        let (marker_at, result_at) = (resolve(path), resolve(result));
        if marker_at == result_at {
            return Err(refuse("it is the result file"));
        }
        let (Some(name), Some(stem)) = (
            marker_at.file_name().and_then(|n| n.to_str()),
            result_at.file_stem().and_then(|s| s.to_str()),
        ) else {
            return Err(refuse("no file name in UTF-8"));
        };
        let ext = name
            .rsplit_once('.')
            .map_or("", |(_, e)| e)
            .to_ascii_lowercase();
        if marker_at.parent() == result_at.parent()
            && name.starts_with(&format!("{stem}."))
            && is_output_extension(&ext)
        {
            return Err(refuse(&format!(
                "the run writes files named {stem}.* with .{ext} beside its result"
            )));
        }
        check_marker_target(path, inputs).map_err(|e| match e {
            Error::Output { file, reason } => Error::Output {
                file,
                reason: format!("{reason} (--failure-marker)"),
            },
            other => other,
        })?;
        Ok(FailureMarker {
            path: path.to_path_buf(),
            inputs: inputs.to_vec(),
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Writes `error` after the header, replacing an earlier marker.
    pub fn write(&self, error: &str) -> Result<()> {
        let folder = self.path.parent().unwrap_or(Path::new(""));
        let stem = self
            .path
            .file_stem()
            .and_then(|s| s.to_str())
            .unwrap_or("marker");
        let outputs = OutputTransaction::new(folder, stem, &self.inputs)?;
        super::write_text_atomically(
            &outputs.stage_marker(&self.path)?,
            &format!("{HEADER}{error}\n"),
        )?;
        outputs.commit()?;
        Ok(())
    }

    /// Removes the marker of an earlier failed run, if any (checked again:
    /// only a marker is removed).
    pub fn remove_stale(&self) -> Result<()> {
        if std::fs::symlink_metadata(&self.path).is_err() {
            return Ok(());
        }
        check_marker_target(&self.path, &self.inputs)?;
        std::fs::remove_file(&self.path).map_err(|e| {
            Error::output(
                &self.path,
                format!("cannot remove the old failure marker: {e}"),
            )
        })
    }
}

/// The error a marker holds (its text after the header, without the last
/// newline); an error naming the file when it is no marker.
pub fn read_marker(path: &Path) -> Result<String> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| Error::output(path, format!("cannot read the failure marker: {e}")))?;
    let error = text.strip_prefix(HEADER).ok_or_else(|| {
        Error::output(
            path,
            format!(
                "not a failure marker: its first line is not `{}`",
                HEADER.trim_end()
            ),
        )
    })?;
    Ok(error.strip_suffix('\n').unwrap_or(error).to_string())
}

/// The failure marker of a result file: `RUN.failed` beside `RUN.h5`.
pub fn marker_path(result: &Path) -> PathBuf {
    result.with_extension("failed")
}

/// The error of the run that was to write `result`, when its marker says it
/// failed: the marker exists and is not older than the result file (a failed
/// rerun leaves the earlier result in place). None when the run's last
/// outcome is the result file, or neither file exists.
pub fn newer_failure(result: &Path) -> Result<Option<String>> {
    let marker = marker_path(result);
    let modified = |p: &Path| std::fs::metadata(p).and_then(|m| m.modified()).ok();
    match (modified(result), modified(&marker)) {
        (r, Some(failed)) if r.is_none_or(|r| failed >= r) => read_marker(&marker).map(Some),
        _ => Ok(None),
    }
}

/// `path` with its folder resolved (symlinks, `..`) when the folder exists.
fn resolve(path: &Path) -> PathBuf {
    let name = path.file_name().map(PathBuf::from).unwrap_or_default();
    let folder = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    folder
        .canonicalize()
        .or_else(|_| std::path::absolute(folder))
        .unwrap_or_else(|_| folder.to_path_buf())
        .join(name)
}
