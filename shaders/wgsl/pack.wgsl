// Packing on the device: one layer of a frame from the node's render targets into its link
// format (`protocol::format`), bit for bit what the CPU pack writes, plus what the band headers
// need (whether each band has a non-zero source value, how many pixels saturated) and the frame's
// illumination peak. Every decision is made on the f32 bits with integer operations: WGSL lets an
// implementation assume no NaN or infinity, flush subnormals and contract a multiply and an add
// into one rounding, and none of that may change a packed bit. The only float operation is one
// multiply whose result is rounded here by integer code (`rne`).
//
// One invocation per pixel; a workgroup is 64 pixels of one row (dispatch ⌈width/64⌉ × height),
// so all of it lies in one band and it adds its counts with one global atomic each.

struct Params {
    width: u32,
    height: u32,
    band_height: u32,
    // `PixelFormat` as its wire byte.
    format: u32,
    // 1: the source holds f16 texels (two per word), else f32 words.
    halves: u32,
    // Source channels packed (6, 3 or 1).
    channels: u32,
    // Words (f16: halves / 2) per source pixel, and per source row.
    texel_words: u32,
    row_words: u32,
    // Word offset of channels 3..5 relative to channels 0..2 (the lit buffer's specular vec4, or
    // the forward pass's specular target copied after the diffuse one).
    group_offset: u32,
    // 1: this is the illumination layer, whose finite maximum is the frame's peak.
    peak: u32,
    // seed64: f32 bits of 2047/scale, 1023/scale, the scale, and 2·scale (saturated to f32::MAX).
    kd: u32,
    ks: u32,
    scale: u32,
    limit: u32,
    // Index of this layer's first band in `counts` (two words a band).
    band_base: u32,
    _pad: u32,
}

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> src: array<u32>;
@group(0) @binding(2) var<storage, read_write> dst: array<u32>;
// Word 0: the peak's bits; then per band of each layer: non-zero flag, saturated pixels.
@group(0) @binding(3) var<storage, read_write> counts: array<atomic<u32>>;
// sRGB encoding: 256 threshold bits, then 4096 bucket starts (`format::rgba8`).
@group(0) @binding(4) var<storage, read> srgb: array<u32>;

var<workgroup> wg_nonzero: atomic<u32>;
var<workgroup> wg_saturated: atomic<u32>;
var<workgroup> wg_peak: atomic<u32>;

const SIGN: u32 = 0x80000000u;
const ABS: u32 = 0x7FFFFFFFu;
const INF: u32 = 0x7F800000u;
const F32_MAX: u32 = 0x7F7FFFFFu;
const F16_MAX: u32 = 0x477FE000u;       // 65504
const RGB9E5_MAX: u32 = 0x477F8000u;    // 65408
const RGB9E5_FLOOR: u32 = 0x37800000u;  // 2^-16
const ONE: u32 = 0x3F800000u;
const DMAX: u32 = 0x44FFE000u;          // 2047
const SMAX: u32 = 0x447FC000u;          // 1023

const SEED64: u32 = 0u;
const RGB9E5X2: u32 = 1u;
const F16X6: u32 = 2u;
const F32X6: u32 = 3u;
const RGBA8: u32 = 4u;
const RGBA8_SRGB: u32 = 5u;
const F16X4: u32 = 6u;
const DEPTH32: u32 = 7u;
const F32X3: u32 = 8u;

fn is_nan(b: u32) -> bool {
    return (b & ABS) > INF;
}

// A non-negative number (not NaN) above `max`: what the CPU's `v > max` counts.
fn above(b: u32, max: u32) -> bool {
    return (b & SIGN) == 0u && !is_nan(b) && b > max;
}

// `clamp_nonneg`: NaN and negatives (−0 too) to +0, values above `max` to `max`.
fn clamp_nonneg(b: u32, max: u32) -> u32 {
    if (b & SIGN) != 0u || is_nan(b) {
        return 0u;
    }
    return min(b, max);
}

// round-ties-even(value(b) · 2^k) for a non-negative finite f32 `b` whose result is below 2^23,
// subnormals included: the CPU's `round_u32` of an exact product.
fn rne(b: u32, k: i32) -> u32 {
    let e = i32(b >> 23u);
    var m = b & 0x7FFFFFu;
    var ee = e;
    if e == 0 {
        ee = 1;
    } else {
        m = m | 0x800000u;
    }
    let shift = 150 - ee - k;
    if shift <= 0 {
        return m << u32(-shift);
    }
    if shift > 25 {
        return 0u;
    }
    let s = u32(shift);
    let q = m >> s;
    let rem = m & ((1u << s) - 1u);
    let half = 1u << (s - 1u);
    let up = rem > half || (rem == half && (q & 1u) == 1u);
    return q + select(0u, 1u, up);
}

// A value in [0, 65504] (clamped bits) as the half `format::encode_half` writes.
fn f16_bits(b: u32) -> u32 {
    if b < (113u << 23u) {
        return rne(b, 24);
    }
    let odd = (b >> 13u) & 1u;
    return ((b + 0xC8000000u + 0xFFFu + odd) >> 13u) & 0xFFFFu;
}

// An f16's bits as the f32's bits it decodes to (exactly; NaN stays NaN).
fn f16_to_f32(h: u32) -> u32 {
    let sign = (h & 0x8000u) << 16u;
    let e = (h >> 10u) & 0x1Fu;
    let m = h & 0x3FFu;
    if e == 0x1Fu {
        return sign | INF | (m << 13u);
    }
    if e != 0u {
        return sign | ((e + 112u) << 23u) | (m << 13u);
    }
    if m == 0u {
        return sign;
    }
    let p = firstLeadingBit(m);
    return sign | ((p + 103u) << 23u) | ((m << (23u - p)) & 0x7FFFFFu);
}

// The f32 bits of channel `c` of pixel (x, y).
fn load(x: u32, y: u32, c: u32) -> u32 {
    if P.halves != 0u {
        let w = src[y * P.row_words + x * P.texel_words + c / 2u];
        return f16_to_f32((w >> (16u * (c % 2u))) & 0xFFFFu);
    }
    return src[(c / 3u) * P.group_offset + y * P.row_words + x * P.texel_words + c % 3u];
}

fn rgb9e5(r: u32, g: u32, b: u32) -> u32 {
    let cr = clamp_nonneg(r, RGB9E5_MAX);
    let cg = clamp_nonneg(g, RGB9E5_MAX);
    let cb = clamp_nonneg(b, RGB9E5_MAX);
    let m = max(max(max(cr, cg), cb), RGB9E5_FLOOR);
    let es = ((m + 0x4000u) >> 23u) - 111u;
    let k = 24 - i32(es);
    return rne(cr, k) | (rne(cg, k) << 9u) | (rne(cb, k) << 18u) | (es << 27u);
}

// round(clamp(v, 0, 1) · span) with the product rounded once, as the CPU's.
fn scaled_unit(b: u32, span: f32) -> u32 {
    let x = clamp_nonneg(b, ONE);
    return rne(bitcast<u32>(bitcast<f32>(x) * span), 0);
}

fn srgb8(b: u32) -> u32 {
    let x = clamp_nonneg(b, ONE);
    let bucket = min(scaled_unit(x, 4095.0), 4095u);
    let c = srgb[256u + bucket];
    return c + select(0u, 1u, x >= srgb[c]);
}

// A seed64 code: round(clamp(v·k, 0, top)).
fn seed(b: u32, k: u32, top: u32) -> u32 {
    if (b & SIGN) != 0u || (b & ABS) == 0u || is_nan(b) {
        return 0u;
    }
    if b > P.limit {
        return rne(top, 0);
    }
    let p = bitcast<u32>(bitcast<f32>(b) * bitcast<f32>(k));
    return rne(min(p, top), 0);
}

fn pack_pixel(x: u32, y: u32) {
    var v: array<u32, 6>;
    var nonzero = false;
    var peak = 0u;
    for (var c = 0u; c < P.channels; c++) {
        let b = load(x, y, c);
        v[c] = b;
        nonzero = nonzero || (b & ABS) != 0u;
        if (b & SIGN) == 0u && (b & INF) != INF {
            peak = max(peak, b);
        }
    }
    let i = y * P.width + x;
    var max_bits = F32_MAX;
    switch P.format {
        case 0u: {
            max_bits = P.scale;
            let d0 = seed(v[0], P.kd, DMAX);
            let d1 = seed(v[1], P.kd, DMAX);
            let d2 = seed(v[2], P.kd, DMAX);
            let s0 = seed(v[3], P.ks, SMAX);
            let s1 = seed(v[4], P.ks, SMAX);
            let s2 = seed(v[5], P.ks, SMAX);
            dst[2u * i] = d0 | (d1 << 11u) | (d2 << 22u);
            dst[2u * i + 1u] = (d2 >> 10u) | (s0 << 1u) | (s1 << 11u) | (s2 << 21u);
        }
        case 1u: {
            max_bits = RGB9E5_MAX;
            dst[2u * i] = rgb9e5(v[0], v[1], v[2]);
            dst[2u * i + 1u] = rgb9e5(v[3], v[4], v[5]);
        }
        case 2u: {
            max_bits = F16_MAX;
            for (var w = 0u; w < 3u; w++) {
                let lo = f16_bits(clamp_nonneg(v[2u * w], F16_MAX));
                let hi = f16_bits(clamp_nonneg(v[2u * w + 1u], F16_MAX));
                dst[3u * i + w] = lo | (hi << 16u);
            }
        }
        case 6u: {
            max_bits = F16_MAX;
            let h0 = f16_bits(clamp_nonneg(v[0], F16_MAX));
            let h1 = f16_bits(clamp_nonneg(v[1], F16_MAX));
            let h2 = f16_bits(clamp_nonneg(v[2], F16_MAX));
            dst[2u * i] = h0 | (h1 << 16u);
            dst[2u * i + 1u] = h2 | (0x3C00u << 16u);
        }
        case 3u, 8u: {
            for (var c = 0u; c < P.channels; c++) {
                dst[P.channels * i + c] = clamp_nonneg(v[c], F32_MAX);
            }
        }
        case 4u: {
            max_bits = ONE;
            dst[i] = scaled_unit(v[0], 255.0) | (scaled_unit(v[1], 255.0) << 8u)
                | (scaled_unit(v[2], 255.0) << 16u) | (255u << 24u);
        }
        case 5u: {
            max_bits = ONE;
            dst[i] = srgb8(v[0]) | (srgb8(v[1]) << 8u) | (srgb8(v[2]) << 16u) | (255u << 24u);
        }
        default: {
            // depth32: NaN to 0, ±∞ to ±f32::MAX (saturated), everything else as it is.
            let b = v[0];
            var out = b;
            if is_nan(b) {
                out = 0u;
            } else if (b & ABS) == INF {
                out = (b & SIGN) | F32_MAX;
            }
            dst[i] = out;
            max_bits = INF;
            if (b & ABS) == INF {
                atomicAdd(&wg_saturated, 1u);
            }
        }
    }
    if P.format != DEPTH32 {
        var over = false;
        for (var c = 0u; c < P.channels; c++) {
            over = over || above(v[c], max_bits);
        }
        if over {
            atomicAdd(&wg_saturated, 1u);
        }
    }
    if nonzero {
        atomicOr(&wg_nonzero, 1u);
    }
    if P.peak != 0u && peak != 0u {
        atomicMax(&wg_peak, peak);
    }
}

@compute @workgroup_size(64)
fn cs_pack(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    if li == 0u {
        atomicStore(&wg_nonzero, 0u);
        atomicStore(&wg_saturated, 0u);
        atomicStore(&wg_peak, 0u);
    }
    workgroupBarrier();
    let y = wid.y;
    if gid.x < P.width && y < P.height {
        pack_pixel(gid.x, y);
    }
    workgroupBarrier();
    if li == 0u {
        let band = P.band_base + 2u * (y / P.band_height);
        if atomicLoad(&wg_nonzero) != 0u {
            atomicOr(&counts[band], 1u);
        }
        let saturated = atomicLoad(&wg_saturated);
        if saturated != 0u {
            atomicAdd(&counts[band + 1u], saturated);
        }
        let peak = atomicLoad(&wg_peak);
        if peak != 0u {
            atomicMax(&counts[0], peak);
        }
    }
}
