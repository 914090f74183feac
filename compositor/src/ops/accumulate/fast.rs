//! The fast `accumulate`: per block of `BLOCK` pixels, the output is initialised from the
//! upstream partial, each local term is added in input order with loops over four pixels at a
//! time (24 lanes the compiler vectorises), and the block saturates once at the end. The same
//! terms serve `apply_packed` (`packed.rs`).

use super::decode::GROUP;
use super::{Accumulate, AmbientMask};
use crate::ops::{MAX_VALUE, clamp_fast};

/// How one local input contributes.
#[derive(Debug, Clone, Copy)]
pub(super) enum Kind {
    Plain,
    /// Eq. 6 with `I^a = 1`.
    Uniform,
    /// Eq. 7: `I^a` from the ambient-mask layer.
    Masked,
}

/// One local input's contribution: its kind and channel factors.
#[derive(Debug, Clone)]
pub(super) struct Term {
    pub(super) kind: Kind,
    c24: [f32; 24],
    c6: [f32; 6],
    /// `c6` repeated over a decoder group (`decode::GROUP` pixels).
    pub(super) cg: [f32; GROUP * 6],
}

pub(super) fn terms(op: &Accumulate) -> Vec<Term> {
    (0..op.coeffs.len())
        .map(|j| Term {
            kind: match op.fold_of(j) {
                None => Kind::Plain,
                Some(AmbientMask::Uniform) => Kind::Uniform,
                Some(AmbientMask::Layer) => Kind::Masked,
            },
            c24: std::array::from_fn(|k| op.coeffs[j][k % 6]),
            c6: op.coeffs[j],
            cg: std::array::from_fn(|k| op.coeffs[j][k % 6]),
        })
        .collect()
}

/// Eq. 6 with `I^a = 1`: 1 on the diffuse channels, 0 (an exact no-op) on the specular ones.
const UNIFORM_AMBIENT: [f32; 24] = {
    let mut a = [0.0; 24];
    let mut k = 0;
    while k < 24 {
        if k % 6 < 3 {
            a[k] = 1.0;
        }
        k += 1;
    }
    a
};

/// Starts a block from the upstream partial (sanitised) or from zero.
#[inline(always)]
pub(super) fn init(o: &mut [f32], up: Option<&[f32]>) {
    match up {
        Some(u) => {
            for (o, u) in o.iter_mut().zip(u) {
                *o = clamp_fast(*u);
            }
        }
        None => o.fill(0.0),
    }
}

/// Saturates a finished block (sums of non-negative terms may have reached +Inf).
#[inline(always)]
pub(super) fn finish(o: &mut [f32]) {
    // `min` gives `saturate`'s bits (NaN cannot occur, and would also give MAX_VALUE) without
    // the compare-and-keep that AVX2 code generation turns into a slow masked store.
    for o in o.iter_mut() {
        *o = o.min(MAX_VALUE);
    }
}

impl Term {
    /// Adds this term to the block `o`; `x` is the block of the input's illumination (absent:
    /// an empty band) and `a` the block of its ambient layer (masked folding only).
    #[inline(always)]
    pub(super) fn add(&self, o: &mut [f32], x: Option<&[f32]>, a: Option<&[f32]>) {
        match (self.kind, x) {
            (Kind::Plain, None) => {}
            (Kind::Plain, Some(x)) => madd::<false>(o, x, &self.c24),
            (Kind::Uniform, Some(x)) => madd::<true>(o, x, &self.c24),
            (Kind::Uniform, None) => {
                // An empty band on the folding node still adds c^d ⊙ I^a.
                for o4 in o.chunks_mut(24) {
                    for ((o, a), c) in o4.iter_mut().zip(&UNIFORM_AMBIENT).zip(&self.c24) {
                        *o += *c * *a;
                    }
                }
            }
            (Kind::Masked, x) => {
                let (c, a) = (
                    &self.c6,
                    a.expect("checked: the masked input has an ambient-mask layer"),
                );
                for (px, (o, a)) in o.chunks_exact_mut(6).zip(a.chunks_exact(3)).enumerate() {
                    let x: [f32; 6] = match x {
                        Some(x) => std::array::from_fn(|k| clamp_fast(x[px * 6 + k])),
                        None => [0.0; 6],
                    };
                    for k in 0..3 {
                        o[k] += c[k] * (x[k] + clamp_fast(a[k]));
                    }
                    for k in 3..6 {
                        o[k] += c[k] * x[k];
                    }
                }
            }
        }
    }
}

/// `o += c ⊙ clamp(x)`, or with `FOLD` `o += c ⊙ (clamp(x) + I^a)` for `I^a = 1`, over whole
/// groups of four pixels, then the rest.
#[inline(always)]
fn madd<const FOLD: bool>(o: &mut [f32], x: &[f32], c: &[f32; 24]) {
    let term = |x: f32, k: usize| {
        if FOLD {
            clamp_fast(x) + UNIFORM_AMBIENT[k]
        } else {
            clamp_fast(x)
        }
    };
    let mut oc = o.chunks_exact_mut(24);
    let mut xc = x.chunks_exact(24);
    for (o, x) in (&mut oc).zip(&mut xc) {
        for k in 0..24 {
            o[k] += c[k] * term(x[k], k);
        }
    }
    for (k, (o, x)) in oc
        .into_remainder()
        .iter_mut()
        .zip(xc.remainder())
        .enumerate()
    {
        *o += c[k] * term(*x, k);
    }
}
