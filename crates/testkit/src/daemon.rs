//! `gonio daemon` as a child process on an ephemeral loopback port, and `gonio ctl` against it: every child is
//! killed when its guard drops (even when the test fails), and every wait is bounded.

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Output, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use crate::cli::gonio;

/// The daemon child: killed on drop.
#[derive(Debug)]
pub struct Daemon {
    pub child: Child,
    /// `http://127.0.0.1:PORT`.
    pub url: String,
    /// The daemon's standard output, line by line.
    pub stdout: mpsc::Receiver<String>,
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// `time_scale`: simulated seconds per real second for the simulated instrument.
pub fn start_daemon(data: &Path, time_scale: &str, env: &[(&str, &str)]) -> Daemon {
    start_daemon_on(data, time_scale, env, None)
}

/// [`start_daemon`] on the instrument file `instrument` (default: the embedded simulated one).
pub fn start_daemon_on(
    data: &Path,
    time_scale: &str,
    env: &[(&str, &str)],
    instrument: Option<&Path>,
) -> Daemon {
    let mut cmd = gonio();
    cmd.args(["daemon", "--listen", "127.0.0.1:0", "--data"])
        .arg(data);
    if let Some(file) = instrument {
        cmd.arg("--instrument").arg(file);
    }
    cmd.args(["--sim-time-scale", time_scale, "--shutdown-grace-s", "5"])
        .env_remove("GONIO_TOKEN")
        .stdout(Stdio::piped())
        .stderr(Stdio::null());
    for (k, v) in env {
        cmd.env(k, v);
    }
    let mut child = cmd.spawn().expect("start gonio daemon");
    let stdout = child.stdout.take().expect("stdout");
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let mut daemon = Daemon {
        child,
        url: String::new(),
        stdout: rx,
    };
    let line = daemon
        .stdout
        .recv_timeout(Duration::from_secs(30))
        .expect("the daemon prints its address");
    let addr = line
        .strip_prefix("gonio daemon listening on ")
        .and_then(|rest| rest.split_whitespace().next())
        .unwrap_or_else(|| panic!("unexpected first line {line:?}"));
    assert!(addr.starts_with("http://127.0.0.1:"), "{addr}");
    daemon.url = addr.to_string();
    daemon
}

/// Run `gonio ctl` with a deadline.
pub fn ctl(daemon: &Daemon, args: &[&str], env: &[(&str, &str)]) -> Output {
    let mut cmd = gonio();
    cmd.args(["ctl", "--url", &daemon.url])
        .args(args)
        .env_remove("GONIO_TOKEN");
    for (k, v) in env {
        cmd.env(k, v);
    }
    let mut child = cmd
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start gonio ctl");
    let start = Instant::now();
    loop {
        if child.try_wait().expect("wait").is_some() {
            return child.wait_with_output().expect("output");
        }
        if start.elapsed() > Duration::from_secs(120) {
            let _ = child.kill();
            let out = child.wait_with_output().expect("output");
            panic!(
                "gonio ctl {args:?} did not finish: {}",
                String::from_utf8_lossy(&out.stdout)
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}
