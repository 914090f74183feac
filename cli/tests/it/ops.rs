//! What an operator sees: a multi-process cluster (2 nodes, 2 compositors, a coordinator), each
//! serving `--metrics-listen` and logging JSON, scraped while it renders — `/metrics` parses
//! (and passes `promtool check metrics` where Prometheus is installed), counters increase,
//! `/readyz` flips as coordinators configure daemons and leave, every log line is a JSON object
//! naming its daemon, `--stats` has a line per frame — and a node under `--require-gpu` on a
//! machine without a hardware adapter refuses to start, saying why.

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

const TOKEN: &str = "ops-test-token-of-32-bytes-long!";
const FRAMES: u32 = 40;
/// Starting a device and calibrating it takes seconds on a loaded 2-core machine.
const START: Duration = Duration::from_secs(120);

/// Children killed and reaped on drop, so a failing test leaves no process behind.
struct Procs(Vec<Child>);

impl Drop for Procs {
    fn drop(&mut self) {
        for c in &mut self.0 {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

fn dir(name: &str) -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A daemon started with metrics and JSON logs; returns its control and metrics addresses.
fn daemon(procs: &mut Procs, role: &str, id: &str, logs: &Path) -> (String, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_lightfold"))
        .args(["--log-format", "json", role, "--listen", "127.0.0.1:0"])
        .args(["--id", id, "--metrics-listen", "127.0.0.1:0"])
        .env("LIGHTFOLD_TOKEN", TOKEN)
        .env_remove("RUST_LOG")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(std::fs::File::create(logs.join(format!("{id}.log"))).unwrap())
        .spawn()
        .expect("spawn lightfold");
    let stdout = child.stdout.take().unwrap();
    procs.0.push(child);
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let mut lines = BufReader::new(stdout).lines();
        let _ = tx.send(lines.next());
        let _ = tx.send(lines.next());
        for _ in lines {}
    });
    let line = |what: &str| match rx.recv_timeout(START) {
        Ok(Some(Ok(l))) => l
            .strip_prefix(what)
            .unwrap_or_else(|| panic!("{id}: {l:?} is not `{what}ADDR`"))
            .trim()
            .to_string(),
        other => panic!("{id} did not print `{what}ADDR`: {other:?}"),
    };
    let control = line("listening ");
    let metrics = line("metrics ");
    (control, metrics)
}

/// GET `path` from `addr`: status and body (a deadline on every step).
fn get(addr: &str, path: &str) -> (u16, String) {
    let mut s = TcpStream::connect_timeout(&addr.parse().unwrap(), Duration::from_secs(5))
        .unwrap_or_else(|e| panic!("connect {addr}: {e}"));
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    s.set_write_timeout(Some(Duration::from_secs(10))).unwrap();
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n"
    )
    .unwrap();
    let mut reply = String::new();
    s.read_to_string(&mut reply)
        .unwrap_or_else(|e| panic!("read {addr}{path}: {e}"));
    let status = reply
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or_else(|| panic!("{addr}{path}: no status in {reply:?}"));
    let (head, body) = reply.split_once("\r\n\r\n").unwrap_or((&reply, ""));
    // Small answers come whole; a chunked one is reassembled.
    let body = if head
        .to_ascii_lowercase()
        .contains("transfer-encoding: chunked")
    {
        dechunk(body)
    } else {
        body.to_string()
    };
    (status, body)
}

fn dechunk(mut s: &str) -> String {
    let mut out = String::new();
    while let Some((size, rest)) = s.split_once("\r\n") {
        let n = usize::from_str_radix(size.trim(), 16).expect("chunk size");
        if n == 0 {
            break;
        }
        out.push_str(&rest[..n]);
        s = &rest[n + 2..];
    }
    out
}

/// One sample of the Prometheus text format.
#[derive(Debug)]
struct Sample {
    name: String,
    labels: BTreeMap<String, String>,
    value: f64,
}

/// Parses the exposition strictly: every sample line is `name{labels} value`, every label value
/// quoted, every value a number, and every family has `# TYPE` before its samples.
fn parse(text: &str) -> Vec<Sample> {
    let mut typed: BTreeMap<String, String> = BTreeMap::new();
    let mut out = Vec::new();
    for line in text.lines().filter(|l| !l.trim().is_empty()) {
        if let Some(t) = line.strip_prefix("# TYPE ") {
            let (name, kind) = t.split_once(' ').expect("TYPE name kind");
            assert!(
                ["counter", "gauge", "histogram", "summary", "untyped"].contains(&kind),
                "{line}"
            );
            typed.insert(name.to_string(), kind.to_string());
            continue;
        }
        if line.starts_with('#') {
            assert!(line.starts_with("# HELP "), "unexpected comment {line:?}");
            continue;
        }
        let (series, value) = line.rsplit_once(' ').expect("sample value");
        let value: f64 = value
            .parse()
            .unwrap_or_else(|_| panic!("value of {line:?}"));
        let (name, labels) = match series.split_once('{') {
            Some((n, rest)) => (n, labels(rest.strip_suffix('}').expect("closing brace"))),
            None => (series, BTreeMap::new()),
        };
        assert!(
            name.chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == ':'),
            "metric name {name:?}"
        );
        let family = ["_bucket", "_sum", "_count"]
            .iter()
            .find_map(|s| name.strip_suffix(s).filter(|f| typed.contains_key(*f)))
            .unwrap_or(name);
        assert!(typed.contains_key(family), "{name} has no # TYPE line");
        out.push(Sample {
            name: name.to_string(),
            labels,
            value,
        });
    }
    out
}

fn labels(mut s: &str) -> BTreeMap<String, String> {
    let mut out = BTreeMap::new();
    while !s.is_empty() {
        let (k, rest) = s.split_once("=\"").expect("label=\"");
        let mut value = String::new();
        let mut chars = rest.char_indices();
        let end = loop {
            match chars.next().expect("unterminated label value") {
                (_, '\\') => value.push(chars.next().expect("escape").1),
                (i, '"') => break i,
                (_, c) => value.push(c),
            }
        };
        out.insert(k.to_string(), value);
        s = rest[end + 1..].trim_start_matches(',');
    }
    out
}

/// The sum of the samples called `name` whose labels include `with`.
fn value(samples: &[Sample], name: &str, with: &[(&str, &str)]) -> f64 {
    samples
        .iter()
        .filter(|s| s.name == name)
        .filter(|s| {
            with.iter()
                .all(|(k, v)| s.labels.get(*k).map(String::as_str) == Some(v))
        })
        .map(|s| s.value)
        .sum()
}

fn scrape(addr: &str) -> (String, Vec<Sample>) {
    let (status, body) = get(addr, "/metrics");
    assert_eq!(status, 200, "{addr}/metrics: {body}");
    let samples = parse(&body);
    (body, samples)
}

/// Waits until `f` holds, polling every 50 ms.
fn wait_for(what: &str, limit: Duration, mut f: impl FnMut() -> bool) {
    let start = Instant::now();
    while !f() {
        assert!(start.elapsed() < limit, "{what}: not within {limit:?}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// `promtool check metrics` over a scraped sample, where Prometheus is installed
/// (`scripts/install-deps.sh --test` installs it); says loudly when it is not.
fn promtool(what: &str, text: &str) {
    let child = Command::new("promtool")
        .args(["check", "metrics"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn();
    let mut child = match child {
        Ok(c) => c,
        Err(e) => {
            eprintln!(
                "SKIPPED promtool check of {what}: promtool not runnable ({e}); install \
                 Debian's `prometheus` package (scripts/install-deps.sh --test)"
            );
            return;
        }
    };
    child
        .stdin
        .take()
        .unwrap()
        .write_all(text.as_bytes())
        .unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "promtool check metrics on {what}: {}{}\n{text}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn a_cluster_is_scraped_while_it_renders() {
    let logs = dir("ops-cluster");
    let mut procs = Procs(Vec::new());
    let nodes: Vec<(String, String)> = (0..2)
        .map(|i| daemon(&mut procs, "node", &format!("node-{i}"), &logs))
        .collect();
    let comps: Vec<(String, String)> = (0..2)
        .map(|i| daemon(&mut procs, "compositor", &format!("comp-{i}"), &logs))
        .collect();
    let all: Vec<&(String, String)> = nodes.iter().chain(&comps).collect();

    // Live once serving (a node after opening its device); not ready before a coordinator.
    for (_, m) in &all {
        wait_for("/healthz 200", START, || get(m, "/healthz").0 == 200);
        let (status, why) = get(m, "/readyz");
        assert_eq!(status, 503, "{m}: ready before any coordinator: {why}");
        assert!(why.contains("waiting for a coordinator"), "{why}");
        assert_eq!(get(m, "/nothing").0, 404);
    }
    let (_, before) = scrape(&nodes[0].1);
    let adapter = before
        .iter()
        .find(|s| s.name == "lightfold_adapter_info")
        .expect("the node reports its adapter");
    assert!(!adapter.labels["adapter"].is_empty());
    assert!(["true", "false"].contains(&adapter.labels["software"].as_str()));
    assert_eq!(adapter.labels["daemon"], "node-0");
    assert_eq!(adapter.labels["role"], "node");

    let stats = logs.join("frames.jsonl");
    let mut coordinator = Command::new(env!("CARGO_BIN_EXE_lightfold"));
    coordinator
        .args(["--log-format", "json", "coordinator"])
        .args(["--size", "160x120", "--frames", &FRAMES.to_string()])
        .args(["--orbit", "2", "--no-frame-files"])
        .args([
            "--metrics-listen",
            "127.0.0.1:0",
            "--connect-timeout",
            "120",
        ])
        .arg("--stats")
        .arg(&stats)
        .arg("--out")
        .arg(logs.join("out.png"))
        .arg("--exr")
        .arg(logs.join("out.exr"))
        .env("LIGHTFOLD_TOKEN", TOKEN)
        .env_remove("RUST_LOG")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(std::fs::File::create(logs.join("coordinator.log")).unwrap());
    for (c, _) in &nodes {
        coordinator.args(["--node", c]);
    }
    for (c, _) in &comps {
        coordinator.args(["--compositor", c]);
    }
    let mut child = coordinator.spawn().expect("spawn coordinator");
    let stdout = child.stdout.take().unwrap();
    procs.0.push(child);
    let coord = procs.0.len() - 1;
    let (tx, rx) = std::sync::mpsc::channel();
    let (addr_tx, addr_rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let mut text = String::new();
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if let Some(a) = line.strip_prefix("metrics ") {
                let _ = addr_tx.send(a.trim().to_string());
            }
            text.push_str(&line);
            text.push('\n');
        }
        let _ = tx.send(text);
    });
    let coord_metrics = addr_rx
        .recv_timeout(START)
        .expect("the coordinator's metrics address");

    // Ready once configured; then the frame counters move while frames run.
    for (_, m) in &all {
        wait_for("/readyz 200 once configured", START, || {
            get(m, "/readyz").0 == 200
        });
    }
    let done = |m: &str| value(&scrape(m).1, "lightfold_frames_done_total", &[]);
    let first = done(&nodes[0].1);
    wait_for("frames done to increase", START, || {
        done(&nodes[0].1) > first
    });
    // The node read below may not have finished a frame yet when node 0 has.
    wait_for("the second node to finish a frame", START, || {
        done(&nodes[1].1) >= 1.0
    });
    let (during, samples) = scrape(&nodes[1].1);
    let running = procs.0[coord].try_wait().unwrap().is_none();
    // A stage finishes its first frame after the nodes do.
    wait_for("a stage to finish a frame", START, || {
        done(&comps[0].1) >= 1.0
    });
    let (comp_text, comp_samples) = scrape(&comps[0].1);
    promtool("a node's /metrics", &during);
    promtool("a compositor's /metrics", &comp_text);
    assert!(
        value(
            &samples,
            "lightfold_frame_phase_seconds_count",
            &[("phase", "eye")]
        ) >= 1.0
    );
    assert!(value(&samples, "lightfold_bytes_out_total", &[]) > 0.0);
    assert!(value(&samples, "lightfold_bytes_in_total", &[("kind", "scene")]) > 0.0);
    assert!(value(&samples, "lightfold_peak_rss_bytes", &[]) > 1e6);
    assert_eq!(value(&samples, "lightfold_ready", &[]), 1.0);
    assert!(value(&samples, "lightfold_plan_epoch", &[]) >= 1.0);
    assert!(value(&samples, "lightfold_plan_session_start_seconds", &[]) > 1.7e9);
    assert!(
        value(
            &comp_samples,
            "lightfold_bytes_in_total",
            &[("kind", "bands")]
        ) > 0.0
    );
    assert!(
        value(
            &comp_samples,
            "lightfold_frame_phase_seconds_count",
            &[("phase", "total")]
        ) >= 1.0
    );
    // Bytes per input link, labelled by the producing daemon: every link counts its own.
    let links: Vec<&Sample> = comp_samples
        .iter()
        .filter(|s| s.name == "lightfold_link_bytes_in_total")
        .collect();
    assert!(!links.is_empty(), "no per-link counter:\n{comp_text}");
    assert!(
        links
            .iter()
            .all(|s| s.labels.contains_key("peer") && s.value > 0.0),
        "{comp_text}"
    );
    eprintln!("scraped while the coordinator was running: {running}");
    let (coord_text, c) = scrape(&coord_metrics);
    promtool("the coordinator's /metrics", &coord_text);
    assert_eq!(
        get(&coord_metrics, "/readyz"),
        (200, "serving\n".to_string())
    );
    assert!(value(&c, "lightfold_frames_delivered_total", &[]) >= 1.0);
    assert!(value(&c, "lightfold_frame_latency_seconds_count", &[]) >= 1.0);
    assert_eq!(value(&c, "lightfold_daemons", &[("role", "node")]), 2.0);
    assert_eq!(
        value(&c, "lightfold_daemons", &[("role", "compositor")]),
        2.0
    );
    assert_eq!(value(&c, "lightfold_daemons_lost_total", &[]), 0.0);
    // What the binary is, and the standard process series, on every daemon.
    for (text, parsed) in [
        (&coord_text, &c),
        (&comp_text, &comp_samples),
        (&during, &samples),
    ] {
        let protocol = lightfold_protocol::PROTOCOL_VERSION.to_string();
        assert_eq!(
            value(
                parsed,
                "lightfold_build_info",
                &[
                    ("version", env!("CARGO_PKG_VERSION")),
                    ("protocol", protocol.as_str())
                ]
            ),
            1.0,
            "{text}"
        );
        assert!(
            value(parsed, "process_resident_memory_bytes", &[]) > 0.0,
            "{text}"
        );
        // (Whole seconds: `metrics` counters are integers.)
        assert!(
            parsed.iter().any(|s| s.name == "process_cpu_seconds_total"),
            "{text}"
        );
        assert!(value(parsed, "process_open_fds", &[]) > 0.0, "{text}");
    }
    assert!(
        value(
            &c,
            "lightfold_daemon_frame_seconds_count",
            &[("peer", "node-1"), ("phase", "total")]
        ) >= 1.0
    );

    let status = {
        let c = &mut procs.0[coord];
        let start = Instant::now();
        loop {
            if let Some(s) = c.try_wait().unwrap() {
                break s;
            }
            assert!(start.elapsed() < START, "the coordinator did not finish");
            std::thread::sleep(Duration::from_millis(100));
        }
    };
    let out = rx.recv_timeout(Duration::from_secs(10)).unwrap();
    let log = std::fs::read_to_string(logs.join("coordinator.log")).unwrap();
    assert!(status.success(), "coordinator failed:\n{out}\n{log}");
    assert!(out.contains("adapters: 2 × "), "{out}");

    // Every node rendered every frame once, every stage combined it once; nothing failed. The
    // coordinator left: not ready any more.
    for (i, (_, m)) in all.iter().enumerate() {
        let (_, s) = scrape(m);
        assert_eq!(
            value(&s, "lightfold_frames_done_total", &[]),
            f64::from(FRAMES),
            "daemon {i}"
        );
        assert_eq!(value(&s, "lightfold_frames_failed_total", &[]), 0.0);
        wait_for("/readyz 503 once the coordinator left", START, || {
            get(m, "/readyz").0 == 503
        });
    }

    // One JSON line per frame, with every daemon's report.
    let lines: Vec<serde_json::Value> = std::fs::read_to_string(&stats)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect();
    assert_eq!(lines.len(), FRAMES as usize);
    for (i, l) in lines.iter().enumerate() {
        assert_eq!(l["frame"], i as u64 + 1);
        assert!(l["latency_ms"].as_f64().unwrap() > 0.0);
        assert_eq!(l["width"], 160);
        let daemons = l["daemons"].as_array().unwrap();
        assert_eq!(daemons.len(), 4, "{l}");
        for d in daemons {
            assert!(d["total_ms"].as_f64().unwrap() > 0.0, "{d}");
        }
    }

    // JSON logs: every line of every process an object naming its daemon.
    for id in ["node-0", "node-1", "comp-0", "comp-1", "coordinator"] {
        let text = std::fs::read_to_string(logs.join(format!("{id}.log"))).unwrap();
        assert!(!text.is_empty(), "{id} logged nothing");
        for line in text.lines() {
            let v: serde_json::Value = serde_json::from_str(line)
                .unwrap_or_else(|e| panic!("{id}: a log line is not JSON ({e}): {line}"));
            assert_eq!(v["daemon"], id, "{line}");
            assert!(
                v["level"].is_string() && v["timestamp"].is_string(),
                "{line}"
            );
            assert!(!line.contains('\u{1b}'), "escape codes in {line}");
        }
    }
    let node_log = std::fs::read_to_string(logs.join("node-0.log")).unwrap();
    assert!(node_log.contains("\"render node ready\""));
}

#[test]
fn require_gpu_refuses_a_software_adapter() {
    let logs = dir("ops-require-gpu");
    let log = logs.join("node.log");
    // Without NODEVICE_SELECT or a session: the binary sets what Mesa needs itself.
    let mut child = Command::new(env!("CARGO_BIN_EXE_lightfold"))
        .args(["node", "--listen", "127.0.0.1:0", "--require-gpu"])
        .env("LIGHTFOLD_TOKEN", TOKEN)
        .env_remove("NODEVICE_SELECT")
        .env_remove("XDG_RUNTIME_DIR")
        .env_remove("RUST_LOG")
        .stdin(Stdio::null())
        .stdout(std::fs::File::create(logs.join("node.out")).unwrap())
        .stderr(std::fs::File::create(&log).unwrap())
        .spawn()
        .unwrap();
    let start = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break Some(s);
        }
        let text = std::fs::read_to_string(&log).unwrap_or_default();
        if text.contains("render node ready") {
            break None;
        }
        if start.elapsed() > START {
            let _ = child.kill();
            panic!("the node neither refused nor started:\n{text}");
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    let text = std::fs::read_to_string(&log).unwrap();
    assert!(
        !text.contains('\u{1b}'),
        "escape codes in a log file:\n{text}"
    );
    assert!(
        !text.contains("XDG_RUNTIME_DIR"),
        "Mesa's device-select layer was not turned off:\n{text}"
    );
    match status {
        Some(s) => {
            assert!(!s.success());
            assert!(
                text.contains("--require-gpu") && text.contains("software rasteriser"),
                "the refusal does not say why:\n{text}"
            );
            // Refused before it bound a port or calibrated the device.
            let out = std::fs::read_to_string(logs.join("node.out")).unwrap_or_default();
            assert!(!out.contains("listening"), "it listened first:\n{out}");
            assert!(!text.contains("calibrat"), "it calibrated first:\n{text}");
            eprintln!("refused as expected:\n{text}");
        }
        None => {
            // A machine with a hardware GPU: it started on it.
            let _ = child.kill();
            let _ = child.wait();
            assert!(
                text.contains("software=false"),
                "started under --require-gpu on a software adapter:\n{text}"
            );
            eprintln!("this machine has a hardware adapter; the node started on it:\n{text}");
        }
    }
}

#[test]
fn no_colour_in_files_and_json_on_request() {
    let logs = dir("ops-logs");
    let out = Command::new(env!("CARGO_BIN_EXE_lightfold"))
        .args(["--log-format", "json", "--log", "debug", "compositor"])
        .args(["--listen", "127.0.0.1:0", "--id", "comp-x"])
        .args(["--metrics-listen", "127.0.0.1:0"])
        .env("LIGHTFOLD_TOKEN", TOKEN)
        .env("NO_COLOR", "1")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut procs = Procs(vec![out]);
    let stdout = procs.0[0].stdout.take().unwrap();
    let mut lines = BufReader::new(stdout).lines();
    let first = lines.next().unwrap().unwrap();
    assert!(first.starts_with("listening "), "{first}");
    let metrics = lines.next().unwrap().unwrap();
    let metrics = metrics.strip_prefix("metrics ").unwrap().to_string();
    // Live: its signal handlers are installed. Stop it and read what it logged.
    wait_for("/healthz 200", START, || get(&metrics, "/healthz").0 == 200);
    let pid = procs.0[0].id();
    let pid = rustix::process::Pid::from_raw(pid as i32).unwrap();
    rustix::process::kill_process(pid, rustix::process::Signal::TERM).unwrap();
    let c = procs.0.pop().unwrap();
    let done = c.wait_with_output().unwrap();
    assert!(done.status.success(), "SIGTERM ends a compositor cleanly");
    let text = String::from_utf8(done.stderr).unwrap();
    std::fs::write(logs.join("comp-x.log"), &text).unwrap();
    let mut messages = Vec::new();
    for line in text.lines() {
        let v: serde_json::Value =
            serde_json::from_str(line).unwrap_or_else(|e| panic!("not JSON ({e}): {line}"));
        assert_eq!(v["daemon"], "comp-x");
        messages.push(v["message"].as_str().unwrap_or("").to_string());
    }
    assert!(
        messages.iter().any(|m| m == "compositor listening"),
        "{messages:?}"
    );
    assert!(
        messages.iter().any(|m| m.contains("SIGTERM")),
        "{messages:?}"
    );
}

/// Under systemd (`Type=notify`, `WatchdogSec=`): `READY=1` once live, watchdog pings at half
/// the period, `STOPPING=1` on SIGTERM — read from a notify socket of the test's own.
#[test]
fn systemd_hears_ready_watchdog_and_stopping() {
    use std::os::unix::net::UnixDatagram;
    let d = dir("ops-notify");
    let socket_path = d.join("notify.sock");
    let socket = UnixDatagram::bind(&socket_path).unwrap();
    socket
        .set_read_timeout(Some(Duration::from_secs(60)))
        .unwrap();
    let child = Command::new(env!("CARGO_BIN_EXE_lightfold"))
        .args(["compositor", "--listen", "127.0.0.1:0", "--id", "comp-sd"])
        .env("LIGHTFOLD_TOKEN", TOKEN)
        .env("NOTIFY_SOCKET", &socket_path)
        .env("WATCHDOG_USEC", "400000")
        .env_remove("WATCHDOG_PID")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(d.join("comp-sd.log")).unwrap())
        .spawn()
        .unwrap();
    let mut procs = Procs(vec![child]);
    let next = || {
        let mut buf = [0u8; 256];
        let n = socket.recv(&mut buf).expect("a notification within 60 s");
        String::from_utf8_lossy(&buf[..n]).trim().to_string()
    };
    assert_eq!(next(), "READY=1");
    let start = Instant::now();
    assert_eq!(next(), "WATCHDOG=1");
    assert_eq!(next(), "WATCHDOG=1");
    // Two pings at half of 400 ms: about 400 ms, never much faster.
    assert!(
        start.elapsed() >= Duration::from_millis(300),
        "{:?}",
        start.elapsed()
    );
    let pid = rustix::process::Pid::from_raw(procs.0[0].id() as i32).unwrap();
    rustix::process::kill_process(pid, rustix::process::Signal::TERM).unwrap();
    loop {
        match next().as_str() {
            "WATCHDOG=1" => continue,
            other => {
                assert_eq!(other, "STOPPING=1");
                break;
            }
        }
    }
    let c = procs.0.pop().unwrap();
    let status = c.wait_with_output().unwrap().status;
    assert!(status.success());
}
