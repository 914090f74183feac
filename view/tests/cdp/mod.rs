//! A small Chrome DevTools Protocol client: launches Debian's headless Chromium, attaches to one
//! page over the browser's WebSocket (flattened sessions) and sends it commands. Every wait has a
//! deadline; the browser is killed when the client is dropped.

use anyhow::{Context, anyhow, bail};
use futures::{SinkExt, StreamExt};
use serde_json::{Value, json};
use std::process::Stdio;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::net::TcpStream;
use tokio::process::{Child, Command};
use tokio::time::{Instant, sleep, timeout, timeout_at};
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::{MaybeTlsStream, WebSocketStream};

/// Where Debian installs Chromium (`scripts/install-deps.sh --test`); `LIGHTFOLD_CHROMIUM` overrides.
pub(crate) const CHROMIUM: &str = "/usr/bin/chromium";

/// How long the browser may take to start and to answer one command.
const LAUNCH_DEADLINE: Duration = Duration::from_secs(30);
const CALL_DEADLINE: Duration = Duration::from_secs(30);

/// The Chromium binary, or a loud failure naming the install step.
pub(crate) fn chromium_path() -> String {
    let path = std::env::var("LIGHTFOLD_CHROMIUM").unwrap_or_else(|_| CHROMIUM.to_string());
    assert!(
        std::path::Path::new(&path).is_file(),
        "Chromium is not installed at {path}: the browser test needs it; run \
         scripts/install-deps.sh --test (Debian package `chromium`) or set LIGHTFOLD_CHROMIUM"
    );
    path
}

/// A headless browser with one attached page.
#[derive(Debug)]
pub(crate) struct Browser {
    child: Child,
    _profile: tempfile::TempDir,
    ws: WebSocketStream<MaybeTlsStream<TcpStream>>,
    next_id: u64,
    session: Option<String>,
    /// The browser's last lines of standard error (for failure messages).
    stderr: Arc<Mutex<Vec<String>>>,
    /// Exceptions thrown and console messages logged by the page.
    pub exceptions: Vec<String>,
    pub console: Vec<String>,
}

impl Browser {
    /// Starts `chromium --headless=new` with a fresh profile and connects to its DevTools socket.
    pub(crate) async fn launch(width: u32, height: u32) -> anyhow::Result<Browser> {
        let path = chromium_path();
        let profile = tempfile::tempdir().context("creating the browser profile folder")?;
        let mut child = Command::new(&path)
            .args([
                "--headless=new",
                "--no-sandbox",
                "--disable-gpu",
                // Containers often give /dev/shm 64 MiB, too little for Chromium.
                "--disable-dev-shm-usage",
                "--no-first-run",
                "--no-default-browser-check",
                "--disable-extensions",
                "--disable-background-networking",
                "--disable-component-update",
                "--disable-sync",
                "--mute-audio",
                "--remote-debugging-port=0",
                &format!("--window-size={width},{height}"),
                &format!("--user-data-dir={}", profile.path().display()),
                "about:blank",
            ])
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .kill_on_drop(true)
            .spawn()
            .with_context(|| format!("cannot start {path}"))?;
        let stderr = child.stderr.take().context("no stderr pipe")?;
        let lines = Arc::new(Mutex::new(Vec::new()));
        let (url_tx, url_rx) = tokio::sync::oneshot::channel();
        // Keeps draining stderr (a full pipe would stall the browser), noting the DevTools URL.
        let keep = Arc::clone(&lines);
        tokio::spawn(async move {
            let mut url_tx = Some(url_tx);
            let mut r = BufReader::new(stderr).lines();
            while let Ok(Some(line)) = r.next_line().await {
                if let Some(at) = line.find("DevTools listening on ") {
                    let url = line[at + "DevTools listening on ".len()..]
                        .trim()
                        .to_string();
                    if let Some(tx) = url_tx.take() {
                        let _ = tx.send(url);
                    }
                }
                let mut l = keep.lock().unwrap();
                l.push(line);
                if l.len() > 200 {
                    l.remove(0);
                }
            }
        });
        let url = match timeout(LAUNCH_DEADLINE, url_rx).await {
            Ok(Ok(url)) => url,
            Ok(Err(_)) => {
                let status = child.wait().await.ok();
                bail!(
                    "chromium exited ({status:?}) before printing its DevTools address; stderr:\n{}",
                    lines.lock().unwrap().join("\n")
                );
            }
            Err(_) => bail!(
                "chromium printed no DevTools address within {LAUNCH_DEADLINE:?}; stderr:\n{}",
                lines.lock().unwrap().join("\n")
            ),
        };
        let (ws, _) = timeout(
            LAUNCH_DEADLINE,
            tokio_tungstenite::connect_async(url.as_str()),
        )
        .await
        .context("connecting to the DevTools socket timed out")?
        .with_context(|| format!("cannot connect to {url}"))?;
        Ok(Browser {
            child,
            _profile: profile,
            ws,
            next_id: 0,
            session: None,
            stderr: lines,
            exceptions: Vec::new(),
            console: Vec::new(),
        })
    }

    /// The browser's recent standard error.
    pub(crate) fn stderr_tail(&self) -> String {
        self.stderr.lock().unwrap().join("\n")
    }

    /// Opens a blank page and attaches to it; later commands go to that page.
    pub(crate) async fn open_page(&mut self, width: u32, height: u32) -> anyhow::Result<()> {
        let target = self
            .browser_call("Target.createTarget", json!({"url": "about:blank"}))
            .await?;
        let target_id = target["targetId"]
            .as_str()
            .context("no targetId")?
            .to_string();
        let attached = self
            .browser_call(
                "Target.attachToTarget",
                json!({"targetId": target_id, "flatten": true}),
            )
            .await?;
        let session = attached["sessionId"].as_str().context("no sessionId")?;
        self.session = Some(session.to_string());
        self.call("Page.enable", json!({})).await?;
        self.call("Runtime.enable", json!({})).await?;
        self.call(
            "Emulation.setDeviceMetricsOverride",
            json!({"width": width, "height": height, "deviceScaleFactor": 1, "mobile": false}),
        )
        .await?;
        Ok(())
    }

    pub(crate) async fn navigate(&mut self, url: &str) -> anyhow::Result<()> {
        let r = self.call("Page.navigate", json!({ "url": url })).await?;
        if let Some(e) = r.get("errorText") {
            bail!("navigating to {url} failed: {e}");
        }
        Ok(())
    }

    /// Evaluates `expression` in the page; its value (JSON).
    pub(crate) async fn eval(&mut self, expression: &str) -> anyhow::Result<Value> {
        let r = self
            .call(
                "Runtime.evaluate",
                json!({"expression": expression, "returnByValue": true, "awaitPromise": true}),
            )
            .await?;
        if let Some(e) = r.get("exceptionDetails") {
            bail!("evaluating `{expression}` threw: {e}");
        }
        Ok(r["result"].get("value").cloned().unwrap_or(Value::Null))
    }

    /// Evaluates `expression` until `done` holds for its value, or fails after `deadline`.
    pub(crate) async fn wait_for(
        &mut self,
        what: &str,
        expression: &str,
        deadline: Duration,
        done: impl Fn(&Value) -> bool,
    ) -> anyhow::Result<Value> {
        let end = Instant::now() + deadline;
        let mut last = Value::Null;
        while Instant::now() < end {
            last = self.eval(expression).await?;
            if done(&last) {
                return Ok(last);
            }
            sleep(Duration::from_millis(100)).await;
        }
        Err(anyhow!(
            "waited {deadline:?} for {what}; last `{expression}` = {last}; page exceptions: {:?}",
            self.exceptions
        ))
    }

    /// The page as PNG bytes.
    pub(crate) async fn screenshot(&mut self) -> anyhow::Result<Vec<u8>> {
        let r = self
            .call(
                "Page.captureScreenshot",
                json!({"format": "png", "fromSurface": true}),
            )
            .await?;
        base64_decode(r["data"].as_str().context("no screenshot data")?)
    }

    /// One mouse event at (`x`, `y`) in CSS pixels.
    pub(crate) async fn mouse(
        &mut self,
        kind: &str,
        x: f64,
        y: f64,
        buttons: u32,
    ) -> anyhow::Result<()> {
        self.mouse_with(kind, x, y, buttons, 0).await
    }

    /// [`Browser::mouse`] with keys held (`modifiers`: CDP's bits, 1 = Alt, 8 = Shift).
    pub(crate) async fn mouse_with(
        &mut self,
        kind: &str,
        x: f64,
        y: f64,
        buttons: u32,
        modifiers: u32,
    ) -> anyhow::Result<()> {
        self.call(
            "Input.dispatchMouseEvent",
            json!({"type": kind, "x": x, "y": y, "button": "left", "buttons": buttons,
                   "modifiers": modifiers,
                   "clickCount": if kind == "mouseMoved" { 0 } else { 1 }}),
        )
        .await?;
        Ok(())
    }

    /// Closes the browser (politely, then by force).
    pub(crate) async fn close(mut self) {
        let _ = timeout(
            Duration::from_secs(5),
            self.browser_call("Browser.close", json!({})),
        )
        .await;
        if timeout(Duration::from_secs(5), self.child.wait())
            .await
            .is_err()
        {
            let _ = self.child.start_kill();
            let _ = timeout(Duration::from_secs(5), self.child.wait()).await;
        }
    }

    /// A command to the attached page.
    pub(crate) async fn call(&mut self, method: &str, params: Value) -> anyhow::Result<Value> {
        let session = self.session.clone().context("no page attached")?;
        self.send(method, params, Some(session)).await
    }

    /// A command to the browser itself.
    pub(crate) async fn browser_call(
        &mut self,
        method: &str,
        params: Value,
    ) -> anyhow::Result<Value> {
        self.send(method, params, None).await
    }

    async fn send(
        &mut self,
        method: &str,
        params: Value,
        session: Option<String>,
    ) -> anyhow::Result<Value> {
        self.next_id += 1;
        let id = self.next_id;
        let mut msg = json!({"id": id, "method": method, "params": params});
        if let Some(s) = session {
            msg["sessionId"] = Value::String(s);
        }
        let end = Instant::now() + CALL_DEADLINE;
        timeout_at(end, self.ws.send(Message::Text(msg.to_string().into())))
            .await
            .with_context(|| format!("sending {method} timed out"))??;
        loop {
            let m = timeout_at(end, self.ws.next())
                .await
                .with_context(|| format!("no answer to {method} within {CALL_DEADLINE:?}"))?
                .with_context(|| format!("the DevTools socket closed awaiting {method}"))??;
            let Message::Text(text) = m else { continue };
            let v: Value = serde_json::from_str(&text)?;
            if v["id"].as_u64() == Some(id) {
                if let Some(e) = v.get("error") {
                    bail!("{method} failed: {e}");
                }
                return Ok(v["result"].clone());
            }
            self.note_event(&v);
        }
    }

    fn note_event(&mut self, v: &Value) {
        match v["method"].as_str() {
            Some("Runtime.exceptionThrown") => {
                let d = &v["params"]["exceptionDetails"];
                let text = d["exception"]["description"]
                    .as_str()
                    .or(d["text"].as_str())
                    .unwrap_or("?");
                self.exceptions.push(text.to_string());
            }
            Some("Runtime.consoleAPICalled") => {
                let args: Vec<String> = v["params"]["args"]
                    .as_array()
                    .map(|a| {
                        a.iter()
                            .map(|x| match &x["value"] {
                                Value::String(s) => s.clone(),
                                Value::Null => x["description"].as_str().unwrap_or("").to_string(),
                                other => other.to_string(),
                            })
                            .collect()
                    })
                    .unwrap_or_default();
                let kind = v["params"]["type"].as_str().unwrap_or("log");
                self.console.push(format!("{kind}: {}", args.join(" ")));
            }
            _ => {}
        }
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        let _ = self.child.start_kill();
    }
}

/// Standard base64 (the screenshot's encoding), without a dependency for it.
fn base64_decode(s: &str) -> anyhow::Result<Vec<u8>> {
    let mut out = Vec::with_capacity(s.len() * 3 / 4);
    let (mut acc, mut bits) = (0u32, 0u32);
    for c in s.bytes() {
        let v = match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' => 62,
            b'/' => 63,
            b'=' | b'\n' | b'\r' => continue,
            _ => bail!("not base64: {:?}", c as char),
        };
        acc = (acc << 6) | v as u32;
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
            acc &= (1 << bits) - 1;
        }
    }
    Ok(out)
}
