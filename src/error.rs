//! One error type for the whole pipeline. Every variant names the file (or
//! stage), the field and the reason, so a failed run says what to fix.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A scene file (or a `--set` override) is malformed or out of range.
    #[error("{file}: field `{field}`: {reason}")]
    Scene {
        file: PathBuf,
        field: String,
        reason: String,
    },
    /// A scene, study or benchmark file that cannot be read, or is no TOML:
    /// the reason keeps TOML's own lines (line, column, the caret under the
    /// offending character).
    #[error("{file}: {reason}")]
    SceneFile { file: PathBuf, reason: String },
    /// A mesh file is unreadable, malformed or geometrically invalid.
    #[error("{file}: {reason}")]
    Mesh { file: PathBuf, reason: String },
    /// gmsh is missing or failed.
    #[error("gmsh ({geo}): {reason}")]
    Gmsh { geo: PathBuf, reason: String },
    /// A numerical failure: divergence, non-finite values, singular matrix,
    /// constraint never satisfied. `measure` names what failed.
    #[error("{stage}: {measure}: {reason}")]
    Numerical {
        stage: String,
        measure: String,
        reason: String,
    },
    /// A result file cannot be written or read.
    #[error("{file}: {reason}")]
    Output { file: PathBuf, reason: String },
    /// An external tool (FreeFEM, ...) is missing or failed.
    #[error("{tool}: {reason}")]
    Tool { tool: String, reason: String },
}

pub type Result<T> = std::result::Result<T, Error>;

impl Error {
    pub fn numerical(stage: &str, measure: &str, reason: impl Into<String>) -> Self {
        Error::Numerical {
            stage: stage.to_string(),
            measure: measure.to_string(),
            reason: reason.into(),
        }
    }
    pub fn mesh(file: impl Into<PathBuf>, reason: impl Into<String>) -> Self {
        Error::Mesh {
            file: file.into(),
            reason: reason.into(),
        }
    }
    pub fn output(file: impl Into<PathBuf>, reason: impl Into<String>) -> Self {
        Error::Output {
            file: file.into(),
            reason: reason.into(),
        }
    }
}
