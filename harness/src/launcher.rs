//! The one launcher of local clusters of daemon processes (`lightfold demo`, `lightfold soak`,
//! `lightfold bench`): each daemon is a `lightfold node` or `lightfold compositor` process with a
//! token file, `--parent-pid` (so a killed launcher leaves no orphans) and a process group of
//! its own, read back by the `listening ADDR` line it prints; [`Children`] stops and reaps them
//! on every exit path. Also what launchers measure and signal their processes with.

use anyhow::{Context, bail};
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// Where local daemons listen: loopback, a port the kernel picks.
pub const ANY_PORT: &str = "127.0.0.1:0";

/// How long a daemon may take to print its address.
pub const START_WITHIN: Duration = Duration::from_secs(30);

/// Spawned daemons (id, process), stopped (SIGTERM, then SIGKILL after 5 s) and reaped on drop,
/// so every exit path, panics included, cleans up. `soak` replaces entries when it restarts a
/// daemon.
#[derive(Debug, Default)]
pub struct Children(pub Vec<(String, Child)>);

impl Drop for Children {
    fn drop(&mut self) {
        for (_, c) in &mut self.0 {
            // A child already reaped may have passed its pid on to another process.
            if matches!(c.try_wait(), Ok(None)) {
                send_signal(c.id(), rustix::process::Signal::TERM);
            }
        }
        let deadline = Instant::now() + Duration::from_secs(5);
        for (name, c) in &mut self.0 {
            loop {
                match c.try_wait() {
                    Ok(Some(_)) => break,
                    Ok(None) if Instant::now() < deadline => {
                        std::thread::sleep(Duration::from_millis(20))
                    }
                    _ => {
                        tracing::warn!(daemon = %name, "did not stop on SIGTERM; killing");
                        let _ = c.kill();
                        let _ = c.wait();
                        break;
                    }
                }
            }
        }
    }
}

/// One daemon started: its id, role (`node` or `compositor`) and the address it listens on.
#[derive(Debug, Clone)]
pub struct Started {
    pub id: String,
    pub role: &'static str,
    pub addr: String,
}

/// Starts daemon processes of the `lightfold` executable `exe`.
#[derive(Debug, Clone)]
pub struct Launcher {
    pub exe: PathBuf,
    /// The token file every daemon reads (see [`write_token`]).
    pub token: PathBuf,
    /// The daemons' log filter (`--log`).
    pub log: String,
    /// Where each daemon's stderr is appended (`ID.log`); `None`: this process's stderr.
    pub logs: Option<PathBuf>,
    /// Lavapipe threads per render node (`LP_NUM_THREADS`); 0 leaves Mesa's default.
    pub gpu_threads: u32,
    /// Whether each daemon serves `/metrics` on a port of its own (`--metrics-listen`).
    pub metrics: bool,
    /// More flags for render nodes (`--backend`, `--pack`).
    pub node_args: Vec<String>,
}

impl Launcher {
    /// A launcher of this process's own executable.
    pub fn this_exe(token: PathBuf, log: &str) -> anyhow::Result<Launcher> {
        Ok(Launcher {
            exe: std::env::current_exe().context("cannot find the lightfold executable")?,
            token,
            log: log.to_string(),
            logs: None,
            gpu_threads: 0,
            metrics: false,
            node_args: Vec::new(),
        })
    }

    /// Starts `nodes` render nodes (`node-0`, …) then `compositors` compositors (`comp-0`, …),
    /// each on a port the kernel picks, all at once; returns them once each printed its address
    /// (those already started are stopped when one fails).
    pub fn start_cluster(
        &self,
        nodes: usize,
        compositors: usize,
    ) -> anyhow::Result<(Children, Vec<Started>)> {
        let mut children = Children::default();
        let roles: Vec<(String, &'static str)> = (0..nodes)
            .map(|i| (format!("node-{i}"), "node"))
            .chain((0..compositors).map(|i| (format!("comp-{i}"), "compositor")))
            .collect();
        for (id, role) in &roles {
            let child = self.spawn(id, role, ANY_PORT)?;
            children.0.push((id.clone(), child));
        }
        let deadline = Instant::now() + START_WITHIN;
        let mut started = Vec::new();
        for ((id, child), (_, role)) in children.0.iter_mut().zip(&roles) {
            let addr = read_listening(child, id, deadline)?;
            started.push(Started {
                id: id.clone(),
                role,
                addr,
            });
        }
        Ok((children, started))
    }

    /// Starts daemon `id` listening on `listen` (a restarted daemon's old address); returns it
    /// once it printed its address.
    pub fn start(
        &self,
        id: &str,
        role: &str,
        listen: &str,
        within: Duration,
    ) -> anyhow::Result<(Child, String)> {
        let mut child = self.spawn(id, role, listen)?;
        match read_listening(&mut child, id, Instant::now() + within) {
            Ok(addr) => Ok((child, addr)),
            Err(e) => {
                let _ = child.kill();
                let _ = child.wait();
                Err(e)
            }
        }
    }

    fn spawn(&self, id: &str, role: &str, listen: &str) -> anyhow::Result<Child> {
        let mut cmd = daemon_command(&self.exe, role, id, &self.token, &self.log, listen);
        if role == "node" {
            if self.gpu_threads > 0 {
                cmd.env("LP_NUM_THREADS", self.gpu_threads.to_string());
            }
            cmd.args(&self.node_args);
        }
        if self.metrics {
            cmd.args(["--metrics-listen", ANY_PORT]);
        }
        if let Some(logs) = &self.logs {
            let path = logs.join(format!("{id}.log"));
            let log = std::fs::OpenOptions::new()
                .create(true)
                .append(true)
                .open(&path)
                .with_context(|| format!("cannot open {}", path.display()))?;
            cmd.stderr(Stdio::from(log));
        }
        cmd.spawn().with_context(|| format!("cannot start {id}"))
    }
}

/// The cluster file (`docs/cluster.md`) naming `started` daemons, the sink on a loopback port
/// the kernel picks.
pub fn cluster_file(started: &[Started]) -> String {
    let mut text = String::from("version = 1\nsink_listen = \"127.0.0.1:0\"\n");
    for d in started {
        let table = if d.role == "node" {
            "node"
        } else {
            "compositor"
        };
        text.push_str(&format!(
            "[[{table}]]\naddress = \"{}\"\nid = \"{}\"\n",
            d.addr, d.id
        ));
    }
    text
}

/// A token for one run: a fresh temporary folder (`prefix…`, removed when the guard drops), the
/// token file in it ([`write_token`]) and the token's bytes.
pub fn run_token(prefix: &str) -> anyhow::Result<(tempfile::TempDir, PathBuf, Vec<u8>)> {
    let work = tempfile::Builder::new()
        .prefix(prefix)
        .tempdir()
        .context("cannot create a temporary directory")?;
    let path = work.path().join("token");
    write_token(&path)?;
    let token = lightfold_net::load_token(Some(&path))?;
    Ok((work, path, token))
}

/// Writes a fresh random token (32 bytes, hex) to `path`, readable by its owner only.
pub fn write_token(path: &Path) -> anyhow::Result<()> {
    use std::io::{Read, Write};
    let mut bytes = [0u8; 32];
    std::fs::File::open("/dev/urandom")?.read_exact(&mut bytes)?;
    let hex = hex::encode(bytes);
    let mut f = std::fs::File::create(path)?;
    let mut perms = f.metadata()?.permissions();
    std::os::unix::fs::PermissionsExt::set_mode(&mut perms, 0o600);
    std::fs::set_permissions(path, perms)?;
    f.write_all(hex.as_bytes())?;
    Ok(())
}

/// The command line of one daemon of a local cluster, listening on `listen` ([`ANY_PORT`], or a
/// port it had before when a daemon is restarted); stdout is piped for [`read_listening`].
pub fn daemon_command(
    exe: &Path,
    role: &str,
    id: &str,
    token: &Path,
    log: &str,
    listen: &str,
) -> Command {
    let mut cmd = Command::new(exe);
    cmd.arg("--log")
        .arg(log)
        .arg(role)
        .arg("--listen")
        .arg(listen)
        .arg("--id")
        .arg(id)
        .arg("--token-file")
        .arg(token)
        .arg("--parent-pid")
        .arg(std::process::id().to_string())
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit());
    // A process group of its own: a Ctrl-C at the terminal interrupts the launcher and its
    // coordinator, which stop the daemons once the frames in flight are done (they still exit
    // when the launcher does, by `--parent-pid`).
    std::os::unix::process::CommandExt::process_group(&mut cmd, 0);
    cmd
}

/// Reads the daemon's `listening <addr>` line from its stdout by `deadline`; keeps draining the
/// pipe afterwards (saying where the daemon's metrics are).
pub fn read_listening(child: &mut Child, name: &str, deadline: Instant) -> anyhow::Result<String> {
    let stdout = child
        .stdout
        .take()
        .with_context(|| format!("{name} has no stdout"))?;
    let (tx, rx) = std::sync::mpsc::channel();
    let who = name.to_string();
    std::thread::spawn(move || {
        let mut lines = BufReader::new(stdout).lines();
        let first = lines.next();
        let _ = tx.send(first);
        // Keep draining so the daemon never blocks on a full pipe; say where its metrics are.
        for line in lines.map_while(Result::ok) {
            if let Some(a) = line.strip_prefix("metrics ") {
                eprintln!("{who}: metrics on http://{}/metrics", a.trim());
            }
        }
    });
    let left = deadline.saturating_duration_since(Instant::now());
    match rx.recv_timeout(left) {
        Ok(Some(Ok(line))) => match line.strip_prefix("listening ") {
            Some(addr) => Ok(addr.trim().to_string()),
            None => bail!("{name} printed {line:?} instead of its address"),
        },
        Ok(_) => bail!("{name} exited before it was listening"),
        Err(_) => bail!(
            "{name} did not start listening within {:.0} s",
            left.as_secs_f64()
        ),
    }
}

/// Sends `signal` to process `pid`; false if it is gone or may not be signalled.
pub fn send_signal(pid: u32, signal: rustix::process::Signal) -> bool {
    i32::try_from(pid)
        .ok()
        .and_then(rustix::process::Pid::from_raw)
        .is_some_and(|p| rustix::process::kill_process(p, signal).is_ok())
}

/// CPU seconds (user + system, all threads) process `pid` has used so far; 0 if unknown.
pub fn cpu_seconds(pid: u32) -> f64 {
    i32::try_from(pid)
        .ok()
        .and_then(|p| procfs::process::Process::new(p).ok())
        .and_then(|p| p.stat().ok())
        .map_or(0.0, |s| {
            (s.utime + s.stime) as f64 / procfs::ticks_per_second().max(1) as f64
        })
}

/// Peak resident set (`VmHWM`) of process `pid` in KiB; 0 if unknown.
pub fn peak_rss_kib(pid: u32) -> u64 {
    i32::try_from(pid)
        .ok()
        .and_then(|p| procfs::process::Process::new(p).ok())
        .and_then(|p| p.status().ok())
        .and_then(|s| s.vmhwm)
        .unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn this_process_is_measured_and_signalled() {
        let me = std::process::id();
        assert!(peak_rss_kib(me) > 0);
        // Spin until the CPU clock has ticked at least once.
        let start = std::time::Instant::now();
        while cpu_seconds(me) == 0.0 && start.elapsed() < Duration::from_secs(5) {
            std::hint::black_box((0..10_000u64).sum::<u64>());
        }
        assert!(cpu_seconds(me) > 0.0);
        assert_eq!(cpu_seconds(u32::MAX), 0.0);
        // A child ended by the signal shows that it arrived.
        let mut child = std::process::Command::new("sleep")
            .arg("30")
            .spawn()
            .unwrap();
        assert!(send_signal(child.id(), rustix::process::Signal::TERM));
        let status = child.wait().unwrap();
        assert_eq!(
            std::os::unix::process::ExitStatusExt::signal(&status),
            Some(rustix::process::Signal::TERM.as_raw())
        );
        assert!(!send_signal(u32::MAX, rustix::process::Signal::TERM));
    }

    #[test]
    fn the_cluster_file_names_every_daemon() {
        let d = |id: &str, role, addr: &str| Started {
            id: id.into(),
            role,
            addr: addr.into(),
        };
        let text = cluster_file(&[
            d("node-0", "node", "127.0.0.1:1"),
            d("comp-0", "compositor", "127.0.0.1:2"),
        ]);
        assert_eq!(
            text,
            "version = 1\nsink_listen = \"127.0.0.1:0\"\n[[node]]\naddress = \"127.0.0.1:1\"\n\
             id = \"node-0\"\n[[compositor]]\naddress = \"127.0.0.1:2\"\nid = \"comp-0\"\n"
        );
    }
}
