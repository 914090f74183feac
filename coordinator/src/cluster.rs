//! The cluster file: which daemons exist and where (TOML, versioned, `deny_unknown_fields`).
//!
//! ```toml
//! version = 1
//! sink_listen = "0.0.0.0:7400"          # where the sink compositor sends final bands
//! sink_advertise = "coordinator:7400"   # how compositors reach it (defaults to sink_listen)
//! [[node]]
//! address = "render-0.lightfold:7300"  # DNS names are re-resolved on every dial
//! [[compositor]]
//! address = "comp-0.lightfold:7300"
//! ```

use serde::Deserialize;
use std::path::Path;

pub const CLUSTER_FILE_VERSION: u32 = 1;
/// The largest cluster file read (a thousand daemons take about 60 KiB).
pub const MAX_CLUSTER_FILE: u64 = 4 << 20;

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClusterFile {
    pub version: u32,
    #[serde(default = "default_sink")]
    pub sink_listen: String,
    #[serde(default)]
    pub sink_advertise: Option<String>,
    #[serde(default, rename = "node")]
    pub nodes: Vec<DaemonEntry>,
    #[serde(default, rename = "compositor")]
    pub compositors: Vec<DaemonEntry>,
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DaemonEntry {
    /// Address (host:port) of the daemon's listener.
    pub address: String,
    /// Expected daemon id; when set, a daemon registering under another id is refused.
    #[serde(default)]
    pub id: Option<String>,
}

fn default_sink() -> String {
    "127.0.0.1:0".to_string()
}

#[derive(Debug, thiserror::Error)]
pub enum ClusterFileError {
    #[error("cannot read cluster file {path}: {message}")]
    Read { path: String, message: String },
    #[error("malformed cluster file {path}: {message}")]
    Parse { path: String, message: String },
    #[error(
        "cluster file {path} has version {found}; this lightfold reads version {CLUSTER_FILE_VERSION}"
    )]
    Version { path: String, found: u32 },
    #[error("cluster file {path} lists no {what}")]
    Empty { path: String, what: &'static str },
}

impl ClusterFile {
    /// Reads and checks the file at `path` (a regular file of at most [`MAX_CLUSTER_FILE`]
    /// bytes, `lightfold_scene::read_bounded`).
    pub fn load(path: &Path) -> Result<ClusterFile, ClusterFileError> {
        let shown = path.display().to_string();
        let read = |message| ClusterFileError::Read {
            path: shown.clone(),
            message,
        };
        let bytes = lightfold_scene::read_bounded(path, MAX_CLUSTER_FILE).map_err(read)?;
        let text = String::from_utf8(bytes).map_err(|_| read("not UTF-8 text".into()))?;
        Self::parse(&text, &shown)
    }

    /// The daemons to connect: render nodes, then compositors, each with the id it must register
    /// under where the file gives one.
    pub fn daemons(&self) -> Vec<crate::control::DaemonAddr> {
        let with = |role| {
            move |e: &DaemonEntry| crate::control::DaemonAddr {
                address: e.address.clone(),
                role,
                id: e.id.clone(),
            }
        };
        let nodes = self.nodes.iter().map(with(lightfold_protocol::Role::Node));
        nodes
            .chain(
                self.compositors
                    .iter()
                    .map(with(lightfold_protocol::Role::Compositor)),
            )
            .collect()
    }

    pub fn parse(text: &str, origin: &str) -> Result<ClusterFile, ClusterFileError> {
        let file: ClusterFile = toml::from_str(text).map_err(|e| ClusterFileError::Parse {
            path: origin.to_string(),
            message: e.to_string(),
        })?;
        if file.version != CLUSTER_FILE_VERSION {
            return Err(ClusterFileError::Version {
                path: origin.to_string(),
                found: file.version,
            });
        }
        if file.nodes.is_empty() {
            return Err(ClusterFileError::Empty {
                path: origin.to_string(),
                what: "[[node]]",
            });
        }
        if file.compositors.is_empty() {
            return Err(ClusterFileError::Empty {
                path: origin.to_string(),
                what: "[[compositor]]",
            });
        }
        Ok(file)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_a_cluster() {
        let f = ClusterFile::parse(
            "version = 1\n[[node]]\naddress = \"a:1\"\n[[compositor]]\naddress = \"b:2\"\nid = \"c0\"\n",
            "t",
        )
        .unwrap();
        assert_eq!(f.nodes[0].address, "a:1");
        assert_eq!(f.compositors[0].id.as_deref(), Some("c0"));
    }

    #[test]
    fn rejects_unknown_fields_versions_and_empty_lists() {
        let e = ClusterFile::parse("version = 1\nbogus = 3\n", "t").unwrap_err();
        assert!(e.to_string().contains("malformed cluster file t"), "{e}");
        let e = ClusterFile::parse("version = 2\n[[node]]\naddress=\"a\"\n", "t").unwrap_err();
        assert!(
            matches!(e, ClusterFileError::Version { found: 2, .. }),
            "{e}"
        );
        let e = ClusterFile::parse("version = 1\n", "t").unwrap_err();
        assert!(matches!(e, ClusterFileError::Empty { .. }), "{e}");
        let e = ClusterFile::parse("version = 1\n[[node]]\naddress = 5\n", "t").unwrap_err();
        assert!(matches!(e, ClusterFileError::Parse { .. }), "{e}");
    }

    #[test]
    fn loads_within_a_bound_and_lists_its_daemons_in_order() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("cluster.toml");
        let text = "version = 1\n[[compositor]]\naddress = \"b:2\"\n[[node]]\naddress = \"a:1\"\nid = \"n0\"\n";
        std::fs::write(&path, text).unwrap();
        let d = ClusterFile::load(&path).unwrap().daemons();
        assert_eq!(d.len(), 2);
        assert_eq!(
            (d[0].address.as_str(), d[0].role),
            ("a:1", lightfold_protocol::Role::Node)
        );
        assert_eq!(d[0].id.as_deref(), Some("n0"));
        assert_eq!(d[1].role, lightfold_protocol::Role::Compositor);
        // A file one byte over the bound (a comment, so it would parse) is refused unparsed.
        let padding = "#".repeat(MAX_CLUSTER_FILE as usize + 1 - text.len());
        std::fs::write(&path, format!("{text}{padding}")).unwrap();
        let e = ClusterFile::load(&path).unwrap_err();
        assert!(matches!(e, ClusterFileError::Read { .. }), "{e}");
        assert!(e.to_string().contains("more than the 4194304 bytes"), "{e}");
        // A folder is not read (nor would a FIFO be waited on).
        let e = ClusterFile::load(dir.path()).unwrap_err();
        assert!(e.to_string().contains("not a regular file"), "{e}");
        let e = ClusterFile::load(&dir.path().join("missing.toml")).unwrap_err();
        assert!(matches!(e, ClusterFileError::Read { .. }), "{e}");
    }
}
