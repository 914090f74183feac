//! Strategies for every control message, hello, proof and band frame, shared by the round-trip
//! property tests and the mutation test. `variant` names each `Message` variant through an
//! exhaustive match, so adding a variant without a strategy here fails to compile.

use bytes::Bytes;
use lightfold_protocol::format::PixelFormat;
use lightfold_protocol::pipeline::*;
use lightfold_protocol::*;
use proptest::prelude::*;

/// Every `Message` variant, in declaration order.
pub(crate) const VARIANTS: [&str; 17] = [
    "Register",
    "SceneOffer",
    "SceneNeed",
    "SceneChunk",
    "SceneReady",
    "ConfigureNode",
    "ConfigureCompositor",
    "Configured",
    "RenderFrame",
    "FrameDone",
    "Error",
    "Ping",
    "Pong",
    "Shutdown",
    "Claim",
    "Claimed",
    "Release",
];

pub(crate) fn variant(m: &Message) -> &'static str {
    match m {
        Message::Register(_) => "Register",
        Message::SceneOffer { .. } => "SceneOffer",
        Message::SceneNeed { .. } => "SceneNeed",
        Message::SceneChunk { .. } => "SceneChunk",
        Message::SceneReady { .. } => "SceneReady",
        Message::ConfigureNode(_) => "ConfigureNode",
        Message::ConfigureCompositor(_) => "ConfigureCompositor",
        Message::Configured { .. } => "Configured",
        Message::RenderFrame { .. } => "RenderFrame",
        Message::FrameDone(_) => "FrameDone",
        Message::Error { .. } => "Error",
        Message::Release { .. } => "Release",
        Message::Ping { .. } => "Ping",
        Message::Pong { .. } => "Pong",
        Message::Shutdown => "Shutdown",
        Message::Claim { .. } => "Claim",
        Message::Claimed { .. } => "Claimed",
    }
}

/// Any f32 but NaN (so `PartialEq` can judge a round trip).
pub(crate) fn num() -> impl Strategy<Value = f32> {
    prop_oneof![
        3 => -1.0e4f32..1.0e4,
        1 => prop::num::f32::NORMAL | prop::num::f32::SUBNORMAL | prop::num::f32::ZERO | prop::num::f32::INFINITE,
    ]
}

pub(crate) fn v3() -> impl Strategy<Value = [f32; 3]> {
    prop::array::uniform3(num())
}

pub(crate) fn text() -> impl Strategy<Value = String> {
    prop_oneof![3 => "[a-z0-9:./-]{0,24}", 1 => ".{0,12}"]
}

pub(crate) fn role() -> impl Strategy<Value = Role> {
    prop::sample::select(vec![
        Role::Coordinator,
        Role::Node,
        Role::Compositor,
        Role::Viewer,
    ])
}

pub(crate) fn layer() -> impl Strategy<Value = Layer> {
    prop::sample::select(Layer::ALL.to_vec())
}

pub(crate) fn format() -> impl Strategy<Value = PixelFormat> {
    prop::sample::select(PixelFormat::ALL.to_vec())
}

pub(crate) fn layers() -> impl Strategy<Value = Vec<(Layer, PixelFormat)>> {
    prop::collection::vec((layer(), format()), 0..4)
}

pub(crate) fn camera() -> impl Strategy<Value = WireCamera> {
    (v3(), v3(), v3(), num(), any::<u32>(), any::<u32>()).prop_map(
        |(position, target, up, fov_y_deg, width, height)| WireCamera {
            position,
            target,
            up,
            fov_y_deg,
            width,
            height,
        },
    )
}

pub(crate) fn light() -> impl Strategy<Value = WireLight> {
    (
        v3(),
        v3(),
        any::<u8>(),
        prop::array::uniform2(num()),
        num(),
        v3(),
        num(),
        any::<(u32, u32)>(),
        prop::option::of((any::<u8>(), v3(), v3(), v3())),
        num(),
    )
        .prop_map(
            |(
                position,
                direction,
                kind,
                cone,
                intensity,
                color,
                range,
                (light, sample),
                area,
                cell,
            )| {
                WireLight {
                    position,
                    direction,
                    kind,
                    cone,
                    intensity,
                    color,
                    range,
                    light,
                    sample,
                    area: area.map(|(kind, center, u, v)| WireArea { kind, center, u, v }),
                    cell,
                }
            },
        )
}

pub(crate) fn capabilities() -> impl Strategy<Value = Capabilities> {
    (
        (role(), text(), text(), text(), text()),
        (
            any::<u32>(),
            any::<u32>(),
            prop::collection::vec(format(), 0..9),
            text(),
            text(),
        ),
        (
            any::<u64>(),
            any::<u64>(),
            any::<u32>(),
            text(),
            any::<u64>(),
            any::<u64>(),
        ),
    )
        .prop_map(
            |(
                (role, daemon_id, advertise, adapter, backend),
                (max_lights, max_texture_size, formats, device, cpu_host),
                (cost_per_light_us, fixed_cost_us, threads, version, memory_bytes, eye_ns),
            )| Capabilities {
                role,
                daemon_id,
                advertise,
                adapter,
                backend,
                device,
                cpu_host,
                max_lights,
                max_texture_size,
                formats,
                cost_per_light_us,
                fixed_cost_us,
                threads,
                version,
                memory_bytes,
                eye_ns_per_triangle: eye_ns,
            },
        )
}

pub(crate) fn node_config() -> impl Strategy<Value = NodeConfig> {
    let shadow = (
        any::<u32>(),
        any::<u32>(),
        prop::collection::vec(any::<u32>(), 0..6),
    )
        .prop_map(|(light, map_size, casters)| WireShadow {
            light,
            map_size,
            casters,
        });
    (
        (
            any::<u64>(),
            any::<[u8; 32]>(),
            prop::collection::vec(light(), 0..4),
        ),
        (
            prop::collection::vec(shadow, 0..3),
            v3(),
            layers(),
            num(),
            any::<u32>(),
        ),
        (
            camera(),
            any::<bool>(),
            text(),
            any::<u32>(),
            any::<u32>(),
            num(),
            num(),
        ),
        prop::option::of(prop::collection::vec(any::<u32>(), 0..4)),
        prop::collection::vec(
            (any::<u32>(), prop::array::uniform16(num()))
                .prop_map(|(mesh, matrix)| WireMove { mesh, matrix }),
            0..3,
        ),
        (
            prop::option::of(any::<[u32; 2]>()),
            prop::option::of(any::<u32>()),
        ),
    )
        .prop_map(
            |(
                (epoch, scene, lights),
                (shadows, color, layers, scale, band_height),
                (camera, walkthrough, downstream, input_index, filter, depth_bias, slope_bias),
                eye_meshes,
                moves,
                (rows, peel),
            )| NodeConfig {
                epoch,
                scene,
                lights,
                shadows,
                color,
                layers,
                scale,
                band_height,
                camera,
                walkthrough,
                downstream,
                input_index,
                filter,
                depth_bias,
                slope_bias,
                eye_meshes,
                moves,
                rows,
                peel,
            },
        )
}

pub(crate) fn node_color() -> impl Strategy<Value = NodeColor> {
    prop_oneof![
        v3().prop_map(NodeColor::Rgb),
        (v3(), v3()).prop_map(|(diffuse, specular)| NodeColor::Split { diffuse, specular }),
    ]
}

pub(crate) fn op_layers() -> impl Strategy<Value = Vec<Layer>> {
    prop::collection::vec(layer(), 0..4)
}

/// Any operator with any parameters (valid or not: the wire carries both).
pub(crate) fn op_spec() -> impl Strategy<Value = OpSpec> {
    let ambient = prop::option::of(
        (
            any::<u32>(),
            prop::sample::select(vec![AmbientMask::Uniform, AmbientMask::Layer]),
        )
            .prop_map(|(input, mask)| AmbientFold { input, mask }),
    );
    let stage = prop::sample::select(vec![
        MaterialStage::Specular,
        MaterialStage::Diffuse,
        MaterialStage::Ambient,
        MaterialStage::Emissive,
        MaterialStage::Single,
    ]);
    prop_oneof![
        (
            prop::collection::vec(node_color(), 0..4),
            any::<bool>(),
            prop::option::of(v3()),
            ambient
        )
            .prop_map(|(colors, upstream, specular_color, ambient)| {
                OpSpec::Accumulate(AccumulateParams {
                    colors,
                    upstream,
                    specular_color,
                    ambient,
                })
            }),
        (stage, prop::option::of(v3()), any::<bool>(), any::<bool>()).prop_map(
            |(stage, ambient_color, specular, emissive)| OpSpec::Material(MaterialParams {
                stage,
                ambient_color,
                specular,
                emissive,
            })
        ),
        (any::<u32>(), op_layers(), any::<bool>(), any::<bool>()).prop_map(
            |(inputs, layers, reversed_z, zero_is_empty)| OpSpec::Depth(DepthParams {
                inputs,
                layers,
                reversed_z,
                zero_is_empty,
            })
        ),
        (any::<u32>(), layer())
            .prop_map(|(inputs, layer)| OpSpec::Join(JoinParams { inputs, layer })),
        prop::collection::vec(op_layers(), 0..4)
            .prop_map(|inputs| OpSpec::Merge(MergeParams { inputs })),
        num().prop_map(|exposure| OpSpec::Output(OutputParams { exposure })),
        (
            (any::<u32>(), any::<u32>(), num()),
            (prop::option::of(num()), any::<bool>(), any::<bool>())
        )
            .prop_map(
                |((width, radius, depth_tolerance), (crease_tolerance, specular, tent))| {
                    OpSpec::Penumbra(PenumbraParams {
                        width,
                        radius,
                        depth_tolerance,
                        crease_tolerance,
                        specular,
                        kernel: if tent { Kernel::Tent } else { Kernel::Box },
                    })
                }
            ),
        any::<u32>().prop_map(|inputs| OpSpec::Blend(BlendParams { inputs })),
    ]
}

pub(crate) fn compositor_config() -> impl Strategy<Value = CompositorConfig> {
    let input = (text(), layers()).prop_map(|(peer, layers)| StageInput { peer, layers });
    (
        (any::<u64>(), any::<u32>(), any::<u32>(), any::<u32>()),
        (
            prop::collection::vec(input, 0..3),
            prop::collection::vec(op_spec(), 0..3),
            prop::collection::vec(
                prop::collection::vec(
                    prop_oneof![
                        any::<u32>().prop_map(OpSource::Input),
                        any::<u32>().prop_map(OpSource::Op)
                    ],
                    0..3,
                ),
                0..3,
            ),
        ),
        (layers(), text(), any::<u32>(), any::<u32>()),
    )
        .prop_map(
            |(
                (epoch, width, height, band_height),
                (inputs, ops, wiring),
                (outputs, downstream, input_index, frames_in_flight),
            )| CompositorConfig {
                epoch,
                width,
                height,
                band_height,
                inputs,
                ops,
                wiring,
                outputs,
                downstream,
                input_index,
                frames_in_flight,
            },
        )
}

pub(crate) fn frame_stats() -> impl Strategy<Value = FrameStats> {
    (
        (any::<u64>(), any::<u64>(), text(), any::<[u64; 7]>()),
        (any::<u32>(), prop::collection::vec(any::<u32>(), 0..8)),
        (any::<u64>(), any::<u32>(), any::<u64>(), any::<u64>()),
    )
        .prop_map(
            |(
                (epoch, frame, daemon_id, t),
                (shadow_passes, lights_rendered),
                (bytes_out, empty_bands, saturated, peak_rss_bytes),
            )| FrameStats {
                epoch,
                frame,
                daemon_id,
                setup_us: t[5] / 7,
                shadow_us: t[0],
                eye_us: t[1],
                readback_us: t[2],
                read_bytes: bytes_out / 3,
                prefetched: empty_bands % 2 == 1,
                pack_us: t[3],
                send_us: t[4],
                composite_us: t[5],
                total_us: t[6],
                shadow_passes,
                maps_kept: shadow_passes / 2,
                pose_us: t[0] / 3,
                lights_rendered,
                bytes_out,
                empty_bands,
                saturated,
                peak: (t[1] % 4096) as f32 / 8.0,
                scale: (t[2] % 4096) as f32 / 4.0 + 1.0,
                peak_rss_bytes,
            },
        )
}

pub(crate) fn error_code() -> impl Strategy<Value = ErrorCode> {
    prop::sample::select(vec![
        ErrorCode::UnknownScene,
        ErrorCode::UnsupportedFormat,
        ErrorCode::UnknownOperator,
        ErrorCode::BadConfig,
        ErrorCode::BandMismatch,
        ErrorCode::RenderFailed,
        ErrorCode::Timeout,
        ErrorCode::PeerLost,
        ErrorCode::Internal,
        ErrorCode::Busy,
        ErrorCode::TakenOver,
    ])
}

pub(crate) fn message() -> impl Strategy<Value = Message> {
    let hash = any::<[u8; 32]>;
    let params = (
        prop::collection::vec((any::<u32>(), v3()), 0..3),
        prop::option::of(num()),
        prop::collection::vec(light(), 0..2),
        prop::option::of(any::<[u32; 2]>()),
    )
        .prop_map(|(colors, scale, lights, rows)| FrameParams {
            colors,
            scale,
            time: None,
            lights,
            rows,
        });
    prop_oneof![
        capabilities().prop_map(Message::Register).boxed(),
        (hash(), any::<u64>())
            .prop_map(|(hash, size)| Message::SceneOffer { hash, size })
            .boxed(),
        (hash(), any::<bool>())
            .prop_map(|(hash, need)| Message::SceneNeed { hash, need })
            .boxed(),
        (
            hash(),
            any::<u64>(),
            prop::collection::vec(any::<u8>(), 0..64),
            any::<bool>()
        )
            .prop_map(|(hash, offset, data, last)| Message::SceneChunk {
                hash,
                offset,
                data,
                last
            })
            .boxed(),
        (hash(), any::<u64>())
            .prop_map(|(hash, triangles)| Message::SceneReady { hash, triangles })
            .boxed(),
        node_config().prop_map(Message::ConfigureNode).boxed(),
        compositor_config()
            .prop_map(Message::ConfigureCompositor)
            .boxed(),
        any::<u64>()
            .prop_map(|epoch| Message::Configured { epoch })
            .boxed(),
        (
            any::<u64>(),
            any::<u64>(),
            prop::option::of(camera()),
            params
        )
            .prop_map(|(epoch, frame, camera, params)| Message::RenderFrame {
                epoch,
                frame,
                camera,
                params
            })
            .boxed(),
        frame_stats().prop_map(Message::FrameDone).boxed(),
        (
            error_code(),
            text(),
            proptest::option::of(any::<u64>()),
            proptest::option::of(any::<u64>())
        )
            .prop_map(|(code, message, epoch, frame)| Message::Error {
                code,
                message,
                epoch,
                frame
            })
            .boxed(),
        any::<u64>().prop_map(|seq| Message::Ping { seq }).boxed(),
        any::<u64>().prop_map(|seq| Message::Pong { seq }).boxed(),
        Just(Message::Shutdown).boxed(),
        any::<u64>()
            .prop_map(|epoch| Message::Release { epoch })
            .boxed(),
        (any::<u64>(), any::<bool>())
            .prop_map(|(session, take_over)| Message::Claim { session, take_over })
            .boxed(),
        any::<u64>()
            .prop_map(|session| Message::Claimed { session })
            .boxed(),
    ]
}

pub(crate) fn hello() -> impl Strategy<Value = Hello> {
    (role(), "[A-Za-z0-9._:-]{1,64}", any::<[u8; 32]>()).prop_map(|(role, daemon_id, nonce)| {
        Hello {
            magic: MAGIC,
            version: PROTOCOL_VERSION,
            role,
            daemon_id,
            nonce,
        }
    })
}

/// A valid band: a small rectangle of a layer in a format of the same channel count, its
/// payload random bytes of the right length (or none when empty), header sealed.
pub(crate) fn band() -> impl Strategy<Value = (BandHeader, Bytes)> {
    let pair =
        (layer(), format()).prop_filter("format fits layer", |(l, f)| l.channels() == f.channels());
    (
        pair,
        (
            any::<u64>(),
            any::<u64>(),
            0u32..4096,
            0u32..4096,
            0u32..9,
            0u32..9,
        ),
        (0.0f32..1e6, any::<bool>(), any::<u32>(), any::<u64>()),
    )
        .prop_map(
            |(
                (layer, format),
                (frame, epoch, x0, y0, width, height),
                (scale, empty, saturated, seed),
            )| {
                let mut header = BandHeader {
                    frame,
                    epoch,
                    layer,
                    format,
                    x0,
                    y0,
                    width,
                    height,
                    scale,
                    empty,
                    payload_len: 0,
                    checksum: 0,
                    saturated,
                };
                let len = header.expected_payload_len();
                let payload: Vec<u8> = (0..len)
                    .map(|i| (seed.wrapping_mul(i as u64 + 1) >> 7) as u8)
                    .collect();
                header.seal(&payload);
                (header, Bytes::from(payload))
            },
        )
}

pub(crate) fn frame() -> impl Strategy<Value = Frame> {
    prop_oneof![
        1 => hello().prop_map(Frame::Hello),
        1 => any::<[u8; 32]>().prop_map(Frame::Proof),
        4 => message().prop_map(Frame::Control),
        2 => band().prop_map(|(h, p)| Frame::Band(h, p)),
    ]
}
