//! Scenes by content hash: the few most recent decoded scenes in memory, their bytes on disk under
//! an optional cache directory, and the assembly of one incoming transfer from `SceneChunk`s.
//! Nothing from the network or the disk is trusted: a transfer must arrive in order and within its
//! size, and a decoded scene (`Scene::from_bytes` is bounded and validates) must have the content
//! hash it was offered under before it is used or cached.

use lightfold_protocol::{ErrorCode, Hash};
use lightfold_scene::Scene;
use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Decoded scenes kept in memory.
pub const MEMORY_SCENES: usize = 4;

#[derive(Debug, thiserror::Error)]
pub enum SceneCacheError {
    #[error("scene {hash} of {size} bytes exceeds this node's limit of {max} bytes")]
    TooLarge { hash: String, size: u64, max: u64 },
    #[error("chunk for scene {hash}, which was not offered (or whose transfer already ended)")]
    NotOffered { hash: String },
    #[error("chunk of scene {hash} at offset {got}, expected offset {expected}")]
    Offset {
        hash: String,
        expected: u64,
        got: u64,
    },
    #[error("scene {hash} chunks exceed the offered size of {size} bytes")]
    Overrun { hash: String, size: u64 },
    #[error("scene {hash} ended after {got} of the offered {size} bytes")]
    Short { hash: String, got: u64, size: u64 },
    #[error("received scene has content hash {actual}, but was offered as {expected}")]
    HashMismatch { expected: String, actual: String },
    #[error("scene {hash} does not decode: {message}")]
    Decode { hash: String, message: String },
    #[error("scene {hash} is not cached on this node; offer it first")]
    Unknown { hash: String },
}

impl SceneCacheError {
    /// The code the coordinator sees in `Message::Error`.
    pub fn code(&self) -> ErrorCode {
        match self {
            SceneCacheError::Decode { .. } => ErrorCode::BadConfig,
            _ => ErrorCode::UnknownScene,
        }
    }
}

/// Hex of a scene hash, for logs, errors and file names.
pub fn hex(hash: &Hash) -> String {
    hash.iter().map(|b| format!("{b:02x}")).collect()
}

/// Decodes `bytes` and checks the scene's content hash is `hash` (CPU-heavy for big scenes: call
/// off the async runtime).
pub fn decode_verified(bytes: &[u8], hash: &Hash) -> Result<Scene, SceneCacheError> {
    let scene = Scene::from_bytes(bytes).map_err(|e| SceneCacheError::Decode {
        hash: hex(hash),
        message: e.to_string(),
    })?;
    let actual = scene.content_hash();
    if actual != *hash {
        return Err(SceneCacheError::HashMismatch {
            expected: hex(hash),
            actual: hex(&actual),
        });
    }
    Ok(scene)
}

#[derive(Debug)]
struct Incoming {
    hash: Hash,
    size: u64,
    bytes: Vec<u8>,
}

/// The node's scenes.
#[derive(Debug)]
pub struct SceneCache {
    memory: VecDeque<(Hash, Arc<Scene>)>,
    dir: Option<PathBuf>,
    max_bytes: u64,
    incoming: Option<Incoming>,
}

impl SceneCache {
    pub fn new(dir: Option<PathBuf>, max_bytes: u64) -> SceneCache {
        SceneCache {
            memory: VecDeque::new(),
            dir,
            max_bytes,
            incoming: None,
        }
    }

    /// A decoded scene held in memory.
    pub fn get(&mut self, hash: &Hash) -> Option<Arc<Scene>> {
        let i = self.memory.iter().position(|(h, _)| h == hash)?;
        let entry = self.memory.remove(i)?;
        let scene = entry.1.clone();
        self.memory.push_back(entry);
        Some(scene)
    }

    pub fn insert(&mut self, hash: Hash, scene: Arc<Scene>) {
        self.memory.retain(|(h, _)| *h != hash);
        self.memory.push_back((hash, scene));
        while self.memory.len() > MEMORY_SCENES {
            self.memory.pop_front();
        }
    }

    /// Where the bytes of `hash` live on disk, if this node has a cache directory.
    pub fn disk_path(&self, hash: &Hash) -> Option<PathBuf> {
        self.dir
            .as_ref()
            .map(|d| d.join(format!("{}.scene", hex(hash))))
    }

    /// Starts receiving a scene of `size` bytes (replacing any unfinished transfer).
    pub fn begin(&mut self, hash: Hash, size: u64) -> Result<(), SceneCacheError> {
        self.incoming = None;
        if size > self.max_bytes {
            return Err(SceneCacheError::TooLarge {
                hash: hex(&hash),
                size,
                max: self.max_bytes,
            });
        }
        // Reserve gradually: the offered size is the peer's word, not yet backed by bytes.
        self.incoming = Some(Incoming {
            hash,
            size,
            bytes: Vec::with_capacity(size.min(16 << 20) as usize),
        });
        Ok(())
    }

    /// Appends one chunk; returns the whole byte string once the `last` chunk has arrived. Any
    /// error abandons the transfer.
    pub fn chunk(
        &mut self,
        hash: Hash,
        offset: u64,
        data: &[u8],
        last: bool,
    ) -> Result<Option<Vec<u8>>, SceneCacheError> {
        let Some(incoming) = self.incoming.as_mut().filter(|i| i.hash == hash) else {
            return Err(SceneCacheError::NotOffered { hash: hex(&hash) });
        };
        let result = append(incoming, offset, data, last);
        match result {
            Ok(false) => Ok(None),
            Ok(true) => Ok(self.incoming.take().map(|i| i.bytes)),
            Err(e) => {
                self.incoming = None;
                Err(e)
            }
        }
    }
}

fn append(i: &mut Incoming, offset: u64, data: &[u8], last: bool) -> Result<bool, SceneCacheError> {
    let have = i.bytes.len() as u64;
    if offset != have {
        return Err(SceneCacheError::Offset {
            hash: hex(&i.hash),
            expected: have,
            got: offset,
        });
    }
    if have + data.len() as u64 > i.size {
        return Err(SceneCacheError::Overrun {
            hash: hex(&i.hash),
            size: i.size,
        });
    }
    i.bytes.extend_from_slice(data);
    if last && i.bytes.len() as u64 != i.size {
        return Err(SceneCacheError::Short {
            hash: hex(&i.hash),
            got: i.bytes.len() as u64,
            size: i.size,
        });
    }
    Ok(last)
}

/// Reads and verifies a cached scene file; `None` (after logging why) when it is missing or bad.
pub fn load_file(path: &Path, hash: &Hash) -> Option<Scene> {
    let bytes = match std::fs::read(path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return None,
        Err(e) => {
            tracing::warn!(path = %path.display(), error = %e, "cannot read cached scene");
            return None;
        }
    };
    match decode_verified(&bytes, hash) {
        Ok(scene) => Some(scene),
        Err(e) => {
            tracing::warn!(path = %path.display(), error = %e, "discarding bad cached scene");
            let _ = std::fs::remove_file(path);
            None
        }
    }
}

/// Writes verified scene bytes to the cache directory (via a temporary file, so a crash never
/// leaves a truncated file under the final name).
pub fn store_file(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir)?;
    }
    let tmp = path.with_extension("part");
    std::fs::write(&tmp, bytes)?;
    std::fs::rename(&tmp, path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chunks_assemble_in_order_only() {
        let bytes: Vec<u8> = (0..100u8).collect();
        let hash = [3; 32];
        let mut c = SceneCache::new(None, 1000);
        c.begin(hash, 100).unwrap();
        assert!(c.chunk(hash, 0, &bytes[..40], false).unwrap().is_none());
        let whole = c.chunk(hash, 40, &bytes[40..], true).unwrap().unwrap();
        assert_eq!(whole, bytes);
        assert!(matches!(
            c.chunk(hash, 100, &[], true),
            Err(SceneCacheError::NotOffered { .. })
        ));

        c.begin(hash, 100).unwrap();
        assert!(matches!(
            c.chunk(hash, 10, &bytes[10..], true),
            Err(SceneCacheError::Offset { .. })
        ));
        c.begin(hash, 50).unwrap();
        assert!(matches!(
            c.chunk(hash, 0, &bytes, true),
            Err(SceneCacheError::Overrun { .. })
        ));
        c.begin(hash, 100).unwrap();
        assert!(matches!(
            c.chunk(hash, 0, &bytes[..99], true),
            Err(SceneCacheError::Short { .. })
        ));
        assert!(matches!(
            c.begin(hash, 1001),
            Err(SceneCacheError::TooLarge { .. })
        ));
    }

    #[test]
    fn a_scene_must_have_the_offered_hash() {
        let scene = Scene::new("one");
        let bytes = scene.to_bytes().unwrap();
        let hash = scene.content_hash();
        assert_eq!(decode_verified(&bytes, &hash).unwrap().content_hash(), hash);
        let e = decode_verified(&bytes, &[9; 32]).unwrap_err();
        assert!(matches!(e, SceneCacheError::HashMismatch { .. }), "{e}");
        assert_eq!(e.code(), ErrorCode::UnknownScene);
        let e = decode_verified(b"not a scene", &hash).unwrap_err();
        assert_eq!(e.code(), ErrorCode::BadConfig);
    }

    #[test]
    fn memory_keeps_the_most_recent_scenes() {
        let mut c = SceneCache::new(None, 1000);
        for i in 0..=MEMORY_SCENES as u8 {
            c.insert([i; 32], Arc::new(Scene::new(&format!("s{i}"))));
        }
        assert!(c.get(&[0; 32]).is_none());
        assert_eq!(c.get(&[1; 32]).unwrap().name, "s1");
    }
}
