//! Associativity in practice: 32 nodes summed by a chain of accumulate stages (the paper's
//! pipeline) and by a tree (pairs, then binary joins) agree within 1e-6 relative, and both are
//! within the f32 rounding bound of the exact sum; the same topology gives the same bits run to
//! run, on one thread or many.

use crate::common;

use common::{Owned, assert_same_bits, rng, run};
use lightfold_compositor::ops;
use lightfold_protocol::Layer;
use rand::Rng;
use serde_json::json;

const NODES: usize = 32;
const PIXELS: usize = 40_000;

struct Scene {
    nodes: Vec<Owned>,
    colors: Vec<[f32; 3]>,
}

/// Node illumination: `hdr` spreads pixels log-uniformly over 1e4 : 1, else values in [0, 4).
fn scene(seed: u64, hdr: bool) -> Scene {
    let mut r = rng(seed);
    let nodes = (0..NODES)
        .map(|_| {
            let data = (0..PIXELS * 6)
                .map(|_| {
                    if hdr {
                        10f32.powf(r.random_range(-4.0..0.0f32))
                    } else {
                        r.random_range(0.0..4.0f32)
                    }
                })
                .collect();
            Owned {
                pixels: PIXELS,
                layers: vec![(Layer::Illumination, data)],
            }
        })
        .collect();
    let colors = (0..NODES)
        .map(|_| std::array::from_fn(|_| r.random_range(0.2..1.5f32)))
        .collect();
    Scene { nodes, colors }
}

fn chain(s: &Scene) -> Owned {
    let first = ops::create(
        "accumulate",
        &json!({"upstream": false, "colors": [s.colors[0]]}),
    );
    let mut p = run(&*first.unwrap(), &s.nodes[..1], PIXELS, false);
    for n in 1..NODES {
        let op = ops::create("accumulate", &json!({"colors": [s.colors[n]]})).unwrap();
        p = run(&*op, &[p, s.nodes[n].clone()], PIXELS, false);
    }
    p
}

fn tree(s: &Scene) -> Owned {
    let mut level: Vec<Owned> = (0..NODES / 2)
        .map(|k| {
            let op = ops::create(
                "accumulate",
                &json!({"upstream": false, "colors": [s.colors[2 * k], s.colors[2 * k + 1]]}),
            )
            .unwrap();
            run(&*op, &s.nodes[2 * k..2 * k + 2], PIXELS, false)
        })
        .collect();
    let join = ops::create("join", &json!({"inputs": 2})).unwrap();
    while level.len() > 1 {
        level = level
            .chunks(2)
            .map(|pair| run(&*join, pair, PIXELS, false))
            .collect();
    }
    level.pop().unwrap()
}

/// The exact sum in f64 of the f32 products `c_n ⊙ I_n`.
fn exact(s: &Scene) -> Vec<f64> {
    let mut sum = vec![0f64; PIXELS * 6];
    for (node, c) in s.nodes.iter().zip(&s.colors) {
        for (k, v) in node.layer(Layer::Illumination).iter().enumerate() {
            sum[k] += f64::from(c[k % 6 % 3] * v);
        }
    }
    sum
}

#[test]
fn chain_and_tree_agree() {
    for (seed, hdr) in [(1, false), (2, true)] {
        let s = scene(seed, hdr);
        let (c, t, e) = (chain(&s), tree(&s), exact(&s));
        let (c, t) = (c.layer(Layer::Illumination), t.layer(Layer::Illumination));
        let mut worst = (0f64, 0f64);
        for k in 0..PIXELS * 6 {
            let rel = (f64::from(c[k]) - f64::from(t[k])).abs() / e[k];
            worst.0 = worst.0.max(rel);
            // Each of the 31 additions rounds by at most half an ulp of the running sum.
            let vs_exact = (f64::from(c[k]) - e[k]).abs() / e[k];
            worst.1 = worst.1.max(vs_exact);
        }
        println!(
            "hdr={hdr}: chain vs tree {:.2e}, chain vs exact {:.2e}",
            worst.0, worst.1
        );
        assert!(
            worst.0 <= 1e-6,
            "hdr={hdr}: chain and tree differ by {:e}",
            worst.0
        );
        assert!(
            worst.1 <= 31.0 * f64::from(f32::EPSILON) / 2.0,
            "{:e}",
            worst.1
        );
    }
}

#[test]
fn same_topology_same_bits() {
    let s = scene(3, true);
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let many = rayon::ThreadPoolBuilder::new()
        .num_threads(4)
        .build()
        .unwrap();
    let a = one.install(|| chain(&s));
    let b = many.install(|| chain(&s));
    let c = chain(&s);
    assert_same_bits(&a, &b, "chain, 1 vs 4 threads");
    assert_same_bits(&a, &c, "chain, run to run");
    let t1 = one.install(|| tree(&s));
    let t2 = many.install(|| tree(&s));
    assert_same_bits(&t1, &t2, "tree, 1 vs 4 threads");
}
