//! Branch-free block decoders of the two 8-byte link formats, `rgb9e5x2` and `seed64`, straight
//! into (or onto) an interleaved f32 block, with the bits of `protocol::format::unpack`. Written
//! in two shapes of the same arithmetic, because the compiler vectorises each well on different
//! instruction sets (`docs/operators.md`, "Throughput"):
//!
//! - `Shape::Loop`: one pixel (or word) per iteration; the loop vectoriser interleaves. Best with
//!   AVX-512's two-source permutes.
//! - `Shape::Staged`: as `Loop`, but each term is decoded into an L1 buffer and added by the f32
//!   kernel, which SSE2 runs faster for `rgb9e5x2` than one fused loop.
//! - `Shape::Lanes`: a group of `GROUP` pixels as 48 straight-line lanes, lane `k` being pixel
//!   `k / 6`, channel `k % 6`, already in the band's order; the straight-line vectoriser packs
//!   them into permutes, masks, conversions and multiplies. Best with AVX2, and for `seed64` at
//!   SSE2.
//!
//! In the lanes a field is masked where it lies in its 32-bit word instead of being shifted down
//! (that would need a different shift per lane): the code at bit `p` converts exactly to
//! `code·2^p`, and the lane's factor carries `2^-p`. Both are exact scalings of the same real
//! product, so the rounded result is `unpack`'s `code as f32 · factor` whenever `factor·2^-p` is
//! itself exact, which `Decoder::of` checks once per band.

use crate::ops::Isa;
use lightfold_protocol::PixelFormat;

/// Pixels per lanes group: 48 floats, whole 4-, 8- and 16-lane vectors.
pub(super) const GROUP: usize = 8;

/// Bytes per pixel of every format decoded here.
pub(super) const BPP: usize = 8;

/// How a block loop is written (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Shape {
    Loop,
    Lanes,
    /// As `Loop`, but a term is decoded into a buffer and then added by the f32 kernel (the
    /// caller does that; `madd` is never called with it). Best for `rgb9e5x2` at SSE2.
    Staged,
}

impl Shape {
    /// The shape measured fastest for `isa` and this decoder (docs/operators.md).
    pub(super) fn best(isa: Isa, decoder: &Decoder) -> Shape {
        match (isa, decoder) {
            (Isa::Baseline, Decoder::Rgb9e5x2) => Shape::Staged,
            (Isa::Baseline, Decoder::Seed64 { .. }) | (Isa::Avx2, _) => Shape::Lanes,
            (Isa::Avx512, _) => Shape::Loop,
        }
    }
}

/// `rgb9e5x2` lane `c` (channel within a triple): where the 9-bit mantissa lies in its word and
/// the exponent bias that turns `2^(e−24)` into `2^(e−24−9c)` (never subnormal: e ≥ 0).
const R9_MASK: [u32; 3] = [0x1FF, 0x1FF << 9, 0x1FF << 18];
const R9_BIAS: [u32; 3] = [103, 103 - 9, 103 - 18];

/// `seed64` channel `k` (bits 0–10, 11–21, 22–32, 33–42, 43–52, 53–62): the 64-bit shift that
/// gives the 32-bit view holding it (diffuse blue straddles the halves, so its view starts at
/// bit 22), where its code lies in that view, and that position.
const S64_SHIFT: [u32; 6] = [0, 0, 22, 22, 32, 32];
const S64_MASK: [u32; 6] = [
    0x7FF,
    0x7FF << 11,
    0x7FF,
    0x3FF << 11,
    0x3FF << 11,
    0x3FF << 21,
];
const S64_POS: [i32; 6] = [0, 11, 0, 11, 11, 21];

/// A band's decoder: the format and, for `seed64`, its factors.
#[derive(Debug, Clone, Copy)]
pub(super) enum Decoder {
    Rgb9e5x2,
    Seed64 {
        /// `scale / 2047` (diffuse) and `scale / 1023` (specular), as `unpack` computes them.
        fd: f32,
        fs: f32,
        /// Lane factors: `fd` or `fs` times `2^-pos` for each channel.
        lanes: [f32; 6],
    },
}

impl Decoder {
    /// The decoder of a band in `format` with the header's `scale`, if this module decodes it
    /// bit for bit (`seed64` with a scale so small that `factor·2^-21` is subnormal does not).
    pub(super) fn of(format: PixelFormat, scale: f32) -> Option<Decoder> {
        match format {
            PixelFormat::Rgb9e5x2 => Some(Decoder::Rgb9e5x2),
            PixelFormat::Seed64 => {
                let (fd, fs) = (scale / 2047.0, scale / 1023.0);
                let factor = |k: usize| if k < 3 { fd } else { fs };
                let lanes: [f32; 6] = std::array::from_fn(|k| factor(k) * 2f32.powi(-S64_POS[k]));
                let exact = (0..6).all(|k| lanes[k] * 2f32.powi(S64_POS[k]) == factor(k));
                exact.then_some(Decoder::Seed64 { fd, fs, lanes })
            }
            _ => None,
        }
    }

    /// `o = decode(bytes)` over a block (`bytes.len() / BPP` pixels).
    #[inline(always)]
    pub(super) fn load(&self, shape: Shape, o: &mut [f32], bytes: &[u8]) {
        if shape != Shape::Lanes
            && let Decoder::Rgb9e5x2 = self
        {
            // Word by word: the triples interleave with one shuffle pattern.
            for (b, o) in bytes
                .as_chunks::<4>()
                .0
                .iter()
                .zip(o.as_chunks_mut::<3>().0)
            {
                *o = rgb9e5_word(u32::from_le_bytes(*b));
            }
            return;
        }
        self.blocks::<STORE>(shape, o, bytes, &[0.0; GROUP * 6]);
    }

    /// `o += c ⊙ decode(bytes)`, or with `FOLD` `o += c ⊙ (decode(bytes) + I^a)` for `I^a` = 1
    /// on the diffuse channels, over a block. `c` holds a pixel's six factors `GROUP` times.
    #[inline(always)]
    pub(super) fn madd<const FOLD: bool>(
        &self,
        shape: Shape,
        o: &mut [f32],
        bytes: &[u8],
        c: &[f32; GROUP * 6],
    ) {
        if FOLD {
            self.blocks::<ADD_FOLD>(shape, o, bytes, c);
        } else {
            self.blocks::<ADD>(shape, o, bytes, c);
        }
    }

    #[inline(always)]
    fn blocks<const MODE: u8>(
        &self,
        shape: Shape,
        o: &mut [f32],
        bytes: &[u8],
        c: &[f32; GROUP * 6],
    ) {
        match *self {
            Decoder::Rgb9e5x2 => blocks::<_, MODE>(Rgb9e5, shape, o, bytes, c),
            Decoder::Seed64 { fd, fs, lanes } => {
                blocks::<_, MODE>(Seed64 { fd, fs, lanes }, shape, o, bytes, c)
            }
        }
    }
}

/// What a block does with the decoded value `x` of lane `k`: `o = x`.
const STORE: u8 = 0;
/// `o += c[k]·x`.
const ADD: u8 = 1;
/// `o += c[k]·(x + 1)` on diffuse lanes, `o += c[k]·(x + 0)` on specular ones (eq. 6, `I^a = 1`).
const ADD_FOLD: u8 = 2;

/// 1 on the diffuse channels of each pixel, 0 (an exact no-op when added) on the specular ones.
const FOLD_AMBIENT: [f32; GROUP * 6] = {
    let mut a = [0.0; GROUP * 6];
    let mut k = 0;
    while k < GROUP * 6 {
        if k % 6 < 3 {
            a[k] = 1.0;
        }
        k += 1;
    }
    a
};

#[inline(always)]
fn put<const MODE: u8>(o: &mut f32, x: f32, c: &[f32; GROUP * 6], k: usize) {
    match MODE {
        STORE => *o = x,
        ADD => *o += c[k] * x,
        _ => *o += c[k] * (x + FOLD_AMBIENT[k]),
    }
}

/// A format decoded here: `GROUP` pixels as lanes, or one pixel.
trait Codec: Copy {
    fn group(self, b: &[u8; GROUP * BPP]) -> [f32; GROUP * 6];
    fn pixel(self, b: &[u8; BPP]) -> [f32; 6];
}

/// Runs a block in `shape`: whole groups as lanes and the rest pixel by pixel, or every pixel in
/// one loop (lanes 0–5 of the group's pattern serve a pixel).
#[inline(always)]
fn blocks<C: Codec, const MODE: u8>(
    codec: C,
    shape: Shape,
    o: &mut [f32],
    bytes: &[u8],
    c: &[f32; GROUP * 6],
) {
    let (o, bytes) = match shape {
        Shape::Loop | Shape::Staged => (o, bytes),
        Shape::Lanes => {
            let (og, orest) = o.as_chunks_mut::<{ GROUP * 6 }>();
            let (bg, brest) = bytes.as_chunks::<{ GROUP * BPP }>();
            for (o, b) in og.iter_mut().zip(bg) {
                let x = codec.group(b);
                let mut v = *o;
                for k in 0..GROUP * 6 {
                    put::<MODE>(&mut v[k], x[k], c, k);
                }
                *o = v;
            }
            (orest, brest)
        }
    };
    for (o, b) in o
        .as_chunks_mut::<6>()
        .0
        .iter_mut()
        .zip(bytes.as_chunks::<BPP>().0)
    {
        let x = codec.pixel(b);
        for k in 0..6 {
            put::<MODE>(&mut o[k], x[k], c, k);
        }
    }
}

/// The group's pixels as little-endian 64-bit words.
#[inline(always)]
fn pixels(b: &[u8; GROUP * BPP]) -> [u64; GROUP] {
    let mut q = [0u64; GROUP];
    for (q, b) in q.iter_mut().zip(b.as_chunks::<8>().0) {
        *q = u64::from_le_bytes(*b);
    }
    q
}

/// `[lane::<0>(arg), lane::<1>(arg), …]` over a group's 48 lanes: each lane's constants are known
/// at compile time, so the lanes are straight-line code (a loop over tables is not unrolled).
macro_rules! lanes {
    ($lane:ident, $arg:expr) => {
        lanes!(@ $lane, $arg; 0 1 2 3 4 5 6 7 8 9 10 11 12 13 14 15 16 17 18 19 20 21 22 23
            24 25 26 27 28 29 30 31 32 33 34 35 36 37 38 39 40 41 42 43 44 45 46 47)
    };
    (@ $lane:ident, $arg:expr; $($k:literal)*) => {{
        let arg = $arg;
        [$($lane::<$k>(arg)),*]
    }};
}

/// One `rgb9e5x2` triple, as `unpack` decodes it.
#[inline(always)]
fn rgb9e5_word(w: u32) -> [f32; 3] {
    let f = f32::from_bits(((w >> 27) + 103) << 23);
    [
        (w & 0x1FF) as i32 as f32 * f,
        (w >> 9 & 0x1FF) as i32 as f32 * f,
        (w >> 18 & 0x1FF) as i32 as f32 * f,
    ]
}

#[derive(Debug, Clone, Copy)]
struct Rgb9e5;

impl Codec for Rgb9e5 {
    /// Lane `k` reads word `k / 3` (half `k % 6 / 3` of pixel `k / 6`), channel `k % 3`.
    #[inline(always)]
    fn group(self, b: &[u8; GROUP * BPP]) -> [f32; GROUP * 6] {
        #[inline(always)]
        fn lane<const K: usize>(q: &[u64; GROUP]) -> f32 {
            let (w, c) = ((q[K / 6] >> (32 * (K % 6 / 3))) as u32, K % 3);
            let m = (w & R9_MASK[c]) as i32 as f32;
            m * f32::from_bits(((w >> 27) + R9_BIAS[c]) << 23)
        }
        lanes!(lane, &pixels(b))
    }

    #[inline(always)]
    fn pixel(self, b: &[u8; BPP]) -> [f32; 6] {
        let q = u64::from_le_bytes(*b);
        let (d, s) = (rgb9e5_word(q as u32), rgb9e5_word((q >> 32) as u32));
        [d[0], d[1], d[2], s[0], s[1], s[2]]
    }
}

#[derive(Debug, Clone, Copy)]
struct Seed64 {
    fd: f32,
    fs: f32,
    lanes: [f32; 6],
}

impl Codec for Seed64 {
    /// Lane `k` is pixel `k / 6`, channel `k % 6`, masked in its view.
    #[inline(always)]
    fn group(self, b: &[u8; GROUP * BPP]) -> [f32; GROUP * 6] {
        #[inline(always)]
        fn lane<const K: usize>((q, f): (&[u64; GROUP], &[f32; 6])) -> f32 {
            let c = K % 6;
            let view = (q[K / 6] >> S64_SHIFT[c]) as u32;
            (view & S64_MASK[c]) as i32 as f32 * f[c]
        }
        lanes!(lane, (&pixels(b), &self.lanes))
    }

    /// As `unpack` decodes it.
    #[inline(always)]
    fn pixel(self, b: &[u8; BPP]) -> [f32; 6] {
        let w = u64::from_le_bytes(*b);
        let (fd, fs) = (self.fd, self.fs);
        [
            (w & 0x7FF) as i32 as f32 * fd,
            (w >> 11 & 0x7FF) as i32 as f32 * fd,
            (w >> 22 & 0x7FF) as i32 as f32 * fd,
            (w >> 33 & 0x3FF) as i32 as f32 * fs,
            (w >> 43 & 0x3FF) as i32 as f32 * fs,
            (w >> 53 & 0x3FF) as i32 as f32 * fs,
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seed64_is_decoded_directly_only_where_the_lane_factors_are_exact() {
        for scale in [0.0, 1e-20, 1.0, 3.0, 4096.0, f32::MAX] {
            assert!(Decoder::of(PixelFormat::Seed64, scale).is_some(), "{scale}");
        }
        // scale/1023 · 2^-21 is subnormal and rounds: the band is staged through `unpack`.
        assert!(Decoder::of(PixelFormat::Seed64, 1e-31).is_none());
        assert!(Decoder::of(PixelFormat::Rgb9e5x2, 0.0).is_some());
        assert!(Decoder::of(PixelFormat::F16x6, 1.0).is_none());
    }
}
