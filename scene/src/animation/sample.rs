//! Sampling one channel at a clip time (glTF 2.0 Appendix C): before the first key its value,
//! after the last the last; step holds a key, linear interpolates (slerp for rotations along the
//! shorter arc), cubic spline evaluates the Hermite segment with tangents scaled by the key gap.

use super::{Channel, Interpolation, Target};

/// The channel's value at clip time `t` (`width` components; rotations normalised).
pub(super) fn sample(c: &Channel, t: f32) -> Vec<f32> {
    let w = c.width as usize;
    let cubic = c.interpolation == Interpolation::CubicSpline;
    // The value (not tangent) of key k.
    let value = |k: usize| -> &[f32] {
        let at = if cubic { (3 * k + 1) * w } else { k * w };
        &c.values[at..at + w]
    };
    let n = c.times.len();
    let out = if n == 1 || t <= c.times[0] {
        value(0).to_vec()
    } else if t >= c.times[n - 1] {
        value(n - 1).to_vec()
    } else {
        // The segment [k, k+1] holding t: the last key at or before t.
        let k = c
            .times
            .partition_point(|&x| x <= t)
            .saturating_sub(1)
            .min(n - 2);
        let (t0, t1) = (c.times[k], c.times[k + 1]);
        let gap = t1 - t0;
        let s = if gap > 0.0 { (t - t0) / gap } else { 0.0 };
        match c.interpolation {
            Interpolation::Step => value(k).to_vec(),
            Interpolation::Linear if c.target == Target::Rotation => {
                slerp(value(k), value(k + 1), s)
            }
            Interpolation::Linear => value(k)
                .iter()
                .zip(value(k + 1))
                .map(|(a, b)| a + (b - a) * s)
                .collect(),
            Interpolation::CubicSpline => {
                let out_tangent = &c.values[(3 * k + 2) * w..(3 * k + 3) * w];
                let in_tangent = &c.values[3 * (k + 1) * w..(3 * (k + 1) + 1) * w];
                let (s2, s3) = (s * s, s * s * s);
                let h00 = 2.0 * s3 - 3.0 * s2 + 1.0;
                let h10 = s3 - 2.0 * s2 + s;
                let h01 = -2.0 * s3 + 3.0 * s2;
                let h11 = s3 - s2;
                (0..w)
                    .map(|i| {
                        h00 * value(k)[i]
                            + h10 * gap * out_tangent[i]
                            + h01 * value(k + 1)[i]
                            + h11 * gap * in_tangent[i]
                    })
                    .collect()
            }
        }
    };
    if c.target == Target::Rotation {
        normalize4(out)
    } else {
        out
    }
}

fn normalize4(q: Vec<f32>) -> Vec<f32> {
    let len = q.iter().map(|v| v * v).sum::<f32>().sqrt();
    if len > 1e-12 && len.is_finite() {
        q.iter().map(|v| v / len).collect()
    } else {
        vec![0.0, 0.0, 0.0, 1.0]
    }
}

/// Spherical linear interpolation of unit quaternions along the shorter arc.
fn slerp(a: &[f32], b: &[f32], s: f32) -> Vec<f32> {
    let qa = glam::Quat::from_xyzw(a[0], a[1], a[2], a[3]).normalize();
    let qb = glam::Quat::from_xyzw(b[0], b[1], b[2], b[3]).normalize();
    let q = qa.slerp(qb, s);
    vec![q.x, q.y, q.z, q.w]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn channel(
        target: Target,
        interpolation: Interpolation,
        times: &[f32],
        values: &[f32],
        width: u32,
    ) -> Channel {
        Channel {
            node: 0,
            target,
            interpolation,
            times: times.to_vec(),
            values: values.to_vec(),
            width,
            repeat: false,
        }
    }

    #[test]
    fn linear_translation_interpolates_and_clamps() {
        let c = channel(
            Target::Translation,
            Interpolation::Linear,
            &[1.0, 3.0],
            &[0.0, 0.0, 0.0, 4.0, 2.0, -2.0],
            3,
        );
        assert_eq!(sample(&c, 0.0), vec![0.0, 0.0, 0.0]);
        assert_eq!(sample(&c, 2.0), vec![2.0, 1.0, -1.0]);
        assert_eq!(sample(&c, 9.0), vec![4.0, 2.0, -2.0]);
    }

    #[test]
    fn step_holds_the_earlier_key() {
        let c = channel(
            Target::Scale,
            Interpolation::Step,
            &[0.0, 1.0],
            &[1.0, 1.0, 1.0, 2.0, 2.0, 2.0],
            3,
        );
        assert_eq!(sample(&c, 0.999), vec![1.0; 3]);
        assert_eq!(sample(&c, 1.0), vec![2.0; 3]);
    }

    #[test]
    fn slerp_turns_at_constant_rate() {
        // 0° → 90° about Y: at a quarter of the way, 22.5°.
        let h = std::f32::consts::FRAC_1_SQRT_2;
        let c = channel(
            Target::Rotation,
            Interpolation::Linear,
            &[0.0, 1.0],
            &[0.0, 0.0, 0.0, 1.0, 0.0, h, 0.0, h],
            4,
        );
        let q = sample(&c, 0.25);
        let angle = 2.0 * q[3].acos();
        assert!((angle - 22.5f32.to_radians()).abs() < 1e-5, "{angle}");
    }

    #[test]
    fn cubic_spline_passes_through_keys_and_follows_tangents() {
        // Scalar-like translation x: keys 0 → 1 with zero tangents is smoothstep.
        let v = [
            0.0, 0.0, 0.0, /* in */ 0.0, 0.0, 0.0, /* value */ 0.0, 0.0,
            0.0, /* out */
            0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0,
        ];
        let c = channel(
            Target::Translation,
            Interpolation::CubicSpline,
            &[0.0, 2.0],
            &v,
            3,
        );
        assert_eq!(sample(&c, 0.0)[0], 0.0);
        assert_eq!(sample(&c, 2.0)[0], 1.0);
        assert!((sample(&c, 1.0)[0] - 0.5).abs() < 1e-6);
        assert!((sample(&c, 0.5)[0] - (3.0 * 0.0625 - 2.0 * 0.015625)).abs() < 1e-6);
        // A unit out-tangent (per second) at key 0 over a 2 s gap: slope at s = 0 is gap·1 per s.
        let mut v2 = v;
        v2[6] = 1.0;
        let c2 = channel(
            Target::Translation,
            Interpolation::CubicSpline,
            &[0.0, 2.0],
            &v2,
            3,
        );
        let eps = 1e-3;
        let slope = (sample(&c2, eps)[0] - sample(&c2, 0.0)[0]) / eps;
        assert!((slope - 1.0).abs() < 1e-2, "{slope}");
    }
}
