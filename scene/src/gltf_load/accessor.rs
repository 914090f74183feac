//! Reading glTF accessors with every range checked here, so that a malformed file gives an error
//! naming the accessor instead of a panic or an out-of-bounds slice (the `gltf` crate's own reader
//! trusts byte ranges and strides).

use crate::limits::Budget;
use gltf::accessor::{DataType, Dimensions, sparse::IndexType};

/// Most elements an accessor may declare: guards allocations driven by untrusted counts.
const MAX_ELEMENTS: usize = 1 << 26;

/// The decoded buffers of a document, indexed like `document.buffers()`, with what the model may
/// still read from files (`files`: buffers and images) and decode (`decoded`: accessors and
/// images).
pub(super) struct Buffers {
    pub data: Vec<Vec<u8>>,
    pub files: Budget,
    pub decoded: Budget,
}

/// A reading failure; the loader wraps it with the file name.
pub(super) type ReadResult<T> = Result<T, String>;

impl Buffers {
    /// The bytes of a buffer view, checked against its buffer.
    pub(super) fn view_bytes(&self, view: &gltf::buffer::View) -> ReadResult<&[u8]> {
        let buffer = view.buffer().index();
        let data = self
            .data
            .get(buffer)
            .ok_or_else(|| format!("buffer view {} names missing buffer {buffer}", view.index()))?;
        let start = view.offset();
        let end = start
            .checked_add(view.length())
            .filter(|&e| e <= data.len())
            .ok_or_else(|| {
                format!(
                    "buffer view {} spans bytes {start}..{} but buffer {buffer} holds {}",
                    view.index(),
                    start.saturating_add(view.length()),
                    data.len()
                )
            })?;
        Ok(&data[start..end])
    }

    /// All elements of `acc` as f32 components (`count × components` values), integers
    /// normalised when the accessor says so. `what` names the use for error messages.
    pub(super) fn read_f32(
        &self,
        acc: &gltf::Accessor,
        expect: &[Dimensions],
        what: &str,
    ) -> ReadResult<(Vec<f32>, usize)> {
        let comps = check_dims(acc, expect, what)?;
        let normalized = acc.normalized();
        let dt = acc.data_type();
        let mut out = Vec::new();
        self.read_raw(acc, what, |bytes| {
            for c in 0..comps {
                out.push(component_f32(&bytes[c * dt.size()..], dt, normalized));
            }
        })?;
        Ok((out, comps))
    }

    /// All elements of an integer accessor (indices, joints) as u32 components.
    pub(super) fn read_u32(
        &self,
        acc: &gltf::Accessor,
        expect: &[Dimensions],
        what: &str,
    ) -> ReadResult<(Vec<u32>, usize)> {
        let comps = check_dims(acc, expect, what)?;
        let dt = acc.data_type();
        if !matches!(dt, DataType::U8 | DataType::U16 | DataType::U32) {
            return Err(format!(
                "accessor {} ({what}) has component type {dt:?}, expected an unsigned integer",
                acc.index()
            ));
        }
        let mut out = Vec::new();
        self.read_raw(acc, what, |bytes| {
            for c in 0..comps {
                out.push(component_u32(&bytes[c * dt.size()..], dt));
            }
        })?;
        Ok((out, comps))
    }

    /// Calls `visit` with the bytes of each element in order (dense data then sparse overrides).
    fn read_raw(
        &self,
        acc: &gltf::Accessor,
        what: &str,
        mut visit: impl FnMut(&[u8]),
    ) -> ReadResult<()> {
        let id = acc.index();
        let count = acc.count();
        if count > MAX_ELEMENTS {
            return Err(format!("accessor {id} ({what}) declares {count} elements"));
        }
        let elem = acc.size();
        // What this read keeps (4 bytes per component, at least the dense copy's size), charged
        // before anything is allocated: an accessor is read once per use, and a small file can
        // name a large sparse accessor many times.
        let kept = (count as u64) * (acc.dimensions().multiplicity() as u64) * 4;
        self.decoded
            .take(kept.max(count as u64 * elem as u64))
            .map_err(|e| format!("accessor {id} ({what}): {e}"))?;
        if matches!(acc.dimensions(), Dimensions::Mat2 | Dimensions::Mat3)
            && acc.data_type().size() < 4
        {
            // Column padding rules for small matrices: never needed by this loader.
            return Err(format!(
                "accessor {id} ({what}): padded matrix layouts are not supported"
            ));
        }
        let mut dense = vec![0u8; count * elem];
        if let Some(view) = acc.view() {
            let bytes = self.view_bytes(&view)?;
            let stride = view.stride().unwrap_or(elem);
            if stride < elem {
                return Err(format!(
                    "accessor {id} ({what}): buffer view {} stride {stride} is smaller than the {elem}-byte element",
                    view.index()
                ));
            }
            if count > 0 {
                let start = acc.offset();
                let end = (count - 1)
                    .checked_mul(stride)
                    .and_then(|x| x.checked_add(start))
                    .and_then(|x| x.checked_add(elem))
                    .filter(|&e| e <= bytes.len())
                    .ok_or_else(|| {
                        format!(
                            "accessor {id} ({what}): {count} elements from byte {start} with stride {stride} exceed buffer view {} ({} bytes)",
                            view.index(),
                            bytes.len()
                        )
                    })?;
                let src = &bytes[start..end];
                for i in 0..count {
                    dense[i * elem..(i + 1) * elem]
                        .copy_from_slice(&src[i * stride..i * stride + elem]);
                }
            }
        } else if acc.sparse().is_none() {
            return Err(format!(
                "accessor {id} ({what}) has neither a buffer view nor sparse data"
            ));
        }
        if let Some(sparse) = acc.sparse() {
            let n = sparse.count();
            let idx = sparse.indices();
            let isize = match idx.index_type() {
                IndexType::U8 => 1,
                IndexType::U16 => 2,
                IndexType::U32 => 4,
            };
            let ib = self.view_bytes(&idx.view())?;
            let vb = self.view_bytes(&sparse.values().view())?;
            let need_i = n
                .checked_mul(isize)
                .and_then(|x| x.checked_add(idx.offset()));
            let need_v = n
                .checked_mul(elem)
                .and_then(|x| x.checked_add(sparse.values().offset()));
            if need_i.is_none_or(|x| x > ib.len()) || need_v.is_none_or(|x| x > vb.len()) {
                return Err(format!(
                    "accessor {id} ({what}): sparse data exceeds its buffer views"
                ));
            }
            for k in 0..n {
                let at = idx.offset() + k * isize;
                let target = match isize {
                    1 => ib[at] as usize,
                    2 => u16::from_le_bytes([ib[at], ib[at + 1]]) as usize,
                    _ => u32::from_le_bytes([ib[at], ib[at + 1], ib[at + 2], ib[at + 3]]) as usize,
                };
                if target >= count {
                    return Err(format!(
                        "accessor {id} ({what}): sparse index {target} is out of range ({count} elements)"
                    ));
                }
                let v = sparse.values().offset() + k * elem;
                dense[target * elem..(target + 1) * elem].copy_from_slice(&vb[v..v + elem]);
            }
        }
        for e in dense.chunks_exact(elem.max(1)) {
            visit(e);
        }
        Ok(())
    }
}

fn check_dims(acc: &gltf::Accessor, expect: &[Dimensions], what: &str) -> ReadResult<usize> {
    let dims = acc.dimensions();
    if !expect.contains(&dims) {
        return Err(format!(
            "accessor {} ({what}) is {dims:?}, expected {expect:?}",
            acc.index()
        ));
    }
    Ok(dims.multiplicity())
}

fn component_u32(b: &[u8], dt: DataType) -> u32 {
    match dt {
        DataType::U8 => b[0] as u32,
        DataType::U16 => u16::from_le_bytes([b[0], b[1]]) as u32,
        _ => u32::from_le_bytes([b[0], b[1], b[2], b[3]]),
    }
}

/// One component as f32; normalised integers map to [0, 1] or [−1, 1] as glTF specifies.
fn component_f32(b: &[u8], dt: DataType, normalized: bool) -> f32 {
    let (v, scale) = match dt {
        DataType::F32 => return f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
        DataType::I8 => (b[0] as i8 as f32, 127.0),
        DataType::U8 => (b[0] as f32, 255.0),
        DataType::I16 => (i16::from_le_bytes([b[0], b[1]]) as f32, 32767.0),
        DataType::U16 => (u16::from_le_bytes([b[0], b[1]]) as f32, 65535.0),
        DataType::U32 => (
            u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f32,
            4_294_967_295.0,
        ),
    };
    if normalized { (v / scale).max(-1.0) } else { v }
}
