//! The shared cluster token: read from a file or the `LIGHTFOLD_TOKEN` environment variable,
//! never from argv.

use std::path::Path;

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
}

/// The token from `path` if given, else from `LIGHTFOLD_TOKEN`. Surrounding whitespace is ignored.
pub fn load_token(path: Option<&Path>) -> Result<Vec<u8>, TokenError> {
    let (bytes, origin) = match path {
        Some(p) => (
            std::fs::read(p).map_err(|source| TokenError::Read {
                path: p.display().to_string(),
                source,
            })?,
            p.display().to_string(),
        ),
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
    Ok(trimmed)
}
