//! One run of a scene, whichever kind: the adaptive loop of its `[adapt]`
//! table ([`crate::adapt`]), else the run on its one mesh
//! ([`crate::pipeline::run_uniform`]). Both sit on the pipeline's stages;
//! this module, above them, picks (so the adaptive loop and the pipeline do
//! not import each other).

use crate::error::Result;
use crate::pipeline::RunSummary;
use crate::scene::Scene;
use std::path::Path;

/// Runs `scene` and writes `out` (and its companions) in one output
/// transaction; an adaptive run's summary is its last step's.
pub fn run_scene(scene: &Scene, out: &Path, show_progress: bool) -> Result<RunSummary> {
    match scene.adapt {
        Some(_) => crate::adapt::run_adaptive(scene, out).map(|(summary, _)| summary),
        None => crate::pipeline::run_uniform(scene, out, show_progress),
    }
}
