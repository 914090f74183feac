//! The live page in a real browser: headless Chromium (Debian's `chromium`, installed by
//! `scripts/install-deps.sh --test`) opens the view of an in-process cluster over the DevTools protocol,
//! must show a frame that is not blank, and a mouse drag across the frame must orbit the camera:
//! the steering revision rises, a frame requested at it arrives, and the picture changes. Then
//! the page's other controls: the exposure slider brightens the frame on screen with no render,
//! the PNG, JPEG and EXR links download the frame, the numeric camera fields set the camera and
//! field of view on Enter, and camera bookmarks are saved, kept across a reload, recalled and
//! deleted; a light's marker and an object (Alt+drag) are dragged and move, and another scene
//! is opened from the Scene box. Without Chromium the test fails, naming the install step.

mod cdp;

use anyhow::{Context, anyhow, ensure};
use cdp::Browser;
use image::RgbImage;
use lightfold_coordinator::plan::PlanOptions;
use lightfold_harness::{InProcessCluster, small, test_control};
use lightfold_view::{View, ViewOptions};
use serde_json::Value;
use std::time::Duration;
use tokio_util::sync::CancellationToken;

/// The browser's viewport, CSS pixels at device scale 1.
const WIDTH: u32 = 1280;
const HEIGHT: u32 = 800;
/// Lavapipe on two shared cores renders the small scene in a few hundred ms; be generous.
const WAIT: Duration = Duration::from_secs(60);
/// The whole test, cluster start to stop.
const TEST_DEADLINE: Duration = Duration::from_secs(300);
/// A rendered frame region varies far more than this (standard deviation of a channel's 8-bit
/// values over the region); a blank or uniform one does not vary at all.
const MIN_STD_DEV: f64 = 10.0;
/// Mean absolute difference (8-bit channel values) that a large orbit must exceed.
const MIN_DIFF: f64 = 8.0;

/// What the page showed.
#[derive(Debug)]
struct Figures {
    std_dev: f64,
    diff: f64,
    region: (u32, u32),
    first: Value,
    after: Value,
    revision_before: i64,
    revision_after: i64,
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn the_page_shows_frames_and_a_drag_orbits_the_camera() {
    // Fail at once, before the cluster starts, when the browser is missing.
    cdp::chromium_path();
    let scene = small("balls");
    let cluster = InProcessCluster::start(2, 1).await.unwrap();
    let mut session = cluster.connect(test_control()).await.unwrap();
    let plan = PlanOptions {
        lights_per_node: 4,
        ..PlanOptions::default()
    };
    // The built-ins to pick from, opened small as the session's scene is.
    let scenes = lightfold_view::SceneCatalog {
        dir: None,
        open: Box::new(|name: &str| {
            let scene = small(name);
            let options = PlanOptions {
                lights_per_node: 4,
                ..PlanOptions::default()
            };
            Ok(lightfold_view::Opened { scene, options })
        }),
    };
    let view = View::bind(ViewOptions {
        listen: "127.0.0.1:0".into(),
        scenes: Some(std::sync::Arc::new(scenes)),
        ..ViewOptions::default()
    })
    .await
    .unwrap();
    let url = format!("http://{}/", view.local_addr());
    let stop = CancellationToken::new();
    let ended = CancellationToken::new();
    let run = async {
        let outcome = view.run(&mut session, &scene, &plan, stop.clone()).await;
        ended.cancel();
        outcome
    };
    let drive = async {
        let r = tokio::select! {
            r = browse(&url) => r,
            _ = ended.cancelled() => Err(anyhow!("the view stopped before the page was checked")),
        };
        stop.cancel();
        r
    };
    let (outcome, figures) =
        tokio::time::timeout(TEST_DEADLINE, async { tokio::join!(run, drive) })
            .await
            .expect("the browser test timed out");
    let figures = figures.unwrap_or_else(|e| panic!("{e:#}"));
    assert!(
        outcome.error.is_none(),
        "the view's event loop failed: {:?}",
        outcome.error
    );
    println!(
        "frame region {}x{} px: std-dev {:.2} (> {MIN_STD_DEV}), difference after the drag \
         {:.2} (> {MIN_DIFF}); revision {} -> {}; first frame {}, after the drag {}",
        figures.region.0,
        figures.region.1,
        figures.std_dev,
        figures.diff,
        figures.revision_before,
        figures.revision_after,
        figures.first,
        figures.after,
    );
    session.shutdown().await;
    cluster.stop().await.unwrap();
}

/// Drives the page at `url`: a frame, not blank; a drag; a changed frame.
async fn browse(url: &str) -> anyhow::Result<Figures> {
    let mut b = Browser::launch(WIDTH, HEIGHT).await?;
    let r = steps(&mut b, url).await;
    let r = r.map_err(|e| {
        e.context(format!(
            "page exceptions: {:?}\npage console: {:?}\nchromium stderr (tail):\n{}",
            b.exceptions,
            b.console,
            tail(&b.stderr_tail(), 30)
        ))
    });
    b.close().await;
    r
}

async fn steps(b: &mut Browser, url: &str) -> anyhow::Result<Figures> {
    b.open_page(WIDTH, HEIGHT).await?;
    b.navigate(url).await?;
    let state = "(() => { const v = window.lightfoldView; return v ? { connected: v.connected, \
        frames: v.frames, canSteer: v.canSteer, revision: v.revision, unacked: v.unacked, \
        header: v.header, shown: v.displayed, errors: v.errors, lights: v.lights, \
        ended: v.ended } : null; })()";
    let first = b
        .wait_for("a first frame on screen", state, WAIT, |v| {
            v["frames"].as_u64().unwrap_or(0) >= 1 && v["shown"].is_object()
        })
        .await?;
    ensure!(
        first["canSteer"] == Value::Bool(true),
        "a page served to loopback may steer: {first}"
    );
    let shown = &first["shown"];
    ensure!(
        shown["daemons"].as_array().is_some_and(|d| !d.is_empty()),
        "the frame header names no daemons: {shown}"
    );

    let rect = frame_rect(b).await?;
    let before_png = b.screenshot().await?;
    let before = crop(&before_png, rect)?;
    save(&before_png, "browser-before.png");
    let std_dev = not_blank(&before).context("the first frame on screen")?;
    // Negative control: the same check refuses a uniform picture of the region's size.
    let uniform = RgbImage::from_pixel(before.width(), before.height(), mean_pixel(&before));
    ensure!(
        not_blank(&uniform).is_err(),
        "the blank check passed a uniform image"
    );

    let revision_before = first["revision"].as_i64().unwrap_or(-1);
    // Drag left to right across the middle of the frame, left button held.
    let (x0, x1, y) = (
        rect.0 + rect.2 * 0.3,
        rect.0 + rect.2 * 0.7,
        rect.1 + rect.3 * 0.5,
    );
    b.mouse("mousePressed", x0, y, 1).await?;
    let moves = 12;
    for i in 1..=moves {
        let x = x0 + (x1 - x0) * i as f64 / moves as f64;
        b.mouse("mouseMoved", x, y + (i % 3) as f64, 1).await?;
        tokio::time::sleep(Duration::from_millis(25)).await;
    }
    b.mouse("mouseReleased", x1, y, 0).await?;
    let acked = b
        .wait_for("the drag's steering acknowledged", state, WAIT, |v| {
            v["revision"].as_i64().unwrap_or(-1) > revision_before
                && v["unacked"].as_u64() == Some(0)
        })
        .await?;
    let revision_after = acked["revision"].as_i64().context("no revision")?;
    let after = b
        .wait_for("a frame at the new revision on screen", state, WAIT, |v| {
            v["shown"]["revision"].as_i64().unwrap_or(-1) >= revision_after
        })
        .await?;

    let rect2 = frame_rect(b).await?;
    ensure!(rect2 == rect, "the frame moved: {rect:?} then {rect2:?}");
    let after_png = b.screenshot().await?;
    save(&after_png, "browser-after.png");
    let moved = crop(&after_png, rect)?;
    not_blank(&moved).context("the frame after the drag")?;
    let diff = mean_abs_diff(&before, &moved);
    ensure!(
        mean_abs_diff(&before, &before) < MIN_DIFF,
        "the difference check passed identical images"
    );
    ensure!(
        diff > MIN_DIFF,
        "the frame did not change after the drag: mean |difference| {diff:.3} <= {MIN_DIFF}"
    );

    // The other controls: a wheel notch zooms, a key orbits, a slider sets a light's power; the
    // server accepts them all (no `error` message) and echoes the light.
    b.call(
        "Input.dispatchMouseEvent",
        serde_json::json!({"type": "mouseWheel", "x": x0, "y": y, "deltaX": 0, "deltaY": 100}),
    )
    .await?;
    b.call(
        "Input.dispatchKeyEvent",
        serde_json::json!({"type": "keyDown", "key": "ArrowLeft", "code": "ArrowLeft",
                           "windowsVirtualKeyCode": 37}),
    )
    .await?;
    b.call(
        "Input.dispatchKeyEvent",
        serde_json::json!({"type": "keyUp", "key": "ArrowLeft", "code": "ArrowLeft",
                           "windowsVirtualKeyCode": 37}),
    )
    .await?;
    b.eval(
        "(() => { const s = document.querySelector('#lights input[type=range]'); \
         s.value = '2'; s.dispatchEvent(new Event('input')); return true; })()",
    )
    .await?;
    let steered = b
        .wait_for("zoom, key and light acknowledged", state, WAIT, |v| {
            v["revision"].as_i64().unwrap_or(-1) >= revision_after + 3
                && v["unacked"].as_u64() == Some(0)
                && v["lights"][0]["intensity"].as_f64() == Some(2.0)
        })
        .await?;
    ensure!(
        steered["errors"].as_array().is_some_and(|e| e.is_empty()),
        "the server refused the page's messages: {}",
        steered["errors"]
    );

    // What once ended the cluster from this page: a saturated colour (a pure-red light, whose
    // node colour has zero channels), then a frame budget set and cleared, each a re-plan over
    // the red scene. The session goes on: frames at the last revision arrive, nothing is refused
    // and the page is not told the session ended.
    let revision = steered["revision"].as_i64().context("no revision")?;
    b.eval(
        "(() => { const c = document.querySelector('#lights input[type=color]'); \
         c.value = '#ff0000'; c.dispatchEvent(new Event('input')); return true; })()",
    )
    .await?;
    for budget in ["40", ""] {
        b.eval(&format!(
            "(() => {{ document.getElementById('budget').value = '{budget}'; \
             document.getElementById('budget-form').requestSubmit(); return true; }})()"
        ))
        .await?;
        tokio::time::sleep(Duration::from_millis(300)).await;
    }
    let red = b
        .wait_for(
            "frames after a red light and a budget set and cleared",
            state,
            WAIT,
            |v| {
                let rev = v["revision"].as_i64().unwrap_or(-1);
                rev >= revision + 3
                    && v["unacked"].as_u64() == Some(0)
                    && v["shown"]["revision"].as_i64().unwrap_or(-1) >= rev
            },
        )
        .await?;
    ensure!(
        red["ended"].is_null() && red["connected"] == Value::Bool(true),
        "the session ended after a red light and a budget: {red}"
    );
    ensure!(
        red["errors"].as_array().is_some_and(|e| e.is_empty()),
        "the server refused the red light or the budget: {}",
        red["errors"]
    );
    let red_png = b.screenshot().await?;
    save(&red_png, "browser-red.png");
    let red_frame = crop(&red_png, rect)?;
    not_blank(&red_frame).context("the frame under the red light")?;
    // A still scene shows no playback controls.
    let anim = b
        .eval("getComputedStyle(document.getElementById('anim')).display")
        .await?;
    ensure!(
        anim == "none",
        "a still scene shows playback controls: {anim}"
    );
    exposure(b, rect, &red, &red_frame).await?;
    downloads(b).await?;
    camera_fields_and_bookmarks(b, url).await?;
    light_marker_drag(b).await?;
    object_drag(b, rect).await?;
    open_scene(b, rect).await?;
    ensure!(
        b.exceptions.is_empty(),
        "the page threw: {:?}",
        b.exceptions
    );
    Ok(Figures {
        std_dev,
        diff,
        region: (before.width(), before.height()),
        first: first["shown"]["frame"].clone(),
        after: after["shown"]["frame"].clone(),
        revision_before,
        revision_after,
    })
}

/// The page's state for the controls below.
const CONTROLS: &str = "(() => { const v = window.lightfoldView; return v ? { connected: v.connected, \
    revision: v.revision, unacked: v.unacked, shown: v.displayed, errors: v.errors, \
    camera: v.camera, exposure: v.exposure, bookmarks: v.bookmarks, scene: v.scene?.name } \
    : null; })()";

/// Two stops more on the exposure slider: the frame on screen is encoded again, brighter, at the
/// same steering revision (nothing rendered for it).
async fn exposure(
    b: &mut Browser,
    rect: (f64, f64, f64, f64),
    at: &Value,
    frame: &RgbImage,
) -> anyhow::Result<()> {
    let shown = &at["shown"];
    let stops = shown["exposure"]
        .as_f64()
        .context("no exposure in the header")?;
    let set = b
        .eval(
            "(() => { const s = document.getElementById('exposure'); \
             s.value = String(Number(s.value) + 2); s.dispatchEvent(new Event('input')); \
             return Number(s.value); })()",
        )
        .await?;
    let want = set.as_f64().context("the slider's value")?;
    ensure!(
        (want - stops - 2.0).abs() < 1e-6,
        "slider {set}, frame at {stops}"
    );
    let brighter = b
        .wait_for("the frame on screen at 2 stops more", CONTROLS, WAIT, |v| {
            v["shown"]["exposure"]
                .as_f64()
                .is_some_and(|e| (e - want).abs() < 1e-4)
                && v["unacked"].as_u64() == Some(0)
        })
        .await?;
    ensure!(
        brighter["shown"]["revision"] == shown["revision"]
            && brighter["revision"] == at["revision"]
            && brighter["shown"]["frame"] == shown["frame"],
        "an exposure edit rendered a frame: {} then {}",
        shown,
        brighter["shown"]
    );
    ensure!(brighter["exposure"].as_f64() == Some(want), "{brighter}");
    let png = b.screenshot().await?;
    save(&png, "browser-exposure.png");
    let after = crop(&png, rect)?;
    let (dark, bright) = (mean_luma(frame), mean_luma(&after));
    println!("exposure {stops} -> {want} stops: mean luma on screen {dark:.1} -> {bright:.1}");
    ensure!(
        bright > dark + 5.0,
        "2 stops more did not brighten the frame: {dark:.1} -> {bright:.1}"
    );
    Ok(())
}

/// The page's PNG, JPEG and EXR links fetch the frame in those formats.
async fn downloads(b: &mut Browser) -> anyhow::Result<()> {
    let got = b
        .eval(
            "(async () => { const out = {}; for (const id of ['dl-png', 'dl-jpg', 'exr']) { \
             const a = document.getElementById(id); const r = await fetch(a.getAttribute('href')); \
             const buf = await r.arrayBuffer(); out[id] = { href: a.getAttribute('href'), \
             status: r.status, type: r.headers.get('content-type'), bytes: buf.byteLength, \
             head: Array.from(new Uint8Array(buf.slice(0, 4))) }; } return out; })()",
        )
        .await?;
    for (id, href, kind, magic) in [
        (
            "dl-png",
            "/frame.png",
            "image/png",
            [0x89, b'P', b'N', b'G'],
        ),
        (
            "dl-jpg",
            "/frame.jpg",
            "image/jpeg",
            [0xFF, 0xD8, 0xFF, 0xE0],
        ),
        ("exr", "/frame.exr", "image/x-exr", [0x76, 0x2F, 0x31, 0x01]),
    ] {
        let d = &got[id];
        let head: Vec<u8> = d["head"]
            .as_array()
            .context("no bytes")?
            .iter()
            .filter_map(|x| x.as_u64().map(|x| x as u8))
            .collect();
        ensure!(
            d["href"] == href && d["status"] == 200 && d["type"] == kind,
            "{id}: {d}"
        );
        // The JPEG's fourth byte depends on the encoder's first segment: check its marker only.
        let n = if id == "dl-jpg" { 3 } else { 4 };
        ensure!(head[..n] == magic[..n], "{id} starts {head:02x?}: {d}");
    }
    Ok(())
}

/// The numeric camera fields set position, target and field of view on Enter; a bookmark of that
/// camera survives a reload and brings it back after a reset; deleting it empties the list.
/// A light's marker dragged across the frame moves the light: its position in the lights the
/// page is sent changes, and a frame at the new revision reaches the screen.
async fn light_marker_drag(b: &mut Browser) -> anyhow::Result<()> {
    let marker = "(() => { const m = document.querySelector('.marker[data-index=\"0\"]'); \
        if (!m) return null; const r = m.getBoundingClientRect(); \
        const v = window.lightfoldView; \
        return { x: r.left + r.width / 2, y: r.top + r.height / 2, revision: v.revision, \
        unacked: v.unacked, shown: v.displayed?.revision, \
        position: (v.lightInfo || [])[0]?.position }; })()";
    let before = b
        .wait_for("light 0's marker over the frame", marker, WAIT, |v| {
            v["x"].is_number()
        })
        .await?;
    let (x, y) = (
        before["x"].as_f64().context("x")?,
        before["y"].as_f64().context("y")?,
    );
    let revision = before["revision"].as_i64().unwrap_or(-1);
    b.mouse("mousePressed", x, y, 1).await?;
    for i in 1..=8 {
        b.mouse("mouseMoved", x + 8.0 * i as f64, y, 1).await?;
        tokio::time::sleep(Duration::from_millis(25)).await;
    }
    b.mouse("mouseReleased", x + 64.0, y, 0).await?;
    let moved = b
        .wait_for("the light moved and its frame shown", marker, WAIT, |v| {
            v["revision"].as_i64().unwrap_or(-1) > revision
                && v["unacked"].as_u64() == Some(0)
                && v["shown"].as_i64() >= v["revision"].as_i64()
        })
        .await?;
    ensure!(
        moved["position"] != before["position"] && moved["position"].is_array(),
        "the light did not move: {before} then {moved}"
    );
    Ok(())
}

/// Alt+drag in the frame picks the object under the pointer and moves it: the page names it,
/// every page is told its move, and a frame at the new revision reaches the screen.
async fn object_drag(b: &mut Browser, rect: (f64, f64, f64, f64)) -> anyhow::Result<()> {
    let state = "(() => { const v = window.lightfoldView; \
        return { revision: v.revision, unacked: v.unacked, shown: v.displayed?.revision, \
        object: v.object, moves: v.moves }; })()";
    let before = b.eval(state).await?;
    let revision = before["revision"].as_i64().unwrap_or(-1);
    let (x, y) = (rect.0 + rect.2 * 0.5, rect.1 + rect.3 * 0.6);
    const ALT: u32 = 1;
    b.mouse_with("mousePressed", x, y, 1, ALT).await?;
    b.wait_for("the object under the pointer picked", state, WAIT, |v| {
        v["object"]["mesh"].is_number()
    })
    .await?;
    for i in 1..=8 {
        b.mouse_with("mouseMoved", x + 6.0 * i as f64, y, 1, ALT)
            .await?;
        tokio::time::sleep(Duration::from_millis(25)).await;
    }
    b.mouse_with("mouseReleased", x + 48.0, y, 0, ALT).await?;
    let moved = b
        .wait_for("the object moved and its frame shown", state, WAIT, |v| {
            v["revision"].as_i64().unwrap_or(-1) > revision
                && v["unacked"].as_u64() == Some(0)
                && v["shown"].as_i64() >= v["revision"].as_i64()
                && v["moves"].as_array().is_some_and(|m| !m.is_empty())
        })
        .await?;
    let (picked, listed) = (&moved["object"]["mesh"], &moved["moves"][0]["mesh"]);
    ensure!(
        picked == listed && moved["moves"][0]["translate"] != serde_json::json!([0.0, 0.0, 0.0]),
        "the picked object is not the one moved: {moved}"
    );
    Ok(())
}

/// The Scene box: `box` picked and opened; the page is welcomed with it and shows its frames.
async fn open_scene(b: &mut Browser, rect: (f64, f64, f64, f64)) -> anyhow::Result<()> {
    // A light's numeric editor stays folded until its ✎ is clicked (a stylesheet's `display:
    // grid` once overrode the `hidden` attribute and every editor showed).
    let shown = b
        .eval(
            "[...document.querySelectorAll('.light-edit')].filter((e) =>              getComputedStyle(e).display !== 'none').length",
        )
        .await?;
    ensure!(shown == 0, "{shown} light editors unfolded unasked");
    let before = crop(&b.screenshot().await?, rect)?;
    let picked = b
        .eval(
            "(() => { const box = document.getElementById('scene-box');              const pick = document.getElementById('scene-pick');              if (box.hidden || ![...pick.options].some((o) => o.value === 'box')) return false;              pick.value = 'box';              document.getElementById('scene-form').requestSubmit(); return true; })()",
        )
        .await?;
    ensure!(picked == Value::Bool(true), "no `box` in the Scene box");
    let opened = b
        .wait_for("box opened and its frame shown", CONTROLS, WAIT, |v| {
            v["scene"] == "box"
                && v["unacked"].as_u64() == Some(0)
                && v["shown"]["revision"].as_i64() >= v["revision"].as_i64()
        })
        .await?;
    ensure!(
        opened["errors"].as_array().is_some_and(|e| e.is_empty()),
        "the server refused the pick: {}",
        opened["errors"]
    );
    let png = b.screenshot().await?;
    save(&png, "browser-scene.png");
    let after = crop(&png, rect)?;
    not_blank(&after).context("the opened scene's frame")?;
    let diff = mean_abs_diff(&before, &after);
    ensure!(
        diff > MIN_DIFF,
        "the frame did not change when box opened: {diff:.3}"
    );
    Ok(())
}

async fn camera_fields_and_bookmarks(b: &mut Browser, url: &str) -> anyhow::Result<()> {
    let now = b.eval(CONTROLS).await?;
    let cam = &now["camera"];
    let v3 = |v: &Value| -> anyhow::Result<[f64; 3]> {
        let a = v.as_array().with_context(|| format!("not a vector: {v}"))?;
        ensure!(a.len() == 3, "not a vector: {v}");
        Ok([0, 1, 2].map(|i| a[i].as_f64().unwrap_or(f64::NAN)))
    };
    let (pos, target) = (v3(&cam["position"])?, v3(&cam["target"])?);
    // A quarter further from the target, at 30°.
    let want: [f64; 3] =
        [0, 1, 2].map(|i| ((target[i] + (pos[i] - target[i]) * 1.25) * 1000.0).round() / 1000.0);
    let fov = 30.0;
    let revision = now["revision"].as_i64().unwrap_or(-1);
    b.eval(&format!(
        "(() => {{ const set = (id, v) => {{ document.getElementById(id).value = String(v); }}; \
         set('cam-px', {}); set('cam-py', {}); set('cam-pz', {}); set('cam-tx', {}); \
         set('cam-ty', {}); set('cam-tz', {}); set('cam-fov', {fov}); \
         document.getElementById('cam-fov').focus(); \
         document.getElementById('camera-form').requestSubmit(); return true; }})()",
        want[0], want[1], want[2], target[0], target[1], target[2]
    ))
    .await?;
    let is_wanted = move |v: &Value| -> bool {
        let c = &v["camera"];
        let p = c["position"].as_array();
        c["fov_y_deg"]
            .as_f64()
            .is_some_and(|f| (f - fov).abs() < 1e-4)
            && p.is_some_and(|p| {
                p.len() == 3
                    && (0..3).all(|i| p[i].as_f64().is_some_and(|x| (x - want[i]).abs() < 1e-3))
            })
    };
    let set = b
        .wait_for("the camera from the fields", CONTROLS, WAIT, |v| {
            is_wanted(v)
                && v["unacked"].as_u64() == Some(0)
                && v["revision"].as_i64() > Some(revision)
        })
        .await?;
    ensure!(
        set["errors"].as_array().is_some_and(|e| e.is_empty()),
        "the camera fields were refused: {}",
        set["errors"]
    );
    b.wait_for("a frame from the new camera", CONTROLS, WAIT, |v| {
        v["shown"]["revision"].as_i64() >= set["revision"].as_i64()
    })
    .await?;

    // Bookmark it, reload (the list is the browser's), reset, recall.
    b.eval(
        "(() => { document.getElementById('bookmark-name').value = 'wide'; \
         document.getElementById('bookmark-form').requestSubmit(); return true; })()",
    )
    .await?;
    let has = |name: &'static str| {
        move |v: &Value| {
            v["bookmarks"]
                .as_array()
                .is_some_and(|b| b.iter().any(|x| x == name))
        }
    };
    b.wait_for("the bookmark listed", CONTROLS, WAIT, has("wide"))
        .await?;
    b.navigate(url).await?;
    b.wait_for("the bookmark after a reload", CONTROLS, WAIT, |v| {
        v["connected"] == Value::Bool(true) && has("wide")(v)
    })
    .await?;
    b.eval("(() => { document.getElementById('btn-reset').click(); return true; })()")
        .await?;
    let reset = b
        .wait_for("the scene's camera again", CONTROLS, WAIT, |v| {
            v["camera"]["fov_y_deg"]
                .as_f64()
                .is_some_and(|f| (f - fov).abs() > 0.5)
                && v["unacked"].as_u64() == Some(0)
        })
        .await?;
    ensure!(
        !is_wanted(&reset),
        "reset left the bookmarked camera: {reset}"
    );
    b.eval(
        "(() => { const b = [...document.querySelectorAll('#bookmarks button.bname')] \
         .find((x) => x.textContent === 'wide'); b.click(); return true; })()",
    )
    .await?;
    b.wait_for("the bookmarked camera recalled", CONTROLS, WAIT, |v| {
        is_wanted(v) && v["unacked"].as_u64() == Some(0)
    })
    .await?;
    b.eval(
        "(() => { document.querySelector('#bookmarks button[aria-label=\"delete wide\"]').click(); \
         return true; })()",
    )
    .await?;
    b.wait_for("the bookmark deleted", CONTROLS, WAIT, |v| {
        v["bookmarks"].as_array().is_some_and(|b| b.is_empty())
    })
    .await?;
    let stored = b
        .eval("localStorage.getItem('lightfold.bookmarks.' + window.lightfoldView.scene.name)")
        .await?;
    ensure!(stored == "[]", "localStorage still holds {stored}");
    Ok(())
}

fn mean_luma(img: &RgbImage) -> f64 {
    let n = (img.width() as f64 * img.height() as f64).max(1.0);
    img.pixels()
        .map(|p| 0.2126 * p[0] as f64 + 0.7152 * p[1] as f64 + 0.0722 * p[2] as f64)
        .sum::<f64>()
        / n
}

/// The `#frame` element's box (x, y, width, height) in CSS pixels.
async fn frame_rect(b: &mut Browser) -> anyhow::Result<(f64, f64, f64, f64)> {
    let r = b
        .eval(
            "(() => { const r = document.getElementById('frame').getBoundingClientRect(); \
             return [r.x, r.y, r.width, r.height]; })()",
        )
        .await?;
    let n = |i: usize| r[i].as_f64().with_context(|| format!("bad rect {r}"));
    let rect = (n(0)?, n(1)?, n(2)?, n(3)?);
    ensure!(
        rect.2 >= 32.0 && rect.3 >= 32.0,
        "the frame is too small to judge: {rect:?}"
    );
    Ok(rect)
}

/// The region of the screenshot inside `rect`, 2 px in from its edges.
fn crop(png: &[u8], rect: (f64, f64, f64, f64)) -> anyhow::Result<RgbImage> {
    let img = image::load_from_memory_with_format(png, image::ImageFormat::Png)
        .context("decoding the screenshot")?
        .to_rgb8();
    let x = (rect.0.ceil() as u32 + 2).min(img.width());
    let y = (rect.1.ceil() as u32 + 2).min(img.height());
    let x1 = ((rect.0 + rect.2).floor() as u32)
        .saturating_sub(2)
        .min(img.width());
    let y1 = ((rect.1 + rect.3).floor() as u32)
        .saturating_sub(2)
        .min(img.height());
    ensure!(
        x1 > x + 8 && y1 > y + 8,
        "the frame region {rect:?} lies outside the {}x{} screenshot",
        img.width(),
        img.height()
    );
    Ok(image::imageops::crop_imm(&img, x, y, x1 - x, y1 - y).to_image())
}

/// The standard deviation of the region's channel values if it is above `MIN_STD_DEV`.
fn not_blank(img: &RgbImage) -> anyhow::Result<f64> {
    let s = std_dev(img);
    ensure!(
        s > MIN_STD_DEV,
        "the frame region looks blank: channel std-dev {s:.3} <= {MIN_STD_DEV}"
    );
    Ok(s)
}

/// The largest of the three channels' standard deviations over the region's pixels.
fn std_dev(img: &RgbImage) -> f64 {
    let n = (img.width() as f64 * img.height() as f64).max(1.0);
    (0..3)
        .map(|c| {
            let values = || img.pixels().map(move |p| p[c] as f64);
            let mean = values().sum::<f64>() / n;
            (values().map(|x| (x - mean).powi(2)).sum::<f64>() / n).sqrt()
        })
        .fold(0.0, f64::max)
}

fn mean_pixel(img: &RgbImage) -> image::Rgb<u8> {
    let mut sum = [0u64; 3];
    for p in img.pixels() {
        for (s, &v) in sum.iter_mut().zip(&p.0) {
            *s += v as u64;
        }
    }
    let n = (img.width() as u64 * img.height() as u64).max(1);
    image::Rgb(sum.map(|s| (s / n) as u8))
}

fn mean_abs_diff(a: &RgbImage, b: &RgbImage) -> f64 {
    let (a, b) = (a.as_raw(), b.as_raw());
    let total: u64 = a.iter().zip(b).map(|(&x, &y)| x.abs_diff(y) as u64).sum();
    total as f64 / a.len().max(1) as f64
}

/// Keeps a screenshot beside the build for a person to look at.
fn save(png: &[u8], name: &str) {
    let path = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    if std::fs::write(&path, png).is_ok() {
        println!("screenshot: {}", path.display());
    }
}

fn tail(text: &str, lines: usize) -> String {
    let v: Vec<&str> = text.lines().collect();
    v[v.len().saturating_sub(lines)..].join("\n")
}

/// The image checks themselves, without a browser: a picture passes, a uniform one fails, and
/// the difference of a picture with itself is zero.
#[test]
fn the_image_checks_tell_pictures_from_blanks() {
    let picture = RgbImage::from_fn(64, 48, |x, y| {
        image::Rgb([(x * 4) as u8, (y * 5) as u8, ((x + y) * 2) as u8])
    });
    assert!(not_blank(&picture).is_ok());
    assert!(not_blank(&RgbImage::from_pixel(64, 48, image::Rgb([20, 24, 30]))).is_err());
    assert_eq!(mean_abs_diff(&picture, &picture), 0.0);
    let shifted = RgbImage::from_fn(64, 48, |x, y| *picture.get_pixel((x + 16) % 64, y));
    assert!(mean_abs_diff(&picture, &shifted) > MIN_DIFF);
}
