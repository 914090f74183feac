//! Prints the precision study's tables (docs/precision.md): a 32-stage accumulate chain whose
//! partial sum is re-packed at every hop, per link format, on HDR and dark content.
//!
//! ```sh
//! cargo bench -p lightfold-compositor --bench precision
//! ```

use lightfold_compositor::ops::precision::study::{self, Content, Outcome, Scale, Setup};
use lightfold_protocol::PixelFormat;

const PIXELS: usize = 65_536;
const STAGES: usize = 32;

fn label(f: PixelFormat, s: Scale) -> String {
    match (f, s) {
        (PixelFormat::Seed64, Scale::Fixed(v)) => format!("seed64, fixed scale {v}"),
        (PixelFormat::Seed64, Scale::TrueMax) => "seed64, scale = true max".into(),
        (f, _) => f.name().into(),
    }
}

/// One table row; `saturated` is the chain's last hop or, for node links, the node bands.
fn row(name: &str, content: Content, o: &Outcome, saturated: u64, of: usize) {
    println!(
        "| {name} | {content:?} | {:.2e} | {:.2e} | {:+.2e} | {saturated} ({:.1} %) | {} / {} |",
        o.rms_rel,
        o.max_rel,
        o.energy_bias,
        100.0 * saturated as f64 / of as f64,
        o.dark_lost,
        o.dark,
    );
}

fn header(first: &str, saturated: &str) {
    println!(
        "| {first} | content | RMS rel. error | max rel. error | energy bias | {saturated} | dark px lost |"
    );
    println!("|---|---|---|---|---|---|---|");
}

fn run(
    content: Content,
    node: Option<(PixelFormat, Scale)>,
    chain: (PixelFormat, Scale),
) -> Outcome {
    study::run(&Setup {
        content,
        stages: STAGES,
        pixels: PIXELS,
        node,
        chain,
        seed: 2026,
    })
    .expect("study formats and scales are valid")
}

fn main() {
    let fixed = Scale::Fixed(1.0);
    let max = Scale::TrueMax;
    let formats = [
        (PixelFormat::Seed64, fixed),
        (PixelFormat::Seed64, max),
        (PixelFormat::Rgb9e5x2, max),
        (PixelFormat::F16x6, max),
        (PixelFormat::F32x6, max),
    ];
    println!("### Compositor → compositor: {STAGES} hops, node links exact, {PIXELS} pixels\n");
    header("chain link", "saturated px");
    for content in [Content::Hdr, Content::Dark] {
        for (f, s) in formats {
            let o = run(content, None, (f, s));
            assert_eq!(o.over_bound, 0, "{f:?} exceeds chain_bound");
            row(&label(f, s), content, &o, o.saturated, PIXELS);
        }
    }
    println!("\n### Node → compositor: each node's band packed once, chain in f32x6\n");
    header("node link", "saturated node px");
    for content in [Content::Hdr, Content::Dark] {
        for (f, s) in &formats[..4] {
            let o = run(content, Some((*f, *s)), (PixelFormat::F32x6, max));
            row(
                &label(*f, *s),
                content,
                &o,
                o.node_saturated,
                PIXELS * STAGES,
            );
        }
    }
    println!("\n### The recommended formats end to end (rgb9e5x2 nodes, f16x6 chain)\n");
    header("links", "saturated px");
    for content in [Content::Hdr, Content::Dark] {
        let o = run(
            content,
            Some((PixelFormat::Rgb9e5x2, max)),
            (PixelFormat::F16x6, max),
        );
        row(
            "rgb9e5x2 → f16x6",
            content,
            &o,
            o.saturated + o.node_saturated,
            PIXELS,
        );
    }
}
