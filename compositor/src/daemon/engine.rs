//! The stage's frame loop: applies configurations in order, and for each requested frame gathers
//! band b from every input, combines it on the stage's compute pool while band b+1 is gathered,
//! and queues the packed result for the writer. A band that does not match the configuration
//! fails its frame with a report to the coordinator; the loop goes on to the next frame.

use super::check::Expect;
use super::compute::{BandOut, BufferPool, Received, Scratch, Window, combine};
use super::control::{ControlOut, NewConfig};
use super::inputs::{InBand, InputError, Slot, SlotContext};
use super::output::{Feed, Out, Queued, Target};
use super::stage_plan::{Operators, StagePlan};
use crate::ops::Operator;
use lightfold_protocol::{ErrorCode, FrameParams, FrameStats, Message};
use serde_json::json;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::oneshot;
use tokio::sync::{mpsc, watch};
use tokio::time::Instant;

/// Frame requests and configurations, in the order the coordinator sent them.
#[derive(Debug)]
pub(crate) enum Command {
    Configure(Box<NewConfig>),
    Frame(FrameRequest),
    /// Left out of the plan of `epoch` (`Message::Release`): the ordinal of that change.
    Release {
        generation: u64,
        epoch: u64,
    },
}

#[derive(Debug)]
pub(crate) struct FrameRequest {
    pub epoch: u64,
    pub frame: u64,
    pub params: FrameParams,
}

/// Why a frame was not completed.
#[derive(Debug, thiserror::Error)]
enum FrameError {
    #[error(transparent)]
    Input(#[from] InputError),
    #[error("combining band {band} failed: {reason}")]
    Compute { band: u32, reason: String },
    #[error("a newer configuration arrived")]
    Reconfigured,
    #[error("the stage is shutting down")]
    Shutdown,
}

type Ops = Arc<Mutex<Operators>>;
type Pending = oneshot::Receiver<(Scratch, Result<BandOut, String>)>;

pub(crate) struct Engine {
    pub ctx: SlotContext,
    pub control: ControlOut,
    /// To the writer: bands and frame ends, and the configuration applied last (a watch, which
    /// never waits for the writer).
    pub out: Feed,
    /// Configurations received (bumped by the control link before the engine applies them).
    pub generation: watch::Receiver<u64>,
    pub input_timeout: Duration,
    pub daemon_id: String,
    plan: Option<Arc<StagePlan>>,
    ops: Ops,
    slots: Vec<Slot>,
    applied: u64,
    /// Fixed-point scale of outgoing bands; `FrameParams::scale` changes it.
    scale: f32,
    spare: Vec<Scratch>,
    pool: Arc<BufferPool>,
    /// The threads bands are combined on (`CompositorOptions::compute_threads`).
    compute: Arc<rayon::ThreadPool>,
}

impl Engine {
    pub(super) fn new(
        ctx: SlotContext,
        control: ControlOut,
        out: Feed,
        generation: watch::Receiver<u64>,
        input_timeout: Duration,
        daemon_id: String,
        compute: Arc<rayon::ThreadPool>,
    ) -> Engine {
        Engine {
            ctx,
            control,
            out,
            generation,
            input_timeout,
            daemon_id,
            plan: None,
            ops: Arc::default(),
            slots: Vec::new(),
            applied: 0,
            scale: 1.0,
            spare: Vec::new(),
            pool: Arc::default(),
            compute,
        }
    }

    pub(super) async fn run(mut self, mut commands: mpsc::Receiver<Command>) {
        let shutdown = self.ctx.shutdown.clone();
        loop {
            let cmd = tokio::select! {
                _ = shutdown.cancelled() => return,
                cmd = commands.recv() => match cmd {
                    Some(cmd) => cmd,
                    None => return,
                },
            };
            match cmd {
                Command::Configure(new) => self.apply(*new).await,
                Command::Release { generation, epoch } => self.release(generation, epoch),
                Command::Frame(req) => {
                    let (frame, req_epoch) = (req.frame, req.epoch);
                    if *self.generation.borrow() > self.applied {
                        tracing::info!(frame, "frame skipped: a newer configuration follows it");
                        continue;
                    }
                    match self.run_frame(req).await {
                        Ok(()) => {}
                        Err(FrameError::Shutdown) => return,
                        Err(FrameError::Reconfigured) => {
                            // The writer drops what it still has of this frame once the new
                            // configuration is applied.
                            tracing::info!(
                                frame,
                                epoch = req_epoch,
                                "frame abandoned: reconfigured"
                            );
                        }
                        Err(e) => {
                            self.ctx.metrics.frame_failed();
                            let code = match &e {
                                FrameError::Input(InputError::Mismatch { .. }) => {
                                    self.ctx.metrics.mismatch();
                                    ErrorCode::BandMismatch
                                }
                                FrameError::Input(InputError::Timeout { .. }) => ErrorCode::Timeout,
                                FrameError::Input(InputError::Link { .. }) => ErrorCode::PeerLost,
                                _ => ErrorCode::Internal,
                            };
                            self.control.frame_error(
                                req_epoch,
                                frame,
                                code,
                                format!("frame {frame} dropped: {e}"),
                            );
                            let _ = self.send_out(Out::Abort { frame }).await;
                        }
                    }
                }
            }
        }
    }

    /// Leaves the stage unconfigured: its input links close, the writer lets its downstream go
    /// and drops what it holds of the old configuration's frame.
    fn release(&mut self, generation: u64, epoch: u64) {
        self.slots.clear();
        self.plan = None;
        self.applied = generation;
        self.out.target.send_replace(Target {
            generation,
            epoch,
            addr: String::new(),
        });
        tracing::info!(
            epoch,
            "released: the plan of this epoch leaves the stage out"
        );
    }

    /// Switches to a new configuration, keeping the links of inputs that stay.
    async fn apply(&mut self, new: NewConfig) {
        let NewConfig {
            plan,
            ops,
            generation,
        } = new;
        let mut old: Vec<Slot> = std::mem::take(&mut self.slots);
        for (index, input) in plan.config.inputs.iter().enumerate() {
            let budget = plan.input_budget[index];
            let slot = match old.iter().position(|s| s.peer == input.peer) {
                Some(k) => {
                    let mut s = old.swap_remove(k);
                    s.reconfigure(index, budget);
                    s
                }
                None => Slot::new(index, input.peer.clone(), budget),
            };
            self.slots.push(slot);
        }
        // Slots of peers no longer configured drop here, closing their links.
        drop(old);
        *self.ops.lock().unwrap_or_else(|e| e.into_inner()) = ops;
        let addr = plan.config.downstream.clone();
        let epoch = plan.epoch();
        self.plan = Some(Arc::new(plan));
        self.applied = generation;
        tracing::info!(epoch, "configured");
        // The writer gives up on whatever it was doing for the old configuration and dials the
        // new downstream; a watch, so a writer stuck on a dead downstream never holds this up.
        self.out.target.send_replace(Target {
            generation,
            epoch,
            addr,
        });
        self.control.send(Message::Configured { epoch });
    }

    async fn run_frame(&mut self, req: FrameRequest) -> Result<(), FrameError> {
        let Some(plan) = self.plan.clone() else {
            self.control.frame_error(
                req.epoch,
                req.frame,
                ErrorCode::BadConfig,
                format!("frame {} refused: the stage is not configured", req.frame),
            );
            return Ok(());
        };
        if req.epoch != plan.epoch() {
            self.control.frame_error(
                req.epoch,
                req.frame,
                ErrorCode::BadConfig,
                format!(
                    "frame {} refused: it is for epoch {} but the stage is configured for epoch {}",
                    req.frame,
                    req.epoch,
                    plan.epoch()
                ),
            );
            return Ok(());
        }
        self.apply_params(&plan, &req);
        let started = Instant::now();
        let mut stats = FrameStats {
            epoch: req.epoch,
            frame: req.frame,
            daemon_id: self.daemon_id.clone(),
            ..FrameStats::default()
        };
        let mut scales: Vec<Vec<Option<f32>>> = plan
            .config
            .inputs
            .iter()
            .map(|i| vec![None; i.layers.len()])
            .collect();
        let mut pending: Option<(u32, Pending)> = None;
        // With a halo, band b is combined once band b + 1 is here: (band, its inputs, the
        // band above's).
        let mut held: Option<(u32, Arc<Received>, Option<Arc<Received>>)> = None;
        for b in 0..plan.bands {
            let received = self.gather(&plan, req.frame, b, &mut scales).await;
            let received = match received {
                Ok(r) => Arc::new(r),
                Err(e) => {
                    if let Some((_, p)) = pending.take() {
                        self.reclaim(p).await;
                    }
                    return Err(e);
                }
            };
            let window = if plan.halo == 0 {
                Some((
                    b,
                    Window {
                        above: None,
                        centre: received,
                        below: None,
                    },
                ))
            } else {
                let ready = held.take().map(|(hb, centre, above)| {
                    (
                        hb,
                        Window {
                            above,
                            centre: Arc::clone(&centre),
                            below: Some(Arc::clone(&received)),
                        },
                    )
                });
                let above = ready.as_ref().map(|(_, w)| Arc::clone(&w.centre));
                held = Some((b, received, above));
                ready
            };
            if let Some((pb, p)) = pending.take() {
                self.forward(pb, p, &mut stats).await?;
            }
            if let Some((wb, window)) = window {
                pending = Some((wb, self.spawn_combine(&plan, req.frame, wb, window)));
            }
        }
        if let Some((hb, centre, above)) = held.take() {
            if let Some((pb, p)) = pending.take() {
                self.forward(pb, p, &mut stats).await?;
            }
            let window = Window {
                above,
                centre,
                below: None,
            };
            pending = Some((hb, self.spawn_combine(&plan, req.frame, hb, window)));
        }
        if let Some((pb, p)) = pending.take() {
            self.forward(pb, p, &mut stats).await?;
        }
        self.send_out(Out::End { stats, started }).await
    }

    /// Sets this frame's light colours (`(stage input, c_n)`) on the operators that read them.
    fn apply_params(&mut self, plan: &StagePlan, req: &FrameRequest) {
        let params = &req.params;
        if let Some(scale) = params.scale {
            if scale.is_finite() && scale > 0.0 {
                self.scale = scale;
            } else {
                self.control.frame_error(
                    req.epoch,
                    req.frame,
                    ErrorCode::BadConfig,
                    format!("ignored scale {scale}: not finite and positive"),
                );
            }
        }
        let mut refused = Vec::new();
        {
            let mut guard = self.ops.lock().unwrap_or_else(|e| e.into_inner());
            for &(input, rgb) in &params.colors {
                let reader = plan.readers.get(input as usize).copied().flatten();
                let ops = &mut *guard;
                let result = match (ops.pipeline.as_mut(), reader) {
                    (Some(p), Some((k, j))) => {
                        let stage = &p.stages()[k];
                        if stage.op.name() == crate::ops::accumulate::NAME {
                            let name = stage.name.clone();
                            let change = json!({ "input_colors": [[j, rgb]] });
                            let fused = match ops.fused.as_mut() {
                                Some(f) => f.set_params(&change).map_err(|e| e.to_string()),
                                None => Ok(()),
                            };
                            fused.and_then(|()| {
                                p.set_params(&name, &change).map_err(|e| e.to_string())
                            })
                        } else {
                            Err(format!(
                                "operator {k} ({}) takes no light colour",
                                stage.op.name()
                            ))
                        }
                    }
                    _ => Err("no operator reads that input".to_string()),
                };
                if let Err(why) = result {
                    refused.push(format!("colour for input {input} ignored: {why}"));
                }
            }
        }
        for why in refused {
            self.control
                .frame_error(req.epoch, req.frame, ErrorCode::BadConfig, why);
        }
    }

    /// Band `b` of every input layer, in configuration order, each judged against the plan.
    async fn gather(
        &mut self,
        plan: &StagePlan,
        frame: u64,
        b: u32,
        scales: &mut [Vec<Option<f32>>],
    ) -> Result<Vec<Vec<InBand>>, FrameError> {
        let (y0, rows) = plan.band_rows(b);
        let ctx = self.ctx.clone();
        let timeout = self.input_timeout;
        let slots = &mut self.slots;
        let work = async {
            let mut received = Vec::with_capacity(slots.len());
            for (slot, input) in slots.iter_mut().zip(&plan.config.inputs) {
                let mut layers = Vec::with_capacity(input.layers.len());
                for (j, &(layer, format)) in input.layers.iter().enumerate() {
                    let expect = Expect {
                        epoch: plan.epoch(),
                        frame,
                        layer,
                        format,
                        x0: 0,
                        y0,
                        width: plan.config.width,
                        height: rows,
                        scale: scales[slot.index][j],
                    };
                    let band = slot.next(&expect, &ctx, Instant::now() + timeout).await?;
                    if !band.header.empty {
                        scales[slot.index][j].get_or_insert(band.header.scale);
                    }
                    layers.push(band);
                }
                received.push(layers);
            }
            Ok::<_, FrameError>(received)
        };
        let generation = &mut self.generation;
        let applied = self.applied;
        tokio::select! {
            biased;
            _ = ctx.shutdown.cancelled() => Err(FrameError::Shutdown),
            _ = generation.wait_for(|g| *g > applied) => Err(FrameError::Reconfigured),
            r = work => r,
        }
    }

    fn spawn_combine(
        &mut self,
        plan: &Arc<StagePlan>,
        frame: u64,
        b: u32,
        window: Window,
    ) -> Pending {
        let plan = Arc::clone(plan);
        let ops = Arc::clone(&self.ops);
        let mut scratch = self
            .spare
            .pop()
            .unwrap_or_else(|| Scratch::new(Arc::clone(&self.pool)));
        let scale = self.scale;
        let (done, pending) = oneshot::channel();
        // On the stage's compute pool: inside it a band splits across that pool's threads only.
        self.compute.spawn(move || {
            let ops = ops.lock().unwrap_or_else(|e| e.into_inner());
            let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                combine(&plan, &ops, frame, b, &window, scale, &mut scratch)
                    .map_err(|e| e.to_string())
            }))
            .unwrap_or_else(|_| Err("the combine panicked".to_string()));
            // The engine may have given up on this band (a reconfiguration, shutdown).
            let _ = done.send((scratch, r));
        });
        pending
    }

    /// Waits for a combine whose result is no longer wanted, keeping its scratch.
    async fn reclaim(&mut self, p: Pending) {
        if let Ok((scratch, _)) = p.await {
            self.spare.push(scratch);
        }
    }

    /// Waits for band `b`'s combine and queues its output bands.
    async fn forward(
        &mut self,
        b: u32,
        p: Pending,
        stats: &mut FrameStats,
    ) -> Result<(), FrameError> {
        let (scratch, result) = p.await.map_err(|e| FrameError::Compute {
            band: b,
            reason: e.to_string(),
        })?;
        self.spare.push(scratch);
        let out = result.map_err(|reason| FrameError::Compute { band: b, reason })?;
        stats.composite_us += out.composite.as_micros() as u64;
        stats.pack_us += out.pack.as_micros() as u64;
        stats.saturated += out.saturated;
        stats.empty_bands += out.empty;
        for (header, payload) in out.bands {
            let held = self.ctx.metrics.hold(payload.len() as u64);
            self.send_out(Out::Band {
                header,
                payload,
                held,
            })
            .await?;
        }
        Ok(())
    }

    /// Queues for the writer; a stalled consumer blocks here until shutdown or a reconfiguration.
    async fn send_out(&mut self, item: Out) -> Result<(), FrameError> {
        let applied = self.applied;
        tokio::select! {
            biased;
            _ = self.ctx.shutdown.cancelled() => Err(FrameError::Shutdown),
            _ = self.generation.wait_for(|g| *g > applied) => Err(FrameError::Reconfigured),
            r = self.out.queue.send(Queued { generation: applied, item }) => {
                r.map_err(|_| FrameError::Shutdown)
            }
        }
    }
}
