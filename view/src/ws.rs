//! One viewer's WebSocket: the welcome, then the newest frame whenever one is ready and the
//! viewer has taken the one before, the status, camera and lights when they change, and the
//! viewer's steering messages (`docs/live-view.md`).

use crate::access::Access;
use crate::camera::{Steer, SteerError};
use crate::hub::{Hub, ViewFrame};
use crate::json;
use axum::extract::ws::{Message, WebSocket};
use futures::stream::{SplitSink, SplitStream};
use futures::{SinkExt, StreamExt};
use serde::Deserialize;
use serde_json::{Value, json};
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use tokio::sync::watch;

#[derive(Debug, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
enum Input {
    Hello {
        token: String,
    },
    Orbit {
        yaw_deg: f32,
        pitch_deg: f32,
    },
    Pan {
        x: f32,
        y: f32,
    },
    Zoom {
        factor: f32,
    },
    Camera {
        camera: CameraIn,
    },
    Reset,
    Light {
        index: u32,
        color: [f32; 3],
        intensity: f32,
    },
    /// Light `index` as a scene file's `[[light]]` table says (`docs/scenes.md`).
    LightSet {
        index: u32,
        light: lightfold_scene::file::spec::LightSpec,
    },
    LightAdd {
        light: lightfold_scene::file::spec::LightSpec,
    },
    LightRemove {
        index: u32,
    },
    /// Move light `index` by fractions of the view's width and height, at its distance.
    LightDrag {
        index: u32,
        x: f32,
        y: f32,
    },
    /// The object seen through `(x, y)`, fractions of the view from its left and top: answered
    /// with an `object` message (its mesh, name and move; `mesh: null` where there is none).
    ObjectPick {
        x: f32,
        y: f32,
    },
    /// Object `mesh` moved from where the scene has it (`scene::moves::MeshMove`).
    ObjectSet {
        mesh: u32,
        #[serde(default)]
        translate: [f32; 3],
        #[serde(default)]
        rotate: [f32; 3],
        #[serde(default = "unit_scale")]
        scale: f32,
    },
    /// Move object `mesh` by fractions of the view's width and height, at its depth.
    ObjectDrag {
        mesh: u32,
        x: f32,
        y: f32,
    },
    Render,
    Stats,
    /// Jump to a scene time (seconds).
    Time {
        t: f32,
    },
    Play,
    Pause,
    /// Playback speed, times real time.
    Speed {
        speed: f32,
    },
    /// Loop at the end of the clip, or stop there.
    Loop {
        on: bool,
    },
    /// The exposure frames are encoded at, stops (applied to the frames encoded from now on and
    /// to the last frame again; nothing is rendered for it).
    Exposure {
        stops: f32,
    },
    /// The frame budget the planner meets, milliseconds (`null`: none).
    Budget {
        ms: Option<f32>,
    },
    /// Open another scene: one the welcome's `scenes` offers, by name (`crate::open`).
    SceneOpen {
        name: String,
    },
}

fn unit_scale() -> f32 {
    1.0
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraIn {
    position: [f32; 3],
    target: [f32; 3],
    up: [f32; 3],
    fov_y_deg: f32,
}

struct Viewer {
    hub: Arc<Hub>,
    peer: SocketAddr,
    access: Access,
}

/// What a viewer beyond loopback without the token is told (the view was not started with
/// `--public-watch`).
const LOCKED: &str = "this view shows its frames and the cluster only to viewers who present the \
     token (the cluster's, or the view's own)";

/// How long a viewer arriving when the watching slots are full has to present the token.
const HELLO_WAIT: std::time::Duration = std::time::Duration::from_secs(5);

/// Counts a watch-only viewer while it watches.
struct Watching(Arc<Hub>);

impl Watching {
    /// A watching slot, if one is free.
    fn take(hub: &Arc<Hub>) -> Option<Watching> {
        let before = hub.watchers.fetch_add(1, Ordering::Relaxed);
        if before >= crate::hub::MAX_WATCHERS {
            hub.watchers.fetch_sub(1, Ordering::Relaxed);
            return None;
        }
        Some(Watching(Arc::clone(hub)))
    }
}

impl Drop for Watching {
    fn drop(&mut self) {
        self.0.watchers.fetch_sub(1, Ordering::Relaxed);
    }
}

/// Counts a viewer while it is connected.
struct Present(Arc<Hub>);

impl Drop for Present {
    fn drop(&mut self) {
        self.0.viewers.fetch_sub(1, Ordering::Relaxed);
    }
}

/// Serves one viewer's WebSocket until the viewer leaves or is dropped, or the view stops:
/// admits it, sends the welcome and what it may see, then relays frames, changes and its
/// steering messages.
pub(crate) async fn serve(socket: WebSocket, hub: Arc<Hub>, peer: SocketAddr) {
    hub.viewers.fetch_add(1, Ordering::Relaxed);
    let _present = Present(Arc::clone(&hub));
    let mut v = Viewer {
        access: hub.access_of(peer),
        peer,
        hub: Arc::clone(&hub),
    };
    let (mut tx, mut rx) = socket.split();
    let Some((watching, first_answers)) = admit(&mut v, &hub, &mut tx, &mut rx).await else {
        return;
    };
    tracing::info!(%peer, access = ?v.access, "viewer connected");
    let mut feeds = Feeds::subscribe(&hub);
    let mut outbox = opening(&v, &hub, &mut feeds);
    outbox.extend(first_answers);
    relay(&hub, v, tx, rx, watching, feeds, outbox).await;
}

/// The sending half of a viewer's WebSocket.
type Tx = SplitSink<WebSocket, Message>;
/// The receiving half of a viewer's WebSocket.
type Rx = SplitStream<WebSocket>;

/// The hub's channels one viewer follows.
struct Feeds {
    frames: watch::Receiver<Option<Arc<ViewFrame>>>,
    status: watch::Receiver<Option<Arc<Value>>>,
    steer: watch::Receiver<Steer>,
    exposure: watch::Receiver<f32>,
    notices: watch::Receiver<Option<(u64, String)>>,
    ended: watch::Receiver<Option<String>>,
    scenes: watch::Receiver<Arc<crate::open::SceneInfo>>,
}

impl Feeds {
    /// The welcome, then the lights and moves to a viewer who may watch; marks what they say
    /// as seen (notices count from now on) and the newest frame and status as still to send.
    fn welcome(&mut self, v: &Viewer, hub: &Hub) -> Vec<Value> {
        let mut outbox = vec![v.welcome()];
        if v.access.can_watch() {
            let s = self.steer.borrow_and_update().clone();
            outbox.push(json::lights_message(&s));
            outbox.push(json::moves_message(&s, &hub.scene.borrow().objects));
        }
        self.exposure.borrow_and_update();
        self.notices.borrow_and_update();
        self.frames.mark_changed();
        self.status.mark_changed();
        outbox
    }

    /// Subscribes to every channel the viewer follows.
    fn subscribe(hub: &Hub) -> Feeds {
        Feeds {
            frames: hub.frames.subscribe(),
            status: hub.status.subscribe(),
            steer: hub.steer.subscribe(),
            exposure: hub.exposure.subscribe(),
            notices: hub.notice.subscribe(),
            ended: hub.ended.subscribe(),
            scenes: hub.scene.subscribe(),
        }
    }
}

/// Admits the viewer. One that does not steer takes a watching slot; where the slots are full it
/// has `HELLO_WAIT` to present the token, else it is told why and the socket closed (`None`).
/// Returns the slot it holds and the answers to a message read while it waited.
async fn admit(
    v: &mut Viewer,
    hub: &Arc<Hub>,
    tx: &mut Tx,
    rx: &mut Rx,
) -> Option<(Option<Watching>, Vec<Value>)> {
    let mut first_answers = Vec::new();
    // Every viewer that does not steer (watching, or waiting to present the token) takes a
    // watching slot.
    let watching = if v.access.can_steer() {
        None
    } else {
        Watching::take(hub)
    };
    if !v.access.can_steer() && watching.is_none() {
        // The watching slots are full: only a viewer who presents the token takes one of
        // the slots kept for steering.
        if let Ok(Some(Ok(Message::Text(t)))) = tokio::time::timeout(HELLO_WAIT, rx.next()).await {
            first_answers = v.handle(&t);
        }
        if !v.access.can_steer() {
            let m = error(format!(
                "{} viewers are watching already: present the token to steer, or try later",
                crate::hub::MAX_WATCHERS
            ));
            let _ = send(tx, hub, Message::Text(m.to_string().into())).await;
            let _ = tx.send(Message::Close(None)).await;
            return None;
        }
    }
    Some((watching, first_answers))
}

/// The first messages: the welcome, then the lights and moves to a viewer who may watch. Marks
/// what the welcome says already as seen (notices count from now on), and the session's end,
/// the newest frame and the status as still to send.
fn opening(v: &Viewer, hub: &Hub, feeds: &mut Feeds) -> Vec<Value> {
    feeds.scenes.borrow_and_update();
    feeds.ended.mark_changed();
    feeds.welcome(v, hub)
}

/// The viewer's loop: sends what is queued, then waits for the view to stop, a message from the
/// viewer, or a change it may see (a viewer without the token sees only the session's end).
async fn relay(
    hub: &Hub,
    mut v: Viewer,
    mut tx: Tx,
    mut rx: Rx,
    mut watching: Option<Watching>,
    mut feeds: Feeds,
    mut outbox: Vec<Value>,
) {
    let peer = v.peer;
    let mut last_sent: Option<u64> = None;
    loop {
        for m in outbox.drain(..) {
            if !send(&mut tx, hub, Message::Text(m.to_string().into())).await {
                return;
            }
        }
        // A viewer without the token sees nothing of the session until it presents it, unless
        // the view lets everyone watch.
        let watch = v.access.can_watch();
        tokio::select! {
            _ = hub.stop.cancelled() => {
                let _ = tx.send(Message::Close(None)).await;
                return;
            }
            m = rx.next() => match m {
                Some(Ok(Message::Text(t))) => {
                    on_text(&mut v, &t, hub, &mut feeds, &mut watching, &mut outbox);
                }
                Some(Ok(Message::Binary(_))) => {
                    outbox.push(error("the view takes JSON text messages only"));
                }
                Some(Ok(Message::Ping(_) | Message::Pong(_))) => {}
                Some(Ok(Message::Close(_))) | None => return,
                Some(Err(e)) => {
                    tracing::debug!(%peer, "viewer link failed: {e}");
                    return;
                }
            },
            r = feeds.frames.changed(), if watch => {
                if r.is_err() { return; }
                if !send_frame(&mut tx, hub, &mut feeds.frames, &mut last_sent).await {
                    return;
                }
            }
            r = feeds.status.changed(), if watch => {
                if r.is_err() { return; }
                let s = feeds.status.borrow_and_update().clone();
                if let Some(s) = s {
                    let mut s = (*s).clone();
                    s["viewers"] = hub.viewers.load(Ordering::Relaxed).into();
                    outbox.push(v.redacted(s));
                }
            }
            r = feeds.steer.changed(), if watch => {
                if r.is_err() { return; }
                let s = feeds.steer.borrow_and_update().clone();
                outbox.push(json::camera_message(&s));
                outbox.push(json::lights_message(&s));
                outbox.push(json::moves_message(&s, &hub.scene.borrow().objects));
                outbox.push(json::animation_message(&s));
            }
            r = feeds.scenes.changed(), if watch => {
                // Another scene opened (or one refused, and the one before back): the page
                // starts again from the welcome.
                if r.is_err() { return; }
                feeds.scenes.borrow_and_update();
                outbox.push(v.welcome());
                outbox.push(json::lights_message(&feeds.steer.borrow()));
                outbox.push(json::moves_message(&feeds.steer.borrow(), &hub.scene.borrow().objects));
            }
            r = feeds.exposure.changed(), if watch => {
                if r.is_err() { return; }
                let stops = *feeds.exposure.borrow_and_update();
                outbox.push(json::exposure_message(stops));
            }
            r = feeds.notices.changed(), if watch => {
                if r.is_err() { return; }
                if let Some((_, text)) = feeds.notices.borrow_and_update().clone() {
                    outbox.push(v.redacted(json!({"type": "notice", "text": text})));
                }
            }
            r = feeds.ended.changed() => {
                if r.is_err() { return; }
                if send_ended(&v, &mut tx, hub, &mut feeds.ended, watch).await {
                    return;
                }
            }
        }
    }
}

/// Answers one text message from the viewer. A viewer who steers now gives back its watching
/// slot and is sent the welcome, lights and moves again, and the newest frame and status
/// unredacted.
fn on_text(
    v: &mut Viewer,
    text: &str,
    hub: &Hub,
    feeds: &mut Feeds,
    watching: &mut Option<Watching>,
    outbox: &mut Vec<Value>,
) {
    let before = v.access;
    outbox.extend(v.handle(text));
    if v.access.can_steer() && !before.can_steer() {
        // A steering viewer now: its watching slot is free again.
        drop(watching.take());
        // The newest frame and status follow, now unredacted.
        outbox.extend(feeds.welcome(v, hub));
    }
}

/// Sends the newest frame, if any, counting the frames skipped since the last one sent; false
/// when the viewer is gone or too slow.
async fn send_frame(
    tx: &mut Tx,
    hub: &Hub,
    frames: &mut watch::Receiver<Option<Arc<ViewFrame>>>,
    last_sent: &mut Option<u64>,
) -> bool {
    let f = frames.borrow_and_update().clone();
    if let Some(f) = f {
        if let Some(prev) = *last_sent {
            let skipped = f.frame.saturating_sub(prev + 1);
            hub.counters
                .frames_skipped
                .fetch_add(skipped, Ordering::Relaxed);
        }
        *last_sent = Some(f.frame);
        let n = f.message.len() as u64;
        if !send(tx, hub, Message::Binary(f.message.clone())).await {
            return false;
        }
        hub.counters.frames_sent.fetch_add(1, Ordering::Relaxed);
        hub.counters.bytes_sent.fetch_add(n, Ordering::Relaxed);
    }
    true
}

/// Tells the viewer why the session ended, if it has, and closes the socket once that is sent;
/// true when it has ended. A viewer who may not watch is told only that it ended.
async fn send_ended(
    v: &Viewer,
    tx: &mut Tx,
    hub: &Hub,
    ended: &mut watch::Receiver<Option<String>>,
    watch: bool,
) -> bool {
    let why = ended.borrow_and_update().clone();
    let Some(why) = why else {
        return false;
    };
    // The page shows why instead of looping on "reconnecting" with no reason (a viewer that
    // sees nothing of the session is told only that it ended).
    let why = if watch {
        why
    } else {
        "the session ended".to_string()
    };
    let m = v.redacted(json!({"type": "ended", "text": why}));
    if send(tx, hub, Message::Text(m.to_string().into())).await {
        let _ = tx.send(Message::Close(None)).await;
    }
    true
}

/// Sends one message within the deadline; false when the viewer is gone or too slow.
async fn send(
    tx: &mut futures::stream::SplitSink<WebSocket, Message>,
    hub: &Hub,
    m: Message,
) -> bool {
    match tokio::time::timeout(hub.send_timeout, tx.send(m)).await {
        Ok(Ok(())) => true,
        Ok(Err(_)) => false,
        Err(_) => {
            hub.counters.viewers_dropped.fetch_add(1, Ordering::Relaxed);
            tracing::warn!(
                "a viewer took over {} s to take a message: dropped",
                hub.send_timeout.as_secs_f64()
            );
            false
        }
    }
}

fn error(text: impl std::fmt::Display) -> Value {
    json!({"type": "error", "text": text.to_string()})
}

impl Viewer {
    fn welcome(&self) -> Value {
        let token_refused = self.hub.token_refused(self.peer);
        if !self.access.can_watch() {
            // Nothing of the session: only that it must present the token, and whether it can
            // here.
            return json!({
                "type": "welcome",
                "can_steer": false,
                "can_watch": false,
                "token_accepted": token_refused.is_none(),
                "text": token_refused.unwrap_or(LOCKED),
            });
        }
        let info = Arc::clone(&self.hub.scene.borrow());
        let s = self.hub.steer.borrow();
        let mut w = json!({
            "type": "welcome",
            "can_steer": self.access.can_steer(),
            "can_watch": true,
            "token_accepted": token_refused.is_none(),
            "scene": info.json,
            "scenes": self.hub.catalog.as_ref().map(|c| json!({
                "names": c.names(),
                "current": info.name,
            })),
            "camera": json::camera(&s.camera),
            "revision": s.revision,
            "walkthrough": self.hub.plan().is_some_and(|p| p.walkthrough),
            "continuous": self.hub.continuous,
            "refine": json::refine(self.hub.refine.as_ref()),
            "animation": json::animation(&s.clock),
            "exposure": {
                "stops": *self.hub.exposure.borrow(),
                "scene_stops": info.stops,
                "min": crate::encode::MIN_STOPS,
                "max": crate::encode::MAX_STOPS,
            },
        });
        if let Some(why) = token_refused.filter(|_| !self.access.can_steer()) {
            w["text"] = why.into();
        }
        w
    }

    /// `m` as this viewer may see it: without the token, no daemon address.
    fn redacted(&self, mut m: Value) -> Value {
        if !self.access.can_steer() {
            self.hub.addresses.redact(&mut m);
        }
        m
    }

    /// Applies one message from the page; what to answer: an ack when it carried an id and was
    /// applied, an error (with the message's id, if any, in place of the ack) when it was
    /// refused, the stats (then the ack) when asked for.
    fn handle(&mut self, text: &str) -> Vec<Value> {
        let mut value: Value = match serde_json::from_str(text) {
            Ok(v) => v,
            Err(e) => return vec![error(format!("not JSON: {e}"))],
        };
        let id = value
            .as_object_mut()
            .and_then(|o| o.remove("id"))
            .filter(Value::is_number);
        let answer = match serde_json::from_value::<Input>(value) {
            Ok(input) => self.apply(input).err(),
            Err(e) => Some(error(format!("unknown or malformed message: {e}"))),
        };
        match (answer, id) {
            (Some(mut refused), Some(id)) if refused["type"] == "error" => {
                refused["id"] = id;
                vec![refused]
            }
            (answer, id) => {
                let mut out: Vec<Value> = answer.into_iter().collect();
                if let Some(id) = id {
                    let revision = self.hub.steer.borrow().revision;
                    out.push(json!({"type": "ack", "id": id, "revision": revision}));
                }
                out
            }
        }
    }

    /// Applies a message; `Err` holds the answer to send (an error, or the stats asked for).
    fn apply(&mut self, input: Input) -> Result<(), Value> {
        match input {
            Input::Hello { token } => {
                if let Some(why) = self.hub.token_refused(self.peer) {
                    Err(error(why))
                } else if self.hub.token_matches(&token) {
                    self.access = Access::Steer;
                    Ok(())
                } else if self.access.can_watch() {
                    Err(error("wrong token: this view can only watch"))
                } else {
                    Err(error(
                        "wrong token: this view shows nothing without the token",
                    ))
                }
            }
            _ if !self.access.can_watch() => Err(error(LOCKED)),
            Input::Stats => Err(self.hub.stats()),
            _ if !self.access.can_steer() => Err(error(
                "this view can only watch: present the cluster's token to steer",
            )),
            Input::ObjectPick { x, y } => Err(self.pick(x, y)),
            Input::Render => {
                self.hub.render_now.notify_one();
                Ok(())
            }
            Input::Exposure { stops } => self.hub.set_exposure(stops).map(drop).map_err(error),
            Input::SceneOpen { name } => crate::open::start(&self.hub, name).map_err(error),
            input => self.steer(input).map_err(error),
        }
    }

    /// The `object` message for a pick at `(x, y)` (fractions of the view from left and top).
    fn pick(&self, x: f32, y: f32) -> Value {
        if !(x.is_finite() && y.is_finite() && (0.0..=1.0).contains(&x) && (0.0..=1.0).contains(&y))
        {
            return error("a pick is at fractions of the view between 0 and 1");
        }
        let objects = Arc::clone(&self.hub.scene.borrow().objects);
        let s = self.hub.steer.borrow().clone();
        // The first pick builds the ray-cast tree (seconds for millions of triangles): off this
        // worker's other tasks where the runtime has other workers.
        let pick = || objects.pick(&s.camera, &s.moves, x, y);
        let picked = match tokio::runtime::Handle::try_current().map(|h| h.runtime_flavor()) {
            Ok(tokio::runtime::RuntimeFlavor::MultiThread) => tokio::task::block_in_place(pick),
            _ => pick(),
        };
        match picked {
            Some(p) => {
                let mut v = json::object(&s.object_move(p.mesh), &p.name, p.fixed.as_deref());
                v["type"] = "object".into();
                v
            }
            None => json!({"type": "object", "mesh": null}),
        }
    }

    fn steer(&self, input: Input) -> Result<(), SteerError> {
        let objects = Arc::clone(&self.hub.scene.borrow().objects);
        let mut result = Ok(());
        self.hub.steer.send_if_modified(|s| {
            let mut next = s.clone();
            result = match input {
                Input::Orbit { yaw_deg, pitch_deg } => next.orbit(yaw_deg, pitch_deg),
                Input::Pan { x, y } => next.pan(x, y),
                Input::Zoom { factor } => next.zoom(factor),
                Input::Camera { camera: c } => {
                    next.set_camera(c.position, c.target, c.up, c.fov_y_deg)
                }
                Input::Reset => {
                    next.reset();
                    Ok(())
                }
                Input::Light {
                    index,
                    color,
                    intensity,
                } => next.set_light(index, color, intensity),
                Input::LightSet { index, light } => next.edit_light(index, &light),
                Input::LightAdd { light } => next.add_light(&light),
                Input::LightRemove { index } => next.remove_light(index),
                Input::LightDrag { index, x, y } => next.drag_light(index, x, y),
                Input::ObjectSet {
                    mesh,
                    translate,
                    rotate,
                    scale,
                } => next.move_object(
                    &objects,
                    lightfold_scene::moves::MeshMove {
                        mesh,
                        translate,
                        rotate,
                        scale,
                    },
                ),
                Input::ObjectDrag { mesh, x, y } => next.drag_object(&objects, mesh, x, y),
                Input::Time { t } => next.seek(t),
                Input::Play => {
                    next.play(true);
                    Ok(())
                }
                Input::Pause => {
                    next.play(false);
                    Ok(())
                }
                Input::Speed { speed } => next.clock.set_speed(speed),
                Input::Loop { on } => {
                    next.clock.set_looping(on);
                    Ok(())
                }
                Input::Budget { ms } => next.set_budget(ms),
                Input::Hello { .. }
                | Input::Render
                | Input::Stats
                | Input::Exposure { .. }
                | Input::ObjectPick { .. }
                | Input::SceneOpen { .. } => Ok(()),
            };
            if result.is_ok() && next != *s {
                next.changed();
                *s = next;
                true
            } else {
                false
            }
        });
        result
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hub::MAX_WATCHERS;

    #[test]
    fn watchers_leave_slots_for_viewers_who_steer() {
        let scene = lightfold_scene::builtin("balls").unwrap();
        let (_, live) = tokio::sync::watch::channel(Default::default());
        let hub = Arc::new(Hub::new(
            &scene,
            &crate::ViewOptions::default(),
            Arc::default(),
            live,
            tokio_util::sync::CancellationToken::new(),
        ));
        let held: Vec<Watching> = (0..MAX_WATCHERS)
            .map(|_| Watching::take(&hub).expect("a watching slot"))
            .collect();
        assert!(Watching::take(&hub).is_none(), "watchers are capped");
        // Slots are kept for viewers who steer.
        const { assert!(MAX_WATCHERS < crate::hub::MAX_VIEWERS) };
        drop(held);
        assert_eq!(hub.watchers.load(Ordering::Relaxed), 0);
        assert!(Watching::take(&hub).is_some());
    }
}
