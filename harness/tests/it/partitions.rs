//! Sort-last partitions through the cluster (issue 24, `docs/planner.md` § Partitions): the
//! planner splits the meshes into parts, every light group is rendered once per part by a node
//! drawing only that part with maps fitted to it, and the compositor chain depth-composes the
//! parts. The frame equals the single-device render of the same parts within the link formats'
//! bound, and the whole scene's render within the image-bias bound (per pixel, shadow edges
//! fall on other texels); where two parts' surfaces tie exactly in depth the lower part wins,
//! frame after frame. Negative controls: the other tie rule, and the render without one part.

use lightfold_coordinator::plan::PlanOptions;
use lightfold_coordinator::run::RunOptions;
use lightfold_harness::{
    InProcessCluster, assert_close, gpu, render_on, single_device, single_device_parts, small,
    small_glass, test_control,
};
use lightfold_scene::primitives::plane;
use lightfold_scene::{Image, Light, LightShape, Material, Scene};

/// The largest image bias `|Σ cluster / Σ render − 1|` (as `render_parity.rs`).
const MAX_BIAS: f64 = 5e-4;

/// The scene the cluster renders with `parts` partitions (`plan::scene_for`: meshes too large
/// for a part in chunks), which the plan's mesh indices name.
fn rendered(scene: &Scene, parts: u32) -> Scene {
    let options = PlanOptions {
        partitions: parts,
        ..PlanOptions::default()
    };
    let cluster = lightfold_coordinator::plan::ClusterSpec::local(1, 1);
    lightfold_coordinator::plan::scene_for(scene, &cluster, &options).into_owned()
}

fn bias(test: &Image, want: &Image) -> f64 {
    let s = |i: &Image| i.data.iter().map(|&v| f64::from(v)).sum::<f64>();
    s(test) / s(want) - 1.0
}

/// Renders `scene` on the cluster with `partitions` parts at K = `k`: the first frame and the
/// plan.
async fn cluster_frame(
    cluster: &InProcessCluster,
    scene: &Scene,
    partitions: u32,
    k: u32,
    frames: u32,
) -> (Vec<Image>, lightfold_coordinator::plan::Plan) {
    let mut session = cluster.connect(test_control()).await.unwrap();
    let opts = RunOptions {
        control: test_control(),
        frames,
        plan: PlanOptions {
            partitions,
            lights_per_node: k,
            ..PlanOptions::default()
        },
        ..RunOptions::default()
    };
    let out = render_on(&mut session, scene, &opts).await.unwrap();
    session.detach();
    (out.frames.into_iter().map(|f| f.image).collect(), out.plan)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_partitioned_cluster_frame_equals_the_whole_render() {
    let cluster = InProcessCluster::start(6, 3).await.unwrap();
    let gpu = gpu();
    for (scene, parts) in [(small("balls"), 2), (small("balls"), 3), (small_glass(), 2)] {
        let (frames, plan) = cluster_frame(&cluster, &scene, parts, 4, 1).await;
        assert_eq!(plan.partitions.len(), parts as usize, "{}", scene.name);
        assert!(
            plan.nodes.iter().all(|n| n.part.is_some()),
            "every node draws a part"
        );
        let same_parts =
            single_device_parts(&gpu, &rendered(&scene, parts), &plan.partitions, false);
        assert_close(
            &frames[0],
            &same_parts,
            &format!("{} P={parts}", scene.name),
        );
        let whole = single_device(&gpu, &scene, false);
        let b = bias(&frames[0], &whole);
        eprintln!(
            "{} with {parts} parts on {} nodes: bias {:+.4} % against the whole render",
            scene.name,
            plan.nodes.len(),
            b * 100.0
        );
        assert!(b.abs() <= MAX_BIAS, "{}: bias {b}", scene.name);
        // Negative control: the whole render without the last part's surfaces.
        let mut without = plan.partitions.clone();
        without.pop();
        let partial = single_device_parts(&gpu, &rendered(&scene, parts), &without, false);
        assert!(
            bias(&frames[0], &partial).abs() > 10.0 * MAX_BIAS,
            "{}: a part's surfaces make no difference",
            scene.name
        );
    }
    cluster.stop().await.unwrap();
}

/// A 4 × 4 grid of floor tiles with a box on each, lit by two short-range lamps at opposite
/// corners: each lamp's shadow casters are the few meshes near it, so a sort-last node is sent
/// its part and its lamps' casters whole and every other mesh as a stand-in.
fn lamp_lit_tiles() -> Scene {
    let mut s = Scene::new("lamp-lit tiles");
    let grey = s.add_material(Material::diffuse("grey", [0.6; 3]));
    let tan = s.add_material(Material::diffuse("tan", [0.8, 0.6, 0.4]));
    for i in 0..4 {
        for j in 0..4 {
            let (x, z) = (-3.0 + 2.0 * i as f32, -3.0 + 2.0 * j as f32);
            s.add_mesh(plane(
                &format!("tile {i},{j}"),
                [x, 0.0, z],
                [0.0, 1.0, 0.0],
                [1.0, 0.0, 0.0],
                [2.0, 2.0],
                2,
                grey,
            ));
            s.add_mesh(lightfold_scene::primitives::cuboid(
                &format!("box {i},{j}"),
                [x + 0.3, 0.3, z - 0.2],
                [0.25, 0.3, 0.25],
                tan,
            ));
        }
    }
    for (name, p) in [("lamp a", [-3.0, 1.2, -3.0]), ("lamp b", [3.0, 1.2, 3.0])] {
        s.lights.push(Light {
            name: name.into(),
            shape: LightShape::Point { position: p },
            color: [1.0; 3],
            power: 12.0,
            range: Some(2.5),
            samples: 1,
        });
    }
    s.camera.position = [0.0, 7.0, 7.0];
    s.camera.target = [0.0, 0.0, 0.0];
    s.camera.width = 64;
    s.camera.height = 48;
    s
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn sort_last_nodes_are_sent_only_what_they_draw() {
    let cluster = InProcessCluster::start(4, 2).await.unwrap();
    let gpu = gpu();
    let scene = lamp_lit_tiles();
    let (frames, plan) = cluster_frame(&cluster, &scene, 2, 1, 1).await;
    cluster.stop().await.unwrap();
    // Each node's scene: its part and its lamp's casters whole, the rest stand-ins.
    let whole = scene.to_bytes().unwrap().len();
    let mut smaller = 0;
    for n in &plan.nodes {
        let hash = n
            .scene
            .expect("a partition node of a still scene gets its own scene");
        assert_ne!(hash, plan.scene_hash, "{}", n.node);
        let part = &plan.partitions[n.part.unwrap()];
        let mut keep = vec![false; scene.meshes.len()];
        for &m in part.iter().chain(n.shadows.iter().flat_map(|s| &s.casters)) {
            keep[m as usize] = true;
        }
        let sub = lightfold_scene::partition::keep_meshes(&scene, &keep);
        assert_eq!(sub.content_hash(), hash, "{}", n.node);
        let bytes = sub.to_bytes().unwrap().len();
        eprintln!(
            "{}: part {} ({} meshes), {} casters: {bytes} of {whole} scene bytes",
            n.node,
            n.part.unwrap(),
            part.len(),
            n.shadows.iter().map(|s| s.casters.len()).sum::<usize>()
        );
        smaller += usize::from(bytes < whole * 3 / 4);
    }
    assert_eq!(
        smaller,
        plan.nodes.len(),
        "every node is sent less than the scene"
    );
    // And the frame is the one the whole scene gives those parts.
    let same_parts = single_device_parts(&gpu, &rendered(&scene, 2), &plan.partitions, false);
    assert_close(&frames[0], &same_parts, "stand-in scenes");
    let b = bias(&frames[0], &single_device(&gpu, &scene, false));
    assert!(b.abs() <= MAX_BIAS, "bias {b}");
}

/// Two identical floors (one red, one green) in the same place: every visible pixel is an
/// exact depth tie between the two parts.
fn twin_floors() -> Scene {
    let mut s = Scene::new("twin floors");
    let red = s.add_material(Material::diffuse("red", [0.8, 0.1, 0.1]));
    let green = s.add_material(Material::diffuse("green", [0.1, 0.8, 0.1]));
    for (name, m) in [("red floor", red), ("green floor", green)] {
        s.add_mesh(plane(
            name,
            [0.0; 3],
            [0.0, 1.0, 0.0],
            [1.0, 0.0, 0.0],
            [6.0, 6.0],
            4,
            m,
        ));
    }
    s.lights.push(Light {
        name: "bulb".into(),
        shape: LightShape::Point {
            position: [0.5, 3.0, 0.5],
        },
        color: [1.0; 3],
        power: 30.0,
        range: None,
        samples: 1,
    });
    s.camera.position = [0.0, 3.0, 5.0];
    s.camera.target = [0.0, 0.0, 0.0];
    s.camera.width = 48;
    s.camera.height = 32;
    s
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn exact_depth_ties_go_to_the_lower_part_every_frame() {
    let cluster = InProcessCluster::start(2, 2).await.unwrap();
    let gpu = gpu();
    let scene = twin_floors();
    let (frames, plan) = cluster_frame(&cluster, &scene, 2, 1, 2).await;
    cluster.stop().await.unwrap();
    assert_eq!(plan.partitions.len(), 2);
    let lower = &scene.materials[scene.meshes[plan.partitions[0][0] as usize].material];
    let want = single_device_parts(&gpu, &rendered(&scene, 2), &plan.partitions, false);
    let other = single_device_parts(&gpu, &rendered(&scene, 2), &plan.partitions, true);
    for (i, frame) in frames.iter().enumerate() {
        assert_close(frame, &want, &format!("frame {i}"));
    }
    assert_eq!(
        frames[0].data, frames[1].data,
        "the winner of a tie is the same every frame"
    );
    // The lower part's colour is what shows: its dominant channel carries the light.
    let sum = |img: &Image, c: usize| img.data.iter().skip(c).step_by(3).sum::<f32>();
    let dominant = if lower.diffuse[0] > lower.diffuse[1] {
        0
    } else {
        1
    };
    assert!(
        sum(&frames[0], dominant) > 4.0 * sum(&frames[0], 1 - dominant),
        "the lower part ({}) does not show",
        lower.name
    );
    // Negative control: ties to the higher part give the other floor.
    let far: usize = frames[0]
        .data
        .iter()
        .zip(&other.data)
        .filter(|(a, b)| (*a - *b).abs() > 0.025 * b.abs() + 1e-3)
        .count();
    assert!(
        far > frames[0].data.len() / 4,
        "the tie rule makes no difference ({far})"
    );
}

/// A floor and one large ball under a lamp: the ball holds most triangles, more than a part's
/// share at P = 4, so it is split into chunks.
fn big_ball() -> Scene {
    let mut s = Scene::new("big ball");
    let grey = s.add_material(Material::diffuse("grey", [0.6; 3]));
    let red = s.add_material(Material::diffuse("red", [0.8, 0.2, 0.2]));
    s.add_mesh(plane(
        "floor",
        [0.0; 3],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [8.0, 8.0],
        4,
        grey,
    ));
    s.add_mesh(lightfold_scene::primitives::sphere(
        "ball",
        [0.0, 1.0, 0.0],
        1.0,
        64,
        32,
        red,
    ));
    s.lights.push(Light {
        name: "lamp".into(),
        shape: LightShape::Point {
            position: [1.5, 3.5, 1.0],
        },
        color: [1.0; 3],
        power: 40.0,
        range: None,
        samples: 1,
    });
    s.camera.position = [0.0, 3.0, 5.0];
    s.camera.target = [0.0, 0.8, 0.0];
    s.camera.width = 96;
    s.camera.height = 64;
    s
}

/// A mesh too large for a part is split into chunks so the parts balance. The frame over
/// chunked parts equals the same parts on one device, the whole unchunked scene within the
/// image-bias bound, and is as close to the exact point sum as the unchunked render.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_mesh_larger_than_a_part_is_split_into_chunks() {
    let scene = big_ball();
    let chunked = lightfold_scene::partition::chunk_for_parts(&scene, 4)
        .expect("the ball holds more than a quarter of the triangles");
    assert!(chunked.meshes.len() > 4, "{} meshes", chunked.meshes.len());
    assert_eq!(chunked.triangle_count(), scene.triangle_count());
    let cluster = InProcessCluster::start(4, 2).await.unwrap();
    let gpu = gpu();
    let (frames, plan) = cluster_frame(&cluster, &scene, 4, 1, 1).await;
    cluster.stop().await.unwrap();
    assert_eq!(plan.partitions.len(), 4);
    let sizes: Vec<usize> = plan
        .partitions
        .iter()
        .map(|p| {
            p.iter()
                .map(|&m| chunked.meshes[m as usize].triangle_count())
                .sum()
        })
        .collect();
    let (lo, hi) = (sizes.iter().min().unwrap(), sizes.iter().max().unwrap());
    assert!(
        hi - lo <= scene.triangle_count() / 4,
        "parts of {sizes:?} triangles"
    );
    let same_parts = single_device_parts(&gpu, &chunked, &plan.partitions, false);
    assert_close(&frames[0], &same_parts, "chunked parts");
    // Against the exact point sum (ray-traced shadows), the chunked parts are as close as the
    // ball as one mesh on one device: chunks of one surface add no shadow along their seams.
    // (Per pixel the two GPU images differ at some shadow edges: chunk boxes change the
    // receivers maps are fitted and sized to.)
    let one_mesh = single_device(&gpu, &scene, false);
    let samples = lightfold_scene::vpl::frame_samples(&scene);
    let truth = lightfold_reference::radiance_point_sum(&scene, &samples);
    let rmse = |img: &Image| {
        let e: f64 = img
            .data
            .iter()
            .zip(&truth.data)
            .map(|(a, b)| f64::from(a - b).powi(2))
            .sum();
        (e / img.data.len() as f64).sqrt()
    };
    let (e_cluster, e_one) = (rmse(&frames[0]), rmse(&one_mesh));
    eprintln!(
        "RMSE against the point sum: chunked parts {e_cluster:.3e}, one mesh {e_one:.3e}; \
         bias against one mesh {:+.4} %",
        bias(&frames[0], &one_mesh) * 100.0
    );
    assert!(e_cluster <= 1.25 * e_one, "{e_cluster} against {e_one}");
    assert!(bias(&frames[0], &one_mesh).abs() <= MAX_BIAS);
}

/// Automatic partitioning (`--partitions auto`, the default): nodes that report too little
/// memory for the whole scene's geometry get it in parts. Here each node reports the bytes the
/// whole scene needs (`NODE_BYTES_PER_TRIANGLE` a triangle), which is twice what the planner
/// lets a scene take (`SCENE_MEMORY_SHARE`), so the scene is split in 2; the frame is the
/// whole scene's within the image-bias bound. The control: nodes with ample memory draw it
/// whole.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn nodes_short_of_memory_get_the_scene_in_parts() {
    use lightfold_coordinator::plan::NODE_BYTES_PER_TRIANGLE;
    let scene = small("balls");
    let need = scene.triangle_count() as u64 * NODE_BYTES_PER_TRIANGLE;
    let gpu = gpu();
    let whole = single_device(&gpu, &scene, false);
    for (memory, parts) in [(need, 2), (100 * need, 0)] {
        let cluster = InProcessCluster::start_with_node_memory(4, 2, Some(memory))
            .await
            .unwrap();
        // K = 4: two groups of the 8 samples, so 2 parts take all 4 nodes.
        let (frames, plan) = cluster_frame(&cluster, &scene, 0, 4, 1).await;
        cluster.stop().await.unwrap();
        assert_eq!(plan.partitions.len(), parts, "nodes of {memory} bytes");
        assert!(bias(&frames[0], &whole).abs() <= MAX_BIAS);
    }
}

/// The penumbra filter with partitions: the last stage filters the composed illumination with
/// the composed (nearest) depth. The frame is the filtered whole render's within the image-bias
/// bound, and nearer to it than to the unfiltered render (the control).
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn the_penumbra_filter_runs_on_the_composed_parts() {
    let scene = small("balls");
    let cluster = InProcessCluster::start(4, 2).await.unwrap();
    let mut session = cluster.connect(test_control()).await.unwrap();
    let opts = RunOptions {
        control: test_control(),
        frames: 1,
        plan: PlanOptions {
            partitions: 2,
            lights_per_node: 4,
            penumbra_filter: lightfold_coordinator::plan::PenumbraFilter::Radius(2),
            ..PlanOptions::default()
        },
        ..RunOptions::default()
    };
    let out = render_on(&mut session, &scene, &opts).await.unwrap();
    session.detach();
    cluster.stop().await.unwrap();
    assert_eq!(
        (out.plan.partitions.len(), out.plan.penumbra_radius),
        (2, 2)
    );
    let gpu = gpu();
    let filtered = lightfold_harness::single_device_filtered(&gpu, &scene, false, 2);
    let unfiltered = single_device(&gpu, &scene, false);
    let frame = &out.frames[0].image;
    let rms = |a: &Image, b: &Image| {
        let e: f64 = a
            .data
            .iter()
            .zip(&b.data)
            .map(|(x, y)| f64::from(x - y).powi(2))
            .sum();
        (e / a.data.len() as f64).sqrt()
    };
    let (to_filtered, to_unfiltered) = (rms(frame, &filtered), rms(frame, &unfiltered));
    eprintln!(
        "RMS to the filtered render {to_filtered:.3e}, to the unfiltered {to_unfiltered:.3e}"
    );
    assert!(bias(frame, &filtered).abs() <= MAX_BIAS);
    assert!(
        to_filtered < 0.5 * to_unfiltered,
        "{to_filtered} against {to_unfiltered}"
    );
}

/// Partitions composed in a tree (leaves compose runs of parts, `depth` joins pairs above, lower
/// parts first): the frame equals the same parts on one device.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn partitions_compose_in_a_tree() {
    let scene = small("balls");
    let cluster = InProcessCluster::start(6, 5).await.unwrap();
    let mut session = cluster.connect(test_control()).await.unwrap();
    let opts = RunOptions {
        control: test_control(),
        frames: 1,
        plan: PlanOptions {
            partitions: 3,
            lights_per_node: 4,
            topology: lightfold_coordinator::plan::Topology::Tree,
            ..PlanOptions::default()
        },
        ..RunOptions::default()
    };
    let out = render_on(&mut session, &scene, &opts).await.unwrap();
    session.detach();
    cluster.stop().await.unwrap();
    assert_eq!((out.plan.partitions.len(), out.plan.stages.len()), (3, 5));
    let gpu = gpu();
    let same_parts = single_device_parts(&gpu, &rendered(&scene, 3), &out.plan.partitions, false);
    assert_close(&out.frames[0].image, &same_parts, "tree of parts");
}
