//! HTTPS and WSS: the certificate chain and key (PEM files) loaded once when the view binds, on
//! rustls with the ring provider. HTTP/1.1 only (ALPN), which the page's WebSocket needs.

use crate::TlsFiles;
use anyhow::{Context, anyhow, bail};
use std::sync::Arc;
use tokio_rustls::TlsAcceptor;
use tokio_rustls::rustls;
use tokio_rustls::rustls::pki_types::pem::PemObject;
use tokio_rustls::rustls::pki_types::{CertificateDer, PrivateKeyDer};

/// The acceptor for `files`; a clear error for a file that cannot be read, holds no certificate
/// or key, or a key that is not the certificate's.
pub(crate) fn acceptor(files: &TlsFiles) -> anyhow::Result<TlsAcceptor> {
    let cert_pem = std::fs::read(&files.cert).with_context(|| {
        format!(
            "cannot read the view's TLS certificate {}",
            files.cert.display()
        )
    })?;
    let key_pem = std::fs::read(&files.key)
        .with_context(|| format!("cannot read the view's TLS key {}", files.key.display()))?;
    let certs: Vec<CertificateDer<'static>> = CertificateDer::pem_slice_iter(&cert_pem)
        .collect::<Result<_, _>>()
        .map_err(|e| {
            anyhow!(
                "the view's TLS certificate {} is not valid PEM: {e}",
                files.cert.display()
            )
        })?;
    if certs.is_empty() {
        bail!(
            "the view's TLS certificate {} holds no certificate (PEM \"BEGIN CERTIFICATE\")",
            files.cert.display()
        );
    }
    let key = PrivateKeyDer::from_pem_slice(&key_pem).map_err(|e| {
        anyhow!(
            "the view's TLS key {} holds no private key (PEM PKCS#8, PKCS#1 or SEC1): {e}",
            files.key.display()
        )
    })?;
    // ring, not aws-lc (which would need cmake and nasm to build); rustls marks it deprecated
    // for its lack of post-quantum key exchange, which a browser falls back from cleanly.
    #[allow(deprecated)]
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let mut config = rustls::ServerConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .context("TLS protocol versions")?
        .with_no_client_auth()
        .with_single_cert(certs, key)
        .map_err(|e| {
            let why = match e {
                rustls::Error::InconsistentKeys(_) => {
                    "the key is not the certificate's (they do not belong together)".to_string()
                }
                e => e.to_string(),
            };
            anyhow!(
                "cannot serve the view over TLS with certificate {} and key {}: {why}",
                files.cert.display(),
                files.key.display()
            )
        })?;
    config.alpn_protocols = vec![b"http/1.1".to_vec()];
    Ok(TlsAcceptor::from(Arc::new(config)))
}
