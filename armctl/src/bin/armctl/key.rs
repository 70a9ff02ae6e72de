//! `armctl key new` and the key files `--key-file` and `key set` read (docs/PROTOCOL.md
//! section 13). A key file is as good as the key: it is written readable by its owner
//! alone (0600), and one that others can read gets a warning when it is used (issue 31:
//! `armctl key new > arm.key` left it world-readable).

use std::os::unix::fs::{OpenOptionsExt, PermissionsExt};
use std::path::Path;

use armctl::protocol::auth::AuthKey;

use crate::CliResult;

/// The mode of a key file armctl writes: read and write for its owner alone.
const KEY_FILE_MODE: u32 = 0o600;

/// Runs `key new`: a new key to `output` (created 0600, not over an existing file), or to
/// stdout, made 0600 when it is a regular file (`armctl key new > arm.key`).
pub fn new(output: Option<&Path>) -> CliResult {
    let key = armctl::auth::new_key_hex().map_err(|e| e.to_string())?;
    match output {
        Some(path) => {
            use std::io::Write;
            let mut file = std::fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .mode(KEY_FILE_MODE)
                .open(path)
                .map_err(|e| match e.kind() {
                    std::io::ErrorKind::AlreadyExists => format!(
                        "{}: exists; a key is not written over another (remove the file \
                         first, once no controller needs its key)",
                        path.display()
                    ),
                    _ => format!("{}: {e}", path.display()),
                })?;
            writeln!(file, "{key}").map_err(|e| format!("{}: {e}", path.display()))?;
            Ok(())
        }
        None => {
            private_stdout()?;
            println!("{key}");
            Ok(())
        }
    }
}

/// Makes stdout 0600 when it is a regular file (the shell created it with the umask's
/// mode, commonly 0644), before the key is written to it.
fn private_stdout() -> Result<(), String> {
    use std::os::fd::AsFd;
    let Ok(fd) = std::io::stdout().as_fd().try_clone_to_owned() else {
        return Ok(());
    };
    let file = std::fs::File::from(fd);
    match file.metadata() {
        Ok(meta) if meta.is_file() => file
            .set_permissions(std::fs::Permissions::from_mode(KEY_FILE_MODE))
            .map_err(|e| format!("stdout is a file that cannot be made private (0600): {e}")),
        _ => Ok(()),
    }
}

/// Reads a key file, with a warning on stderr when group or others may read it.
pub fn read(path: &Path) -> Result<AuthKey, String> {
    if let Some(warning) = loose_key_file(path) {
        eprintln!("warning: {warning}");
    }
    armctl::auth::read_key_file(path)
}

/// What is wrong with a key file's mode, when group or others may read it.
pub fn loose_key_file(path: &Path) -> Option<String> {
    let mode = std::fs::metadata(path).ok()?.permissions().mode() & 0o777;
    (mode & 0o044 != 0).then(|| {
        format!(
            "{} is readable by group or others (mode {mode:o}): anyone who reads it can \
             drive the arm; `chmod 600 {}`",
            path.display(),
            path.display()
        )
    })
}
