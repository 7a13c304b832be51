//! Names that become part of a file name (scene, study, bench and case names):
//! checked here, once, so that no name escapes its output folder or fails
//! later with an unrelated message.

/// The longest name accepted, in characters: with the suffixes the commands
/// add (`-000.h5`, `-work-precision-u3_min.png`, …) a file name stays well
/// below the 255 bytes file systems allow.
pub const MAX_NAME_CHARS: usize = 100;

/// Checks that `name` can be a file-name component: non-empty, at most
/// [`MAX_NAME_CHARS`] characters, printable (no control character, NUL
/// included), no `/`, `\` or `..`, no leading `.` (hidden files, and the
/// staging folders of `output::transaction`), no leading or trailing blank.
/// The error is the reason, for the caller to attach to its file and field.
pub fn check_name(name: &str) -> Result<(), String> {
    let chars = name.chars().count();
    let reason = if name.trim().is_empty() {
        "must not be empty".to_string()
    } else if chars > MAX_NAME_CHARS {
        format!("is {chars} characters long; at most {MAX_NAME_CHARS} (it becomes a file name)")
    } else if let Some(c) = name.chars().find(|c| c.is_control()) {
        format!(
            "contains the control character U+{:04X} (it becomes a file name)",
            c as u32
        )
    } else if name.contains(['/', '\\']) {
        "must not contain `/` or `\\` (it becomes a file name, not a path)".to_string()
    } else if name.contains("..") {
        "must not contain `..` (it becomes a file name, not a path)".to_string()
    } else if name.starts_with('.') {
        "must not start with `.` (hidden and temporary files do)".to_string()
    } else if name.trim() != name {
        "must not start or end with a blank".to_string()
    } else {
        return Ok(());
    };
    Err(reason)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn good_names() {
        for name in [
            "membrane-thesis",
            "naghdi hypar",
            "shell_p2b-psri.2",
            "α=0.9",
        ] {
            assert_eq!(check_name(name), Ok(()), "{name}");
        }
        assert_eq!(check_name(&"a".repeat(MAX_NAME_CHARS)), Ok(()));
    }

    #[test]
    fn bad_names() {
        let cases: [(&str, &str); 9] = [
            ("", "empty"),
            ("  ", "empty"),
            ("../../x", "`/`"),
            ("a\\b", "`/`"),
            ("a..b", "`..`"),
            (".hidden", "start with `.`"),
            ("a\0b", "U+0000"),
            ("tab\there", "U+0009"),
            (" padded", "blank"),
        ];
        for (name, reason) in cases {
            let e = check_name(name).unwrap_err();
            assert!(e.contains(reason), "{name:?}: {e}");
        }
        let long = "a".repeat(300);
        assert_eq!(
            check_name(&long).unwrap_err(),
            "is 300 characters long; at most 100 (it becomes a file name)"
        );
    }
}
