//! The precision study's conclusions, held as tests: over a 32-hop chain a fixed-scale `seed64`
//! link saturates HDR highlights and loses dark pixels, `f16x6` keeps both, the recommended
//! formats stay within their figures, and every chain stays within `chain_bound`.

use lightfold_compositor::ops::precision::study::{self, Content, Outcome, Scale, Setup};
use lightfold_compositor::ops::{LinkFormat, LinkKind, chain_bound, recommended_link_format};
use lightfold_protocol::PixelFormat;

const PIXELS: usize = 8192;

fn study(
    content: Content,
    node: Option<(PixelFormat, Scale)>,
    chain: (PixelFormat, Scale),
) -> Outcome {
    study::run(&Setup {
        content,
        stages: 32,
        pixels: PIXELS,
        node,
        chain,
        seed: 42,
    })
    .unwrap()
}

const CHAINS: [(PixelFormat, Scale); 5] = [
    (PixelFormat::Seed64, Scale::Fixed(1.0)),
    (PixelFormat::Seed64, Scale::TrueMax),
    (PixelFormat::Rgb9e5x2, Scale::TrueMax),
    (PixelFormat::F16x6, Scale::TrueMax),
    (PixelFormat::F32x6, Scale::TrueMax),
];

#[test]
fn fixed_scale_ten_bit_chain_saturates_and_drops_darks() {
    let hdr = study(Content::Hdr, None, CHAINS[0]);
    assert!(hdr.saturated > PIXELS as u64 / 3, "{hdr:?}");
    assert!(hdr.energy_bias < -0.5, "{hdr:?}");
    let dark = study(Content::Dark, None, CHAINS[0]);
    assert!(dark.dark_lost * 10 > dark.dark * 9, "{dark:?}");
    // A scale from the true maximum avoids saturation but still loses HDR darks.
    let hdr = study(Content::Hdr, None, CHAINS[1]);
    assert_eq!(hdr.saturated, 0);
    assert!(hdr.dark_lost * 10 > hdr.dark * 9, "{hdr:?}");
}

#[test]
fn half_floats_keep_highlights_and_darks() {
    for content in [Content::Hdr, Content::Dark] {
        let o = study(content, None, CHAINS[3]);
        assert_eq!((o.saturated, o.dark_lost), (0, 0), "{content:?} {o:?}");
        assert!(o.energy_bias.abs() < 1e-4, "{content:?} {o:?}");
    }
    assert!(study(Content::Hdr, None, CHAINS[3]).rms_rel < 1e-3);
    assert!(study(Content::Dark, None, CHAINS[3]).rms_rel < 2e-2);
}

#[test]
fn every_chain_within_its_bound() {
    for content in [Content::Hdr, Content::Dark] {
        for chain in CHAINS {
            let o = study(content, None, chain);
            assert_eq!(o.over_bound, 0, "{content:?} {chain:?} {o:?}");
        }
    }
}

#[test]
fn recommended_formats_end_to_end() {
    let node = recommended_link_format(LinkKind::NodeToCompositor);
    let link = recommended_link_format(LinkKind::CompositorToCompositor);
    assert_eq!((node, link), (PixelFormat::Rgb9e5x2, PixelFormat::F16x6));
    assert_eq!(
        recommended_link_format(LinkKind::SinkToCoordinator),
        PixelFormat::F32x3
    );
    for content in [Content::Hdr, Content::Dark] {
        let o = study(
            content,
            Some((node, Scale::TrueMax)),
            (link, Scale::TrueMax),
        );
        assert_eq!((o.saturated, o.dark_lost), (0, 0), "{content:?} {o:?}");
        assert!(
            o.rms_rel < 2e-2 && o.energy_bias.abs() < 1e-3,
            "{content:?} {o:?}"
        );
    }
}

#[test]
fn chain_bound_shape() {
    let f16 = |hops, v| chain_bound(PixelFormat::F16x6, hops, v);
    // Grows with hops and value; half an f16 ulp (2^-11 relative) plus f32 rounding per hop.
    assert!(f16(1, 1.0) < f16(2, 1.0) && f16(32, 1.0) < f16(32, 2.0));
    assert!(f16(1, 1.0) >= 2f32.powi(-11) && f16(1, 1.0) < 2f32.powi(-10));
    assert!(f16(32, 1.0) < 0.035);
    assert_eq!(f16(32, 70000.0), f32::INFINITY);
    assert_eq!(f16(32, f32::NAN), f32::INFINITY);
    assert_eq!(f16(0, 1.0), 0.0);
    // seed64: half a 10-bit step of the scale per hop, infinite above the scale.
    let s = LinkFormat::new(PixelFormat::Seed64, 4.0);
    assert!(chain_bound(s, 1, 1.0) >= 4.0 / 2046.0);
    assert_eq!(chain_bound(s, 1, 4.5), f32::INFINITY);
    // f32: rounding only.
    assert!(chain_bound(PixelFormat::F32x6, 32, 1.0) < 32.0 * f32::EPSILON);
}
