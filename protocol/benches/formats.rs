//! Pack and unpack throughput of every pixel format on a 1920×1080 frame, against memcpy moving the
//! same number of bytes in the same run. Bandwidth counts bytes read plus bytes written for both,
//! so the ratio says how close a format comes to a plain copy. After criterion's own report a
//! summary table prints Mpixel/s, GB/s and the ratio to memcpy.
//!
//! `cargo bench -p lightfold-protocol --bench formats`

use std::collections::BTreeMap;
use std::hint::black_box;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use criterion::{Criterion, Throughput, criterion_group};
use lightfold_protocol::format::{pack, unpack};
use lightfold_protocol::{PixelFormat, stats};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const WIDTH: usize = 1920;
const HEIGHT: usize = 1080;
const PIXELS: usize = WIDTH * HEIGHT;
const SCALE: f32 = 4.0;

/// Median nanoseconds per iteration of each measured routine, keyed by its name.
static TIMES: Mutex<BTreeMap<String, Vec<f64>>> = Mutex::new(BTreeMap::new());

fn record(name: &str, iters: u64, elapsed: Duration) {
    let per_iter = elapsed.as_nanos() as f64 / iters.max(1) as f64;
    if let Ok(mut times) = TIMES.lock() {
        times.entry(name.to_owned()).or_default().push(per_iter);
    }
}

fn median_ns(name: &str) -> Option<f64> {
    let times = TIMES.lock().ok()?;
    stats::median(times.get(name)?)
}

/// A plausible frame: mostly in [0, SCALE], some dark, a few bright (saturating seed64).
fn frame(format: PixelFormat) -> Vec<f32> {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let top = match format {
        PixelFormat::Rgba8Linear | PixelFormat::Rgba8Srgb => 1.0,
        _ => SCALE,
    };
    (0..PIXELS * format.channels())
        .map(|_| match rng.random_range(0..100) {
            0..70 => rng.random_range(0.0..top),
            70..98 => rng.random_range(0.0..top * 0.01),
            _ => rng.random_range(top..top * 4.0),
        })
        .collect()
}

/// Bytes one pack or unpack moves: f32 channels on one side, packed bytes on the other.
fn traffic(format: PixelFormat) -> usize {
    PIXELS * (format.channels() * 4 + format.bytes_per_pixel())
}

fn formats(c: &mut Criterion) {
    for format in PixelFormat::ALL {
        let src = frame(format);
        let mut packed = vec![0u8; PIXELS * format.bytes_per_pixel()];
        let mut out = vec![0f32; src.len()];
        let throughput = Throughput::ElementsAndBytes {
            elements: PIXELS as u64,
            bytes: traffic(format) as u64,
        };
        let mut group = c.benchmark_group(format.name());
        group.throughput(throughput);
        let pack_name = format!("{}/pack", format.name());
        group.bench_function("pack", |b| {
            b.iter_custom(|iters| {
                let start = Instant::now();
                for _ in 0..iters {
                    black_box(pack(format, black_box(&src), SCALE, &mut packed).ok());
                }
                let elapsed = start.elapsed();
                record(&pack_name, iters, elapsed);
                elapsed
            })
        });
        let unpack_name = format!("{}/unpack", format.name());
        group.bench_function("unpack", |b| {
            b.iter_custom(|iters| {
                let start = Instant::now();
                for _ in 0..iters {
                    black_box(unpack(format, black_box(&packed), SCALE, &mut out).ok());
                }
                let elapsed = start.elapsed();
                record(&unpack_name, iters, elapsed);
                elapsed
            })
        });
        // memcpy moving the same bytes: copying n bytes reads n and writes n.
        let n = traffic(format) / 2;
        let from = vec![1u8; n];
        let mut to = vec![0u8; n];
        let copy_name = format!("{}/memcpy", format.name());
        group.bench_function("memcpy", |b| {
            b.iter_custom(|iters| {
                let start = Instant::now();
                for _ in 0..iters {
                    to.copy_from_slice(black_box(&from));
                    black_box(&mut to);
                }
                let elapsed = start.elapsed();
                record(&copy_name, iters, elapsed);
                elapsed
            })
        });
        group.finish();
    }
}

/// Best-of-N time of `f` in nanoseconds.
fn best_ns(rounds: usize, mut f: impl FnMut()) -> f64 {
    (0..rounds)
        .map(|_| {
            let start = Instant::now();
            f();
            start.elapsed().as_nanos() as f64
        })
        .fold(f64::INFINITY, f64::min)
}

/// The summary table. On a shared machine other jobs come and go between criterion's groups, so
/// the ratio is measured here with each routine and its memcpy interleaved round by round, taking
/// the best round of each: both then see the same machine.
fn summary() {
    println!();
    println!(
        "{:<10} {:<7} {:>9} {:>8} {:>13} {:>8} {:>15}",
        "format", "op", "Mpixel/s", "GB/s", "memcpy GB/s", "ratio", "criterion Mpx/s"
    );
    for format in PixelFormat::ALL {
        let src = frame(format);
        let mut packed = vec![0u8; PIXELS * format.bytes_per_pixel()];
        let mut out = vec![0f32; src.len()];
        let bytes = traffic(format);
        let from = vec![1u8; bytes / 2];
        let mut to = vec![0u8; bytes / 2];
        for op in ["pack", "unpack"] {
            let (mut best_op, mut best_copy) = (f64::INFINITY, f64::INFINITY);
            for _ in 0..15 {
                best_op = best_op.min(best_ns(1, || {
                    if op == "pack" {
                        black_box(pack(format, black_box(&src), SCALE, &mut packed).ok());
                    } else {
                        black_box(unpack(format, black_box(&packed), SCALE, &mut out).ok());
                    }
                }));
                best_copy = best_copy.min(best_ns(1, || {
                    to.copy_from_slice(black_box(&from));
                    black_box(&mut to);
                }));
            }
            let criterion = median_ns(&format!("{}/{op}", format.name()))
                .map_or(String::from("-"), |ns| {
                    format!("{:.0}", PIXELS as f64 / ns * 1e3)
                });
            println!(
                "{:<10} {:<7} {:>9.0} {:>8.2} {:>13.2} {:>7.0}% {:>15}",
                format.name(),
                op,
                PIXELS as f64 / best_op * 1e3,
                bytes as f64 / best_op,
                bytes as f64 / best_copy,
                best_copy / best_op * 100.0,
                criterion,
            );
        }
    }
}

/// 8-bit sRGB of a 1080p radiance frame (what every PNG and the live view's JPEG frames start
/// from): the table encoder and the per-channel `powf` reference, against memcpy of the same
/// bytes (12 read, 3 written a pixel), interleaved round by round as above.
fn srgb_summary() {
    use lightfold_protocol::srgb::{encode_rgb8, srgb8};
    let src = frame(PixelFormat::F32x3);
    let bytes = PIXELS * (12 + 3);
    let from = vec![1u8; bytes / 2];
    let mut to = vec![0u8; bytes / 2];
    let mut out = Vec::with_capacity(PIXELS * 3);
    for (name, table) in [("table", true), ("powf", false)] {
        let (mut best_op, mut best_copy) = (f64::INFINITY, f64::INFINITY);
        for _ in 0..9 {
            best_op = best_op.min(best_ns(1, || {
                out.clear();
                if table {
                    encode_rgb8(black_box(&src), 3, 1.0, &mut out);
                } else {
                    out.extend(src.iter().map(|&v| srgb8(v)));
                }
                black_box(&mut out);
            }));
            best_copy = best_copy.min(best_ns(1, || {
                to.copy_from_slice(black_box(&from));
                black_box(&mut to);
            }));
        }
        println!(
            "{:<10} {:<7} {:>9.0} {:>8.2} {:>13.2} {:>7.0}% {:>15}",
            "srgb8",
            name,
            PIXELS as f64 / best_op * 1e3,
            bytes as f64 / best_op,
            bytes as f64 / best_copy,
            best_copy / best_op * 100.0,
            "-",
        );
    }
}

criterion_group! {
    name = benches;
    // The machine is shared: short, few samples.
    config = Criterion::default()
        .sample_size(10)
        .warm_up_time(Duration::from_millis(300))
        .measurement_time(Duration::from_millis(1200));
    targets = formats
}

fn main() {
    benches();
    Criterion::default().configure_from_args().final_summary();
    // Under `cargo test` each routine runs once: too little for a meaningful table.
    if std::env::args().any(|a| a == "--bench") {
        summary();
        srgb_summary();
    }
}
