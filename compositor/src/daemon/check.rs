//! Judging a received band against the band the stage expects next on that input: stale (an
//! older epoch or an abandoned frame: dropped), ahead (the input skipped the rest of the expected
//! frame: kept for later), accepted, or a mismatch the coordinator must hear about. Pure.

use lightfold_protocol::{BandHeader, Layer, PixelFormat};

/// The band the stage waits for on one input.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Expect {
    pub epoch: u64,
    pub frame: u64,
    pub layer: Layer,
    pub format: PixelFormat,
    pub x0: u32,
    pub y0: u32,
    pub width: u32,
    pub height: u32,
    /// The scale this input's layer carried on the frame's first band (fixed-point formats keep
    /// one scale per frame so bands have no seams).
    pub scale: Option<f32>,
}

/// How a band differs from what the configuration says.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Mismatch {
    #[error("band of epoch {got} but the stage is configured for epoch {expected}")]
    Epoch { got: u64, expected: u64 },
    #[error("band of layer {got:?} where layer {expected:?} was due")]
    Layer { got: Layer, expected: Layer },
    #[error("layer {layer:?} arrived as {got:?} but the link is configured for {expected:?}")]
    Format {
        layer: Layer,
        got: PixelFormat,
        expected: PixelFormat,
    },
    #[error("band rectangle ({},{}) {}x{} where ({},{}) {}x{} was due", got.0, got.1, got.2, got.3, expected.0, expected.1, expected.2, expected.3)]
    Rect {
        got: (u32, u32, u32, u32),
        expected: (u32, u32, u32, u32),
    },
    #[error("layer {layer:?} changed scale within the frame from {first} to {got}")]
    Scale { layer: Layer, first: f32, got: f32 },
    #[error(
        "band of frame {got} while frame {expected} was incomplete (the producer skipped the rest of it)"
    )]
    Skipped { got: u64, expected: u64 },
}

/// What to do with a received band.
#[derive(Debug, Clone, PartialEq)]
pub enum Verdict {
    Accept,
    /// Belongs to an older epoch or an earlier frame: drop it silently (counted).
    Stale,
    /// Belongs to a later frame: the expected frame fails, the band is kept for the next one.
    Ahead(Mismatch),
    /// Wrong for the expected frame: the frame fails and the band is dropped.
    Reject(Mismatch),
}

/// Judges `h` against `e`.
pub fn judge(h: &BandHeader, e: &Expect) -> Verdict {
    if h.epoch < e.epoch {
        return Verdict::Stale;
    }
    if h.epoch > e.epoch {
        return Verdict::Reject(Mismatch::Epoch {
            got: h.epoch,
            expected: e.epoch,
        });
    }
    if h.frame < e.frame {
        return Verdict::Stale;
    }
    if h.frame > e.frame {
        return Verdict::Ahead(Mismatch::Skipped {
            got: h.frame,
            expected: e.frame,
        });
    }
    if h.layer != e.layer {
        return Verdict::Reject(Mismatch::Layer {
            got: h.layer,
            expected: e.layer,
        });
    }
    if h.format != e.format {
        return Verdict::Reject(Mismatch::Format {
            layer: h.layer,
            got: h.format,
            expected: e.format,
        });
    }
    let got = (h.x0, h.y0, h.width, h.height);
    let expected = (e.x0, e.y0, e.width, e.height);
    if got != expected {
        return Verdict::Reject(Mismatch::Rect { got, expected });
    }
    if let Some(first) = e.scale
        && !h.empty
        && h.scale.to_bits() != first.to_bits()
        && h.format == PixelFormat::Seed64
    {
        return Verdict::Reject(Mismatch::Scale {
            layer: h.layer,
            first,
            got: h.scale,
        });
    }
    Verdict::Accept
}

#[cfg(test)]
mod tests {
    use super::*;

    fn expect() -> Expect {
        Expect {
            epoch: 4,
            frame: 10,
            layer: Layer::Illumination,
            format: PixelFormat::Rgb9e5x2,
            x0: 0,
            y0: 8,
            width: 31,
            height: 8,
            scale: None,
        }
    }

    fn header() -> BandHeader {
        let e = expect();
        BandHeader {
            frame: e.frame,
            epoch: e.epoch,
            layer: e.layer,
            format: e.format,
            x0: 0,
            y0: 8,
            width: 31,
            height: 8,
            scale: 1.0,
            empty: false,
            payload_len: 31 * 8 * 8,
            checksum: 0,
            saturated: 0,
        }
    }

    #[test]
    fn every_field_is_judged() {
        let e = expect();
        assert_eq!(judge(&header(), &e), Verdict::Accept);
        let older = [(3, 99), (4, 9)];
        for (epoch, frame) in older {
            let h = BandHeader {
                epoch,
                frame,
                ..header()
            };
            assert_eq!(judge(&h, &e), Verdict::Stale, "epoch {epoch} frame {frame}");
        }
        let h = BandHeader {
            epoch: 5,
            ..header()
        };
        assert!(matches!(
            judge(&h, &e),
            Verdict::Reject(Mismatch::Epoch {
                got: 5,
                expected: 4
            })
        ));
        let h = BandHeader {
            frame: 11,
            ..header()
        };
        assert!(matches!(
            judge(&h, &e),
            Verdict::Ahead(Mismatch::Skipped { .. })
        ));
        let h = BandHeader {
            layer: Layer::Depth,
            ..header()
        };
        assert!(matches!(
            judge(&h, &e),
            Verdict::Reject(Mismatch::Layer { .. })
        ));
        let h = BandHeader {
            format: PixelFormat::F16x6,
            ..header()
        };
        assert!(matches!(
            judge(&h, &e),
            Verdict::Reject(Mismatch::Format { .. })
        ));
        let h = BandHeader {
            height: 7,
            ..header()
        };
        assert!(matches!(
            judge(&h, &e),
            Verdict::Reject(Mismatch::Rect { .. })
        ));
        let h = BandHeader { x0: 1, ..header() };
        assert!(matches!(
            judge(&h, &e),
            Verdict::Reject(Mismatch::Rect { .. })
        ));
    }

    #[test]
    fn a_seed64_scale_is_constant_over_the_frame() {
        let e = Expect {
            format: PixelFormat::Seed64,
            scale: Some(2.0),
            ..expect()
        };
        let h = BandHeader {
            format: PixelFormat::Seed64,
            scale: 2.0,
            ..header()
        };
        assert_eq!(judge(&h, &e), Verdict::Accept);
        let h = BandHeader { scale: 3.0, ..h };
        assert!(matches!(
            judge(&h, &e),
            Verdict::Reject(Mismatch::Scale { .. })
        ));
        let h = BandHeader {
            empty: true,
            payload_len: 0,
            ..h
        };
        assert_eq!(judge(&h, &e), Verdict::Accept);
    }
}
