//! gmsh as a subprocess: mesh a `.geo` file into an MSH 2.2 ASCII file.
//!
//! The command line is
//!
//! ```text
//! gmsh <geo> -2 -format msh22 -v 2 -nopopup [-setnumber NAME VALUE]... -o <tmp>
//! ```
//!
//! where `<tmp>` lies in a fresh temporary directory inside the output's
//! directory. gmsh can exit with status 0 yet write an empty or triangle-free
//! file, and can write a partial file while failing, so the result is checked
//! (exit status, no `Error` line in gmsh's output, non-empty file with an
//! `$Elements` section holding triangles) before it is renamed into place:
//! `out_msh` is replaced atomically, and left untouched on failure.

use crate::error::{Error, Result};
use crate::subprocess::{output_with_timeout, RunError};
use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::Command;

/// The gmsh executable, looked up on PATH.
pub const GMSH: &str = "gmsh";

/// Message when gmsh is not on PATH.
pub const GMSH_NOT_FOUND: &str =
    "gmsh not found on PATH; install it with `apt-get install gmsh` (or `make deps`)";

/// Lines of gmsh's output quoted in an error.
const LOG_LINES: usize = 20;

/// Mesh `geo` in 2-D into `out_msh` (MSH 2.2 ASCII), setting each
/// `(NAME, VALUE)` of `params` with `-setnumber NAME VALUE`.
pub fn run_gmsh(geo: &Path, out_msh: &Path, params: &[(String, f64)]) -> Result<()> {
    run_gmsh_with(OsStr::new(GMSH), geo, out_msh, &Job::Mesh(params, None))
}

/// What gmsh is run for.
enum Job<'a> {
    /// Mesh a `.geo` in 2D with `-setnumber` parameters and an optional
    /// background size view.
    Mesh(&'a [(String, f64)], Option<&'a Path>),
    /// Convert a mesh file to MSH 2.2 (`-2` would remesh it).
    Convert,
}

/// The major MSH version a mesh file declares in its `$MeshFormat` header
/// (text even in binary files); None when the file has no such header.
pub fn msh_major_version(path: &Path) -> Option<u32> {
    use std::io::Read as _;
    let mut head = [0u8; 256];
    let n = std::fs::File::open(path).ok()?.read(&mut head).ok()?;
    let text = String::from_utf8_lossy(&head[..n]);
    let mut lines = text.lines().map(str::trim).skip_while(|l| l.is_empty());
    if lines.next()? != "$MeshFormat" {
        return None;
    }
    lines.next()?.split(['.', ' ']).next()?.parse().ok()
}

/// A copy of the mesh file `input` (any format gmsh reads: MSH 4.1, its
/// default, ASCII or binary) as MSH 2.2 ASCII at `out_msh`, written by gmsh
/// itself (`-save -format msh22`), checked and renamed into place like a
/// meshing run's output.
pub fn convert_to_msh22(input: &Path, out_msh: &Path) -> Result<()> {
    run_gmsh_with(OsStr::new(GMSH), input, out_msh, &Job::Convert)
}

/// As [`run_gmsh`], with the sizes of a background mesh (`-bgm`: a `.pos`
/// view of target sizes, as the adaptive loop writes it).
pub fn run_gmsh_sized(
    geo: &Path,
    out_msh: &Path,
    params: &[(String, f64)],
    background: &Path,
) -> Result<()> {
    run_gmsh_with(
        OsStr::new(GMSH),
        geo,
        out_msh,
        &Job::Mesh(params, Some(background)),
    )
}

/// The version gmsh reports (`gmsh --version`), e.g. "4.8.4"; None if gmsh
/// cannot be run.
pub fn gmsh_version() -> Option<String> {
    // Under the same time limit as meshing: a hung gmsh never hangs a run.
    let out = crate::subprocess::output_with_timeout(Command::new(GMSH).arg("--version")).ok()?;
    if !out.status.success() {
        return None;
    }
    [&out.stdout, &out.stderr].iter().find_map(|bytes| {
        String::from_utf8_lossy(bytes)
            .lines()
            .map(str::trim)
            .find(|l| !l.is_empty())
            .map(str::to_string)
    })
}

/// The arguments passed to gmsh (without the program name).
pub fn gmsh_args(geo: &Path, out: &Path, params: &[(String, f64)]) -> Vec<std::ffi::OsString> {
    let mut args: Vec<std::ffi::OsString> = vec![
        geo.as_os_str().to_owned(),
        "-2".into(),
        "-format".into(),
        "msh22".into(),
        "-v".into(),
        "2".into(),
        "-nopopup".into(),
    ];
    for (name, value) in params {
        args.push("-setnumber".into());
        args.push(name.into());
        // Display of f64 round-trips exactly and never uses an exponent.
        args.push(format!("{value}").into());
    }
    args.push("-o".into());
    args.push(out.as_os_str().to_owned());
    args
}

fn run_gmsh_with(program: &OsStr, geo: &Path, out_msh: &Path, job: &Job) -> Result<()> {
    let (params, background) = match *job {
        Job::Mesh(params, background) => (params, background),
        Job::Convert => (&[][..], None),
    };
    let err = |reason: String| Error::Gmsh {
        geo: geo.to_path_buf(),
        reason,
    };

    match std::fs::metadata(geo) {
        Ok(m) if m.is_file() => {}
        Ok(_) => return Err(err("the geometry path is not a file".into())),
        Err(e) => {
            return Err(err(format!(
                "cannot open the geometry file: {e} (no such .geo file?)"
            )))
        }
    }
    for (name, value) in params {
        let valid_name = !name.is_empty()
            && !name.starts_with(|c: char| c.is_ascii_digit())
            && name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '.');
        if !valid_name {
            return Err(err(format!(
                "invalid parameter name `{name}` (letters, digits, `_` and `.` only)"
            )));
        }
        if !value.is_finite() {
            return Err(err(format!("parameter `{name}` = {value} is not finite")));
        }
    }
    let Some(file_name) = out_msh.file_name() else {
        return Err(err(format!(
            "the output path {} has no file name",
            out_msh.display()
        )));
    };
    let dir: PathBuf = match out_msh.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    std::fs::create_dir_all(&dir).map_err(|e| {
        err(format!(
            "cannot create the output directory {}: {e}",
            dir.display()
        ))
    })?;
    let tmp_dir = tempfile::Builder::new()
        .prefix(".gmsh-")
        .tempdir_in(&dir)
        .map_err(|e| {
            err(format!(
                "cannot create a temporary directory in {}: {e}",
                dir.display()
            ))
        })?;
    // Removed on drop, and by the signal handler if the run is interrupted.
    let _on_signal = crate::output::transaction::RemoveOnSignal::new(tmp_dir.path());
    let tmp = tmp_dir.path().join(file_name);

    let mut command = Command::new(program);
    match job {
        Job::Convert => {
            command
                .arg(geo)
                .args(["-save", "-format", "msh22", "-v", "2", "-nopopup", "-o"]);
            command.arg(&tmp);
        }
        Job::Mesh(..) => {
            command.args(gmsh_args(geo, &tmp, params));
        }
    }
    if let Some(b) = background {
        command.arg("-bgm").arg(b);
    }
    let output = output_with_timeout(&mut command).map_err(|e| match e {
        RunError::Spawn(e) if e.kind() == std::io::ErrorKind::NotFound => {
            err(GMSH_NOT_FOUND.to_string())
        }
        e => err(e.describe(&program.to_string_lossy())),
    })?;
    let log = log_tail(&output.stdout, &output.stderr);
    let has_error_line = [&output.stdout, &output.stderr].iter().any(|b| {
        String::from_utf8_lossy(b)
            .lines()
            .any(|l| l.trim_start().starts_with("Error"))
    });
    if !output.status.success() || has_error_line {
        return Err(err(format!("gmsh failed ({}):\n{log}", output.status)));
    }
    let text = match std::fs::read(&tmp) {
        Ok(bytes) => bytes,
        Err(e) => {
            return Err(err(format!(
                "gmsh exited normally but wrote no mesh file ({e}); its output:\n{log}"
            )))
        }
    };
    if let Err(reason) = check_msh(&String::from_utf8_lossy(&text)) {
        let folder = tmp.parent().unwrap_or(Path::new("."));
        let hint = disk_full_hint(folder, free_bytes(folder));
        return Err(err(format!(
            "gmsh exited normally but {reason}{hint}; its output:\n{log}"
        )));
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&tmp, std::fs::Permissions::from_mode(0o644)).map_err(|e| {
            err(format!(
                "cannot set the permissions of {}: {e}",
                tmp.display()
            ))
        })?;
    }
    std::fs::rename(&tmp, out_msh).map_err(|e| {
        err(format!(
            "cannot move the mesh into place at {}: {e}",
            out_msh.display()
        ))
    })?;
    Ok(())
}

/// Below this many free bytes a truncated mesh file is blamed on a full disk.
const NEARLY_FULL_BYTES: u64 = 1 << 20;

/// The bytes free to an unprivileged writer on the file system of `folder`.
fn free_bytes(folder: &Path) -> Option<u64> {
    use std::os::unix::ffi::OsStrExt;
    let c_path = std::ffi::CString::new(folder.as_os_str().as_bytes()).ok()?;
    let mut stat: libc::statvfs = unsafe { std::mem::zeroed() };
    // SAFETY: a NUL-terminated path and a zeroed statvfs for the call to fill.
    let status = unsafe { libc::statvfs(c_path.as_ptr(), &mut stat) };
    (status == 0).then(|| stat.f_bavail as u64 * stat.f_frsize as u64)
}

/// gmsh reports no write error when the disk fills: its mesh file is just
/// short. A nearly full file system is named as the likely cause.
fn disk_full_hint(folder: &Path, free: Option<u64>) -> String {
    match free {
        Some(free) if free < NEARLY_FULL_BYTES => format!(
            " (the file system of {} has {free} bytes free: the disk is full, which truncates the mesh file)",
            folder.display()
        ),
        _ => String::new(),
    }
}

/// Quick sanity check of gmsh's output: non-empty, with an `$Elements`
/// section that holds at least one triangle (type 2) and is closed.
fn check_msh(text: &str) -> std::result::Result<(), String> {
    if text.trim().is_empty() {
        return Err("wrote an empty mesh file".into());
    }
    let mut lines = text.lines().map(str::trim);
    if !lines.any(|l| l == "$Elements") {
        return Err("the mesh file has no $Elements section".into());
    }
    let _count = lines.next();
    let mut triangles = 0usize;
    for l in lines {
        if l == "$EndElements" {
            return if triangles > 0 {
                Ok(())
            } else {
                Err("the mesh has no triangles (does the .geo define a Physical Surface?)".into())
            };
        }
        if l.split_whitespace().nth(1) == Some("2") {
            triangles += 1;
        }
    }
    Err("the mesh file's $Elements section is incomplete (no $EndElements)".into())
}

/// The last lines of gmsh's output (stderr last), for error messages.
fn log_tail(stdout: &[u8], stderr: &[u8]) -> String {
    let out = String::from_utf8_lossy(stdout);
    let err = String::from_utf8_lossy(stderr);
    let lines: Vec<&str> = out
        .lines()
        .chain(err.lines())
        .map(str::trim_end)
        .filter(|l| !l.trim().is_empty())
        .collect();
    if lines.is_empty() {
        return "(gmsh printed nothing)".into();
    }
    let start = lines.len().saturating_sub(LOG_LINES);
    lines[start..].join("\n")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reason(e: Error) -> String {
        match e {
            Error::Gmsh { reason, .. } => reason,
            other => panic!("expected Error::Gmsh, got {other:?}"),
        }
    }

    /// A full disk is named, with the folder and its free bytes; a disk
    /// with room is not blamed.
    #[test]
    fn a_nearly_full_disk_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let free = free_bytes(dir.path()).expect("statvfs of a temporary folder");
        assert!(free > 0);
        let hint = disk_full_hint(Path::new("/x"), Some(4096));
        assert!(
            hint.contains("/x")
                && hint.contains("4096 bytes free")
                && hint.contains("disk is full"),
            "{hint}"
        );
        assert_eq!(disk_full_hint(Path::new("/x"), Some(1 << 30)), "");
        assert_eq!(disk_full_hint(Path::new("/x"), None), "");
    }

    #[test]
    fn missing_geo_is_a_clear_error() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out.msh");
        let e = run_gmsh(&dir.path().join("nope.geo"), &out, &[]).unwrap_err();
        assert!(e.to_string().contains("nope.geo"), "{e}");
        assert!(reason(e).contains("cannot open the geometry file"));
        assert!(!out.exists());
    }

    #[test]
    fn gmsh_not_on_path() {
        let dir = tempfile::tempdir().unwrap();
        let geo = dir.path().join("a.geo");
        std::fs::write(&geo, "Point(1) = {0, 0, 0};\n").unwrap();
        let out = dir.path().join("out.msh");
        std::fs::write(&out, "old").unwrap();
        let e = run_gmsh_with(
            OsStr::new("gmsh-does-not-exist-8f3a"),
            &geo,
            &out,
            &Job::Mesh(&[("n".into(), 4.0)], None),
        )
        .unwrap_err();
        assert_eq!(reason(e), GMSH_NOT_FOUND);
        assert_eq!(std::fs::read_to_string(&out).unwrap(), "old");
    }

    #[test]
    fn bad_parameters_are_rejected() {
        let dir = tempfile::tempdir().unwrap();
        let geo = dir.path().join("a.geo");
        std::fs::write(&geo, "").unwrap();
        let out = dir.path().join("out.msh");
        let e = run_gmsh(&geo, &out, &[("n; Abort".into(), 1.0)]).unwrap_err();
        assert!(reason(e).contains("invalid parameter name"));
        let e = run_gmsh(&geo, &out, &[("h".into(), f64::NAN)]).unwrap_err();
        assert!(reason(e).contains("not finite"));
    }

    #[test]
    fn arguments() {
        let args = gmsh_args(
            Path::new("m/disk.geo"),
            Path::new("o.msh"),
            &[("n".into(), 16.0), ("h".into(), 0.2)],
        );
        let s: Vec<String> = args
            .iter()
            .map(|a| a.to_string_lossy().into_owned())
            .collect();
        assert_eq!(
            s.join(" "),
            "m/disk.geo -2 -format msh22 -v 2 -nopopup -setnumber n 16 -setnumber h 0.2 -o o.msh"
        );
        assert_eq!(format!("{}", 1e-7), "0.0000001");
    }

    #[test]
    fn output_check() {
        assert!(check_msh("").is_err());
        assert!(check_msh("$MeshFormat\n2.2 0 8\n$EndMeshFormat\n").is_err());
        let no_tri = "$Elements\n1\n1 15 2 0 1 1\n$EndElements\n";
        assert!(check_msh(no_tri).unwrap_err().contains("no triangles"));
        let tri = "$Elements\n1\n1 2 2 1 1 1 2 3\n$EndElements\n";
        assert!(check_msh(tri).is_ok());
        assert!(check_msh("$Elements\n1\n1 2 2 1 1 1 2 3\n")
            .unwrap_err()
            .contains("incomplete"));
    }
}
