//! Helpers shared by the compositor tests: seeded random bands with hostile values, and owned
//! bands that lend `BandView`s and `BandMut`s.

use lightfold_compositor::ops::{BandMut, BandView, Operator};
use lightfold_protocol::Layer;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

pub(crate) fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

/// One value: mostly ordinary, sometimes NaN, ±Inf, negative, subnormal, zero or huge.
pub(crate) fn hostile(r: &mut ChaCha8Rng) -> f32 {
    match r.random_range(0..100) {
        0..4 => f32::NAN,
        4..7 => f32::INFINITY,
        7..9 => f32::NEG_INFINITY,
        9..17 => -r.random_range(0.0..10.0f32),
        17..20 => f32::from_bits(r.random_range(1..0x0080_0000)),
        20..24 => 0.0,
        24..27 => -0.0,
        27..30 => r.random_range(1e37..3e38f32),
        _ => r.random_range(0.0..4.0f32),
    }
}

/// Ordinary non-negative values (no specials).
pub(crate) fn ordinary(r: &mut ChaCha8Rng) -> f32 {
    r.random_range(0.0..4.0f32)
}

/// An owned band: layers of `pixels` pixels.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Owned {
    pub pixels: usize,
    pub layers: Vec<(Layer, Vec<f32>)>,
}

impl Owned {
    pub(crate) fn zeros(pixels: usize, layers: &[Layer]) -> Owned {
        Owned {
            pixels,
            layers: layers
                .iter()
                .map(|&l| (l, vec![0.0; pixels * l.channels()]))
                .collect(),
        }
    }

    pub(crate) fn random(
        pixels: usize,
        layers: &[Layer],
        r: &mut ChaCha8Rng,
        f: fn(&mut ChaCha8Rng) -> f32,
    ) -> Owned {
        Owned {
            pixels,
            layers: layers
                .iter()
                .map(|&l| (l, (0..pixels * l.channels()).map(|_| f(r)).collect()))
                .collect(),
        }
    }

    pub(crate) fn view(&self) -> BandView<'_> {
        BandView {
            pixels: self.pixels,
            layers: self
                .layers
                .iter()
                .map(|(l, d)| (*l, d.as_slice()))
                .collect(),
        }
    }

    pub(crate) fn view_mut(&mut self) -> BandMut<'_> {
        BandMut {
            pixels: self.pixels,
            layers: self
                .layers
                .iter_mut()
                .map(|(l, d)| (*l, d.as_mut_slice()))
                .collect(),
        }
    }

    pub(crate) fn layer(&self, layer: Layer) -> &[f32] {
        &self
            .layers
            .iter()
            .find(|(l, _)| *l == layer)
            .expect("layer")
            .1
    }
}

/// Runs `op` (fast, or the reference) on owned inputs into a fresh output band.
pub(crate) fn run(op: &dyn Operator, inputs: &[Owned], pixels: usize, scalar: bool) -> Owned {
    let mut out = Owned::zeros(pixels, &op.signature().outputs);
    let views: Vec<BandView<'_>> = inputs.iter().map(Owned::view).collect();
    let mut o = out.view_mut();
    if scalar {
        op.apply_scalar(&views, &mut o).expect("apply_scalar");
    } else {
        op.apply(&views, &mut o).expect("apply");
    }
    drop(o);
    out
}

/// Asserts two bands hold the same bits, naming the first difference.
pub(crate) fn assert_same_bits(a: &Owned, b: &Owned, what: &str) {
    assert_eq!(a.layers.len(), b.layers.len(), "{what}: layer count");
    for ((la, da), (lb, db)) in a.layers.iter().zip(&b.layers) {
        assert_eq!(la, lb, "{what}: layer order");
        for (k, (x, y)) in da.iter().zip(db).enumerate() {
            assert!(
                x.to_bits() == y.to_bits(),
                "{what}: {la:?}[{k}] differs: {x:e} vs {y:e}"
            );
        }
    }
}
