//! One output transaction per command: every file a run writes (result,
//! XDMF, mesh, plots, tables) is staged in a hidden folder beside its target,
//! `.<label>.obstacle-tmp-<pid>-XXXXXX/`, and moved into place only when all of
//! them were written. A failed run leaves the previous outputs as they were.
//!
//! A target is refused, before anything is computed ([`OutputTransaction::stage`])
//! and again before anything is moved ([`OutputTransaction::commit`]), when it
//! is an input of the run (scene, `.geo`, mesh file), a directory, or an
//! existing file of another kind than its extension says (a `.h5` that is no
//! HDF5 file, a `.msh` that is no mesh, …): outputs replace earlier outputs,
//! nothing else.
//!
//! Staging folders and other temporaries registered with [`RemoveOnSignal`]
//! are removed when the transaction is dropped uncommitted and on SIGINT or
//! SIGTERM (the process then exits with 128 + the signal number, 130 or 143).
//! A SIGKILL or a crash cannot be caught: its staging folder stays, hidden,
//! until the next transaction in that folder sees its process gone.

use crate::error::{Error, Result};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// A staging folder is `.<label>` + this + `<pid>-XXXXXX`.
pub const STAGING_MARK: &str = ".obstacle-tmp-";

/// Files (or folders) to remove if the process is interrupted.
static PENDING: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// Registers a temporary file or folder for removal on SIGINT/SIGTERM for as
/// long as it lives (removing the path itself is its owner's job).
pub struct RemoveOnSignal {
    path: PathBuf,
}

impl RemoveOnSignal {
    pub fn new(path: &Path) -> RemoveOnSignal {
        install_signal_cleanup();
        PENDING
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push(path.to_path_buf());
        RemoveOnSignal {
            path: path.to_path_buf(),
        }
    }
}

impl Drop for RemoveOnSignal {
    fn drop(&mut self) {
        let mut pending = PENDING.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(i) = pending.iter().rposition(|p| *p == self.path) {
            pending.swap_remove(i);
        }
    }
}

/// A thread that waits for SIGINT or SIGTERM, removes the registered paths and
/// exits with 128 + the signal. signal-hook rather than ctrlc: it tells the two
/// signals apart (exit 130 vs 143) and its handler only writes to a pipe, so
/// the removal runs in an ordinary thread, not in signal context.
fn install_signal_cleanup() {
    static INSTALLED: std::sync::Once = std::sync::Once::new();
    INSTALLED.call_once(|| {
        use signal_hook::consts::{SIGINT, SIGTERM};
        let Ok(mut signals) = signal_hook::iterator::Signals::new([SIGINT, SIGTERM]) else {
            return; // no handler: the default action, as before
        };
        std::thread::spawn(move || {
            if let Some(signal) = signals.forever().next() {
                exit_after_cleanup(128 + signal);
            }
        });
    });
}

/// Ends the process with `status` after removing every registered temporary
/// (staging folders, gmsh/FreeFEM files): the end of a run interrupted by a
/// signal or by a closed output pipe (`console`).
pub fn exit_after_cleanup(status: i32) -> ! {
    let pending = PENDING.lock().unwrap_or_else(|e| e.into_inner());
    for path in pending.iter() {
        remove_all(path);
    }
    std::process::exit(status)
}

/// Removes the staging folders in `folder` left by runs that died without
/// cleaning up (SIGKILL, a crash): those whose process (the number after
/// [`STAGING_MARK`]) no longer exists. Only where /proc tells.
fn remove_orphaned_staging(folder: &Path) {
    if !Path::new("/proc/self").exists() {
        return;
    }
    let Ok(entries) = std::fs::read_dir(folder) else {
        return;
    };
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let pid = name
            .split_once(STAGING_MARK)
            .and_then(|(_, rest)| rest.split('-').next())
            .and_then(|p| p.parse::<u32>().ok());
        if let Some(pid) = pid.filter(|_| name.starts_with('.')) {
            if !Path::new(&format!("/proc/{pid}")).exists() {
                remove_all(&entry.path());
            }
        }
    }
}

/// Removes a file or a folder with its contents. A child process (gmsh) may
/// still be writing into the folder: a few attempts.
fn remove_all(path: &Path) {
    for _ in 0..5 {
        let gone = match std::fs::symlink_metadata(path) {
            Err(_) => true,
            Ok(m) if m.is_dir() => std::fs::remove_dir_all(path).is_ok(),
            Ok(_) => std::fs::remove_file(path).is_ok(),
        };
        if gone {
            return;
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
}

/// The outputs of one command, staged in one folder and moved into place together.
pub struct OutputTransaction {
    /// Where the outputs land, as given and canonical.
    folder: PathBuf,
    canonical_folder: PathBuf,
    staging: PathBuf,
    /// Canonical paths of the run's inputs, never replaced.
    inputs: Vec<PathBuf>,
    /// File names staged as failure markers ([`OutputTransaction::stage_marker`]):
    /// their kind is their content's, whatever their extension.
    markers: Mutex<Vec<std::ffi::OsString>>,
    _cleanup: RemoveOnSignal,
    committed: bool,
}

impl OutputTransaction {
    /// Starts a transaction whose files land in `folder` (created when
    /// missing); `label` names its staging folder (e.g. the result's stem);
    /// `inputs` are the files of the run that no output may replace.
    pub fn new(folder: &Path, label: &str, inputs: &[PathBuf]) -> Result<OutputTransaction> {
        // Before the staging folder exists: a signal never finds it unguarded.
        install_signal_cleanup();
        let folder = if folder.as_os_str().is_empty() {
            Path::new(".")
        } else {
            folder
        };
        std::fs::create_dir_all(folder)
            .map_err(|e| Error::output(folder, format!("cannot create the output folder: {e}")))?;
        let canonical = folder
            .canonicalize()
            .map_err(|e| Error::output(folder, format!("cannot resolve the output folder: {e}")))?;
        remove_orphaned_staging(&canonical);
        let staging = tempfile::Builder::new()
            .prefix(&format!(".{label}{STAGING_MARK}{}-", std::process::id()))
            .tempdir_in(&canonical)
            .map_err(|e| {
                Error::output(folder, format!("cannot create a staging folder in it: {e}"))
            })?
            .keep();
        let cleanup = RemoveOnSignal::new(&staging);
        Ok(OutputTransaction {
            folder: folder.to_path_buf(),
            canonical_folder: canonical,
            staging,
            inputs: inputs
                .iter()
                .filter_map(|p| p.canonicalize().ok())
                .collect(),
            markers: Mutex::new(Vec::new()),
            _cleanup: cleanup,
            committed: false,
        })
    }

    /// The folder the outputs land in, as given.
    pub fn folder(&self) -> &Path {
        &self.folder
    }

    /// Stages a result file `out` (FILE.h5) with the companions
    /// `write_result` writes beside it: FILE.xdmf and, for a shell (a result
    /// with a 3D surface), FILE.domain.xdmf. Returns the staged FILE.h5.
    pub fn stage_result(&self, out: &Path, with_surface: bool) -> Result<PathBuf> {
        let staged = self.stage(out)?;
        self.stage(&super::xdmf_path(out))?;
        if with_surface {
            self.stage(&super::domain_xdmf_path(out))?;
        }
        Ok(staged)
    }

    /// Stages a failure marker (`solve --failure-marker`, any extension):
    /// an existing file at `target` is replaced only if it is a marker.
    pub fn stage_marker(&self, target: &Path) -> Result<PathBuf> {
        if let Some(name) = target.file_name() {
            self.markers
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .push(name.to_os_string());
        }
        self.stage(target)
    }

    /// The path at which to write the file that becomes `target` on commit.
    /// Refuses a target outside the transaction's folder, an input of the
    /// run, a directory, or a file of another kind.
    pub fn stage(&self, target: &Path) -> Result<PathBuf> {
        let name = target
            .file_name()
            .ok_or_else(|| Error::output(target, "the output path has no file name"))?;
        let parent = match target.parent() {
            Some(p) if !p.as_os_str().is_empty() => p,
            _ => Path::new("."),
        };
        if parent.canonicalize().ok().as_deref() != Some(self.canonical_folder.as_path()) {
            return Err(Error::output(
                target,
                format!(
                    "internal: staged outside the output folder {}",
                    self.canonical_folder.display()
                ),
            ));
        }
        self.check_target(target)?;
        Ok(self.staging.join(name))
    }

    /// Moves every file written into the staging folder onto its target:
    /// all targets are checked first, then renamed (each rename atomic),
    /// result files (`.h5`) last so that a result changes only with its
    /// companions. Returns the targets.
    pub fn commit(mut self) -> Result<Vec<PathBuf>> {
        let fail = |e: std::io::Error| {
            Error::output(&self.staging, format!("cannot list the staged files: {e}"))
        };
        let mut staged: Vec<PathBuf> = Vec::new();
        for entry in std::fs::read_dir(&self.staging).map_err(fail)? {
            let entry = entry.map_err(fail)?;
            // Hidden files are the writers' own temporaries, never outputs.
            let hidden = entry.file_name().to_string_lossy().starts_with('.');
            if entry.file_type().map_err(fail)?.is_file() && !hidden {
                staged.push(entry.path());
            }
        }
        staged.sort_by_key(|p| (has_extension(p, "h5"), p.clone()));
        let moves: Vec<(PathBuf, PathBuf)> = staged
            .into_iter()
            .map(|from| {
                let to = self
                    .canonical_folder
                    .join(from.file_name().expect("a listed file"));
                (from, to)
            })
            .collect();
        for (_, to) in &moves {
            self.check_target(to)?;
        }
        for (i, (from, to)) in moves.iter().enumerate() {
            set_readable(from);
            std::fs::rename(from, to).map_err(|e| {
                let done: Vec<String> = moves[..i]
                    .iter()
                    .map(|(_, t)| t.display().to_string())
                    .collect();
                Error::output(
                    to,
                    format!(
                        "cannot move the finished file into place: {e} (already in place: {})",
                        if done.is_empty() {
                            "none".into()
                        } else {
                            done.join(", ")
                        }
                    ),
                )
            })?;
        }
        self.committed = true;
        remove_all(&self.staging);
        Ok(moves.into_iter().map(|(_, to)| to).collect())
    }

    /// Refuses to replace an input of the run, a directory, a special file,
    /// or a file whose content is not what its extension (a marker: its
    /// staging as one) says.
    fn check_target(&self, target: &Path) -> Result<()> {
        let is_marker = target.file_name().is_some_and(|name| {
            self.markers
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .iter()
                .any(|m| m == name)
        });
        let kind = if is_marker {
            Some(OutputKind::Marker)
        } else if target.file_name().is_some_and(|n| n == "Snakefile") {
            Some(OutputKind::Workflow)
        } else {
            OutputKind::of(&extension(target))
        };
        check_replaceable(target, kind, &self.inputs)
    }
}

/// Whether obstacle writes files with this extension (lower case, no dot).
pub(crate) fn is_output_extension(ext: &str) -> bool {
    OutputKind::of(ext).is_some()
}

/// Checks that a failure marker may be written or removed at `target`:
/// nothing there, or a marker (it begins with [`MARKER_HEADER`]),
/// and not one of `inputs`.
pub(crate) fn check_marker_target(target: &Path, inputs: &[PathBuf]) -> Result<()> {
    let inputs: Vec<PathBuf> = inputs
        .iter()
        .filter_map(|p| p.canonicalize().ok())
        .collect();
    check_replaceable(target, Some(OutputKind::Marker), &inputs)
}

fn extension(path: &Path) -> String {
    path.extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase()
}

/// Whether an existing `target` may be replaced by an output of `kind`
/// (None: an extension obstacle never writes); `inputs` are canonical.
fn check_replaceable(target: &Path, kind: Option<OutputKind>, inputs: &[PathBuf]) -> Result<()> {
    let refuse = |reason: String| Error::output(target, format!("{reason}; not replacing it"));
    let meta = match std::fs::metadata(target) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(refuse(format!("cannot inspect the existing path: {e}"))),
    };
    if meta.is_dir() {
        return Err(refuse("the output path is a directory".into()));
    }
    if !meta.is_file() {
        return Err(refuse("the output path is not a regular file".into()));
    }
    if let Ok(canonical) = target.canonicalize() {
        if inputs.contains(&canonical) {
            return Err(refuse("the output path is an input of this run".into()));
        }
    }
    let Some(kind) = kind else {
        return Err(refuse(format!(
            "an existing file with an extension obstacle never writes (`.{}`)",
            extension(target)
        )));
    };
    let head =
        read_head(target).map_err(|e| refuse(format!("cannot read the existing file: {e}")))?;
    // An empty file is a write that never happened, but for a marker,
    // which is recognised by its content alone.
    let empty_ok = head.is_empty() && !matches!(kind, OutputKind::Marker);
    if !empty_ok && !kind.matches(&head) {
        return Err(refuse(format!(
            "the existing file is not {} file",
            kind.description()
        )));
    }
    Ok(())
}

impl Drop for OutputTransaction {
    fn drop(&mut self) {
        if !self.committed {
            remove_all(&self.staging);
        }
    }
}

/// What obstacle writes, by extension: how an existing file of that kind begins.
#[derive(Clone, Copy)]
enum OutputKind {
    Hdf5,
    Msh,
    Xml,
    Png,
    Text,
    /// `solve --failure-marker`: by content, never by extension.
    Marker,
    /// The files of `study --workflow snakemake` (`Snakefile`, the profile's
    /// `config.yaml`): by their first line, [`WORKFLOW_HEADER`].
    Workflow,
}

/// The first line of every failure marker (`solve --failure-marker`,
/// `output::marker`): a file there without it is not replaced.
pub const MARKER_HEADER: &str = "# obstacle failure marker: this run failed numerically\n";

/// The first line of every file `study --workflow snakemake` writes: a
/// Snakefile or profile without it is not replaced.
pub const WORKFLOW_HEADER: &str =
    "# Written by `obstacle study --workflow snakemake`: replaced when that is run again.\n";

impl OutputKind {
    fn of(ext: &str) -> Option<OutputKind> {
        Some(match ext {
            "h5" => OutputKind::Hdf5,
            "msh" => OutputKind::Msh,
            "xdmf" | "svg" | "html" => OutputKind::Xml,
            "png" => OutputKind::Png,
            "md" | "csv" | "txt" => OutputKind::Text,
            "yaml" => OutputKind::Workflow,
            _ => return None,
        })
    }

    fn matches(self, head: &[u8]) -> bool {
        let text = || String::from_utf8_lossy(head).trim_start().to_string();
        match self {
            OutputKind::Hdf5 => head.starts_with(b"\x89HDF\r\n\x1a\n"),
            OutputKind::Msh => text().starts_with("$MeshFormat"),
            OutputKind::Xml => text().starts_with('<'),
            OutputKind::Png => head.starts_with(b"\x89PNG\r\n\x1a\n"),
            OutputKind::Text => !head.contains(&0),
            OutputKind::Marker => head.starts_with(MARKER_HEADER.as_bytes()),
            OutputKind::Workflow => head.starts_with(WORKFLOW_HEADER.as_bytes()),
        }
    }

    fn description(self) -> &'static str {
        match self {
            OutputKind::Hdf5 => "an HDF5",
            OutputKind::Msh => "a gmsh mesh ($MeshFormat)",
            OutputKind::Xml => "an XML/HTML",
            OutputKind::Png => "a PNG",
            OutputKind::Text => "a text",
            OutputKind::Marker => "an obstacle failure marker",
            OutputKind::Workflow => "an obstacle workflow",
        }
    }
}

/// The first bytes of a file (enough for a signature).
fn read_head(path: &Path) -> std::io::Result<Vec<u8>> {
    use std::io::Read as _;
    let mut head = Vec::with_capacity(512);
    std::fs::File::open(path)?
        .take(512)
        .read_to_end(&mut head)?;
    Ok(head)
}

fn has_extension(path: &Path, ext: &str) -> bool {
    path.extension().and_then(|e| e.to_str()) == Some(ext)
}

/// Mode 0644: temporaries are created 0600, outputs are for everyone to read.
fn set_readable(path: &Path) {
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let _ = std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o644));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn staging_folders(dir: &Path) -> Vec<String> {
        std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.contains(STAGING_MARK))
            .collect()
    }

    #[test]
    fn commit_moves_everything_and_drop_moves_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let a = dir.path().join("r.h5");
        let b = dir.path().join("r.xdmf");
        std::fs::write(&b, "<old/>").unwrap();

        let tx = OutputTransaction::new(dir.path(), "r", &[]).unwrap();
        std::fs::write(tx.stage(&a).unwrap(), b"\x89HDF\r\n\x1a\nnew").unwrap();
        std::fs::write(tx.stage(&b).unwrap(), "<new/>").unwrap();
        drop(tx);
        assert!(!a.exists());
        assert_eq!(std::fs::read_to_string(&b).unwrap(), "<old/>");
        assert!(staging_folders(dir.path()).is_empty());

        let tx = OutputTransaction::new(dir.path(), "r", &[]).unwrap();
        std::fs::write(tx.stage(&a).unwrap(), b"\x89HDF\r\n\x1a\nnew").unwrap();
        std::fs::write(tx.stage(&b).unwrap(), "<new/>").unwrap();
        let moved = tx.commit().unwrap();
        assert_eq!(moved.len(), 2);
        assert!(
            moved[1].ends_with("r.h5"),
            "the result file last: {moved:?}"
        );
        assert_eq!(std::fs::read_to_string(&b).unwrap(), "<new/>");
        assert!(staging_folders(dir.path()).is_empty());
    }

    #[test]
    fn orphaned_staging_folders_are_removed() {
        let dir = tempfile::tempdir().unwrap();
        // No process has this number (above the kernel's pid_max limit of 2^22).
        let orphan = dir.path().join(format!(".r{STAGING_MARK}4294967-abc"));
        let alive = dir
            .path()
            .join(format!(".r{STAGING_MARK}{}-abc", std::process::id()));
        std::fs::create_dir_all(orphan.join(".gmsh-x")).unwrap();
        std::fs::create_dir(&alive).unwrap();
        let tx = OutputTransaction::new(dir.path(), "r", &[]).unwrap();
        assert!(!orphan.exists());
        assert!(alive.exists());
        drop(tx);
    }

    #[test]
    fn refused_targets() {
        let dir = tempfile::tempdir().unwrap();
        let scene = dir.path().join("scene.toml");
        std::fs::write(&scene, "name = 'x'").unwrap();
        let fake_h5 = dir.path().join("fake.h5");
        std::fs::write(&fake_h5, "not hdf5").unwrap();
        let as_dir = dir.path().join("d.png");
        std::fs::create_dir(&as_dir).unwrap();
        let as_msh = dir.path().join("scene.msh");
        std::fs::write(&as_msh, "$MeshFormat\n").unwrap();

        let tx = OutputTransaction::new(dir.path(), "t", &[scene.clone(), as_msh.clone()]).unwrap();
        let reason = |p: &Path| tx.stage(p).unwrap_err().to_string();
        assert!(reason(&scene).contains("an input of this run"));
        assert!(reason(&as_msh).contains("an input of this run"));
        assert!(reason(&fake_h5).contains("the existing file is not an HDF5 file"));
        assert!(reason(&as_dir).contains("is a directory"));

        // A target that turned into a directory after staging: commit refuses, moves nothing.
        let x = dir.path().join("late.xdmf");
        std::fs::write(tx.stage(&x).unwrap(), "<new/>").unwrap();
        std::fs::write(tx.stage(&dir.path().join("late.h5")).unwrap(), "x").unwrap();
        std::fs::create_dir(&x).unwrap();
        let e = tx.commit().unwrap_err().to_string();
        assert!(
            e.contains("late.xdmf") && e.contains("is a directory"),
            "{e}"
        );
        assert!(!dir.path().join("late.h5").exists());
        assert!(staging_folders(dir.path()).is_empty());
    }
}
