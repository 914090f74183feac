//! Compositor stages and data links: a chain like the paper's (each stage adds its nodes to the
//! upstream sum) or a tree (leaf stages accumulate nodes, stages above `join` pairs), with the
//! material and output operators at the last stage, which reads the node carrying the material
//! layers (a tree's root reads one node of its own for that, after its `join`). Operators are
//! the typed ones of `lightfold_protocol::pipeline` (`OpSpec`); a stage's operators read its inputs as a
//! fold: operator 0 the first inputs, each next one the previous output plus the next inputs.

use super::types::{DaemonSpec, Topology};
use super::types::{Downstream, FormatChoice, InputRef, LinkPlan, MaterialMode, Source, StagePlan};
use lightfold_protocol::pipeline::{
    AccumulateParams, AmbientFold, AmbientMask, BlendParams, DepthParams, JoinParams,
    MaterialParams, MaterialStage, MergeParams, NodeColor, OutputParams, PenumbraParams,
};
use lightfold_protocol::{Layer, OpSource, OpSpec, PixelFormat};
use std::ops::Range;

/// Framing cost of one band on a link: the band header plus the frame's kind and length.
pub const BAND_OVERHEAD_BYTES: u64 = lightfold_protocol::frame::BAND_PREFIX_LEN as u64;

/// An illumination node as the topology sees it.
#[derive(Debug, Clone)]
pub(crate) struct IllumInput {
    pub node: String,
    pub color: [f32; 3],
    pub layers: Vec<(Layer, PixelFormat)>,
    /// Estimated frame cost (µs): the cheapest node at the last stage hosts the material layers.
    pub cost: f64,
}

/// What the last stage does after the illumination sum.
#[derive(Debug, Clone)]
pub(crate) struct Finish {
    pub mode: MaterialMode,
    pub ambient: [f32; 3],
    pub ambient_layer: bool,
    pub emissive: bool,
    /// The material layers, and the node of their own that renders them (`None`: extra targets
    /// of an illumination node at the last stage, which `stages` picks).
    pub material_layers: Vec<(Layer, PixelFormat)>,
    pub material_node: Option<String>,
    /// Index into the illumination nodes of the node whose `c_n = c^a` folds the ambient term.
    pub fold: Option<usize>,
    /// Eq. 7: the folding node's input carries its ambient mask (`Layer::AmbientMask`), which
    /// `accumulate` reads (`AmbientMask::Layer`); `None`: eq. 6's `I^a = 1`.
    pub ambient_mask: Option<PixelFormat>,
    pub exposure: f32,
    /// The `penumbra` operator's parameters when the last stage filters the illumination sum
    /// (the depth layer travels with the material layers).
    pub penumbra: Option<PenumbraParams>,
}

/// Where a node streams: `(stage id, input index)`.
pub(crate) type Dest = (String, u32);

/// Where the material layers are rendered.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum MaterialSite {
    /// The material node of its own, streaming to this stage input.
    OwnNode(Dest),
    /// Extra targets of illumination node `nodes[i]` at the last stage.
    Host(usize),
}

/// Builds the stages. Returns them with, per illumination node, its destination, and where the
/// material layers are rendered.
pub(crate) fn stages(
    nodes: &[IllumInput],
    finish: &Finish,
    compositors: &[DaemonSpec],
    topology: Topology,
    formats: &FormatChoice,
) -> (Vec<StagePlan>, Vec<Dest>, MaterialSite) {
    let (tree_host, chunks) = leaf_chunks(nodes.len(), compositors.len(), finish, topology);
    let mut node_dst = vec![(String::new(), 0u32); nodes.len()];
    let mut stages = leaf_stages(
        nodes,
        finish,
        compositors,
        topology,
        formats.chain,
        &chunks,
        &mut node_dst,
    );
    if topology == Topology::Tree {
        // The leaves' partial sums joined pair by pair.
        let join = StagePlan {
            compositor: String::new(),
            wiring: Vec::new(),
            ops: vec![OpSpec::Join(JoinParams {
                inputs: 2,
                layer: Layer::Illumination,
            })],
            inputs: Vec::new(),
            outputs: vec![(Layer::Illumination, formats.chain)],
            downstream: Downstream::Sink,
            input_index: 0,
        };
        join_pairs(&mut stages, compositors, &join);
    }
    // The last stage built is the root: material and output follow its sum.
    let root = stages.last_mut().expect("at least one stage");
    let site = match tree_host {
        Some(h) => {
            node_dst[h] = host_on_tree_root(root, nodes, finish, h);
            MaterialSite::Host(h)
        }
        None => material_site(root, nodes, finish),
    };
    finish_root(root, finish, formats);
    (stages, node_dst, site)
}

/// How the illumination nodes spread over the leaf stages: the node a tree's root reads
/// itself for the material layers (when its root is a `join`), and the contiguous, even
/// chunks of the other nodes per leaf.
fn leaf_chunks(
    nodes: usize,
    compositors: usize,
    finish: &Finish,
    topology: Topology,
) -> (Option<usize>, Vec<Range<usize>>) {
    let c = compositors.max(1);
    // A tree whose root is a `join` reads no node, so its root also reads the last node itself
    // (`join` → `accumulate` → `material`), which carries the material layers.
    let tree_host = (topology == Topology::Tree
        && finish.material_node.is_none()
        && nodes.min(c.div_ceil(2)) >= 2)
        .then(|| nodes - 1);
    let spread = nodes - usize::from(tree_host.is_some());
    let n = spread.max(1);
    // (`Auto` is resolved before stages are built: `Topology::resolve`.)
    let leaves = match topology {
        Topology::Tree => n.min(c.div_ceil(2)),
        Topology::Chain | Topology::Auto => n.min(c),
    };
    // Contiguous, even chunks of nodes per leaf (earlier leaves take the extra ones).
    let mut chunks = Vec::with_capacity(leaves);
    let mut start = 0;
    for i in 0..leaves {
        let len = spread / leaves + usize::from(i < spread % leaves);
        chunks.push(start..start + len);
        start += len;
    }
    (tree_host, chunks)
}

/// `accumulate`'s parameters over the nodes in `range`, folding the ambient term where the
/// folding node is among them.
fn accumulate_range(
    nodes: &[IllumInput],
    finish: &Finish,
    range: &Range<usize>,
    upstream: bool,
) -> AccumulateParams {
    let fold = finish
        .fold
        .filter(|f| range.contains(f))
        .map(|f| f - range.start);
    accumulate_params(&nodes[range.clone()], finish, upstream, fold)
}

/// The leaf stages, one per chunk of nodes on the compositors in order, each summing its
/// nodes (after the upstream stage's sum along a chain); records in `node_dst` where each
/// node streams.
fn leaf_stages(
    nodes: &[IllumInput],
    finish: &Finish,
    compositors: &[DaemonSpec],
    topology: Topology,
    chain_fmt: PixelFormat,
    chunks: &[Range<usize>],
    node_dst: &mut [Dest],
) -> Vec<StagePlan> {
    let ill = |f: PixelFormat| vec![(Layer::Illumination, f)];
    let mut stages: Vec<StagePlan> = Vec::new();
    for (i, range) in chunks.iter().enumerate() {
        let id = compositors[i].id.clone();
        let upstream = topology == Topology::Chain && i > 0;
        let mut inputs = Vec::new();
        if upstream {
            inputs.push(InputRef {
                source: Source::Stage(stages[i - 1].compositor.clone()),
                layers: ill(chain_fmt),
            });
        }
        for (j, k) in range.clone().enumerate() {
            node_dst[k] = (id.clone(), (j + usize::from(upstream)) as u32);
            inputs.push(InputRef {
                source: Source::Node(nodes[k].node.clone()),
                layers: nodes[k].layers.clone(),
            });
        }
        if let (Topology::Chain, Some(prev)) = (topology, stages.last_mut()) {
            prev.downstream = Downstream::Stage(id.clone());
            prev.input_index = 0;
        }
        let ops = if range.is_empty() {
            Vec::new()
        } else {
            vec![OpSpec::Accumulate(accumulate_range(
                nodes, finish, range, upstream,
            ))]
        };
        stages.push(StagePlan {
            compositor: id,
            ops,
            wiring: Vec::new(),
            inputs,
            outputs: ill(chain_fmt),
            downstream: Downstream::Sink,
            input_index: 0,
        });
    }
    stages
}

/// Makes a tree's root read node `h` itself: it joins the two partial sums, adds that node,
/// then shades with its material layers. Returns where the node streams.
fn host_on_tree_root(
    root: &mut StagePlan,
    nodes: &[IllumInput],
    finish: &Finish,
    h: usize,
) -> Dest {
    let sum_inputs = root.inputs.len() as u32;
    let mut layers = nodes[h].layers.clone();
    layers.extend(finish.material_layers.iter().copied());
    root.inputs.push(InputRef {
        source: Source::Node(nodes[h].node.clone()),
        layers,
    });
    root.ops.push(OpSpec::Accumulate(accumulate_range(
        nodes,
        finish,
        &(h..h + 1),
        true,
    )));
    root.wiring = vec![
        (0..sum_inputs).map(OpSource::Input).collect(),
        vec![OpSource::Op(0), OpSource::Input(sum_inputs)],
        vec![OpSource::Op(1), OpSource::Input(sum_inputs)],
        vec![OpSource::Op(2)],
    ];
    (root.compositor.clone(), sum_inputs)
}

/// Adds the material layers to the root: as extra targets of the cheapest node it reads,
/// unless a node of their own is given, which then becomes another input.
fn material_site(root: &mut StagePlan, nodes: &[IllumInput], finish: &Finish) -> MaterialSite {
    let sum_inputs = root.inputs.len() as u32;
    // Extra targets of the cheapest node the root reads, unless a node of their own is given.
    let host = finish.material_node.is_none().then(|| {
        root.inputs
            .iter()
            .enumerate()
            .filter_map(|(j, i)| match &i.source {
                Source::Node(id) => nodes.iter().position(|n| &n.node == id).map(|k| (j, k)),
                Source::Stage(_) => None,
            })
            .min_by(|a, b| {
                nodes[a.1]
                    .cost
                    .total_cmp(&nodes[b.1].cost)
                    .then(a.1.cmp(&b.1))
            })
    });
    match (host.flatten(), &finish.material_node) {
        (Some((j, k)), _) => {
            root.inputs[j]
                .layers
                .extend(finish.material_layers.iter().copied());
            // The sum reads every input as before; `material` reads the sum and the host's
            // material layers, `output` the material's radiance.
            root.wiring = vec![
                (0..sum_inputs).map(OpSource::Input).collect(),
                vec![OpSource::Op(0), OpSource::Input(j as u32)],
                vec![OpSource::Op(1)],
            ];
            MaterialSite::Host(k)
        }
        (None, material_node) => {
            let node = material_node.clone().unwrap_or_default();
            root.inputs.push(InputRef {
                source: Source::Node(node),
                layers: finish.material_layers.clone(),
            });
            MaterialSite::OwnNode((root.compositor.clone(), sum_inputs))
        }
    }
}

/// `accumulate`'s parameters over `nodes` (after the upstream sum when `upstream`), with the
/// ambient term folded into `nodes[fold]`'s input when given.
fn accumulate_params(
    nodes: &[IllumInput],
    finish: &Finish,
    upstream: bool,
    fold: Option<usize>,
) -> AccumulateParams {
    AccumulateParams {
        colors: nodes.iter().map(|n| NodeColor::Rgb(n.color)).collect(),
        upstream,
        specular_color: match finish.mode {
            MaterialMode::UniformSpecular { specular } => Some(specular),
            _ => None,
        },
        ambient: fold.map(|f| AmbientFold {
            input: (f + usize::from(upstream)) as u32,
            mask: match finish.ambient_mask {
                Some(_) => AmbientMask::Layer,
                None => AmbientMask::Uniform,
            },
        }),
    }
}

/// The stages of a sort-last grid (`docs/planner.md` § Partitions): `parts[q]` are the nodes
/// drawing part q, one per light group, the first of them also carrying the eye depth and the
/// material layers of its part. A part's illumination is summed over its light groups
/// (`accumulate`) and put beside its first node's depth and material layers (`merge`); parts are
/// then depth-composed (`depth`, reading node eye depth: `zero_is_empty`), lower parts first, so
/// ties go to the lower part. Stages take contiguous runs of parts: along a chain, each
/// depth-composing the upstream stream with its own parts; in a tree, leaves compose their own
/// parts and stages above `depth`-join pairs of them. The last stage shades. Returns the stages
/// and, per part and node, where the node streams.
pub(crate) fn partition_stages(
    parts: &[Vec<IllumInput>],
    finish: &Finish,
    compositors: &[DaemonSpec],
    topology: Topology,
    formats: &FormatChoice,
) -> (Vec<StagePlan>, Vec<Vec<Dest>>) {
    let chain = topology == Topology::Chain;
    // A tree's leaves take runs of parts and `depth` joins pairs of them level by level (2·leaves
    // − 1 stages); a chain's stages each take a run and the upstream stream.
    let count = if chain {
        parts.len().min(compositors.len()).max(1)
    } else {
        parts.len().min(compositors.len().div_ceil(2)).max(1)
    };
    let chunks = even_runs(parts.len(), count);
    // What travels between stages: the eye depth with every layer it selects.
    // (The depth the penumbra filter reads is the composed one.)
    let material_kinds: Vec<Layer> = finish
        .material_layers
        .iter()
        .map(|l| l.0)
        .filter(|&l| l != Layer::Depth)
        .collect();
    let mut carried = vec![Layer::Illumination];
    carried.extend(&material_kinds);
    let mut own = vec![Layer::Depth];
    own.extend(&material_kinds);
    let format_of = |l: Layer| match l {
        Layer::Illumination => formats.chain,
        Layer::Depth => PixelFormat::DepthF32,
        other => finish
            .material_layers
            .iter()
            .find(|m| m.0 == other)
            .map_or(formats.material, |m| m.1),
    };
    let depth_params = |inputs: usize| {
        OpSpec::Depth(DepthParams {
            inputs: inputs as u32,
            layers: carried.clone(),
            reversed_z: false,
            zero_is_empty: true,
        })
    };
    let mut stages: Vec<StagePlan> = Vec::with_capacity(count);
    let mut dst: Vec<Vec<Dest>> = parts
        .iter()
        .map(|p| vec![(String::new(), 0); p.len()])
        .collect();
    for (i, chunk) in chunks.iter().enumerate() {
        let id = compositors[i].id.clone();
        let mut inputs = Vec::new();
        let mut ops: Vec<OpSpec> = Vec::new();
        let mut wiring: Vec<Vec<OpSource>> = Vec::new();
        let mut composed = Vec::new();
        if let Some(prev) = stages.last_mut().filter(|_| chain) {
            prev.downstream = Downstream::Stage(id.clone());
            prev.input_index = 0;
            inputs.push(InputRef {
                source: Source::Stage(prev.compositor.clone()),
                layers: prev.outputs.clone(),
            });
            composed.push(OpSource::Input(0));
        }
        for q in chunk.clone() {
            let first = inputs.len() as u32;
            for (j, n) in parts[q].iter().enumerate() {
                dst[q][j] = (id.clone(), inputs.len() as u32);
                inputs.push(InputRef {
                    source: Source::Node(n.node.clone()),
                    layers: n.layers.clone(),
                });
            }
            let last = inputs.len() as u32;
            ops.push(OpSpec::Accumulate(accumulate_params(
                &parts[q], finish, false, None,
            )));
            wiring.push((first..last).map(OpSource::Input).collect());
            ops.push(OpSpec::Merge(MergeParams {
                inputs: vec![vec![Layer::Illumination], own.clone()],
            }));
            wiring.push(vec![
                OpSource::Op(ops.len() as u32 - 2),
                OpSource::Input(first),
            ]);
            composed.push(OpSource::Op(ops.len() as u32 - 1));
        }
        let outputs: Vec<Layer> = if composed.len() > 1 {
            ops.push(depth_params(composed.len()));
            wiring.push(composed);
            std::iter::once(Layer::Depth)
                .chain(carried.iter().copied())
                .collect()
        } else {
            std::iter::once(Layer::Illumination)
                .chain(own.iter().copied())
                .collect()
        };
        stages.push(StagePlan {
            compositor: id,
            ops,
            wiring,
            inputs,
            outputs: outputs.into_iter().map(|l| (l, format_of(l))).collect(),
            downstream: Downstream::Sink,
            input_index: 0,
        });
    }
    if !chain {
        // Join adjacent pairs level by level, the lower parts first (ties go to them); an odd
        // stage moves up unchanged.
        let joined: Vec<Layer> = std::iter::once(Layer::Depth)
            .chain(carried.iter().copied())
            .collect();
        let join = StagePlan {
            compositor: String::new(),
            ops: vec![depth_params(2)],
            wiring: vec![vec![OpSource::Input(0), OpSource::Input(1)]],
            inputs: Vec::new(),
            outputs: joined.iter().map(|&l| (l, format_of(l))).collect(),
            downstream: Downstream::Sink,
            input_index: 0,
        };
        join_pairs(&mut stages, compositors, &join);
    }
    let root = stages.last_mut().expect("at least one stage");
    // `material` reads the sum and the material layers, both in the composed stream.
    let composed = OpSource::Op(root.ops.len() as u32 - 1);
    root.wiring.push(vec![composed, composed]);
    root.wiring.push(vec![OpSource::Op(root.ops.len() as u32)]);
    finish_root(root, finish, formats);
    (stages, dst)
}

/// The stages of a peeled plan (`docs/translucency.md` § Peeled layers): `layers[q]` are the
/// nodes rendering eye layer q, back to front (the opaque layer first, the nearest translucent
/// layer last), one per light group, the first of them also carrying the layer's material layers
/// and, for a translucent layer, its transmittance. Each layer's illumination is summed over its
/// groups (`accumulate`) and shaded with its own material layers (`material`: its radiance,
/// premultiplied by its coverage); a translucent layer's radiance is put beside its
/// transmittance (`merge`), and `blend` lays the layers over one another in order. Stages take
/// contiguous runs of layers along a chain (the back first), each blending its own over the
/// upstream radiance ("over" is applied in order, so a tree would need the combined
/// transmittance too: peeled plans chain); the last stage applies the exposure. Returns the
/// stages and, per layer and node, where the node streams.
pub(crate) fn peeled_stages(
    layers: &[Vec<IllumInput>],
    translucent: &[bool],
    finish: &Finish,
    compositors: &[DaemonSpec],
    formats: &FormatChoice,
) -> (Vec<StagePlan>, Vec<Vec<Dest>>) {
    let count = layers.len().min(compositors.len()).max(1);
    let mut dst: Vec<Vec<Dest>> = layers
        .iter()
        .map(|l| vec![(String::new(), 0); l.len()])
        .collect();
    let mut stages: Vec<StagePlan> = Vec::with_capacity(count);
    for (run, compositor) in even_runs(layers.len(), count).into_iter().zip(compositors) {
        let id = compositor.id.clone();
        let mut inputs = Vec::new();
        let mut ops: Vec<OpSpec> = Vec::new();
        let mut wiring: Vec<Vec<OpSource>> = Vec::new();
        // What `blend` lays over one another, back to front.
        let mut over = Vec::new();
        if let Some(prev) = stages.last_mut() {
            prev.downstream = Downstream::Stage(id.clone());
            prev.input_index = 0;
            inputs.push(InputRef {
                source: Source::Stage(prev.compositor.clone()),
                layers: prev.outputs.clone(),
            });
            over.push(OpSource::Input(0));
        }
        for q in run {
            let first = inputs.len() as u32;
            for (j, n) in layers[q].iter().enumerate() {
                dst[q][j] = (id.clone(), inputs.len() as u32);
                inputs.push(InputRef {
                    source: Source::Node(n.node.clone()),
                    layers: n.layers.clone(),
                });
            }
            let last = inputs.len() as u32;
            ops.push(OpSpec::Accumulate(accumulate_params(
                &layers[q], finish, false, None,
            )));
            wiring.push((first..last).map(OpSource::Input).collect());
            ops.push(material_params(finish));
            wiring.push(vec![
                OpSource::Op(ops.len() as u32 - 2),
                OpSource::Input(first),
            ]);
            if translucent[q] {
                ops.push(OpSpec::Merge(MergeParams {
                    inputs: vec![vec![Layer::Radiance], vec![Layer::Transmittance]],
                }));
                wiring.push(vec![
                    OpSource::Op(ops.len() as u32 - 2),
                    OpSource::Input(first),
                ]);
            }
            over.push(OpSource::Op(ops.len() as u32 - 1));
        }
        if over.len() > 1 {
            ops.push(OpSpec::Blend(BlendParams {
                inputs: over.len() as u32,
            }));
            wiring.push(over);
        }
        stages.push(StagePlan {
            compositor: id,
            ops,
            wiring,
            inputs,
            outputs: vec![(Layer::Radiance, formats.sink)],
            downstream: Downstream::Sink,
            input_index: 0,
        });
    }
    let root = stages.last_mut().expect("at least one stage");
    root.ops.push(OpSpec::Output(OutputParams {
        exposure: finish.exposure,
    }));
    root.wiring
        .push(vec![OpSource::Op(root.ops.len() as u32 - 2)]);
    (stages, dst)
}

/// `n` items in `count` contiguous runs, the first `n % count` one longer (`count` ≥ 1).
fn even_runs(n: usize, count: usize) -> Vec<Range<usize>> {
    let mut start = 0;
    (0..count)
        .map(|i| {
            let len = n / count + usize::from(i < n % count);
            start += len;
            start - len..start
        })
        .collect()
}

/// Joins `stages` (the leaves) pair by pair, level by level, on the next compositors: each join
/// is `join` with the pair as its inputs 0 and 1 (each carrying what that stage sends), on a
/// compositor of its own; an odd stage moves up unchanged. The last stage is the root.
fn join_pairs(stages: &mut Vec<StagePlan>, compositors: &[DaemonSpec], join: &StagePlan) {
    let mut level: Vec<usize> = (0..stages.len()).collect();
    let mut next = stages.len();
    while level.len() > 1 {
        let mut up = Vec::new();
        for pair in level.chunks(2) {
            if pair.len() == 1 {
                up.push(pair[0]);
                continue;
            }
            let id = compositors[next].id.clone();
            next += 1;
            let mut inputs = Vec::new();
            for (j, &k) in pair.iter().enumerate() {
                stages[k].downstream = Downstream::Stage(id.clone());
                stages[k].input_index = j as u32;
                inputs.push(InputRef {
                    source: Source::Stage(stages[k].compositor.clone()),
                    layers: stages[k].outputs.clone(),
                });
            }
            stages.push(StagePlan {
                compositor: id,
                inputs,
                ..join.clone()
            });
            up.push(stages.len() - 1);
        }
        level = up;
    }
}

/// The one `material` stage (eq. 2) that shades the illumination sum with the material layers.
fn material_params(finish: &Finish) -> OpSpec {
    OpSpec::Material(MaterialParams {
        stage: MaterialStage::Single,
        ambient_color: finish.ambient_layer.then_some(finish.ambient),
        specular: matches!(finish.mode, MaterialMode::General),
        emissive: finish.emissive,
    })
}

/// Appends `material` and `output` to the root stage, which sends radiance to the sink.
fn finish_root(root: &mut StagePlan, finish: &Finish, formats: &FormatChoice) {
    root.ops.push(material_params(finish));
    root.ops.push(OpSpec::Output(OutputParams {
        exposure: finish.exposure,
    }));
    root.outputs = vec![(Layer::Radiance, formats.sink)];
    root.downstream = Downstream::Sink;
    if let Some(params) = &finish.penumbra {
        insert_penumbra(root, params.clone());
    }
}

/// Puts the `penumbra` operator between the illumination sum and `material`: it reads what
/// `material` read (the sum, and the input with the material layers, whose depth it needs), and
/// `material` reads its output.
fn insert_penumbra(root: &mut StagePlan, params: PenumbraParams) {
    let Some(mi) = root
        .ops
        .iter()
        .position(|o| matches!(o, OpSpec::Material(_)))
    else {
        return;
    };
    if root.wiring.is_empty() {
        // The fold made explicit (the material layers' own node is the last input):
        // `accumulate` reads the others, `material` its sum and that node, `output` the rest.
        let last = root.inputs.len() as u32 - 1;
        root.wiring = vec![
            (0..last).map(OpSource::Input).collect(),
            vec![OpSource::Op(0), OpSource::Input(last)],
            vec![OpSource::Op(1)],
        ];
    }
    let reads = root.wiring[mi].clone();
    let Some(&material_input) = reads.get(1) else {
        return;
    };
    for sources in root.wiring.iter_mut().skip(mi + 1) {
        for s in sources.iter_mut() {
            if let OpSource::Op(k) = s
                && *k >= mi as u32
            {
                *k += 1;
            }
        }
    }
    root.ops.insert(mi, OpSpec::Penumbra(params));
    root.wiring.insert(mi, reads);
    root.wiring[mi + 1] = vec![OpSource::Op(mi as u32), material_input];
}

/// Bytes of one frame of these layers at this size and band height, band framing included.
pub(crate) fn frame_bytes(
    layers: &[(Layer, PixelFormat)],
    w: u32,
    h: u32,
    band_height: u32,
) -> u64 {
    let bands = u64::from(h.div_ceil(band_height.max(1)));
    layers
        .iter()
        .map(|(_, f)| {
            u64::from(w) * u64::from(h) * f.bytes_per_pixel() as u64 + bands * BAND_OVERHEAD_BYTES
        })
        .sum()
}

/// One link per stage input, plus the sink link.
pub(crate) fn links(
    stages: &[StagePlan],
    address_of: impl Fn(&str) -> String,
    sink: &str,
    (w, h, band_height): (u32, u32, u32),
) -> Vec<LinkPlan> {
    let mut out = Vec::new();
    for s in stages {
        for i in &s.inputs {
            let from = match &i.source {
                Source::Node(n) | Source::Stage(n) => n.clone(),
            };
            out.push(LinkPlan {
                from,
                to: s.compositor.clone(),
                address: address_of(&s.compositor),
                layers: i.layers.clone(),
                bytes_per_frame: frame_bytes(&i.layers, w, h, band_height),
            });
        }
        if s.downstream == Downstream::Sink {
            out.push(LinkPlan {
                from: s.compositor.clone(),
                to: "sink".to_string(),
                address: sink.to_string(),
                layers: s.outputs.clone(),
                bytes_per_frame: frame_bytes(&s.outputs, w, h, band_height),
            });
        }
    }
    out
}
