//! How shadow maps store depth: reversed-Z in `Depth32Float` (near 1, far 0, so a float's
//! relative precision holds at every distance), or one of two textbook ways precision collapses
//! at range that only the depth negative controls select ([`Fault::Depth16`],
//! [`Fault::ConventionalZ`]). Everything that writes, clears or compares a shadow depth asks this.

use super::lights::Fault;

/// The shadow maps' depth encoding.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(super) enum ShadowDepth {
    /// Reversed-Z in `Depth32Float`: the renderer.
    #[default]
    Reversed32,
    /// Reversed-Z in `Depth16Unorm`: a fixed step of 2^-16 of a depth that falls like near/D.
    Reversed16,
    /// Near 0, far 1 in `Depth32Float`: depth 1 − near/D crowds below 1, where a float's step is
    /// 2^-24 absolute, i.e. a relative step in D of 2^-24·D/near.
    Conventional32,
}

impl ShadowDepth {
    pub(super) fn of(fault: Option<Fault>) -> ShadowDepth {
        match fault {
            Some(Fault::Depth16) => ShadowDepth::Reversed16,
            Some(Fault::ConventionalZ) => ShadowDepth::Conventional32,
            _ => ShadowDepth::Reversed32,
        }
    }

    pub(super) fn format(self) -> wgpu::TextureFormat {
        match self {
            ShadowDepth::Reversed16 => wgpu::TextureFormat::Depth16Unorm,
            ShadowDepth::Reversed32 | ShadowDepth::Conventional32 => {
                wgpu::TextureFormat::Depth32Float
            }
        }
    }

    pub(super) fn reversed(self) -> bool {
        self != ShadowDepth::Conventional32
    }

    /// The depth of "nothing in front": uncovered texels are lit.
    pub(super) fn clear(self) -> f32 {
        if self.reversed() { 0.0 } else { 1.0 }
    }

    /// The depth test of the shadow pass: the nearer fragment wins.
    pub(super) fn write_compare(self) -> wgpu::CompareFunction {
        if self.reversed() {
            wgpu::CompareFunction::Greater
        } else {
            wgpu::CompareFunction::Less
        }
    }

    /// The comparison sampler's test: a receiver is lit where it is at least as near as the
    /// stored depth.
    pub(super) fn lookup_compare(self) -> wgpu::CompareFunction {
        if self.reversed() {
            wgpu::CompareFunction::GreaterEqual
        } else {
            wgpu::CompareFunction::LessEqual
        }
    }

    /// The projection a view's depth is written and looked up with, from its reversed-Z one
    /// (column-major). Conventional Z is `w − z` of reversed-Z: `1 − d_rev = f(1 − n/D)/(f − n)`,
    /// the textbook matrix (`p22 = f/(n − f)`, `p32 = nf/(n − f)`). The shader's reference for a
    /// receiver behind the light's plane stays reversed-Z's "nearest" (1.0), which conventional Z
    /// reads as "farthest": such receivers (within the bias of a light's plane) come out shadowed
    /// under this fault.
    pub(super) fn projection(self, proj: &[[f32; 4]; 4]) -> [[f32; 4]; 4] {
        let mut p = *proj;
        if !self.reversed() {
            for c in &mut p {
                c[2] = c[3] - c[2];
            }
        }
        p
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `d` of a point `depth` metres along the view axis under column-major `p`.
    fn ndc_depth(p: &[[f32; 4]; 4], depth: f32) -> f64 {
        let z = -f64::from(depth);
        let clip = |r: usize| f64::from(p[2][r]) * z + f64::from(p[3][r]);
        clip(2) / clip(3)
    }

    #[test]
    fn conventional_z_is_the_textbook_projection() {
        let (n, f) = (0.0134f32, 1340.0f32);
        let a = n / (f - n);
        let reversed = [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, a, -1.0],
            [0.0, 0.0, a * f, 0.0],
        ];
        let p = ShadowDepth::Conventional32.projection(&reversed);
        let (n64, f64_) = (f64::from(n), f64::from(f));
        assert!((f64::from(p[2][2]) - f64_ / (n64 - f64_)).abs() < 1e-6);
        assert!((f64::from(p[3][2]) - n64 * f64_ / (n64 - f64_)).abs() < 1e-6);
        for depth in [n, 1.0, 5.0, 300.0, f] {
            let (r, c) = (ndc_depth(&reversed, depth), ndc_depth(&p, depth));
            assert!((r + c - 1.0).abs() < 1e-6, "{depth}: {r} + {c}");
        }
        assert!(ndc_depth(&p, n).abs() < 1e-6 && (ndc_depth(&p, f) - 1.0).abs() < 1e-6);
        assert_eq!(ShadowDepth::Reversed16.projection(&reversed), reversed);
        assert_eq!(ShadowDepth::Reversed32.projection(&reversed), reversed);
    }

    #[test]
    fn only_the_depth_faults_change_the_encoding() {
        assert_eq!(ShadowDepth::of(None), ShadowDepth::Reversed32);
        assert_eq!(
            ShadowDepth::of(Some(Fault::NoBias)),
            ShadowDepth::Reversed32
        );
        let c = ShadowDepth::of(Some(Fault::ConventionalZ));
        assert_eq!(
            (c.format(), c.clear(), c.write_compare(), c.lookup_compare()),
            (
                wgpu::TextureFormat::Depth32Float,
                1.0,
                wgpu::CompareFunction::Less,
                wgpu::CompareFunction::LessEqual
            )
        );
        let s = ShadowDepth::of(Some(Fault::Depth16));
        assert_eq!(
            (s.format(), s.clear(), s.write_compare()),
            (
                wgpu::TextureFormat::Depth16Unorm,
                0.0,
                wgpu::CompareFunction::Greater
            )
        );
    }
}
