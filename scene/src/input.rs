//! Reading the files a scene names, bounded: a path a model or scene file refers to is resolved
//! only inside that file's folder (relative, no escape by `..` or a symbolic link), only regular
//! files are read (never a device, FIFO or folder), and a size cap is checked from the file's
//! metadata before reading and again by the read itself (`Read::take`), so a file that grows
//! while it is read is refused too.

use std::io::Read;
use std::path::{Component, Path, PathBuf};

/// Reads the regular file at `path`, at most `cap` bytes. The error says what went wrong, not
/// which file: callers name it once (`cannot read PATH: …`). Every file lightfold reads that a
/// user names (scenes, cluster files, job files) is read through it.
pub fn read_bounded(path: &Path, cap: u64) -> Result<Vec<u8>, String> {
    // `metadata` follows symbolic links: what is checked is what would be opened. Checked before
    // opening, since opening a FIFO blocks until a writer comes.
    let meta = std::fs::metadata(path).map_err(|e| e.to_string())?;
    if !meta.is_file() {
        return Err(format!(
            "not a regular file ({}); only regular files are read",
            kind(&meta)
        ));
    }
    if meta.len() > cap {
        return Err(format!(
            "{} bytes, more than the {cap} bytes allowed",
            meta.len()
        ));
    }
    let file = std::fs::File::open(path).map_err(|e| e.to_string())?;
    // The file opened may not be the one checked (replaced in between): check it again.
    let meta = file.metadata().map_err(|e| e.to_string())?;
    if !meta.is_file() {
        return Err(format!("not a regular file ({})", kind(&meta)));
    }
    let mut bytes = Vec::with_capacity(meta.len().min(cap) as usize);
    file.take(cap.saturating_add(1))
        .read_to_end(&mut bytes)
        .map_err(|e| e.to_string())?;
    if bytes.len() as u64 > cap {
        return Err(format!(
            "more than the {cap} bytes allowed (it grew while being read)"
        ));
    }
    Ok(bytes)
}

fn kind(meta: &std::fs::Metadata) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    let t = meta.file_type();
    if t.is_dir() {
        "a folder"
    } else if t.is_char_device() || t.is_block_device() {
        "a device"
    } else if t.is_fifo() {
        "a FIFO"
    } else if t.is_socket() {
        "a socket"
    } else {
        "not a file"
    }
}

/// Why [`resolve_inside`] gives no path: the file cannot be read (`io`, e.g. it does not exist),
/// or the path is refused.
#[derive(Debug)]
pub(crate) struct PathError {
    pub io: Option<PathBuf>,
    pub message: String,
}

impl std::fmt::Display for PathError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.io {
            Some(path) => write!(f, "cannot read {}: {}", path.display(), self.message),
            None => f.write_str(&self.message),
        }
    }
}

impl From<PathError> for String {
    fn from(e: PathError) -> String {
        e.to_string()
    }
}

/// `relative` resolved inside `folder`: it must be a relative path, and once every symbolic
/// link is resolved it must still lie inside `folder` (itself resolved). `what` names the
/// referring file's kind in errors ("the model's", "the scene file's").
pub(crate) fn resolve_inside(
    folder: &Path,
    relative: &str,
    what: &str,
) -> Result<PathBuf, PathError> {
    let refused = |message: String| PathError { io: None, message };
    let rel = Path::new(relative);
    if rel.is_absolute() || rel.has_root() || relative.starts_with('\\') {
        return Err(refused(format!(
            "{relative:?} is an absolute path; only paths relative to {what} folder are read"
        )));
    }
    // Lexically first (`a/../../x` escapes whether or not `x` exists), then on disk below.
    let mut depth = 0usize;
    for c in rel.components() {
        match c {
            Component::Normal(_) => depth += 1,
            Component::CurDir => {}
            Component::ParentDir if depth > 0 => depth -= 1,
            _ => {
                return Err(refused(format!(
                    "{relative:?} leads outside {what} folder; only files inside it are read"
                )));
            }
        }
    }
    let io = |path: &Path, e: std::io::Error| PathError {
        io: Some(path.to_path_buf()),
        message: e.to_string(),
    };
    let root = folder.canonicalize().map_err(|e| io(folder, e))?;
    let joined = root.join(rel);
    let resolved = joined.canonicalize().map_err(|e| io(&joined, e))?;
    if !resolved.starts_with(&root) {
        return Err(refused(format!(
            "{relative:?} resolves to {}, outside {what} folder {}; only files inside it are read",
            resolved.display(),
            root.display()
        )));
    }
    Ok(resolved)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("lightfold-input-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(d.join("inner")).unwrap();
        d
    }

    #[test]
    fn paths_stay_inside_the_folder() {
        let d = temp("paths");
        std::fs::write(d.join("inner/a.bin"), b"abc").unwrap();
        std::fs::write(d.join("outside.bin"), b"secret").unwrap();
        let inner = d.join("inner");
        assert_eq!(
            resolve_inside(&inner, "a.bin", "the model's").unwrap(),
            inner.canonicalize().unwrap().join("a.bin")
        );
        let e = resolve_inside(&inner, "./x/../a.bin", "the model's").unwrap_err();
        assert!(e.io.is_some(), "{e}");
        let msg = |r: &str| {
            resolve_inside(&inner, r, "the model's")
                .unwrap_err()
                .to_string()
        };
        let e = msg("../outside.bin");
        assert!(e.contains("leads outside the model's folder"), "{e}");
        let e = msg("x/../../missing.bin");
        assert!(e.contains("leads outside the model's folder"), "{e}");
        let e = msg("/etc/passwd");
        assert!(e.contains("absolute path"), "{e}");
        std::os::unix::fs::symlink(d.join("outside.bin"), inner.join("link.bin")).unwrap();
        let e = msg("link.bin");
        assert!(
            e.contains("resolves to") && e.contains("outside the model's folder"),
            "{e}"
        );
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn reads_are_bounded_and_regular_files_only() {
        let d = temp("reads");
        let f = d.join("inner/a.bin");
        std::fs::write(&f, b"abcdef").unwrap();
        assert_eq!(read_bounded(&f, 6).unwrap(), b"abcdef");
        let e = read_bounded(&f, 5).unwrap_err();
        assert!(e.contains("6 bytes, more than the 5 bytes allowed"), "{e}");
        let e = read_bounded(&d, 5).unwrap_err();
        assert!(e.contains("not a regular file (a folder)"), "{e}");
        let e = read_bounded(Path::new("/dev/zero"), 1 << 20).unwrap_err();
        assert!(e.contains("not a regular file (a device)"), "{e}");
        let fifo = d.join("fifo");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        assert!(made.unwrap().success(), "mkfifo");
        // Refused without opening it (opening a FIFO would block until a writer comes).
        let e = read_bounded(&fifo, 1 << 20).unwrap_err();
        assert!(e.contains("not a regular file (a FIFO)"), "{e}");
        std::fs::remove_dir_all(&d).unwrap();
    }
}
