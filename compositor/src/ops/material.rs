//! `material`: the material nodes of paper §3, which turn the illumination sum into radiance.
//! Input 0 is the upstream partial, input 1 the material layers of a material node.
//!
//! Stages: `specular` (`p^s ← p^s ⊙ m^s`, illumination out), `diffuse` (`p = p^d ⊙ m^d + p^s`,
//! radiance out; with a pre-multiplied specular this is eq. 5), `ambient` (`p + m^a ⊙ c^a`) and
//! `emissive` (`e + p`), or `single`: eq. 2 in one stage, `(e + m^a ⊙ c^a) + (m^d ⊙ p^d + m^s ⊙ p^s)`,
//! with the `specular`, `ambient` and `emissive` layers only when the plan has them (eq. 4–5).
//! Per-light ambient illumination is folded into the diffuse sum upstream (eq. 6–7), so the
//! ambient term here is the global `c^a` alone.

use super::params;
use super::{
    BandMut, BandView, InputSpec, MAX_VALUE, OpError, Operator, Signature, check_band, clamp_fast,
    for_spans, sanitize, saturate,
};
use lightfold_protocol::Layer;
use serde_json::Value;

pub const NAME: &str = MaterialParams::NAME;

pub use lightfold_protocol::pipeline::{MaterialParams, MaterialStage};

/// The material operator (see the module documentation).
#[derive(Debug, Clone)]
pub struct Material {
    params: MaterialParams,
}

fn bad(reason: String) -> OpError {
    OpError::BadParam { op: NAME, reason }
}

impl Material {
    /// From JSON parameters (`MaterialParams`).
    pub fn new(params: &Value) -> Result<Self, OpError> {
        Self::from_params(params::parse(NAME, params)?)
    }

    /// From typed parameters, validated (`MaterialParams::validate`).
    pub fn from_params(p: MaterialParams) -> Result<Self, OpError> {
        p.validate()?;
        Ok(Material { params: p })
    }

    pub fn stage(&self) -> MaterialStage {
        self.params.stage
    }

    /// (layer of input 0, material layers of input 1, output layer).
    fn layers(&self) -> (Layer, Vec<Layer>, Layer) {
        let p = &self.params;
        match p.stage {
            MaterialStage::Specular => (
                Layer::Illumination,
                vec![Layer::Specular],
                Layer::Illumination,
            ),
            MaterialStage::Diffuse => (Layer::Illumination, vec![Layer::Diffuse], Layer::Radiance),
            MaterialStage::Ambient => (Layer::Radiance, vec![Layer::Ambient], Layer::Radiance),
            MaterialStage::Emissive => (Layer::Radiance, vec![Layer::Emissive], Layer::Radiance),
            MaterialStage::Single => {
                let mut m = vec![Layer::Diffuse];
                m.extend(p.specular.then_some(Layer::Specular));
                m.extend(p.ambient_color.map(|_| Layer::Ambient));
                m.extend(p.emissive.then_some(Layer::Emissive));
                (Layer::Illumination, m, Layer::Radiance)
            }
        }
    }
}

/// The layers one band of a material stage reads, resolved once.
struct Src<'a> {
    p: &'a [f32],
    d: Option<&'a [f32]>,
    s: Option<&'a [f32]>,
    a: Option<&'a [f32]>,
    e: Option<&'a [f32]>,
}

impl<'a> Src<'a> {
    fn new(op: &Material, inputs: &[BandView<'a>]) -> Self {
        let (l0, _, _) = op.layers();
        let m = &inputs[1];
        let used = |l: Layer| op.layers().1.contains(&l).then(|| m.layer(l)).flatten();
        Src {
            p: inputs[0].layer(l0).expect("checked"),
            d: used(Layer::Diffuse),
            s: used(Layer::Specular),
            a: used(Layer::Ambient),
            e: used(Layer::Emissive),
        }
    }
}

impl Operator for Material {
    fn name(&self) -> &'static str {
        NAME
    }

    fn signature(&self) -> Signature {
        let (l0, m, out) = self.layers();
        Signature {
            inputs: vec![
                InputSpec {
                    required: vec![l0],
                    optional: vec![],
                },
                InputSpec {
                    required: m,
                    optional: vec![],
                },
            ],
            outputs: vec![out],
        }
    }

    fn apply_scalar(&self, inputs: &[BandView<'_>], out: &mut BandMut<'_>) -> Result<(), OpError> {
        check_band(NAME, &self.signature(), inputs, out)?;
        let src = Src::new(self, inputs);
        let ca = self.params.ambient_color.unwrap_or([0.0; 3]);
        let (_, _, lout) = self.layers();
        let pixels = out.pixels;
        let dst = out.layer_mut(lout).expect("checked");
        let m = |layer: Option<&[f32]>, px: usize, c: usize| layer.map(|l| sanitize(l[px * 3 + c]));
        for px in 0..pixels {
            for c in 0..3 {
                match self.params.stage {
                    MaterialStage::Specular => {
                        dst[px * 6 + c] = sanitize(src.p[px * 6 + c]);
                        let s = sanitize(src.p[px * 6 + 3 + c]) * m(src.s, px, c).expect("checked");
                        dst[px * 6 + 3 + c] = s.min(MAX_VALUE);
                    }
                    MaterialStage::Diffuse => {
                        let d = sanitize(src.p[px * 6 + c]) * m(src.d, px, c).expect("checked");
                        dst[px * 3 + c] = (d + sanitize(src.p[px * 6 + 3 + c])).min(MAX_VALUE);
                    }
                    MaterialStage::Ambient => {
                        let a = m(src.a, px, c).expect("checked") * ca[c];
                        dst[px * 3 + c] = (sanitize(src.p[px * 3 + c]) + a).min(MAX_VALUE);
                    }
                    MaterialStage::Emissive => {
                        let e = m(src.e, px, c).expect("checked");
                        dst[px * 3 + c] = (e + sanitize(src.p[px * 3 + c])).min(MAX_VALUE);
                    }
                    MaterialStage::Single => {
                        // Eq. 2 in the order of scene::shading::compose.
                        let e = m(src.e, px, c).unwrap_or(0.0);
                        let a = m(src.a, px, c).map_or(0.0, |a| a * ca[c]);
                        let d = m(src.d, px, c).expect("checked") * sanitize(src.p[px * 6 + c]);
                        let s = m(src.s, px, c).unwrap_or(1.0) * sanitize(src.p[px * 6 + 3 + c]);
                        dst[px * 3 + c] = ((e + a) + (d + s)).min(MAX_VALUE);
                    }
                }
            }
        }
        Ok(())
    }

    fn apply(&self, inputs: &[BandView<'_>], out: &mut BandMut<'_>) -> Result<(), OpError> {
        check_band(NAME, &self.signature(), inputs, out)?;
        let src = Src::new(self, inputs);
        let ca = self.params.ambient_color.unwrap_or([0.0; 3]);
        let (_, _, lout) = self.layers();
        let (stage, pixels) = (self.params.stage, out.pixels);
        let dst = out.layer_mut(lout).expect("checked");
        for_spans(pixels, vec![(lout.channels(), dst)], |first, outs| {
            let o = &mut *outs[0];
            let (lo, hi) = (first, first + o.len() / lout.channels());
            fn part(l: Option<&[f32]>, lo: usize, hi: usize) -> Option<&[f32]> {
                l.map(|l| &l[lo * 3..hi * 3])
            }
            let m3 = |l| part(l, lo, hi);
            match stage {
                MaterialStage::Specular => {
                    specular(o, &src.p[lo * 6..hi * 6], m3(src.s).expect("checked"))
                }
                MaterialStage::Diffuse => {
                    diffuse(o, &src.p[lo * 6..hi * 6], m3(src.d).expect("checked"))
                }
                MaterialStage::Ambient => {
                    let a = m3(src.a).expect("checked");
                    for ((o, p), a) in o
                        .chunks_exact_mut(3)
                        .zip(src.p[lo * 3..hi * 3].chunks_exact(3))
                        .zip(a.chunks_exact(3))
                    {
                        for c in 0..3 {
                            o[c] = saturate(clamp_fast(p[c]) + clamp_fast(a[c]) * ca[c]);
                        }
                    }
                }
                MaterialStage::Emissive => {
                    let e = m3(src.e).expect("checked");
                    for ((o, p), e) in o.iter_mut().zip(&src.p[lo * 3..hi * 3]).zip(e) {
                        *o = saturate(clamp_fast(*e) + clamp_fast(*p));
                    }
                }
                MaterialStage::Single => {
                    let p = &src.p[lo * 6..hi * 6];
                    let d = m3(src.d).expect("checked");
                    match (m3(src.s), m3(src.a), m3(src.e)) {
                        (None, None, None) => diffuse(o, p, d),
                        (s, a, e) => single(o, p, d, s, a.map(|a| (a, ca)), e),
                    }
                }
            }
        });
        Ok(())
    }

    fn set_params(&mut self, params: &Value) -> Result<(), OpError> {
        let current = serde_json::to_value(&self.params).map_err(|e| bad(e.to_string()))?;
        let next = Material::new(&params::merge(NAME, &current, params)?)?;
        if next.signature() != self.signature() {
            return Err(OpError::SignatureChange { op: NAME });
        }
        *self = next;
        Ok(())
    }
}

/// The specular node: diffuse passes through, specular is multiplied by `m^s`.
fn specular(o: &mut [f32], p: &[f32], s: &[f32]) {
    for ((o, p), s) in o
        .chunks_exact_mut(6)
        .zip(p.chunks_exact(6))
        .zip(s.chunks_exact(3))
    {
        for c in 0..3 {
            o[c] = clamp_fast(p[c]);
            o[3 + c] = saturate(clamp_fast(p[3 + c]) * clamp_fast(s[c]));
        }
    }
}

/// Eq. 5: `p^d ⊙ m^d + p^s`.
fn diffuse(o: &mut [f32], p: &[f32], d: &[f32]) {
    for ((o, p), d) in o
        .chunks_exact_mut(3)
        .zip(p.chunks_exact(6))
        .zip(d.chunks_exact(3))
    {
        for c in 0..3 {
            o[c] = saturate(clamp_fast(p[c]) * clamp_fast(d[c]) + clamp_fast(p[3 + c]));
        }
    }
}

/// Eq. 2 with the optional layers; absent ones contribute the exact identities (0 added, 1 times).
fn single(
    o: &mut [f32],
    p: &[f32],
    d: &[f32],
    s: Option<&[f32]>,
    a: Option<(&[f32], [f32; 3])>,
    e: Option<&[f32]>,
) {
    for (px, (o, p)) in o.chunks_exact_mut(3).zip(p.chunks_exact(6)).enumerate() {
        for c in 0..3 {
            let k = px * 3 + c;
            let ev = e.map_or(0.0, |e| clamp_fast(e[k]));
            let av = a.map_or(0.0, |(a, ca)| clamp_fast(a[k]) * ca[c]);
            let ms = s.map_or(1.0, |s| clamp_fast(s[k]));
            let dv = clamp_fast(d[k]) * clamp_fast(p[c]);
            o[c] = saturate((ev + av) + (dv + ms * clamp_fast(p[3 + c])));
        }
    }
}
