//! Operator throughput at 1920×1080 and 800×600, on one thread and on every core, next to memcpy
//! of the same bytes (read + written) in the same run, and each fast version against its scalar
//! reference. `compositor/benches/summarise.py` turns criterion's estimates into the table in
//! docs/operators.md:
//!
//! ```sh
//! cargo bench -p lightfold-compositor --bench operators
//! python3 compositor/benches/summarise.py
//! ```

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use lightfold_compositor::ops::{
    self, Accumulate, BandMut, BandView, Depth, Isa, Operator, Output, PAR_SPAN,
    PackedIllumination, PackedLayer, PackedOut,
};
use lightfold_protocol::format::pack;
use lightfold_protocol::{Layer, PixelFormat};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde_json::json;
use std::hint::black_box;
use std::time::Duration;

fn random(n: usize, r: &mut ChaCha8Rng) -> Vec<f32> {
    (0..n).map(|_| r.random_range(0.0..4.0f32)).collect()
}

fn packed(format: PixelFormat, v: &[f32], scale: f32) -> Vec<u8> {
    let mut b = vec![0u8; v.len() / 6 * format.bytes_per_pixel()];
    pack(format, v, scale, &mut b).expect("valid band");
    b
}

/// Bands of one size, shared by every benchmark of that size.
struct Data {
    pixels: usize,
    up: Vec<f32>,
    local: Vec<f32>,
    z: [Vec<f32>; 2],
    diffuse: Vec<f32>,
    radiance: Vec<f32>,
    packed: Vec<(PixelFormat, Vec<u8>, Vec<u8>)>,
    f16_up: Vec<u8>,
    f16_local: Vec<u8>,
    /// `z` as `depth32` payloads.
    z32: [Vec<u8>; 2],
}

impl Data {
    fn new(pixels: usize) -> Data {
        let mut r = ChaCha8Rng::seed_from_u64(1);
        let up = random(pixels * 6, &mut r);
        let local = random(pixels * 6, &mut r);
        let z = [random(pixels, &mut r), random(pixels, &mut r)];
        let z32 = z.clone().map(|z| {
            let mut b = vec![0u8; pixels * 4];
            pack(PixelFormat::DepthF32, &z, 1.0, &mut b).expect("valid band");
            b
        });
        let bands = [PixelFormat::Rgb9e5x2, PixelFormat::Seed64]
            .into_iter()
            .map(|f| (f, packed(f, &up, 4.0), packed(f, &local, 4.0)))
            .collect();
        Data {
            pixels,
            f16_up: packed(PixelFormat::F16x6, &up, 1.0),
            f16_local: packed(PixelFormat::F16x6, &local, 1.0),
            z32,
            up,
            local,
            z,
            diffuse: random(pixels * 3, &mut r),
            radiance: random(pixels * 3, &mut r),
            packed: bands,
        }
    }
}

/// Runs `op` over the inputs into a fresh output band (allocated once per benchmark).
fn bench_op(
    g: &mut criterion::BenchmarkGroup<'_, criterion::measurement::WallTime>,
    pool: &rayon::ThreadPool,
    name: &str,
    op: &dyn Operator,
    inputs: &[BandView<'_>],
    pixels: usize,
    scalar: bool,
) {
    let outs = op.signature().outputs;
    let mut bufs: Vec<Vec<f32>> = outs
        .iter()
        .map(|l| vec![0f32; pixels * l.channels()])
        .collect();
    g.bench_function(name, |b| {
        b.iter(|| {
            let mut out = BandMut {
                pixels,
                layers: outs
                    .iter()
                    .zip(bufs.iter_mut())
                    .map(|(l, v)| (*l, v.as_mut_slice()))
                    .collect(),
            };
            pool.install(|| {
                if scalar {
                    op.apply_scalar(inputs, &mut out)
                } else {
                    op.apply(inputs, &mut out)
                }
            })
            .expect("bench bands are well formed");
            black_box(&mut out);
        })
    });
}

/// memcpy moving `moved` bytes (half read, half written), split over the pool's threads.
fn bench_memcpy(
    g: &mut criterion::BenchmarkGroup<'_, criterion::measurement::WallTime>,
    pool: &rayon::ThreadPool,
    moved_per_pixel: usize,
    pixels: usize,
) {
    let n = moved_per_pixel * pixels / 2;
    let src = vec![7u8; n];
    let mut dst = vec![0u8; n];
    let chunk = n.div_ceil(pool.current_num_threads());
    g.bench_function(format!("memcpy_{moved_per_pixel}B"), |b| {
        b.iter(|| {
            pool.install(|| {
                dst.par_chunks_mut(chunk)
                    .zip(src.par_chunks(chunk))
                    .for_each(|(d, s)| d.copy_from_slice(s));
            });
            black_box(&mut dst);
        })
    });
}

/// `depth` from two packed links (`f16x6` illumination + `depth32`) to the packed outgoing bands:
/// `apply_packed` (`_packed` on the widest instruction set, suffixed on each narrower one) against
/// the general path a stage runs without it in the same run: unpack every layer (split across the
/// pool as the stage does), `apply`, and per output the all-zero test, pack and checksum.
fn bench_depth_packed(
    g: &mut criterion::BenchmarkGroup<'_, criterion::measurement::WallTime>,
    pool: &rayon::ThreadPool,
    d: &Data,
) {
    use Layer::{Depth as Z, Illumination as Ill};
    use PixelFormat::{DepthF32, F16x6};
    let px = d.pixels;
    let op = Depth::new(&json!({"inputs": 2})).unwrap();
    let ill = [&d.f16_up, &d.f16_local];
    fn layer(layer: Layer, format: PixelFormat, bytes: &[u8]) -> PackedLayer<'_> {
        PackedLayer {
            layer,
            format,
            scale: 1.0,
            bytes: Some(bytes),
        }
    }
    let inputs: Vec<Vec<PackedLayer<'_>>> = (0..2)
        .map(|i| vec![layer(Ill, F16x6, ill[i]), layer(Z, DepthF32, &d.z32[i])])
        .collect();
    let (mut zout, mut iout) = (vec![0u8; px * 4], vec![0u8; px * 12]);
    for isa in Isa::ALL.into_iter().filter(|i| i.available()) {
        let name = if isa == Isa::best() {
            "depth_f16x6_packed".to_string()
        } else {
            format!("depth_f16x6_packed_{isa}")
        };
        g.bench_function(name, |b| {
            b.iter(|| {
                let out = |layer, format, bytes| PackedOut {
                    layer,
                    format,
                    scale: 1.0,
                    bytes,
                };
                let mut outs = [out(Z, DepthF32, &mut zout), out(Ill, F16x6, &mut iout)];
                let sums = pool.install(|| op.apply_packed_on(isa, &inputs, &mut outs));
                black_box(sums.unwrap());
            })
        });
    }
    let mut zs = [vec![0f32; px], vec![0f32; px]];
    let mut ills = [vec![0f32; px * 6], vec![0f32; px * 6]];
    let (mut zo, mut io) = (vec![0f32; px], vec![0f32; px * 6]);
    g.bench_function("depth_f16x6_unpack_apply_pack", |b| {
        b.iter(|| {
            pool.install(|| {
                fn unpack(f: PixelFormat, bytes: &[u8], v: &mut [f32]) {
                    let (bpp, ch) = (f.bytes_per_pixel(), f.channels());
                    v.par_chunks_mut(PAR_SPAN * ch)
                        .zip(bytes.par_chunks(PAR_SPAN * bpp))
                        .for_each(|(v, b)| {
                            lightfold_protocol::format::unpack(f, b, 1.0, v).unwrap()
                        });
                }
                fn pack_band(f: PixelFormat, v: &[f32], bytes: &mut [u8]) -> (bool, u64, u32) {
                    let nonzero = !v.iter().all(|v| *v == 0.0);
                    let (bpp, ch) = (f.bytes_per_pixel(), f.channels());
                    let saturated = v
                        .par_chunks(PAR_SPAN * ch)
                        .zip(bytes.par_chunks_mut(PAR_SPAN * bpp))
                        .map(|(v, b)| pack(f, v, 1.0, b).unwrap().saturated)
                        .sum();
                    (nonzero, saturated, crc32fast::hash(bytes))
                }
                for i in 0..2 {
                    unpack(F16x6, ill[i], &mut ills[i]);
                    unpack(DepthF32, &d.z32[i], &mut zs[i]);
                }
                let views: Vec<BandView<'_>> = (0..2)
                    .map(|i| BandView::new(px).with(Ill, &ills[i]).with(Z, &zs[i]))
                    .collect();
                let mut o = BandMut::new(px).with(Z, &mut zo).with(Ill, &mut io);
                op.apply(&views, &mut o).unwrap();
                black_box(pack_band(DepthF32, &zo, &mut zout));
                black_box(pack_band(F16x6, &io, &mut iout));
            })
        })
    });
}

fn operators(c: &mut Criterion) {
    let all = std::thread::available_parallelism().map_or(1, |n| n.get());
    for (w, h) in [(1920usize, 1080usize), (800, 600)] {
        let d = Data::new(w * h);
        let px = d.pixels;
        for threads in [1, all] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("thread pool");
            let mut g = c.benchmark_group(format!("ops_{w}x{h}_{threads}t"));
            g.throughput(Throughput::Elements(px as u64));
            fn ill(px: usize, v: &[f32]) -> BandView<'_> {
                BandView::new(px).with(Layer::Illumination, v)
            }
            let scalar_too = threads == 1;

            let acc = ops::create("accumulate", &json!({"colors": [[0.9, 0.8, 0.7]]})).unwrap();
            let two = [ill(px, &d.up), ill(px, &d.local)];
            bench_op(&mut g, &pool, "accumulate", &*acc, &two, px, false);
            if scalar_too {
                bench_op(&mut g, &pool, "accumulate_scalar", &*acc, &two, px, true);
            }
            let acc = Accumulate::new(&json!({"colors": [[0.9, 0.8, 0.7]]})).unwrap();
            let mut out = vec![0f32; px * 6];
            let mut up = vec![0f32; px * 6];
            let mut local = vec![0f32; px * 6];
            for (f, pu, pl) in &d.packed {
                let p = |bytes| {
                    Some(PackedIllumination {
                        format: *f,
                        scale: 4.0,
                        bytes,
                    })
                };
                let inputs = [p(pu.as_slice()), p(pl.as_slice())];
                // `_fused` runs on the widest instruction set (what `apply_packed` picks), the
                // suffixed ones on each narrower set this CPU has.
                for isa in Isa::ALL.into_iter().filter(|i| i.available()) {
                    let name = if isa == Isa::best() {
                        format!("accumulate_{}_fused", f.name())
                    } else {
                        format!("accumulate_{}_fused_{isa}", f.name())
                    };
                    g.bench_function(name, |b| {
                        b.iter(|| {
                            let mut o = BandMut::new(px).with(Layer::Illumination, &mut out);
                            pool.install(|| acc.apply_packed_on(isa, &inputs, &mut o))
                                .unwrap();
                        })
                    });
                }
                g.bench_function(format!("accumulate_{}_unpack_then_apply", f.name()), |b| {
                    b.iter(|| {
                        pool.install(|| {
                            let un = |bytes: &[u8], v: &mut [f32]| {
                                let n = v.len().div_ceil(threads * 6) * 6;
                                let bpp = f.bytes_per_pixel();
                                v.par_chunks_mut(n)
                                    .zip(bytes.par_chunks(n / 6 * bpp))
                                    .for_each(|(v, b)| {
                                        lightfold_protocol::format::unpack(*f, b, 4.0, v).unwrap()
                                    });
                            };
                            un(pu, &mut up);
                            un(pl, &mut local);
                            let views = [ill(px, &up), ill(px, &local)];
                            let mut o = BandMut::new(px).with(Layer::Illumination, &mut out);
                            acc.apply(&views, &mut o).unwrap();
                        })
                    })
                });
            }
            let rec = [
                Some(PackedIllumination {
                    format: PixelFormat::F16x6,
                    scale: 1.0,
                    bytes: &d.f16_up,
                }),
                Some(PackedIllumination {
                    format: PixelFormat::Rgb9e5x2,
                    scale: 1.0,
                    bytes: &d.packed[0].2,
                }),
            ];
            g.bench_function("accumulate_f16x6_rgb9e5x2_fused", |b| {
                b.iter(|| {
                    let mut o = BandMut::new(px).with(Layer::Illumination, &mut out);
                    pool.install(|| acc.apply_packed(&rec, &mut o)).unwrap();
                })
            });

            let mat = ops::create("material", &json!({"stage": "single"})).unwrap();
            let inputs = [
                ill(px, &d.up),
                BandView::new(px).with(Layer::Diffuse, &d.diffuse),
            ];
            bench_op(&mut g, &pool, "material", &*mat, &inputs, px, false);
            if scalar_too {
                bench_op(&mut g, &pool, "material_scalar", &*mat, &inputs, px, true);
            }

            let depth = ops::create("depth", &json!({"inputs": 2})).unwrap();
            let inputs = [
                ill(px, &d.up).with(Layer::Depth, &d.z[0]),
                ill(px, &d.local).with(Layer::Depth, &d.z[1]),
            ];
            bench_op(&mut g, &pool, "depth", &*depth, &inputs, px, false);
            if scalar_too {
                bench_op(&mut g, &pool, "depth_scalar", &*depth, &inputs, px, true);
            }

            bench_depth_packed(&mut g, &pool, &d);

            // The penumbra filter over a receding plane (every tap on the surface: its
            // costliest case), radius 1 and 2.
            let plane: Vec<f32> = (0..px)
                .map(|p| 1.0 / (0.05 + 1e-4 * (p / w) as f32 + 2e-5 * (p % w) as f32))
                .collect();
            // `_crease`: with the crease test the planner gives a 45° camera of this height
            // (every tap on the plane passes it: its costliest case too).
            let crease = ops::penumbra::crease_tolerance(45.0, (px / w) as u32);
            for radius in [1, 2] {
                let inputs = [ill(px, &d.up), BandView::new(px).with(Layer::Depth, &plane)];
                for (suffix, params) in [
                    ("", json!({"width": w, "radius": radius})),
                    (
                        "_crease",
                        json!({"width": w, "radius": radius, "crease_tolerance": crease}),
                    ),
                ] {
                    let op = ops::create("penumbra", &params).unwrap();
                    let name = format!("penumbra_r{radius}{suffix}");
                    bench_op(&mut g, &pool, &name, &*op, &inputs, px, false);
                }
            }

            let join = ops::create("join", &json!({"inputs": 2})).unwrap();
            bench_op(&mut g, &pool, "join", &*join, &two, px, false);
            if scalar_too {
                bench_op(&mut g, &pool, "join_scalar", &*join, &two, px, true);
            }

            let output = Output::new(&json!({"exposure": 0.5})).unwrap();
            let inputs = [BandView::new(px).with(Layer::Radiance, &d.radiance)];
            bench_op(&mut g, &pool, "output", &output, &inputs, px, false);
            if scalar_too {
                bench_op(&mut g, &pool, "output_scalar", &output, &inputs, px, true);
            }
            let mut rgb8 = vec![0u8; px * 3];
            g.bench_function("srgb8", |b| {
                b.iter(|| {
                    pool.install(|| output.encode_srgb8(&d.radiance, &mut rgb8))
                        .unwrap()
                })
            });
            if scalar_too {
                g.bench_function("srgb8_scalar", |b| {
                    b.iter(|| output.encode_srgb8_scalar(&d.radiance, &mut rgb8).unwrap())
                });
            }

            for moved in [72, 40, 44, 48, 84, 24, 15] {
                bench_memcpy(&mut g, &pool, moved, px);
            }
            g.finish();
        }
    }
}

fn config() -> Criterion {
    Criterion::default()
        .sample_size(10)
        .warm_up_time(Duration::from_millis(300))
        .measurement_time(Duration::from_millis(1200))
}

criterion_group! {
    name = benches;
    config = config();
    targets = operators
}
criterion_main!(benches);
