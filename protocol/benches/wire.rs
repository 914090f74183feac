//! What one 1920×1080 illumination layer costs on the link path, per step, on one core: the
//! `f16x6` pack and unpack against `half`'s bare slice conversion of the same values (the floor
//! for a conversion that reads f32 and writes halves), the CRC-32 each side of a link computes, and
//! a memcpy of the packed bytes (what a copy into a write buffer costs). Each routine runs
//! interleaved with the others for `--rounds` rounds (15 by default); the table gives the best and
//! the median round in ms. `docs/bench-protocol.md` has the figures.
//!
//! `cargo bench -p lightfold-protocol --bench wire [-- --rounds N]`

use half::f16;
use half::slice::HalfFloatSliceExt;
use lightfold_protocol::band::checksum;
use lightfold_protocol::format::{pack, unpack};
use lightfold_protocol::{PixelFormat, stats};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;
use std::time::Instant;

const PIXELS: usize = 1920 * 1080;

/// Illumination as the link benchmark's content: mostly in [0, 4], some dark, a few bright, all
/// inside the half range (the common case the pack is built for).
fn layer() -> Vec<f32> {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    (0..PIXELS * 6)
        .map(|_| match rng.random_range(0..100) {
            0..70 => rng.random_range(0.0..4.0),
            70..98 => rng.random_range(0.0..0.04),
            _ => rng.random_range(4.0..16.0),
        })
        .collect()
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let rounds = args
        .iter()
        .position(|a| a == "--rounds")
        .and_then(|i| args.get(i + 1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(15usize);
    let src = layer();
    // With one value out of range in every block, every block takes the clamping path.
    let mut spoiled = src.clone();
    for v in spoiled.iter_mut().step_by(1000) {
        *v = -1.0;
    }
    let mut packed = vec![0u8; src.len() * 2];
    let mut packed2 = vec![0u8; src.len() * 2];
    let mut out = vec![0f32; src.len()];
    let mut halves = vec![f16::ZERO; src.len()];
    let mut copy = vec![0u8; packed.len()];
    let names = [
        "f16x6 pack",
        "f16x6 pack, every block clamped",
        "half convert_from_f32_slice",
        "f16x6 unpack",
        "crc-32 of the packed layer",
        "memcpy of the packed layer",
    ];
    let mut times: Vec<Vec<f64>> = vec![Vec::new(); names.len()];
    let timed = |t: &mut Vec<f64>, f: &mut dyn FnMut()| {
        let start = Instant::now();
        f();
        t.push(start.elapsed().as_secs_f64() * 1e3);
    };
    for _ in 0..rounds {
        timed(&mut times[0], &mut || {
            black_box(pack(PixelFormat::F16x6, black_box(&src), 1.0, &mut packed).ok());
        });
        timed(&mut times[1], &mut || {
            black_box(pack(PixelFormat::F16x6, black_box(&spoiled), 1.0, &mut packed2).ok());
        });
        timed(&mut times[2], &mut || {
            halves.convert_from_f32_slice(black_box(&src));
        });
        timed(&mut times[3], &mut || {
            black_box(unpack(PixelFormat::F16x6, black_box(&packed), 1.0, &mut out).ok());
        });
        timed(&mut times[4], &mut || {
            black_box(checksum(black_box(&packed)));
        });
        timed(&mut times[5], &mut || {
            copy.copy_from_slice(black_box(&packed));
            black_box(&mut copy);
        });
    }
    println!(
        "one 1920x1080 f16x6 layer ({:.1} MB f32, {:.1} MB packed), {rounds} rounds",
        src.len() as f64 * 4e-6,
        src.len() as f64 * 2e-6
    );
    println!("{:<34} {:>8} {:>10}", "step", "best ms", "median ms");
    for (name, t) in names.iter().zip(times) {
        let t = stats::sorted(&t);
        let median = stats::median(&t).expect("rounds > 0");
        println!("{name:<34} {:>8.2} {median:>10.2}", t[0]);
    }
}
