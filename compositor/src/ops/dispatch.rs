//! Runtime choice of instruction set for the hot kernels. The workspace builds for the target's
//! baseline (SSE2 on x86-64, no `target-cpu`) so binaries run on any machine; a kernel that is
//! limited by its arithmetic is compiled a second and third time with AVX2 and AVX-512 enabled
//! and picked at run time from what the CPU reports. Every path runs the same Rust code in the
//! same order (no `mul_add`, and Rust never contracts a multiply and an add by itself), so the
//! paths give the same bits; `tests/differential.rs` forces each available path and compares.
//!
//! Calling a `#[target_feature]` function is `unsafe` (the CPU must have the features), and the
//! workspace denies `unsafe_code`: this module holds the only exception, one call site per
//! instruction set, each behind the detection it relies on (ARCHITECTURE.md, Decisions).

use std::fmt;
use std::sync::OnceLock;

/// An instruction set a dispatched kernel can run on, in increasing order of width.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Isa {
    /// The compile target's baseline (SSE2 on x86-64): always available.
    Baseline,
    /// x86-64 with AVX2: 8-lane integer and float vectors, per-lane shifts, cross-lane permutes.
    Avx2,
    /// x86-64 with AVX-512 F, BW and VL: 16 lanes and two-source permutes.
    Avx512,
}

impl Isa {
    /// Every instruction set, narrowest first.
    pub const ALL: [Isa; 3] = [Isa::Baseline, Isa::Avx2, Isa::Avx512];

    /// The widest instruction set this CPU runs (detected once per process).
    pub fn best() -> Isa {
        static BEST: OnceLock<Isa> = OnceLock::new();
        *BEST.get_or_init(detect)
    }

    /// Whether this CPU runs `self`.
    pub fn available(self) -> bool {
        self <= Isa::best()
    }

    pub fn name(self) -> &'static str {
        match self {
            Isa::Baseline => "baseline",
            Isa::Avx2 => "avx2",
            Isa::Avx512 => "avx512",
        }
    }
}

impl fmt::Display for Isa {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

#[cfg(target_arch = "x86_64")]
fn detect() -> Isa {
    let avx2 = std::arch::is_x86_feature_detected!("avx2");
    if avx2
        && std::arch::is_x86_feature_detected!("avx512f")
        && std::arch::is_x86_feature_detected!("avx512bw")
        && std::arch::is_x86_feature_detected!("avx512vl")
    {
        Isa::Avx512
    } else if avx2 {
        Isa::Avx2
    } else {
        Isa::Baseline
    }
}

#[cfg(not(target_arch = "x86_64"))]
fn detect() -> Isa {
    Isa::Baseline
}

/// A kernel compiled once per instruction set. `run` must be `#[inline(always)]` and call only
/// `#[inline(always)]` code in its hot loops, so that the whole loop is compiled inside each
/// `#[target_feature]` wrapper below; anything it calls out of line runs at the baseline. `isa`
/// is a constant in each copy, so a kernel can pick the loop shape the compiler vectorises best
/// for that set (the arithmetic, and so the bits, must not depend on it).
pub(crate) trait Kernel {
    type Output;
    fn run(self, isa: Isa) -> Self::Output;
}

/// Runs `kernel` compiled for `isa`, or for the widest available set below it if this CPU lacks
/// `isa` (callers that must know pass only `Isa::available` sets).
pub(crate) fn run<K: Kernel>(isa: Isa, kernel: K) -> K::Output {
    let isa = isa.min(Isa::best());
    match isa {
        Isa::Baseline => kernel.run(Isa::Baseline),
        #[cfg(target_arch = "x86_64")]
        #[allow(unsafe_code)]
        // SAFETY: `isa <= Isa::best()`, and `detect` returns `Avx2` or wider only after
        // `is_x86_feature_detected!("avx2")` held, so this CPU executes every instruction `avx2`
        // was compiled with.
        Isa::Avx2 => unsafe { avx2(kernel) },
        #[cfg(target_arch = "x86_64")]
        #[allow(unsafe_code)]
        // SAFETY: `isa <= Isa::best()`, and `detect` returns `Avx512` only after avx2, avx512f,
        // avx512bw and avx512vl were all detected, the features `avx512` is compiled with.
        Isa::Avx512 => unsafe { avx512(kernel) },
        #[cfg(not(target_arch = "x86_64"))]
        _ => kernel.run(Isa::Baseline),
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn avx2<K: Kernel>(kernel: K) -> K::Output {
    kernel.run(Isa::Avx2)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl")]
fn avx512<K: Kernel>(kernel: K) -> K::Output {
    kernel.run(Isa::Avx512)
}
