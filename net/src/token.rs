//! The shared cluster token: read from a file or the `LIGHTFOLD_TOKEN` environment variable,
//! never from argv. A token shorter than [`MIN_TOKEN_BYTES`] or a token file that group or
//! others may access is accepted with a WARN line (an existing cluster keeps working while its
//! operator fixes it).

use std::path::Path;

/// Tokens shorter than this (after trimming) are warned about: easy to guess.
pub(crate) const MIN_TOKEN_BYTES: usize = 16;
/// Largest token file read (a token is a line; this bounds a mistaken path such as a log file).
pub(crate) const MAX_TOKEN_FILE_BYTES: u64 = 64 << 10;

#[derive(Debug, thiserror::Error)]
pub enum TokenError {
    #[error("cannot read token file {path}: {source}")]
    Read {
        path: String,
        source: std::io::Error,
    },
    #[error("token {origin} is empty")]
    Empty { origin: String },
    #[error("no cluster token: pass --token-file or set LIGHTFOLD_TOKEN")]
    Missing,
    #[error(
        "token file {path} is {bytes} bytes; a token file holds at most {MAX_TOKEN_FILE_BYTES}"
    )]
    TooLarge { path: String, bytes: u64 },
    #[error("token file {path} is not a regular file")]
    NotAFile { path: String },
}

/// The token from `path` if given, else from `LIGHTFOLD_TOKEN`. Surrounding whitespace is ignored.
/// Logs a WARN line for each of [`token_warnings`].
pub fn load_token(path: Option<&Path>) -> Result<Vec<u8>, TokenError> {
    let mut mode = None;
    let (bytes, origin) = match path {
        Some(p) => {
            let (bytes, m) = read_token_file(p)?;
            mode = Some(m);
            (bytes, p.display().to_string())
        }
        None => match std::env::var_os("LIGHTFOLD_TOKEN") {
            Some(v) => (
                v.to_string_lossy().as_bytes().to_vec(),
                "LIGHTFOLD_TOKEN".to_string(),
            ),
            None => return Err(TokenError::Missing),
        },
    };
    let trimmed = bytes.trim_ascii().to_vec();
    if trimmed.is_empty() {
        return Err(TokenError::Empty { origin });
    }
    for warning in token_warnings(&trimmed, &origin, mode) {
        tracing::warn!("{warning}");
    }
    Ok(trimmed)
}

/// A token file's bytes and permission bits: a regular file of at most
/// [`MAX_TOKEN_FILE_BYTES`], the read itself bounded.
fn read_token_file(p: &Path) -> Result<(Vec<u8>, u32), TokenError> {
    use std::io::Read;
    use std::os::unix::fs::PermissionsExt;
    let path = p.display().to_string();
    let read = |source| TokenError::Read {
        path: path.clone(),
        source,
    };
    let meta = std::fs::metadata(p).map_err(read)?;
    if !meta.is_file() {
        return Err(TokenError::NotAFile { path });
    }
    if meta.len() > MAX_TOKEN_FILE_BYTES {
        return Err(TokenError::TooLarge {
            path,
            bytes: meta.len(),
        });
    }
    let mut bytes = Vec::new();
    std::fs::File::open(p)
        .map_err(read)?
        .take(MAX_TOKEN_FILE_BYTES + 1)
        .read_to_end(&mut bytes)
        .map_err(read)?;
    if bytes.len() as u64 > MAX_TOKEN_FILE_BYTES {
        return Err(TokenError::TooLarge {
            path,
            bytes: bytes.len() as u64,
        });
    }
    Ok((bytes, meta.permissions().mode()))
}

/// What is weak about a token (trimmed) from `origin`, whose file has permission bits `mode`
/// (`None` for the environment): shorter than [`MIN_TOKEN_BYTES`], or a file group or others
/// may read or write.
pub(crate) fn token_warnings(token: &[u8], origin: &str, mode: Option<u32>) -> Vec<String> {
    let mut out = Vec::new();
    if token.len() < MIN_TOKEN_BYTES {
        out.push(format!(
            "cluster token {origin} is only {} bytes; use at least {MIN_TOKEN_BYTES} random \
             bytes (e.g. `head -c 32 /dev/urandom | xxd -p -c 64`)",
            token.len()
        ));
    }
    if let Some(mode) = mode
        && mode & 0o077 != 0
    {
        out.push(format!(
            "token file {origin} has mode {:03o}: group or others can read it; `chmod 600 {origin}`",
            mode & 0o777
        ));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::PermissionsExt;
    use std::sync::{Arc, Mutex};

    /// Collects the messages of WARN events (a minimal subscriber: this crate has no
    /// tracing-subscriber).
    struct Warnings(Arc<Mutex<Vec<String>>>);

    struct Message<'a>(&'a mut String);

    impl tracing::field::Visit for Message<'_> {
        fn record_debug(&mut self, field: &tracing::field::Field, value: &dyn std::fmt::Debug) {
            if field.name() == "message" {
                *self.0 = format!("{value:?}");
            }
        }
    }

    impl tracing::Subscriber for Warnings {
        fn enabled(&self, _: &tracing::Metadata<'_>) -> bool {
            true
        }
        fn new_span(&self, _: &tracing::span::Attributes<'_>) -> tracing::span::Id {
            tracing::span::Id::from_u64(1)
        }
        fn record(&self, _: &tracing::span::Id, _: &tracing::span::Record<'_>) {}
        fn record_follows_from(&self, _: &tracing::span::Id, _: &tracing::span::Id) {}
        fn event(&self, event: &tracing::Event<'_>) {
            if *event.metadata().level() == tracing::Level::WARN {
                let mut text = String::new();
                event.record(&mut Message(&mut text));
                self.0.lock().unwrap().push(text);
            }
        }
        fn enter(&self, _: &tracing::span::Id) {}
        fn exit(&self, _: &tracing::span::Id) {}
    }

    fn load_warnings(path: &Path) -> (Result<Vec<u8>, TokenError>, Vec<String>) {
        let seen = Arc::new(Mutex::new(Vec::new()));
        let result =
            tracing::subscriber::with_default(Warnings(seen.clone()), || load_token(Some(path)));
        let seen = seen.lock().unwrap().clone();
        (result, seen)
    }

    fn token_file(name: &str, text: &str, mode: u32) -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!("lightfold-token-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap();
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(mode)).unwrap();
        path
    }

    #[test]
    fn a_short_token_in_a_world_readable_file_is_warned_about() {
        // A 1-byte token in a world-readable file used to be accepted silently.
        let path = token_file("weak", "x\n", 0o644);
        let (token, warnings) = load_warnings(&path);
        assert_eq!(token.unwrap(), b"x", "still accepted");
        assert_eq!(warnings.len(), 2, "{warnings:?}");
        assert!(
            warnings[0].contains("is only 1 bytes; use at least 16"),
            "{warnings:?}"
        );
        assert!(
            warnings[1].contains("has mode 644: group or others can read it"),
            "{warnings:?}"
        );
        assert!(warnings[1].contains("chmod 600"), "{warnings:?}");
    }

    #[test]
    fn a_long_token_in_a_private_file_is_quiet() {
        let path = token_file("strong", "0123456789abcdef0123456789abcdef\n", 0o600);
        let (token, warnings) = load_warnings(&path);
        assert_eq!(token.unwrap().len(), 32);
        assert!(warnings.is_empty(), "{warnings:?}");
        let path = token_file("group", "0123456789abcdef0123456789abcdef", 0o640);
        let (_, warnings) = load_warnings(&path);
        assert_eq!(warnings.len(), 1, "{warnings:?}");
        assert!(warnings[0].contains("mode 640"), "{warnings:?}");
    }

    #[test]
    fn environment_tokens_are_only_checked_for_length() {
        assert_eq!(
            token_warnings(b"0123456789abcdef", "LIGHTFOLD_TOKEN", None).len(),
            0
        );
        let w = token_warnings(b"short", "LIGHTFOLD_TOKEN", None);
        assert!(
            w.len() == 1 && w[0].contains("LIGHTFOLD_TOKEN is only 5 bytes"),
            "{w:?}"
        );
    }

    #[test]
    fn token_files_are_bounded_regular_files() {
        let e = load_token(Some(Path::new("/dev/zero"))).unwrap_err();
        assert!(matches!(e, TokenError::NotAFile { .. }), "{e}");
        let big = token_file("big", "", 0o600);
        std::fs::File::options()
            .write(true)
            .open(&big)
            .unwrap()
            .set_len(1 << 30)
            .unwrap();
        let e = load_token(Some(&big)).unwrap_err();
        assert!(e.to_string().contains("at most 65536"), "{e}");
        std::fs::remove_file(&big).unwrap();
    }
}
