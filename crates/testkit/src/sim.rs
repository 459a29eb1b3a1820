//! `gonio sim --link-dir` as a child process: the simulated devices on stable links and the power meter on a
//! socket, reached as real hardware is (an instrument file naming those paths), with the simulated operator on
//! its standard input. Killed when the guard drops, even when the test fails.

use std::collections::HashMap;
use std::io::{BufRead, BufReader, Lines, Write};
use std::path::Path;
use std::process::{Child, ChildStdin, ChildStdout, Stdio};

use crate::cli::gonio;

/// The `gonio sim` child: killed on drop.
#[derive(Debug)]
pub struct SimLinks {
    pub child: Child,
    stdin: Option<ChildStdin>,
    stdout: Lines<BufReader<ChildStdout>>,
    /// Each device's name (`arms`, `stage`, `wheel`, `meter`) and the path (or `usb-socket:PATH`) it is on.
    pub ports: HashMap<String, String>,
}

impl Drop for SimLinks {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Start `gonio sim` on the embedded simulated instrument with `material` mounted, its devices under `links`,
/// at `time_scale` simulated seconds a real second; returns once it says it is ready.
pub fn start_sim_links(links: &Path, material: &str, time_scale: &str) -> SimLinks {
    let mut child = gonio()
        .args([
            "sim",
            "--time-scale",
            time_scale,
            "--material",
            material,
            "--link-dir",
        ])
        .arg(links)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("start gonio sim");
    let stdin = child.stdin.take();
    let stdout = BufReader::new(child.stdout.take().expect("sim stdout")).lines();
    let mut sim = SimLinks {
        child,
        stdin,
        stdout,
        ports: HashMap::new(),
    };
    loop {
        let line = sim.line();
        // One JSON object a line: a device (`device`, and `port` or `path`), then `{"ready":true}`.
        if line.replace(' ', "") == "{\"ready\":true}" {
            break;
        }
        let field = |key: &str| {
            let start = line.find(&format!("\"{key}\":\""))? + key.len() + 4;
            line[start..].split('"').next().map(str::to_string)
        };
        let device = field("device").unwrap_or_else(|| panic!("no device in {line:?}"));
        let port = field("port")
            .or_else(|| field("path"))
            .unwrap_or_else(|| panic!("no path in {line:?}"));
        sim.ports.insert(device, port);
    }
    sim
}

impl SimLinks {
    /// The simulator's next line on its standard output.
    pub fn line(&mut self) -> String {
        self.stdout
            .next()
            .expect("gonio sim printed a line")
            .expect("UTF-8 line")
    }

    /// `base` (an instrument file whose devices are on `port = "sim"`) with every device on its path here.
    pub fn instrument_text(&self, base: &str) -> String {
        let mut text = base.to_string();
        for device in ["arms", "stage", "wheel", "meter"] {
            let block = format!("name = \"{device}\"");
            let at = text.find(&block).expect("device block");
            let port_at = at + text[at..].find("port = \"sim\"").expect("port line");
            text.replace_range(
                port_at..port_at + "port = \"sim\"".len(),
                &format!("port = {:?}", self.ports[device]),
            );
        }
        assert!(
            !text.contains("port = \"sim\""),
            "a device left on the in-process simulator"
        );
        text
    }

    /// The simulated operator does `command` (`sample out`, `sample in`); the simulator's acknowledgement line.
    pub fn operator(&mut self, command: &str) -> String {
        let stdin = self.stdin.as_mut().expect("the simulator's stdin is open");
        stdin
            .write_all(format!("{command}\n").as_bytes())
            .and_then(|()| stdin.flush())
            .unwrap_or_else(|e| panic!("writing {command:?} to gonio sim: {e}"));
        self.line()
    }

    /// Close the simulator's standard input (no more operator commands).
    pub fn close_stdin(&mut self) {
        self.stdin = None;
    }
}
