//! The live view over an in-process cluster: frames reach a WebSocket client, a camera change is
//! in the next frame requested and matches the single-device render from the new camera, a
//! colour change re-renders no node, a colour that splits a node's colour group re-plans and the
//! page is told, a frame budget from the page re-plans at a lowered quality that the frames then
//! match, and a stalled viewer does not hold the cluster back; a pure-red light with a budget set
//! and cleared keeps the session (the colour-split test), and a session that ends tells the page
//! why; an exposure edit re-encodes the frame on screen with nothing rendered, `/frame.png` is the
//! frame at the exposure shown, and the scene's clock plays in the clip (wrapping, or stopping at
//! its end), at a speed.

mod client;

use client::{Client, Frame};
use lightfold_coordinator::control::FrameResult;
use lightfold_coordinator::plan::{MapSizing, PlanOptions};
use lightfold_harness::{InProcessCluster, assert_close, single_device, small, test_control};
use lightfold_node::gpu::{Gpu, GpuOptions};
use lightfold_reference::{AreaOptions, GroundTruth};
use lightfold_scene::Scene;
use lightfold_view::{RefineOptions, Steer, View, ViewOptions};
use serde_json::json;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio_util::sync::CancellationToken;

type Delivered = Arc<Mutex<Vec<FrameResult>>>;

fn plan_options(scene: &Scene, k: u32) -> PlanOptions {
    PlanOptions {
        lights_per_node: k,
        walkthrough: true,
        map_sizing: MapSizing::Fixed(scene.quality.shadow_map_size),
        ..PlanOptions::default()
    }
}

fn loopback() -> ViewOptions {
    ViewOptions {
        listen: "127.0.0.1:0".into(),
        ..ViewOptions::default()
    }
}

/// Runs the view over a fresh cluster while `body(address, delivered frames, counters)` runs,
/// then stops it.
async fn with_view<F, Fut>(scene: Scene, plan: PlanOptions, opts: ViewOptions, body: F)
where
    F: FnOnce(std::net::SocketAddr, Delivered, Arc<lightfold_view::ViewCounters>) -> Fut,
    Fut: std::future::Future<Output = ()>,
{
    let cluster = InProcessCluster::start(3, 3).await.unwrap();
    let mut session = cluster.connect(test_control()).await.unwrap();
    let view = View::bind(opts).await.unwrap();
    let addr = view.local_addr();
    let counters = view.counters();
    let stop = CancellationToken::new();
    let delivered: Delivered = Arc::default();
    let d = Arc::clone(&delivered);
    let run = view.run_with(&mut session, &scene, &plan, stop.clone(), move |f| {
        d.lock().unwrap().push(f)
    });
    let test = async {
        body(addr, Arc::clone(&delivered), counters).await;
        stop.cancel();
    };
    let (outcome, ()) = tokio::time::timeout(lightfold_harness::RUN_DEADLINE, async {
        tokio::join!(run, test)
    })
    .await
    .expect("the view run timed out");
    assert!(outcome.error.is_none(), "{:?}", outcome.error);
    session.detach();
    cluster.stop().await.unwrap();
}

fn delivered_frame(d: &Delivered, frame: u64) -> lightfold_scene::Image {
    d.lock()
        .unwrap()
        .iter()
        .find(|f| f.frame == frame)
        .map(|f| f.image.clone())
        .expect("the frame was delivered")
}

fn frame_number(f: &Frame) -> u64 {
    f.header["frame"].as_u64().unwrap()
}

/// The session saved now (`/scene.toml`, read beside `folder`) renders, single-device, the
/// cluster's frame `shown`; the scene as it started (`original`) does not (the negative
/// control: over 50 channels differ by more than 0.05). Returns the saved file's text.
async fn saved_session_renders(
    addr: std::net::SocketAddr,
    delivered: &Delivered,
    shown: &Frame,
    folder: Option<&std::path::Path>,
    original: &Scene,
) -> String {
    let (head, body) = http_get(addr, "/scene.toml").await;
    assert!(
        head.starts_with("HTTP/1.0 200") || head.starts_with("HTTP/1.1 200"),
        "{head}"
    );
    let text = String::from_utf8(body).unwrap();
    let saved = lightfold_scene::parse_scene_file(&text, "session.toml", folder).unwrap();
    let gpu = Gpu::new(&GpuOptions::default()).expect("a GPU adapter is required");
    let frame = delivered_frame(delivered, frame_number(shown));
    assert_close(
        &frame,
        &single_device(&gpu, &saved, true),
        "the saved session",
    );
    let before = single_device(&gpu, original, true);
    let differs = frame
        .data
        .iter()
        .zip(&before.data)
        .filter(|(a, b)| (*a - *b).abs() > 0.05)
        .count();
    assert!(differs > 50, "the edits changed only {differs} channels");
    text
}

/// Frames until one shows `revision`; how many came before it.
async fn until_revision(c: &mut Client, revision: u64) -> (Frame, usize) {
    let mut before = 0;
    loop {
        let f = c.frame().await;
        if f.header["revision"].as_u64().unwrap() >= revision {
            return (f, before);
        }
        before += 1;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_camera_change_reaches_the_next_frame_and_matches_the_single_device_render() {
    let scene = small("balls");
    let plan = plan_options(&scene, 4);
    let s2 = scene.clone();
    with_view(scene, plan, loopback(), |addr, delivered, _| async move {
        let mut c = Client::connect(addr).await;
        let welcome = c.expect("welcome").await;
        assert_eq!(welcome["can_steer"], true, "a loopback viewer steers");
        let first = c.frame().await;
        assert_eq!(first.header["revision"], 0);
        assert!(first.jpeg.starts_with(&[0xFF, 0xD8]), "a JPEG");
        let img = image::load_from_memory(&first.jpeg).unwrap();
        assert_eq!((img.width(), img.height()), (64, 48));

        let revision = c
            .steer(json!({"type": "orbit", "yaw_deg": 35.0, "pitch_deg": 10.0}))
            .await;
        assert_eq!(revision, 1);
        let (moved, before) = until_revision(&mut c, revision).await;
        assert!(
            before <= 1,
            "{before} frames came before the camera change showed"
        );

        let mut want = Steer::new(&s2);
        want.orbit(35.0, 10.0).unwrap();
        let mut moved_scene = s2.clone();
        moved_scene.camera = want.camera;
        let gpu = Gpu::new(&GpuOptions::default()).expect("a GPU adapter is required");
        let truth = single_device(&gpu, &moved_scene, true);
        assert_close(
            &delivered_frame(&delivered, frame_number(&moved)),
            &truth,
            "the frame after the orbit",
        );
        // Negative control: the frame before the move is not the moved view.
        let old = delivered_frame(&delivered, frame_number(&first));
        let differs = old
            .data
            .iter()
            .zip(&truth.data)
            .filter(|(a, b)| (*a - *b).abs() > 0.05)
            .count();
        assert!(differs > 100, "the orbit changed only {differs} channels");
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_colour_change_rerenders_no_node() {
    let scene = small("balls");
    // K = 4: one node per area light, each with its own colour group.
    let plan = plan_options(&scene, 4);
    let s2 = scene.clone();
    with_view(scene, plan, loopback(), |addr, delivered, _| async move {
        let mut c = Client::connect(addr).await;
        c.expect("welcome").await;
        let first = c.frame().await;
        // Light 0 at half power in another colour: one factor per node, so c_n alone changes.
        let color = [0.3, 0.6, 1.0];
        let revision = c
            .steer(json!({"type": "light", "index": 0, "color": color, "intensity": 0.5}))
            .await;
        let (f, _) = until_revision(&mut c, revision).await;
        let rendered: Vec<(String, u64)> = f.header["daemons"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|d| d["role"] == "node")
            .map(|d| {
                let id = d["id"].as_str().unwrap().to_string();
                (id, d["lights_rendered"].as_u64().unwrap())
            })
            .collect();
        assert!(!rendered.is_empty(), "the header names the nodes");
        assert!(
            rendered.iter().all(|(_, n)| *n == 0),
            "a colour change re-rendered: {rendered:?}"
        );
        let mut recoloured = s2.clone();
        recoloured.lights[0].color = color.map(|v| v * 0.5);
        let gpu = Gpu::new(&GpuOptions::default()).expect("a GPU adapter is required");
        assert_close(
            &delivered_frame(&delivered, frame_number(&f)),
            &single_device(&gpu, &recoloured, true),
            "the recoloured frame",
        );
        assert_eq!(f.header["epoch"], first.header["epoch"], "no re-plan");
    })
    .await;
}

/// A pure-red light (its node colour `[1, 0, 0]` was refused by render nodes, which ended the
/// session) splits a node's colour group: the cluster re-plans and the page is told; then a frame
/// budget set and cleared from the page re-plan over the red scene, and the session goes on.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_colour_that_splits_a_colour_group_replans_and_the_page_is_told() {
    let scene = small("balls");
    // K = 8: one node carries both area lights, so recolouring one of them splits its group.
    let plan = plan_options(&scene, 8);
    let s2 = scene.clone();
    with_view(scene, plan, loopback(), |addr, delivered, _| async move {
        let mut c = Client::connect(addr).await;
        c.expect("welcome").await;
        c.frame().await;
        let color = [1.0, 0.0, 0.0];
        let revision = c
            .steer(json!({"type": "light", "index": 1, "color": color, "intensity": 1.0}))
            .await;
        let notice = c.expect("notice").await;
        assert!(
            notice["text"].as_str().unwrap().contains("split"),
            "{notice}"
        );
        let (f, _) = until_revision(&mut c, revision).await;
        let mut recoloured = s2.clone();
        recoloured.lights[1].color = color;
        let gpu = Gpu::new(&GpuOptions::default()).expect("a GPU adapter is required");
        assert_close(
            &delivered_frame(&delivered, frame_number(&f)),
            &single_device(&gpu, &recoloured, true),
            "the frame after the split",
        );
        let status = c
            .status_where(|s| s["epochs"].as_array().is_some_and(|e| e.len() >= 2))
            .await;
        let reason = status["epochs"][1]["reason"].as_str().unwrap().to_string();
        assert!(reason.contains("split"), "{reason}");
        // A budget set and cleared: two more re-plans over the red scene.
        let revision = c.steer(json!({"type": "budget", "ms": 60000.0})).await;
        until_revision(&mut c, revision).await;
        let revision = c.steer(json!({"type": "budget", "ms": null})).await;
        let (f, _) = until_revision(&mut c, revision).await;
        let ended = c.texts_of("ended");
        assert!(ended.is_empty(), "the session ended: {ended:?}");
        assert_close(
            &delivered_frame(&delivered, frame_number(&f)),
            &single_device(&gpu, &recoloured, true),
            "the red frame after the budget was cleared",
        );
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_budget_from_the_page_replans_and_frames_match_the_lowered_quality() {
    let scene = small("balls");
    let plan = plan_options(&scene, 4);
    let s2 = scene.clone();
    with_view(scene, plan, loopback(), |addr, delivered, _| async move {
        let mut c = Client::connect(addr).await;
        c.expect("welcome").await;
        c.frame().await;
        for bad in [json!(-5.0), json!(0.0), json!(1e9), json!("fast")] {
            let e = c.try_steer(json!({"type": "budget", "ms": bad})).await;
            assert!(e.is_some(), "budget {bad} was taken");
        }
        // 1 ms: no plan meets it; the samples of both area lights go down to one each (K = 1),
        // maps stay at the scene's fixed size. The penumbra filter stays only where the plan
        // without it is estimated no faster (the material host is not the slowest node: it
        // depends on how the nodes calibrated), so the frame is compared with the single-device
        // render at the radius of the plan that rendered it.
        let revision = c.steer(json!({"type": "budget", "ms": 1.0})).await;
        let notice = c.expect("notice").await;
        assert!(
            notice["text"]
                .as_str()
                .unwrap()
                .contains("frame budget 1.0 ms"),
            "{notice}"
        );
        let (f, _) = until_revision(&mut c, revision).await;
        let epoch = f.header["epoch"].clone();
        let status = c
            .status_where(|s| s["epoch"] == epoch && s["plan"]["gave_up"].is_string())
            .await;
        let radius = status["plan"]["penumbra_radius"].as_u64().unwrap() as u32;
        let gpu = Gpu::new(&GpuOptions::default()).expect("a GPU adapter is required");
        let mut lowered = s2.clone();
        lowered.quality.samples_per_area_light = Some(1);
        let got = delivered_frame(&delivered, frame_number(&f));
        assert_close(
            &got,
            &lightfold_harness::single_device_filtered(&gpu, &lowered, true, radius),
            "the frame under the budget",
        );
        // Negative control: the scene's own quality is another image.
        let full = single_device(&gpu, &s2, true);
        let diff = got
            .data
            .iter()
            .zip(&full.data)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(diff > 0.05, "one sample per light looks like four ({diff})");
        let gave_up = status["plan"]["gave_up"].as_str().unwrap();
        assert!(
            gave_up.contains("samples per area light 4 → 1"),
            "{gave_up}"
        );
        assert_eq!(status["plan"]["frame_budget_ms"], 1.0);
        // The page gets the plan's radius, with its line where there is a filter.
        assert_eq!(
            status["plan"]["penumbra"].is_null(),
            radius == 0,
            "{status}"
        );
        assert_eq!(status["plan"]["samples"], 2);
        // No budget again: the scene's quality.
        let revision = c.steer(json!({"type": "budget", "ms": null})).await;
        let (f, _) = until_revision(&mut c, revision).await;
        assert_close(
            &delivered_frame(&delivered, frame_number(&f)),
            &full,
            "the frame without a budget",
        );
        let status = c.status_where(|s| s["plan"]["samples"] == 8).await;
        assert!(status["plan"]["gave_up"].is_null(), "{status}");
    })
    .await;
}

/// `small("balls")` at 96×72 under a 1 ms frame budget (one sample per area light), its
/// area-light truth, and the view refining after `refine` idle (`None`: not at all).
fn refinement_setup(refine: Option<Duration>) -> (Scene, PlanOptions, ViewOptions, GroundTruth) {
    let mut scene = small("balls");
    (scene.camera.width, scene.camera.height) = (96, 72);
    let plan = plan_options(&scene, 4);
    let truth = GroundTruth::render(&scene, &AreaOptions::default());
    assert!(truth.penumbra_pixels() > 100, "the scene has penumbrae");
    let opts = ViewOptions {
        refine: refine.map(|after| RefineOptions {
            after,
            ..RefineOptions::default()
        }),
        ..loopback()
    };
    (scene, plan, opts, truth)
}

/// Penumbra PSNR of a delivered frame against the area-light truth, dB.
fn penumbra_psnr(truth: &GroundTruth, image: &lightfold_scene::Image) -> f64 {
    truth.compare(image).unwrap().penumbra.unwrap().psnr
}

/// Idle refinement: with no input, successive frames approach the area truth (penumbra PSNR
/// rises at every step up to the cap: 8 and 16 samples per area light, then 2× antialiasing,
/// from the budget's one), each step a frame of its own and nothing after the cap; one input then
/// returns the next frame to the budget's quality (the budget's plan, and the single-device render
/// of it). The curve is printed (`--nocapture`): `docs/live-view.md` § Measured.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn idle_refinement_approaches_the_area_truth_and_one_input_drops_back() {
    let (scene, plan, opts, truth) = refinement_setup(Some(Duration::from_millis(300)));
    let s2 = scene.clone();
    with_view(scene, plan, opts, |addr, delivered, _| async move {
        let mut c = Client::connect(addr).await;
        let welcome = c.expect("welcome").await;
        let steps = welcome["refine"]["steps"].as_array().unwrap().clone();
        assert_eq!(steps.len(), 3, "{welcome}");
        assert_eq!(welcome["refine"]["after_ms"], 300);
        let first = c.frame().await;
        assert!(first.header["refine"].is_null(), "{}", first.header);
        let own = penumbra_psnr(&truth, &delivered_frame(&delivered, frame_number(&first)));
        let revision = c.steer(json!({"type": "budget", "ms": 1.0})).await;
        let input = std::time::Instant::now();
        let (f, _) = until_revision(&mut c, revision).await;
        assert!(f.header["refine"].is_null(), "{}", f.header);
        let image = delivered_frame(&delivered, frame_number(&f));
        let mut curve = vec![(input.elapsed(), 0, penumbra_psnr(&truth, &image))];
        let budget_epoch = f.header["epoch"].clone();
        // Idle: one frame a step, each nearer the truth, up to the cap.
        for level in 1..=3u64 {
            let f = c.frame().await;
            let r = &f.header["refine"];
            assert_eq!(r["level"], level, "{}", f.header);
            assert_eq!(r, &steps[level as usize - 1]);
            assert_eq!(f.header["revision"], revision, "no input");
            let psnr = penumbra_psnr(&truth, &delivered_frame(&delivered, frame_number(&f)));
            let before = curve.last().unwrap().2;
            assert!(
                psnr > before,
                "step {level} ({r}): penumbra PSNR {psnr:.2} dB, {before:.2} dB before"
            );
            curve.push((input.elapsed(), level, psnr));
        }
        assert!(
            curve[1].2 > own,
            "the first step is above the scene's own quality"
        );
        eprintln!("refinement curve (96×72 balls, budget 1 ms, refine after 300 ms):");
        eprintln!("  the scene's own quality (4 samples per area light): {own:.2} dB");
        for ((t, level, psnr), step) in curve
            .iter()
            .zip(std::iter::once(&json!(null)).chain(&steps))
        {
            eprintln!(
                "  {:>6.0} ms after the input: level {level} {step}: penumbra PSNR {psnr:.2} dB",
                t.as_secs_f64() * 1e3
            );
        }
        // At the cap nothing more is rendered.
        let (_, more) = c.drain_for(Duration::from_secs(2)).await;
        assert_eq!(more, 0, "frames after the cap");
        // One input: the next frame is back at the budget's quality.
        let dropped = std::time::Instant::now();
        let revision = c
            .steer(json!({"type": "light", "index": 0, "color": [1.0, 1.0, 1.0], "intensity": 0.5}))
            .await;
        let (f, before) = until_revision(&mut c, revision).await;
        eprintln!(
            "  an input at the cap: its frame {:.0} ms later",
            dropped.elapsed().as_secs_f64() * 1e3
        );
        assert_eq!(before, 0, "the input's frame is the next one");
        assert!(f.header["refine"].is_null(), "{}", f.header);
        let epoch = f.header["epoch"].clone();
        assert_ne!(epoch, budget_epoch, "the way back re-plans");
        let status = c
            .status_where(|s| s["epoch"] == epoch && s["plan"]["gave_up"].is_string())
            .await;
        assert_eq!(status["plan"]["samples"], 2, "one sample per area light");
        assert_eq!(status["plan"]["frame_budget_ms"], 1.0);
        let radius = status["plan"]["penumbra_radius"].as_u64().unwrap() as u32;
        eprintln!("  the budget's plan: penumbra filter radius {radius}");
        let mut lowered = s2.clone();
        lowered.quality.samples_per_area_light = Some(1);
        lowered.lights[0].color = [0.5; 3];
        let gpu = Gpu::new(&GpuOptions::default()).expect("a GPU adapter is required");
        assert_close(
            &delivered_frame(&delivered, frame_number(&f)),
            &lightfold_harness::single_device_filtered(&gpu, &lowered, true, radius),
            "the frame after the input",
        );
    })
    .await;
}

/// Refinement under `--continuous`: frames keep coming at every step, the steps rise one at a
/// time to the top and stay there, and an input's frame is at the session's quality again.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn continuous_refinement_steps_up_frame_by_frame_and_drops_back() {
    let (scene, plan, opts, _) = refinement_setup(Some(Duration::from_millis(300)));
    let opts = ViewOptions {
        continuous: true,
        ..opts
    };
    with_view(scene, plan, opts, |addr, _, _| async move {
        let mut c = Client::connect(addr).await;
        c.expect("welcome").await;
        let revision = c
            .steer(json!({"type": "orbit", "yaw_deg": 10.0, "pitch_deg": 0.0}))
            .await;
        until_revision(&mut c, revision).await;
        let mut levels = Vec::new();
        while levels.iter().filter(|&&l| l == 3).count() < 3 {
            let f = c.frame().await;
            assert_eq!(f.header["revision"], revision, "no input");
            levels.push(f.header["refine"]["level"].as_u64().unwrap_or(0));
            assert!(
                levels.len() < 200,
                "the steps did not reach the top: {levels:?}"
            );
        }
        assert!(
            levels.windows(2).all(|w| w[1] == w[0] || w[1] == w[0] + 1),
            "one step at a time: {levels:?}"
        );
        let revision = c
            .steer(json!({"type": "orbit", "yaw_deg": -10.0, "pitch_deg": 0.0}))
            .await;
        let (f, _) = until_revision(&mut c, revision).await;
        assert!(f.header["refine"].is_null(), "{}", f.header);
    })
    .await;
}

/// The negative control of idle refinement: without it, an idle view renders nothing, and frames
/// asked for while idle (`render`) are the budget's frame again, no nearer the truth.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn without_refinement_idle_frames_do_not_improve() {
    let (scene, plan, opts, truth) = refinement_setup(None);
    with_view(scene, plan, opts, |addr, delivered, _| async move {
        let mut c = Client::connect(addr).await;
        let welcome = c.expect("welcome").await;
        assert!(welcome["refine"].is_null(), "{welcome}");
        c.frame().await;
        let revision = c.steer(json!({"type": "budget", "ms": 1.0})).await;
        let (f, _) = until_revision(&mut c, revision).await;
        let first = penumbra_psnr(&truth, &delivered_frame(&delivered, frame_number(&f)));
        let (_, idle) = c.drain_for(Duration::from_secs(2)).await;
        assert_eq!(idle, 0, "an idle view rendered");
        for _ in 0..3 {
            c.send(&json!({"type": "render"})).await;
            let f = c.frame().await;
            assert!(f.header["refine"].is_null(), "{}", f.header);
            let psnr = penumbra_psnr(&truth, &delivered_frame(&delivered, frame_number(&f)));
            assert!(
                (psnr - first).abs() < 0.05,
                "an idle frame at {psnr:.2} dB, the budget's at {first:.2} dB"
            );
        }
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_stalled_viewer_drops_frames_and_never_holds_the_cluster() {
    let mut scene = small("balls");
    scene.camera.width = 320;
    scene.camera.height = 240;
    let plan = plan_options(&scene, 4);
    let opts = ViewOptions {
        continuous: true,
        jpeg_quality: 100,
        send_buffer: 16 << 10,
        send_timeout: Duration::from_secs(2),
        ..loopback()
    };
    with_view(scene, plan, opts, |addr, delivered, counters| async move {
        let mut active = Client::connect(addr).await;
        active.expect("welcome").await;
        // A viewer that connects and then reads nothing, with a tiny receive window.
        let stalled = Client::connect_stalled(addr).await;
        let start = delivered.lock().unwrap().len();
        let mut got = 0;
        while counters.viewers_dropped.load(Ordering::Relaxed) == 0 {
            active.frame().await;
            got += 1;
            assert!(got < 5000, "the stalled viewer was never dropped");
        }
        // The active viewer keeps getting frames after the stalled one is dropped.
        for _ in 0..3 {
            active.frame().await;
        }
        let during = delivered.lock().unwrap().len() - start;
        eprintln!(
            "stalled viewer dropped after {during} frames delivered; the active viewer took {got}; \
             viewers skipped {} frame(s)",
            counters.frames_skipped.load(Ordering::Relaxed)
        );
        assert!(
            got >= 5,
            "the active viewer got {got} frames while the other stalled"
        );
        drop(stalled);
    })
    .await;
}

/// A non-loopback address of this machine, to connect as a remote viewer: the source address
/// of its default route, else the first global IPv4 address `ip` lists (iproute2 is installed by
/// `scripts/install-deps.sh`).
fn non_loopback_address() -> std::net::IpAddr {
    let probe = std::net::UdpSocket::bind("0.0.0.0:0").unwrap();
    // No packet is sent: connecting a UDP socket only picks the route and source address.
    if probe.connect("192.0.2.1:9").is_ok()
        && let Ok(a) = probe.local_addr()
        && !a.ip().is_loopback()
        && !a.ip().is_unspecified()
    {
        return a.ip();
    }
    let out = std::process::Command::new("ip")
        .args(["-o", "-4", "addr", "show", "scope", "global"])
        .output()
        .expect("this test needs `ip` (iproute2) to find a non-loopback address");
    String::from_utf8_lossy(&out.stdout)
        .split_whitespace()
        .skip_while(|w| *w != "inet")
        .nth(1)
        .and_then(|cidr| cidr.split('/').next()?.parse().ok())
        .expect("this test needs a non-loopback IPv4 address (none found)")
}

/// A view on every address with the token `viewer-secret` (its defaults otherwise: no frame to a
/// viewer beyond loopback without the token, and the token refused over plain HTTP from there),
/// and this machine's non-loopback address to reach it as a viewer beyond loopback.
fn beyond_loopback() -> (std::net::IpAddr, ViewOptions) {
    let opts = ViewOptions {
        listen: "0.0.0.0:0".into(),
        token: Some("viewer-secret".into()),
        ..ViewOptions::default()
    };
    (non_loopback_address(), opts)
}

/// Whether `v` (any message, as JSON text) names an address of the test cluster (its daemons
/// and sink listen on 127.0.0.1) or this machine's.
fn names_an_address(v: &serde_json::Value, ip: std::net::IpAddr) -> bool {
    let text = v.to_string();
    text.contains("127.0.0.1") || text.contains(&ip.to_string())
}

/// With `--public-watch` a viewer beyond loopback watches (frames, status) with no daemon
/// address, is refused steering and a wrong token, and steers after the right one (taken over
/// plain HTTP here with `--allow-plain-token`), when it sees the addresses too.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_viewer_beyond_loopback_only_watches_until_it_presents_the_token() {
    let scene = small("balls");
    let plan = plan_options(&scene, 4);
    let (ip, opts) = beyond_loopback();
    let opts = ViewOptions {
        public_watch: true,
        allow_plain_token: true,
        ..opts
    };
    with_view(scene, plan, opts, |addr, _, _| async move {
        let remote = std::net::SocketAddr::new(ip, addr.port());
        let mut c = Client::connect(remote).await;
        let welcome = c.expect("welcome").await;
        assert_eq!(welcome["can_steer"], false, "{welcome}");
        assert_eq!(welcome["can_watch"], true, "{welcome}");
        assert_eq!(welcome["token_accepted"], true, "{welcome}");
        let f = c.frame().await; // watching works
        assert!(!names_an_address(&f.header, ip), "{}", f.header);
        // The status, with the plan, names no address (ids only).
        let status = c.status_where(|s| s["plan"].is_object()).await;
        assert!(status["plan"]["sink"].is_null(), "{status}");
        assert!(!names_an_address(&status, ip), "{status}");
        assert!(
            status["plan"]["nodes"][0]["id"].is_string(),
            "the ids are kept: {status}"
        );
        // The frame routes answer a watcher without the token.
        let (head, _) = http_get(remote, "/frame.png").await;
        assert!(
            head.contains(" 200 ") && head.contains("image/png"),
            "{head}"
        );
        let refused = c
            .try_steer(json!({"type": "orbit", "yaw_deg": 10.0, "pitch_deg": 0.0}))
            .await
            .expect("steering is refused");
        assert!(
            refused["text"].as_str().unwrap().contains("only watch"),
            "{refused}"
        );
        let wrong = c
            .try_steer(json!({"type": "hello", "token": "guess"}))
            .await
            .expect("a wrong token is refused");
        assert!(
            wrong["text"].as_str().unwrap().contains("wrong token"),
            "{wrong}"
        );
        assert!(
            c.try_steer(json!({"type": "hello", "token": "viewer-secret"}))
                .await
                .is_none()
        );
        let welcome = c.expect("welcome").await;
        assert_eq!(welcome["can_steer"], true);
        // Negative control: with the token, the status names the sink's address.
        let status = c.status_where(|s| s["plan"]["sink"].is_string()).await;
        assert!(names_an_address(&status, ip), "{status}");
        let revision = c
            .steer(json!({"type": "orbit", "yaw_deg": 10.0, "pitch_deg": 0.0}))
            .await;
        assert_eq!(
            revision, 1,
            "the refused orbit changed nothing; this one did"
        );
        // The same view from loopback steers without a token.
        let mut local =
            Client::connect(std::net::SocketAddr::from(([127, 0, 0, 1], addr.port()))).await;
        assert_eq!(local.expect("welcome").await["can_steer"], true);
    })
    .await;
}

/// By default a viewer beyond loopback without the token gets the page and, on `/ws`, a welcome
/// that says it must present the token — no scene, no frame, no status, camera or address while
/// a loopback viewer steers and frames flow; the frame routes answer it 401. Over plain HTTP
/// the token itself is refused from there (it would cross the network readable): `hello` and
/// `Authorization: Bearer` alike. Loopback keeps seeing everything.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_viewer_beyond_loopback_without_the_token_sees_nothing_but_the_page() {
    let scene = small("balls");
    let plan = plan_options(&scene, 4);
    let (ip, opts) = beyond_loopback();
    with_view(scene, plan, opts, |addr, _, _| async move {
        let remote = std::net::SocketAddr::new(ip, addr.port());
        let local = std::net::SocketAddr::from(([127, 0, 0, 1], addr.port()));
        let mut op = Client::connect(local).await;
        assert_eq!(op.expect("welcome").await["can_steer"], true);
        op.frame().await;

        let mut c = Client::connect(remote).await;
        let welcome = c.expect("welcome").await;
        assert_eq!(welcome["can_watch"], false, "{welcome}");
        assert_eq!(welcome["can_steer"], false, "{welcome}");
        for key in ["scene", "camera", "animation", "exposure", "revision"] {
            assert!(
                welcome.get(key).is_none(),
                "the welcome has {key}: {welcome}"
            );
        }
        assert_eq!(welcome["token_accepted"], false, "{welcome}");
        assert!(
            welcome["text"].as_str().unwrap().contains("plain HTTP"),
            "{welcome}"
        );
        // The operator steers and frames flow; the viewer without the token gets none of it.
        let revision = op
            .steer(json!({"type": "orbit", "yaw_deg": 15.0, "pitch_deg": 0.0}))
            .await;
        until_revision(&mut op, revision).await;
        op.steer(json!({"type": "exposure", "stops": 1.0})).await;
        op.frame().await;
        let (texts, frames) = c.drain_for(Duration::from_secs(2)).await;
        assert_eq!(frames, 0, "a frame reached a viewer without the token");
        assert!(texts.is_empty(), "it was sent {texts:?}");
        // Asking gets nothing either.
        for m in [
            json!({"type": "stats"}),
            json!({"type": "render"}),
            json!({"type": "orbit", "yaw_deg": 1.0, "pitch_deg": 0.0}),
        ] {
            let e = c.try_steer(m.clone()).await.expect("refused");
            assert!(
                e["text"].as_str().unwrap().contains("present the"),
                "{m}: {e}"
            );
        }
        // The right token is refused over plain HTTP from beyond loopback.
        let e = c
            .try_steer(json!({"type": "hello", "token": "viewer-secret"}))
            .await
            .expect("the token is refused over plain HTTP");
        assert!(e["text"].as_str().unwrap().contains("plain HTTP"), "{e}");
        let (texts, frames) = c.drain_for(Duration::from_secs(1)).await;
        assert!(
            frames == 0 && texts.is_empty(),
            "{frames} frames, {texts:?}"
        );

        // HTTP: the page and its files, but no frame.
        for path in ["/", "/app.js", "/style.css"] {
            let (head, _) = http_get(remote, path).await;
            assert!(head.contains(" 200 "), "{path}: {head}");
        }
        for path in ["/frame.png", "/frame.jpg", "/frame.exr"] {
            let (head, body) = http_get(remote, path).await;
            assert!(head.contains(" 401 "), "{path}: {head}");
            assert!(
                head.to_lowercase().contains("www-authenticate: bearer"),
                "{head}"
            );
            let body = String::from_utf8_lossy(&body);
            assert!(body.contains("present the token"), "{path}: {body}");
            // The token over plain HTTP from beyond loopback: refused, and why.
            let (head, body) =
                http_get_with(remote, path, "Authorization: Bearer viewer-secret\r\n").await;
            assert!(head.contains(" 403 "), "{path}: {head}");
            assert!(String::from_utf8_lossy(&body).contains("plain HTTP"));
            // Negative control: the same route from loopback.
            let (head, _) = http_get(local, path).await;
            assert!(head.contains(" 200 "), "{path} from loopback: {head}");
        }
    })
    .await;
}

/// A self-signed certificate for `ip` and loopback, written to `dir`: (cert.pem, key.pem, the
/// certificate's DER).
fn self_signed(
    dir: &std::path::Path,
    ip: std::net::IpAddr,
) -> (
    std::path::PathBuf,
    std::path::PathBuf,
    tokio_rustls::rustls::pki_types::CertificateDer<'static>,
) {
    let names = vec!["localhost".to_string(), "127.0.0.1".into(), ip.to_string()];
    let ck = rcgen::generate_simple_self_signed(names).unwrap();
    let cert = dir.join("cert.pem");
    let key = dir.join("key.pem");
    std::fs::write(&cert, ck.cert.pem()).unwrap();
    std::fs::write(&key, ck.signing_key.serialize_pem()).unwrap();
    (cert, key, ck.cert.der().clone())
}

/// A TLS client that trusts `cert` alone.
fn tls_client(
    cert: tokio_rustls::rustls::pki_types::CertificateDer<'static>,
) -> tokio_rustls::TlsConnector {
    use tokio_rustls::rustls;
    let mut roots = rustls::RootCertStore::empty();
    roots.add(cert).unwrap();
    #[allow(deprecated)] // ring, as the view uses
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let config = rustls::ClientConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .unwrap()
        .with_root_certificates(roots)
        .with_no_client_auth();
    tokio_rustls::TlsConnector::from(Arc::new(config))
}

async fn tls_connect(
    tls: &tokio_rustls::TlsConnector,
    addr: std::net::SocketAddr,
) -> tokio_rustls::client::TlsStream<tokio::net::TcpStream> {
    let name = tokio_rustls::rustls::pki_types::ServerName::from(addr.ip());
    let tcp = tokio::net::TcpStream::connect(addr).await.unwrap();
    tokio::time::timeout(client::WAIT, tls.connect(name, tcp))
        .await
        .expect("the TLS handshake in time")
        .expect("the TLS handshake")
}

/// With a certificate and key the view serves HTTPS and WSS: a client that trusts the
/// certificate fetches `/frame.png` (with the token from beyond loopback; without it, 401), a
/// viewer beyond loopback presents the token over WSS (taken: the link is encrypted) and then
/// sees frames and the addresses, and plain HTTP to the same port gets no HTTP answer.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn the_view_serves_https_and_wss_with_a_certificate() {
    let scene = small("balls");
    let plan = plan_options(&scene, 4);
    let (ip, opts) = beyond_loopback();
    let dir = tempfile::tempdir().unwrap();
    let (cert, key, der) = self_signed(dir.path(), ip);
    let opts = ViewOptions {
        tls: Some(lightfold_view::TlsFiles { cert, key }),
        ..opts
    };
    let tls = tls_client(der);
    with_view(scene, plan, opts, |addr, _, _| async move {
        let remote = std::net::SocketAddr::new(ip, addr.port());
        let local = std::net::SocketAddr::from(([127, 0, 0, 1], addr.port()));
        // Plain HTTP to the TLS port: no HTTP answer, the connection is closed.
        {
            use tokio::io::{AsyncReadExt, AsyncWriteExt};
            let mut s = tokio::net::TcpStream::connect(local).await.unwrap();
            s.write_all(b"GET /frame.png HTTP/1.0\r\nHost: x\r\n\r\n")
                .await
                .unwrap();
            let mut got = Vec::new();
            let _ = tokio::time::timeout(client::WAIT, s.read_to_end(&mut got))
                .await
                .expect("closed in time");
            assert!(
                !got.starts_with(b"HTTP/"),
                "plain HTTP was answered: {}",
                String::from_utf8_lossy(&got)
            );
        }
        // A loopback viewer over WSS, for a first frame.
        let url = format!("wss://{local}/ws");
        let (ws, _) = tokio_tungstenite::client_async(url, tls_connect(&tls, local).await)
            .await
            .expect("a WebSocket over TLS");
        let mut op = Client::over(ws);
        assert_eq!(op.expect("welcome").await["can_steer"], true);
        let f = op.frame().await;
        // HTTPS from loopback: the frame, as a PNG.
        let (head, body) = request(tls_connect(&tls, local).await, local, "/frame.png", "").await;
        assert!(
            head.contains(" 200 ") && head.contains("image/png"),
            "{head}"
        );
        let png = image::load_from_memory_with_format(&body, image::ImageFormat::Png).unwrap();
        assert_eq!(
            (u64::from(png.width()), u64::from(png.height())),
            (
                f.header["width"].as_u64().unwrap(),
                f.header["height"].as_u64().unwrap()
            )
        );
        // From beyond loopback: 401 without the token, 401 with a wrong one, 200 with it.
        let (head, _) = request(tls_connect(&tls, remote).await, remote, "/frame.png", "").await;
        assert!(head.contains(" 401 "), "{head}");
        let (head, _) = request(
            tls_connect(&tls, remote).await,
            remote,
            "/frame.png",
            "Authorization: Bearer guess\r\n",
        )
        .await;
        assert!(head.contains(" 401 "), "{head}");
        let (head, body) = request(
            tls_connect(&tls, remote).await,
            remote,
            "/frame.png",
            "Authorization: Bearer viewer-secret\r\n",
        )
        .await;
        assert!(
            head.contains(" 200 ") && head.contains("image/png"),
            "{head}"
        );
        assert!(body.starts_with(b"\x89PNG"));
        // A viewer beyond loopback over WSS: nothing until the token, which TLS lets it send.
        let url = format!("wss://{remote}/ws");
        let (ws, _) = tokio_tungstenite::client_async(url, tls_connect(&tls, remote).await)
            .await
            .expect("a WebSocket over TLS");
        let mut c = Client::over(ws);
        let welcome = c.expect("welcome").await;
        assert_eq!(
            (
                welcome["can_watch"].clone(),
                welcome["token_accepted"].clone()
            ),
            (json!(false), json!(true)),
            "{welcome}"
        );
        let (texts, frames) = c.drain_for(Duration::from_secs(1)).await;
        assert!(
            frames == 0 && texts.is_empty(),
            "{frames} frames, {texts:?}"
        );
        assert!(
            c.try_steer(json!({"type": "hello", "token": "viewer-secret"}))
                .await
                .is_none(),
            "the token is taken over TLS"
        );
        let welcome = c.expect("welcome").await;
        assert_eq!(welcome["can_steer"], true, "{welcome}");
        assert_eq!(welcome["scene"]["name"], "balls", "{welcome}");
        c.frame().await;
        let status = c.status_where(|s| s["plan"]["sink"].is_string()).await;
        assert!(names_an_address(&status, ip), "{status}");
    })
    .await;
}

/// A certificate and key that do not belong together, a file that is not there and one that is
/// no PEM are clear errors when the view binds, never a panic; the pair that belongs together
/// binds (the negative control).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_bad_certificate_or_key_is_a_clear_error_at_start() {
    let dir = tempfile::tempdir().unwrap();
    let ip = std::net::IpAddr::from([127, 0, 0, 1]);
    let a = dir.path().join("a");
    let b = dir.path().join("b");
    std::fs::create_dir_all(&a).unwrap();
    std::fs::create_dir_all(&b).unwrap();
    let (cert_a, key_a, _) = self_signed(&a, ip);
    let (_, key_b, _) = self_signed(&b, ip);
    let junk = dir.path().join("junk.pem");
    std::fs::write(&junk, "not a certificate\n").unwrap();
    let bind = |cert: &std::path::Path, key: &std::path::Path| {
        View::bind(ViewOptions {
            tls: Some(lightfold_view::TlsFiles {
                cert: cert.to_path_buf(),
                key: key.to_path_buf(),
            }),
            ..loopback()
        })
    };
    let error = |r: anyhow::Result<View>| format!("{:#}", r.expect_err("refused"));
    let e = error(bind(&cert_a, &key_b).await);
    assert!(e.contains("not the certificate's"), "{e}");
    let e = error(bind(&cert_a, &dir.path().join("missing.pem")).await);
    assert!(e.contains("cannot read the view's TLS key"), "{e}");
    let e = error(bind(&junk, &key_a).await);
    assert!(e.contains("holds no certificate"), "{e}");
    let e = error(bind(&cert_a, &junk).await);
    assert!(e.contains("holds no private key"), "{e}");
    let view = bind(&cert_a, &key_a)
        .await
        .expect("the matching pair binds");
    assert!(view.is_tls());
    println!("a mismatched pair: {}", error(bind(&cert_a, &key_b).await));
}

/// A light dragged from the page moves its shadow in the next frame, without a new epoch when
/// the plan stays the same but for the light (it travels with the frames); in walkthrough mode
/// only the node holding it draws maps again (every other node keeps its maps); a light added
/// joins the next frame; and the session saved as a scene file (`/scene.toml`) renders,
/// single-device, the frame the view shows, after the drag and after the addition.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_dragged_light_redraws_only_its_maps_and_the_saved_session_renders_the_frame() {
    let scene = small("balls");
    let plan = plan_options(&scene, 4);
    let opts = ViewOptions {
        scene_source: Some("balls".into()),
        ..loopback()
    };
    let original = scene.clone();
    with_view(scene, plan, opts, |addr, delivered, _| async move {
        let mut c = Client::connect(addr).await;
        c.expect("welcome").await;
        let first = c.frame().await;
        let nodes = |f: &Frame| -> Vec<(u64, u64, u64)> {
            f.header["daemons"]
                .as_array()
                .unwrap()
                .iter()
                .filter(|d| d["role"] == "node" && d["lights_rendered"].as_u64() > Some(0))
                .map(|d| {
                    (
                        d["lights_rendered"].as_u64().unwrap(),
                        d["shadow_passes"].as_u64().unwrap(),
                        d["maps_kept"].as_u64().unwrap(),
                    )
                })
                .collect()
        };
        // Control: the first frame draws every node's maps.
        let at_start = nodes(&first);
        assert!(at_start.len() >= 2, "{at_start:?}");
        assert!(
            at_start.iter().all(|&(_, passes, _)| passes > 0),
            "{at_start:?}"
        );

        let lights = c.expect("lights").await;
        assert!(lights["lights"][0]["position"].is_array(), "{lights}");
        let revision = c
            .steer(json!({"type": "light_drag", "index": 0, "x": 0.15, "y": 0.05}))
            .await;
        let (dragged, _) = until_revision(&mut c, revision).await;
        let after = nodes(&dragged);
        let drew: Vec<_> = after.iter().filter(|n| n.1 > 0).collect();
        assert_eq!(
            drew.len(),
            1,
            "only the dragged light's node draws maps: {after:?}"
        );
        // Every other node kept its maps, or (its lights and view unchanged) sent its last
        // bands again without rendering.
        let all_nodes = first.header["daemons"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|d| d["role"] == "node")
            .count();
        assert!(all_nodes >= 2, "{}", first.header);
        assert!(
            after.iter().filter(|n| n.1 == 0).all(|n| n.2 > 0),
            "the other nodes keep their maps: {after:?}"
        );
        // A small drag changes no node's groups, casters or map sizes: no new epoch, the moved
        // light travels with the frames (`FrameParams::lights`), and the frame is the edited
        // scene's single-device render.
        assert_eq!(
            dragged.header["epoch"], first.header["epoch"],
            "the drag re-planned"
        );
        saved_session_renders(addr, &delivered, &dragged, None, &original).await;

        // Another light, then the session saved.
        let revision = c
            .steer(json!({"type": "light_add", "light": {"type": "sphere",
                "center": [0.6, 1.6, 0.8], "radius": 0.15, "radiance": 20.0,
                "color": [1.0, 0.7, 0.4], "samples": 4}}))
            .await;
        let (added, _) = until_revision(&mut c, revision).await;
        let text = saved_session_renders(addr, &delivered, &added, None, &original).await;
        assert!(text.contains("scene = \"balls\""), "{text}");
        let saved = lightfold_scene::parse_scene_file(&text, "session.toml", None).unwrap();
        assert_eq!(saved.lights.len(), original.lights.len() + 1);
    })
    .await;
}

/// Lights added beyond what the nodes hold at the scene's samples (K = 4, three nodes, each area
/// light of `small` 4 samples: a fourth area light does not fit) are planned at fewer samples
/// and the session goes on; taking the light out again and dragging another renders the
/// single-device image of the lights as edited.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn lights_added_beyond_the_cluster_keep_the_session_and_later_edits_match() {
    let scene = small("balls");
    let plan = plan_options(&scene, 4);
    let original = scene.clone();
    with_view(scene, plan, loopback(), |addr, delivered, _| async move {
        let mut c = Client::connect(addr).await;
        c.expect("welcome").await;
        c.frame().await;
        let sphere = json!({"type": "sphere", "center": [0.6, 1.6, 0.8], "radius": 0.15,
            "radiance": 20.0, "color": [1.0, 0.7, 0.4], "samples": 4});
        let disk = json!({"type": "disk", "center": [0.0, 2.5, 0.0], "normal": [0.0, -1.0, 0.0],
            "radius": 0.3, "radiance": 10.0, "color": [0.4, 1.0, 0.6], "samples": 4});
        c.steer(json!({"type": "light_add", "light": sphere})).await;
        let revision = c.steer(json!({"type": "light_add", "light": disk})).await;
        until_revision(&mut c, revision).await;
        assert!(c.texts_of("ended").is_empty(), "the session ended");
        c.steer(json!({"type": "light_remove", "index": 3})).await;
        let revision = c
            .steer(json!({"type": "light_drag", "index": 1, "x": -0.1, "y": 0.0}))
            .await;
        let (f, _) = until_revision(&mut c, revision).await;
        let mut want = Steer::new(&original);
        want.add_light(&serde_json::from_value(sphere).unwrap())
            .unwrap();
        want.drag_light(1, -0.1, 0.0).unwrap();
        let mut three = original.clone();
        three.lights = want.scene_lights.as_ref().clone();
        let gpu = Gpu::new(&GpuOptions::default()).expect("a GPU adapter is required");
        assert_close(
            &delivered_frame(&delivered, frame_number(&f)),
            &single_device(&gpu, &three, true),
            "the frame after the edits",
        );
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn malformed_and_hostile_messages_get_errors_and_change_nothing() {
    let scene = small("balls");
    let plan = plan_options(&scene, 4);
    with_view(scene, plan, loopback(), |addr, _, _| async move {
        let mut c = Client::connect(addr).await;
        c.expect("welcome").await;
        let bad = [
            json!({"type": "teleport"}),
            json!({"type": "orbit", "yaw_deg": "left"}),
            json!({"type": "orbit", "yaw_deg": 1e39, "pitch_deg": 0}),
            json!({"type": "orbit", "yaw_deg": 1.0, "pitch_deg": 0, "extra": 1}),
            json!({"type": "zoom", "factor": 0.0}),
            json!({"type": "zoom", "factor": -2.0}),
            json!({"type": "pan", "x": 1e30, "y": 0}),
            json!({"type": "light", "index": 99, "color": [1, 1, 1], "intensity": 1}),
            json!({"type": "light", "index": 0, "color": [-1, 1, 1], "intensity": 1}),
            json!({"type": "light", "index": 0, "color": [1, 1, 1], "intensity": 1e9}),
            json!({"type": "camera", "camera": {"position": [0, 0, 0], "target": [0, 0, 0],
                   "up": [0, 1, 0], "fov_y_deg": 45}}),
            json!({"type": "camera", "camera": {"position": [0, 5, 0], "target": [0, 0, 0],
                   "up": [0, 1, 0], "fov_y_deg": 45}}),
            json!({"type": "camera", "camera": {"position": [0, 0, 5], "target": [0, 0, 0],
                   "up": [0, 1, 0], "fov_y_deg": 500}}),
            json!({"type": "exposure", "stops": 1e39}),
            json!({"type": "exposure", "stops": "bright"}),
            json!({"type": "speed", "speed": 10.0}),
            json!({"type": "speed", "speed": 0.0}),
            json!({"type": "loop", "on": "yes"}),
            // Light edits: unknown lights, unusable or unbounded shapes, a mesh light.
            json!({"type": "light_drag", "index": 99, "x": 0.1, "y": 0}),
            json!({"type": "light_drag", "index": 0, "x": 1e30, "y": 0}),
            json!({"type": "light_remove", "index": 99}),
            json!({"type": "light_set", "index": 0, "light": {"type": "sphere",
                   "center": [0, 1, 0], "radius": -1.0, "radiance": 5.0}}),
            json!({"type": "light_set", "index": 0, "light": {"type": "rect",
                   "center": [0, 1, 0], "size": [1, 1], "normal": [0, 0, 0],
                   "u_axis": [1, 0, 0], "radiance": 5.0}}),
            json!({"type": "light_set", "index": 0, "light": {"type": "point",
                   "position": [1e9, 1, 0], "intensity": 5.0}}),
            json!({"type": "light_add", "light": {"type": "disk", "center": [0, 2, 0],
                   "normal": [0, -1, 0], "radius": 0.3, "radiance": 5.0, "samples": 100000}}),
            json!({"type": "light_add", "light": {"type": "emissive_mesh", "object": "floor",
                   "radiance": 5.0}}),
            json!({"type": "light_add", "light": {"type": "warp", "position": [0, 1, 0]}}),
        ];
        for m in bad {
            let e = c.try_steer(m.clone()).await;
            assert!(e.is_some(), "accepted {m}");
        }
        c.send(&json!("not an object")).await;
        assert_eq!(c.expect("error").await["type"], "error");
        // Nothing changed: the next valid change is revision 1.
        let revision = c.steer(json!({"type": "zoom", "factor": 0.9})).await;
        assert_eq!(revision, 1);
        // An oversized message closes the socket; the view goes on for others.
        let huge = "x".repeat(64 << 10);
        c.send(&json!({"type": "hello", "token": huge})).await;
        assert!(
            c.closed_within(Duration::from_secs(30)).await,
            "an oversized message was read"
        );
        let mut other = Client::connect(addr).await;
        assert_eq!(other.expect("welcome").await["revision"], 1);
        other.frame().await;
    })
    .await;
}

/// `GET path` over HTTP/1.0 (test-side only): status line and body.
async fn http_get(addr: std::net::SocketAddr, path: &str) -> (String, Vec<u8>) {
    http_get_with(addr, path, "").await
}

/// `GET path` with more header lines (`extra`, each ending in CRLF).
async fn http_get_with(addr: std::net::SocketAddr, path: &str, extra: &str) -> (String, Vec<u8>) {
    let s = tokio::net::TcpStream::connect(addr).await.unwrap();
    request(s, addr, path, extra).await
}

/// `GET path` over HTTP/1.0 on an open stream (plain or TLS).
async fn request<S>(
    mut s: S,
    addr: std::net::SocketAddr,
    path: &str,
    extra: &str,
) -> (String, Vec<u8>)
where
    S: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin,
{
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    s.write_all(format!("GET {path} HTTP/1.0\r\nHost: {addr}\r\n{extra}\r\n").as_bytes())
        .await
        .unwrap();
    let mut all = Vec::new();
    let read = tokio::time::timeout(client::WAIT, s.read_to_end(&mut all))
        .await
        .expect("the response in time");
    // (A TLS peer that closes without its close_notify reads as an early end.)
    if let Err(e) = read {
        assert!(
            e.kind() == std::io::ErrorKind::UnexpectedEof && !all.is_empty(),
            "{e}"
        );
    }
    let split = all
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("a header");
    let head = String::from_utf8_lossy(&all[..split]).into_owned();
    (head, all[split + 4..].to_vec())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn the_page_and_the_current_frame_as_exr_and_jpeg_are_served() {
    let scene = small("balls");
    let plan = plan_options(&scene, 4);
    with_view(scene, plan, loopback(), |addr, delivered, _| async move {
        let (head, body) = http_get(addr, "/").await;
        assert!(
            head.starts_with("HTTP/1.0 200") || head.starts_with("HTTP/1.1 200"),
            "{head}"
        );
        let page = String::from_utf8(body).unwrap();
        assert!(
            page.contains("app.js") && page.contains("id=\"frame\""),
            "{page}"
        );
        let mut c = Client::connect(addr).await;
        let welcome = c.expect("welcome").await;
        let stops = welcome["exposure"]["stops"].as_f64().unwrap() as f32;
        let f = c.frame().await;
        let (head, exr) = http_get(addr, "/frame.exr").await;
        assert!(
            head.contains("200") && head.contains("image/x-exr"),
            "{head}"
        );
        let dir = std::env::temp_dir().join(format!("lightfold-view-exr-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("frame.exr");
        std::fs::write(&path, &exr).unwrap();
        let got = lightfold_scene::Image::read_exr(&path).unwrap();
        let want = delivered_frame(&delivered, frame_number(&f));
        assert_eq!((got.width, got.height), (want.width, want.height));
        let want_rgb: Vec<f32> = want
            .data
            .chunks(want.channels)
            .flat_map(|p| p[..3].to_vec())
            .collect();
        assert_eq!(got.data, want_rgb, "the EXR is the frame, bit for bit");
        let (head, jpeg) = http_get(addr, "/frame.jpg").await;
        assert!(head.contains("image/jpeg"), "{head}");
        assert_eq!(jpeg, f.jpeg, "the JPEG is the one pushed");
        // The PNG: the frame, 8-bit sRGB at the exposure shown, losslessly.
        let srgb = |at: f32| want.to_srgb8(at.exp2()).unwrap();
        let png = |bytes: &[u8]| {
            image::load_from_memory_with_format(bytes, image::ImageFormat::Png)
                .expect("a valid PNG")
                .to_rgb8()
        };
        let (head, body) = http_get(addr, "/frame.png").await;
        assert!(head.contains("200") && head.contains("image/png"), "{head}");
        let got = png(&body);
        assert_eq!((got.width(), got.height()), (want.width, want.height));
        let got = got.into_raw();
        assert!(max_diff(&got, &srgb(stops)) <= 1, "the PNG is the frame");
        // Negative control: the frame a stop brighter is another picture.
        assert!(max_diff(&got, &srgb(stops + 1.0)) > 8);
        // At the exposure a viewer sets, from the same linear frame.
        c.steer(json!({"type": "exposure", "stops": stops + 1.0}))
            .await;
        let (_, body) = http_get(addr, "/frame.png").await;
        assert!(max_diff(&png(&body).into_raw(), &srgb(stops + 1.0)) <= 1);
        let (head, _) = http_get(addr, "/nothing-here").await;
        assert!(head.contains("404"), "{head}");
        let _ = std::fs::remove_dir_all(&dir);
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_peer_that_trickles_its_request_header_is_closed() {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let scene = small("balls");
    let plan = plan_options(&scene, 4);
    with_view(scene, plan, loopback(), |addr, _, _| async move {
        let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
        // Half a request header, then nothing.
        s.write_all(b"GET / HTTP/1.1\r\nHost: x\r\n").await.unwrap();
        let started = std::time::Instant::now();
        let mut buf = [0u8; 256];
        let n = tokio::time::timeout(Duration::from_secs(60), s.read(&mut buf))
            .await
            .expect("the view kept a trickling peer open for a minute");
        // Closed (0 bytes) or answered with a timeout status and then closed.
        let text = String::from_utf8_lossy(&buf[..n.unwrap_or(0)]).into_owned();
        assert!(
            text.is_empty() || text.starts_with("HTTP/1.1 408"),
            "{text}"
        );
        assert!(
            started.elapsed() >= Duration::from_secs(5),
            "closed before the header deadline: {:?}",
            started.elapsed()
        );
        // The view still serves others.
        let mut c = Client::connect(addr).await;
        c.expect("welcome").await;
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_time_seek_poses_the_next_frame_as_the_single_device_render_of_that_pose() {
    let scene = small("carousel");
    let plan = plan_options(&scene, 4);
    let s2 = scene.clone();
    with_view(scene, plan, loopback(), |addr, delivered, _| async move {
        let mut c = Client::connect(addr).await;
        let welcome = c.expect("welcome").await;
        let span = welcome["animation"]["span"].as_f64().unwrap();
        assert!(span >= 8.0, "the carousel's longest motion is 8 s: {span}");
        assert_eq!(welcome["animation"]["playing"], false);
        let first = c.frame().await;
        assert_eq!(first.header["time"].as_f64(), Some(0.0));
        // A scene time past the clip's end is posed at its clip time.
        let revision = c.steer(json!({"type": "time", "t": span + 2.0})).await;
        let (posed, _) = until_revision(&mut c, revision).await;
        let shown = posed.header["time"].as_f64().unwrap();
        assert!((shown - 2.0).abs() < 1e-3, "the frame's clip time {shown}");
        let gpu = Gpu::new(&GpuOptions::default()).expect("a GPU adapter is required");
        let truth = single_device(&gpu, &s2.still_at(2.0), true);
        assert_close(
            &delivered_frame(&delivered, frame_number(&posed)),
            &truth,
            "the frame after the seek to 2 s",
        );
        // Negative control: the first frame (t = 0) is not that pose.
        let old = delivered_frame(&delivered, frame_number(&first));
        let differs = old
            .data
            .iter()
            .zip(&truth.data)
            .filter(|(a, b)| (*a - *b).abs() > 0.05)
            .count();
        assert!(differs > 50, "the seek changed only {differs} channels");
        // Playing requests frames on its own: more arrive without further steering.
        c.steer(json!({"type": "play"})).await;
        let a = frame_number(&c.frame().await);
        let b = frame_number(&c.frame().await);
        assert!(b > a);
        c.steer(json!({"type": "pause"})).await;

        // At 4×, looping, from half a second before the end: the frames' clip times wrap to the
        // start, and every one lies in the clip.
        c.steer(json!({"type": "speed", "speed": 4.0})).await;
        c.steer(json!({"type": "time", "t": span - 0.5})).await;
        let played = c.steer(json!({"type": "play"})).await;
        let times = clip_times(&mut c, played, |t| t < span - 0.5).await;
        c.steer(json!({"type": "pause"})).await;
        assert!(
            times.iter().all(|t| (0.0..span).contains(t)),
            "clip times outside [0, {span}): {times:?}"
        );
        // Not looping: the clip times rise to the end and stop there, and the clock stops.
        c.steer(json!({"type": "loop", "on": false})).await;
        c.steer(json!({"type": "time", "t": span - 1.0})).await;
        let played = c.steer(json!({"type": "play"})).await;
        let times = clip_times(&mut c, played, |t| (t - span).abs() < 1e-4).await;
        assert!(
            times.windows(2).all(|w| w[1] >= w[0]) && times.iter().all(|&t| t <= span),
            "{times:?}"
        );
        let mut other = Client::connect(addr).await;
        let w = other.expect("welcome").await;
        let anim = &w["animation"];
        assert_eq!(anim["playing"], false, "stopped at the end: {anim}");
        assert_eq!(
            (anim["loop"].clone(), anim["speed"].as_f64()),
            (json!(false), Some(4.0))
        );
        assert!(
            (anim["time"].as_f64().unwrap() - span).abs() < 1e-4,
            "{anim}"
        );
        println!("clip times at 4x, not looping: {times:?}");
    })
    .await;
}

/// The clip times of the frames requested at `revision` or later, until one satisfies `last`.
async fn clip_times(c: &mut Client, revision: u64, last: impl Fn(f64) -> bool) -> Vec<f64> {
    let mut times = Vec::new();
    loop {
        let f = c.frame().await;
        if f.header["revision"].as_u64().unwrap() < revision {
            continue;
        }
        let t = f.header["time"]
            .as_f64()
            .expect("an animated frame has a time");
        times.push(t);
        if last(t) {
            return times;
        }
        assert!(times.len() < 500, "no such frame: {times:?}");
    }
}

fn max_diff(a: &[u8], b: &[u8]) -> u8 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| x.abs_diff(*y))
        .max()
        .unwrap_or(0)
}

fn mean_luma(jpeg: &[u8]) -> f64 {
    let img = image::load_from_memory(jpeg).unwrap().to_luma8();
    img.pixels().map(|p| f64::from(p[0])).sum::<f64>() / f64::from(img.width() * img.height())
}

/// Exposure is applied where frames are encoded: an edit is acknowledged at the same steering
/// revision, the frame on screen comes again at the new exposure, brighter, with nothing
/// rendered for it, and the next frame rendered is encoded at it too; stops that are not finite
/// are refused, huge ones clamped.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn an_exposure_edit_reencodes_the_frame_on_screen_without_a_render() {
    let scene = small("balls");
    let plan = plan_options(&scene, 4);
    with_view(scene, plan, loopback(), |addr, delivered, _| async move {
        let mut c = Client::connect(addr).await;
        let welcome = c.expect("welcome").await;
        let s0 = welcome["exposure"]["stops"].as_f64().unwrap();
        assert_eq!(welcome["exposure"]["scene_stops"].as_f64(), Some(s0));
        let first = c.frame().await;
        assert_eq!(first.header["exposure"].as_f64(), Some(s0));
        assert_eq!(first.header["reencoded"], false);
        let rendered = delivered.lock().unwrap().len();
        let revision = first.header["revision"].as_u64().unwrap();
        let up = s0 + 1.0;
        let acked = c.steer(json!({"type": "exposure", "stops": up})).await;
        assert_eq!(acked, revision, "an exposure is no render input");
        assert_eq!(c.expect("exposure").await["stops"].as_f64(), Some(up));
        let again = c.frame().await;
        assert_eq!(
            again.header["frame"], first.header["frame"],
            "{}",
            again.header
        );
        assert_eq!(again.header["revision"], first.header["revision"]);
        assert_eq!(again.header["exposure"].as_f64(), Some(up));
        assert_eq!(again.header["reencoded"], true);
        assert_eq!(
            delivered.lock().unwrap().len(),
            rendered,
            "a frame was rendered"
        );
        let (dark, bright) = (mean_luma(&first.jpeg), mean_luma(&again.jpeg));
        assert!(
            bright > dark + 5.0,
            "+1 stop: mean luma {dark:.1} -> {bright:.1}"
        );
        // Negative control: back at the scene's exposure, the frame is as it was.
        c.steer(json!({"type": "exposure", "stops": s0})).await;
        let back = c.frame().await;
        let same = mean_luma(&back.jpeg);
        assert!(
            (same - dark).abs() < 1.0,
            "back to {s0} stops: {dark:.1} vs {same:.1}"
        );
        println!("mean luma at {s0} stops {dark:.1}, at {up} stops {bright:.1}, back {same:.1}");

        // The next frame rendered is encoded at the exposure set.
        c.steer(json!({"type": "exposure", "stops": up})).await;
        let revision = c
            .steer(json!({"type": "orbit", "yaw_deg": 20.0, "pitch_deg": 0.0}))
            .await;
        let (moved, _) = until_revision(&mut c, revision).await;
        assert_eq!(moved.header["exposure"].as_f64(), Some(up));
        assert_eq!(moved.header["reencoded"], false);

        // Stops that are not finite are refused; huge ones are clamped.
        let refused = c
            .try_steer(json!({"type": "exposure", "stops": 1e39}))
            .await
            .expect("infinite stops are refused");
        assert!(
            refused["text"].as_str().unwrap().contains("finite"),
            "{refused}"
        );
        c.steer(json!({"type": "exposure", "stops": 1e9})).await;
        // The exposures every viewer is told, in order, end at the clamped one.
        let max = f64::from(lightfold_view::MAX_STOPS);
        let mut told = Vec::new();
        while told.last() != Some(&max) {
            told.push(c.expect("exposure").await["stops"].as_f64().unwrap());
            assert!(told.len() < 10, "{told:?}");
        }
    })
    .await;
}

/// A session that cannot go on (its only compositor lost, nothing to wait for) tells every
/// viewer why before the page loses its connection, instead of leaving it reconnecting with no
/// reason shown.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn the_page_is_told_why_a_session_ended() {
    let scene = small("balls");
    let plan = plan_options(&scene, 8);
    let cluster = InProcessCluster::start(1, 1).await.unwrap();
    let stage = cluster.stop_token("comp-0").unwrap();
    let mut session = cluster.connect(test_control()).await.unwrap();
    let view = View::bind(loopback()).await.unwrap();
    let addr = view.local_addr();
    let run = view.run(&mut session, &scene, &plan, CancellationToken::new());
    let test = async {
        let mut c = Client::connect(addr).await;
        c.expect("welcome").await;
        c.frame().await;
        stage.cancel();
        let ended = c.expect("ended").await;
        let text = ended["text"].as_str().unwrap().to_string();
        assert!(
            text.starts_with("the session ended") && text.contains("comp-0"),
            "{text}"
        );
        assert!(
            c.closed_within(Duration::from_secs(10)).await,
            "the view closed the page's link"
        );
    };
    let (outcome, ()) = tokio::time::timeout(lightfold_harness::RUN_DEADLINE, async {
        tokio::join!(run, test)
    })
    .await
    .expect("the view run timed out");
    assert!(outcome.error.is_some(), "the session could not go on");
    session.detach();
    cluster.stop().await.unwrap();
}

/// Watch-only viewers cannot lock the operator out: once `MAX_WATCHERS` of them watch, the next
/// is told why and closed, and a viewer who presents the token still gets in and steers (64
/// watch-only viewers used to take every slot, and the operator got 503).
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn watchers_leave_room_for_the_operator() {
    let scene = small("balls");
    let plan = plan_options(&scene, 4);
    let (ip, opts) = beyond_loopback();
    let opts = ViewOptions {
        allow_plain_token: true,
        ..opts
    };
    with_view(scene, plan, opts, |addr, _, _| async move {
        let remote = std::net::SocketAddr::new(ip, addr.port());
        let mut watchers = Vec::new();
        for _ in 0..lightfold_view::MAX_WATCHERS {
            let mut c = Client::connect(remote).await;
            let welcome = c.expect("welcome").await;
            assert_eq!(welcome["can_steer"], false, "{welcome}");
            watchers.push(c);
        }
        // One more watcher: it has a few seconds to present the token, then is told why.
        let mut late = Client::connect(remote).await;
        let refused = late.expect("error").await;
        assert!(
            refused["text"]
                .as_str()
                .unwrap()
                .contains("watching already"),
            "{refused}"
        );
        assert!(late.closed_within(Duration::from_secs(10)).await);
        // The operator presents the token at once and steers.
        let mut op = Client::connect(remote).await;
        op.send(&json!({"type": "hello", "token": "viewer-secret"}))
            .await;
        let welcome = op.expect("welcome").await;
        assert_eq!(welcome["can_steer"], true, "{welcome}");
        let revision = op
            .steer(json!({"type": "orbit", "yaw_deg": 10.0, "pitch_deg": 0.0}))
            .await;
        until_revision(&mut op, revision).await;
        drop(watchers);
    })
    .await;
}

/// The page's scene picker: the built-ins and the scene files of the view's folder, opened as
/// the command line opens `--scene` (here: small). Only a name the view offers opens; the frames
/// after one are its single-device render and every page is welcomed again with it; a scene the
/// cluster cannot plan is refused, and the view goes back to the scene it had.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_scene_opened_from_the_page_renders_and_one_no_plan_fits_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    // Two area lights of 512 samples each: more than three nodes take.
    std::fs::write(
        dir.path().join("too-many.toml"),
        "version = 1\n[base]\nscene = \"balls\"\n[quality]\nsamples_per_area_light = 512\n",
    )
    .unwrap();
    std::fs::write(dir.path().join("notes.txt"), "not a scene").unwrap();
    let scene = small("balls");
    let plan = plan_options(&scene, 4);
    let catalog = lightfold_view::SceneCatalog {
        dir: Some(dir.path().to_path_buf()),
        open: Box::new(|source: &str| {
            let mut s = lightfold_scene::load(source)?;
            if s.quality.samples_per_area_light.is_none() {
                s.quality.samples_per_area_light = Some(4);
            }
            s.camera.width = 64;
            s.camera.height = 48;
            let options = plan_options(&s, 4);
            Ok(lightfold_view::Opened { scene: s, options })
        }),
    };
    let opts = ViewOptions {
        scenes: Some(Arc::new(catalog)),
        ..loopback()
    };
    with_view(scene, plan, opts, |addr, delivered, _| async move {
        let mut c = Client::connect(addr).await;
        let welcome = c.expect("welcome").await;
        let names: Vec<String> =
            serde_json::from_value(welcome["scenes"]["names"].clone()).unwrap();
        assert!(names.iter().any(|n| n == "box"), "{names:?}");
        assert!(names.iter().any(|n| n == "too-many.toml"), "{names:?}");
        assert!(!names.iter().any(|n| n == "notes.txt"), "{names:?}");
        c.frame().await;
        // Names the view does not offer: refused, nothing changes.
        for name in [
            "../too-many.toml",
            "notes.txt",
            "/etc/passwd",
            "nowhere.toml",
        ] {
            let e = c
                .try_steer(json!({"type": "scene_open", "name": name}))
                .await
                .unwrap_or_else(|| panic!("{name:?} was taken"));
            assert!(
                e["text"]
                    .as_str()
                    .unwrap()
                    .contains("not a scene this view offers"),
                "{e}"
            );
        }
        // One that opens.
        c.steer(json!({"type": "scene_open", "name": "box"})).await;
        let again = c.expect("welcome").await;
        assert_eq!(again["scenes"]["current"], "box");
        assert_eq!(again["scene"]["name"], "box");
        let revision = again["revision"].as_u64().unwrap();
        let (f, _) = until_revision(&mut c, revision).await;
        let gpu = Gpu::new(&GpuOptions::default()).expect("a GPU adapter is required");
        assert_close(
            &delivered_frame(&delivered, frame_number(&f)),
            &single_device(&gpu, &small("box"), true),
            "the first frame of the opened scene",
        );
        // One no plan fits: refused by the loop, and the view goes back to `box`.
        c.steer(json!({"type": "scene_open", "name": "too-many.toml"}))
            .await;
        let opened = c.expect("welcome").await;
        assert_eq!(opened["scenes"]["current"], "too-many.toml");
        let back = c.expect("welcome").await;
        assert_eq!(back["scenes"]["current"], "box", "{back}");
        let mut notices = c.texts_of("notice");
        notices.extend(c.drain_for(Duration::from_millis(300)).await.0);
        assert!(
            notices.iter().any(|t| t["type"] == "notice"
                && t["text"].as_str().unwrap().contains("cannot open scene")),
            "{notices:?}"
        );
        let revision = back["revision"].as_u64().unwrap();
        c.send(&json!({"type": "render"})).await;
        let (f, _) = until_revision(&mut c, revision).await;
        assert_close(
            &delivered_frame(&delivered, frame_number(&f)),
            &single_device(&gpu, &small("box"), true),
            "the frame after the refused scene",
        );
        assert!(c.texts_of("ended").is_empty(), "the session ended");
    })
    .await;
}

/// Two boxes 12 m apart on one floor, each under its own spot light whose range (4 m) does not
/// reach the other box: a box casts only into its own light's map.
const TWO_BOXES: &str = r#"
version = 1
name = "two-boxes"

[camera]
position = [-3.0, 5.0, 6.0]
target = [-4.0, 0.0, 0.0]
up = [0.0, 1.0, 0.0]
fov_y_deg = 60.0
width = 160
height = 120

[[object]]
type = "plane"
name = "floor"
center = [0.0, 0.0, 0.0]
normal = [0.0, 1.0, 0.0]
u_axis = [1.0, 0.0, 0.0]
size = [24.0, 10.0]
diffuse = [0.8, 0.8, 0.8]

[[object]]
type = "box"
name = "left"
center = [-6.0, 0.5, 0.0]
size = [1.0, 1.0, 1.0]
diffuse = [0.7, 0.5, 0.4]

[[object]]
type = "box"
name = "right"
center = [6.0, 0.5, 0.0]
size = [1.0, 1.0, 1.0]
diffuse = [0.4, 0.5, 0.7]

[[light]]
type = "spot"
name = "over-left"
position = [-6.0, 3.0, 1.2]
direction = [0.0, -1.0, 0.0]
intensity = 20.0
outer_angle_deg = 60.0
range = 4.0

[[light]]
type = "spot"
name = "over-right"
position = [6.0, 3.0, 1.2]
direction = [0.0, -1.0, 0.0]
intensity = 20.0
outer_angle_deg = 60.0
range = 4.0
"#;

/// An object picked and moved from the page: the pick names it, its move reaches the next
/// frame, in walkthrough mode only the map of the light it casts for is drawn again (the other
/// light's map is kept), and the session saved as a scene file (`[[move]]`) renders,
/// single-device, the frame the view shows; the scene unmoved does not (the control).
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn an_object_moved_from_the_page_redraws_only_the_maps_it_reaches() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("two_boxes.toml");
    std::fs::write(&path, TWO_BOXES).unwrap();
    let scene = lightfold_scene::load(path.to_str().unwrap()).unwrap();
    let plan = plan_options(&scene, 4);
    let opts = ViewOptions {
        scene_source: Some(path.display().to_string()),
        ..loopback()
    };
    let original = scene.clone();
    let folder = dir.path().to_path_buf();
    with_view(scene, plan, opts, |addr, delivered, _| async move {
        let mut c = Client::connect(addr).await;
        c.expect("welcome").await;
        let first = c.frame().await;
        // (shadow passes, maps kept) over the nodes that render lights.
        let maps = |f: &Frame| -> (u64, u64) {
            f.header["daemons"]
                .as_array()
                .unwrap()
                .iter()
                .filter(|d| d["role"] == "node" && d["lights_rendered"].as_u64() > Some(0))
                .fold((0, 0), |(p, k), d| {
                    (
                        p + d["shadow_passes"].as_u64().unwrap(),
                        k + d["maps_kept"].as_u64().unwrap(),
                    )
                })
        };
        // Control: the first frame draws both lights' maps.
        let (passes, _) = maps(&first);
        assert!(passes >= 2, "{:?}", maps(&first));

        // Pick the left box: somewhere on a grid over the view it is seen.
        let mut left = None;
        'grid: for j in 1..12 {
            for i in 1..16 {
                let (x, y) = (i as f32 / 16.0, j as f32 / 12.0);
                c.send(&json!({"type": "object_pick", "x": x, "y": y}))
                    .await;
                let o = c.expect("object").await;
                if o["name"] == "left" {
                    assert!(o["fixed"].is_null(), "{o}");
                    left = o["mesh"].as_u64();
                    break 'grid;
                }
            }
        }
        let left = left.expect("the left box is picked somewhere in the view");
        let revision = c
            .steer(json!({"type": "object_set", "mesh": left,
                "translate": [0.6, 0.0, 0.3], "rotate": [0.0, 30.0, 0.0]}))
            .await;
        let (moved, _) = until_revision(&mut c, revision).await;
        let (passes, kept) = maps(&moved);
        assert!(passes >= 1, "the moved box's light draws its map again");
        assert!(
            kept >= 1,
            "the other light's map is kept: {passes} passes, {kept} kept"
        );
        // Every page is told the moves (the welcome's, with none, came first).
        let moves = loop {
            let m = c.expect("moves").await;
            if m["moves"].as_array().is_some_and(|a| !a.is_empty()) {
                break m;
            }
        };
        assert_eq!(moves["moves"][0]["name"], "left", "{moves}");

        // A drag moves it further; the session saved renders the frame shown.
        let revision = c
            .steer(json!({"type": "object_drag", "mesh": left, "x": 0.05, "y": 0.0}))
            .await;
        let (dragged, _) = until_revision(&mut c, revision).await;
        let text =
            saved_session_renders(addr, &delivered, &dragged, Some(&folder), &original).await;
        assert!(text.contains("[[move]]"), "{text}");

        // Moves that cannot be made are refused and change nothing.
        for bad in [
            json!({"type": "object_set", "mesh": 99, "translate": [1.0, 0.0, 0.0]}),
            json!({"type": "object_set", "mesh": left, "scale": 0.0}),
            json!({"type": "object_drag", "mesh": left, "x": 1e9, "y": 0.0}),
            json!({"type": "object_pick", "x": 2.0, "y": 0.5}),
        ] {
            let e = c.try_steer(bad.clone()).await.expect("refused");
            assert!(e["text"].is_string(), "{bad}: {e}");
        }
    })
    .await;
}
