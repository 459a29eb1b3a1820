//! `gonio sim` end to end: start the binary, read its JSON lines, talk to the devices through the printed
//! pseudo-terminal paths as a plain serial client would, then stop it with SIGTERM.

use std::io::{BufRead, BufReader, Read, Write};
use std::process::Stdio;
use std::time::{Duration, Instant};

use gonio_testkit::gonio;
use gonio_testkit::sim::start_sim_links;

/// Read from `port` until `end` appears or the deadline passes.
fn read_until(port: &mut std::fs::File, end: &[u8], deadline: Duration) -> Vec<u8> {
    let start = Instant::now();
    let mut got = Vec::new();
    let mut buf = [0u8; 256];
    while start.elapsed() < deadline {
        match port.read(&mut buf) {
            Ok(0) => std::thread::sleep(Duration::from_millis(5)),
            Ok(n) => {
                got.extend_from_slice(&buf[..n]);
                if got.windows(end.len()).any(|w| w == end) {
                    break;
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                std::thread::sleep(Duration::from_millis(5))
            }
            Err(e) => panic!("reading the terminal: {e}"),
        }
    }
    got
}

/// Ask the FW102C for its position on a fresh connection and expect `pos?\r1\r> `, after at most the port
/// noise real wheels send ahead of their first answer (NUL bytes and a `CMD_NOT_DEFINED`, which the simulator
/// reproduces under realistic.toml's recorded variants; the ideal instrument sends none).
fn expect_wheel_position_answer(wheel: &mut std::fs::File) {
    wheel.write_all(b"pos?\r").expect("write");
    let got =
        String::from_utf8_lossy(&read_until(wheel, b"pos?\r1\r> ", Duration::from_secs(5))).into_owned();
    let noise = got
        .strip_suffix("pos?\r1\r> ")
        .unwrap_or_else(|| panic!("no answer to pos? in {got:?}"));
    let noise = noise.trim_start_matches('\0');
    assert!(
        noise.is_empty() || noise == "Command error CMD_NOT_DEFINED\r> ",
        "unexpected bytes before the answer: {noise:?}"
    );
}

fn open_port(path: &str) -> std::fs::File {
    use std::os::unix::fs::OpenOptionsExt;
    std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .custom_flags(nix::fcntl::OFlag::O_NONBLOCK.bits() | nix::fcntl::OFlag::O_NOCTTY.bits())
        .open(path)
        .unwrap_or_else(|e| panic!("open {path}: {e}"))
}

#[test]
fn gonio_sim_serves_devices_on_pseudo_terminals_and_exits_cleanly_on_sigterm() {
    let mut child = gonio()
        .args(["sim", "--time-scale", "100"])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("start gonio sim");
    let stdout = child.stdout.take().expect("stdout");
    let mut lines = BufReader::new(stdout).lines();
    let mut devices = Vec::new();
    loop {
        let line = lines.next().expect("a line before ready").expect("utf-8 line");
        let v: serde_json::Value = serde_json::from_str(&line).expect("JSON line");
        if v["ready"] == serde_json::Value::Bool(true) {
            break;
        }
        devices.push(v);
    }
    let path_of = |protocol: &str| -> String {
        devices
            .iter()
            .find(|d| d["protocol"] == protocol)
            .and_then(|d| d["path"].as_str())
            .unwrap_or_else(|| panic!("no {protocol} device in {devices:?}"))
            .to_string()
    };
    let meter = devices
        .iter()
        .find(|d| d["protocol"] == "pm100")
        .expect("the meter is listed");
    assert!(meter["path"].is_null());

    // SMC100: status of controller 1 after power-up is NOT REFERENCED from reset; home it and watch it become READY.
    // Real controllers may leave the first TS after power-up unanswered (realistic.toml's simulator does; the
    // ideal one answers), and drop a command that arrives while they are still busy with the previous one: ask
    // again, and pace.
    let mut arms = open_port(&path_of("smc100"));
    arms.write_all(b"1TS\r\n").expect("write");
    let first = read_until(&mut arms, b"\r\n", Duration::from_millis(500));
    if first.is_empty() {
        arms.write_all(b"1TS\r\n").expect("write");
    }
    let reply = if first.is_empty() {
        read_until(&mut arms, b"\r\n", Duration::from_secs(5))
    } else {
        first
    };
    assert_eq!(String::from_utf8_lossy(&reply), "1TS00000A\r\n");
    arms.write_all(b"1PA10\r\n").expect("write");
    std::thread::sleep(Duration::from_millis(100));
    arms.write_all(b"1TE\r\n").expect("write");
    let reply = read_until(&mut arms, b"\r\n", Duration::from_secs(5));
    assert_eq!(
        String::from_utf8_lossy(&reply),
        "1TEH\r\n",
        "PA while NOT REFERENCED is error H"
    );
    std::thread::sleep(Duration::from_millis(100));
    arms.write_all(b"1OR\r\n").expect("write");
    let start = Instant::now();
    let mut state = String::new();
    while start.elapsed() < Duration::from_secs(10) {
        arms.write_all(b"1TS\r\n").expect("write");
        // A TS right after homing completes may go unanswered: a short wait, then ask again.
        state =
            String::from_utf8_lossy(&read_until(&mut arms, b"\r\n", Duration::from_millis(500))).into_owned();
        if state == "1TS000032\r\n" {
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    assert_eq!(state, "1TS000032\r\n", "READY from HOMING after homing");

    // Zaber: a status request to all devices gets one reply per device.
    let mut stage = open_port(&path_of("zaber-ascii"));
    stage.write_all(b"/\n").expect("write");
    let reply = String::from_utf8_lossy(&read_until(&mut stage, b"@02", Duration::from_secs(5))).into_owned();
    let reply = reply + &String::from_utf8_lossy(&read_until(&mut stage, b"\r\n", Duration::from_secs(5)));
    assert_eq!(reply, "@01 0 OK IDLE WR 0\r\n@02 0 OK IDLE WR 0\r\n");

    // FW102C: echo, reply, prompt.
    let mut wheel = open_port(&path_of("fw102c"));
    expect_wheel_position_answer(&mut wheel);

    drop((arms, stage, wheel));
    nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(child.id() as i32),
        nix::sys::signal::Signal::SIGTERM,
    )
    .expect("send SIGTERM");
    let start = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().expect("wait") {
            break s;
        }
        if start.elapsed() > Duration::from_secs(10) {
            let _ = child.kill();
            panic!("gonio sim did not exit after SIGTERM");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    assert!(status.success(), "exit status {status}");
}

/// With `--link-dir`, a disconnect fault makes the port vanish as an unplugged USB-serial adapter does: the link
/// disappears, an open descriptor hangs up, and after `reconnect_after_s` the same path serves the device again.
#[test]
fn with_link_dir_a_disconnected_port_vanishes_and_comes_back_at_the_same_path() {
    let dir = tempfile::tempdir().expect("tempdir");
    let instrument = dir.path().join("faulty.toml");
    // Simulated seconds at --time-scale 100: gone after 3 s of real time, back 3 s later.
    let text = gonio_instrument::SIMULATED_INSTRUMENT_TOML.replace(
        "[simulator.faults]",
        "[simulator.faults]\ndisconnect_after_s = 300.0\nreconnect_after_s = 300.0",
    );
    std::fs::write(&instrument, text).expect("write instrument");
    let links = dir.path().join("ports");
    let mut child = gonio()
        .args(["sim", "--time-scale", "100", "--instrument"])
        .arg(&instrument)
        .arg("--link-dir")
        .arg(&links)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("start gonio sim");
    let stdout = child.stdout.take().expect("stdout");
    let mut lines = BufReader::new(stdout).lines();
    let mut wheel_path = None;
    loop {
        let line = lines.next().expect("a line before ready").expect("utf-8 line");
        let v: serde_json::Value = serde_json::from_str(&line).expect("JSON line");
        if v["ready"] == serde_json::Value::Bool(true) {
            break;
        }
        if v["protocol"] == "fw102c" {
            wheel_path = v["path"].as_str().map(str::to_string);
        }
    }
    let wheel_path = wheel_path.expect("the wheel is listed");
    assert_eq!(std::path::Path::new(&wheel_path), links.join("wheel"));

    let mut wheel = open_port(&wheel_path);
    expect_wheel_position_answer(&mut wheel);

    let wait_for = |present: bool| {
        let start = Instant::now();
        while std::fs::symlink_metadata(&wheel_path).is_ok() != present {
            assert!(
                start.elapsed() < Duration::from_secs(30),
                "the link never became {}",
                if present { "present" } else { "absent" }
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    };
    wait_for(false);
    // The descriptor opened before the disconnect is hung up: reads end (EOF or EIO), they do not just block.
    let start = Instant::now();
    let hung_up = loop {
        let mut b = [0u8; 64];
        match wheel.read(&mut b) {
            Ok(0) => break true,
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {}
            Err(_) => break true,
            Ok(_) => {}
        }
        if start.elapsed() > Duration::from_secs(5) {
            break false;
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    assert!(
        hung_up,
        "the old terminal still reads as live after the port vanished"
    );
    assert!(
        std::fs::OpenOptions::new().read(true).open(&wheel_path).is_err(),
        "the vanished port cannot be opened"
    );

    wait_for(true);
    // The device answers again behind the same path (a new connection: the port noise may come again).
    let mut wheel = open_port(&wheel_path);
    expect_wheel_position_answer(&mut wheel);
    drop(wheel);

    nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(child.id() as i32),
        nix::sys::signal::Signal::SIGTERM,
    )
    .expect("send SIGTERM");
    let start = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().expect("wait") {
            break s;
        }
        if start.elapsed() > Duration::from_secs(10) {
            let _ = child.kill();
            panic!("gonio sim did not exit after SIGTERM");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    assert!(status.success(), "exit status {status}");
    assert!(
        std::fs::symlink_metadata(links.join("wheel")).is_err(),
        "the links are removed on exit"
    );
}

/// Writes lines to a child's stdin; panics with context if the child went away.
fn say(stdin: &mut std::process::ChildStdin, line: &str) {
    stdin
        .write_all(format!("{line}\n").as_bytes())
        .and_then(|()| stdin.flush())
        .unwrap_or_else(|e| panic!("writing {line:?}: {e}"));
}

/// The whole real-hardware path: `gonio run` against a SEPARATE `gonio sim` process, every device opened by path
/// (serial links, the power meter's USB socket), an absolute calibration with the operator's steps done by hand
/// (the sample taken out of the simulator and put back through its stdin, each prompt confirmed with Enter),
/// and BRDF values that match the material the simulator holds.
#[test]
fn gonio_run_against_a_separate_gonio_sim_through_the_real_hardware_path_matches_the_material() {
    use gonio_brdf::brdf::Brdf;
    use gonio_brdf::geometry::Direction;
    use gonio_brdf::spectrum::Wavelength;

    let dir = tempfile::tempdir().expect("tempdir");
    let mut sim = start_sim_links(&dir.path().join("ports"), "spectralon", "50");
    assert_eq!(sim.ports.len(), 4, "{:?}", sim.ports);
    assert!(sim.ports["meter"].starts_with("usb-socket:"), "{:?}", sim.ports);

    // The simulated instrument's file with every device on a real path instead of "sim".
    let text = sim.instrument_text(gonio_instrument::SIMULATED_INSTRUMENT_TOML);
    let instrument = dir.path().join("lab.toml");
    std::fs::write(&instrument, text).expect("write instrument");
    let campaign = dir.path().join("separate.toml");
    std::fs::write(
        &campaign,
        r#"
[campaign]
id = "separate"
[sample]
radius_mm = 12.5
[plan]
bands_nm = [550.0]
[plan.grid]
kind = "isotropic"
theta_i_deg = { from = 0.0, to = 50.0, step = 25.0 }
theta_o_deg = { from = 10.0, to = 70.0, step = 30.0 }
delta_phi_deg = { from = 0.0, to = 180.0, step = 90.0 }
[acquisition]
averaging = 4
"#,
    )
    .expect("write campaign");

    let out = dir.path().join("out");
    let mut run = gonio()
        .arg("run")
        .arg(&campaign)
        .arg("--instrument")
        .arg(&instrument)
        .arg("--out")
        .arg(&out)
        .arg("--quiet")
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start gonio run");
    let mut run_in = run.stdin.take().expect("run stdin");
    let run_err = BufReader::new(run.stderr.take().expect("run stderr"));
    // The operator: read each prompt, do what it says on the simulator, confirm.
    let mut prompts = Vec::new();
    let mut log = Vec::new();
    for line in run_err.lines() {
        let line = line.expect("utf-8");
        log.push(line.clone());
        let Some(prompt) = line.strip_prefix("operator: ") else {
            continue;
        };
        let command = if prompt.contains("remove the sample") {
            "sample out"
        } else if prompt.contains("mount the sample again") {
            "sample in"
        } else {
            panic!("unexpected operator prompt {prompt:?}");
        };
        let ack = sim.operator(command);
        assert_eq!(
            ack,
            format!("{{\"sample_mounted\":{}}}", command == "sample in"),
            "simulator acknowledgement"
        );
        say(&mut run_in, "");
        prompts.push(command);
    }
    let status = run.wait().expect("wait run");
    assert!(status.success(), "gonio run failed: {}", log.join("\n"));
    assert_eq!(&prompts[..2], ["sample out", "sample in"], "{log:?}");

    let csv = std::fs::read_to_string(out.join("points.csv")).expect("points.csv");
    let mut rows = csv.lines();
    let header: Vec<&str> = rows.next().expect("header").split(',').collect();
    let col = |name: &str| {
        header
            .iter()
            .position(|h| *h == name)
            .unwrap_or_else(|| panic!("no {name}"))
    };
    assert!(
        !header.contains(&"brdf_true_sr"),
        "not a dry-run from gonio run's point of view"
    );
    let material = gonio_brdf::material::Material::preset("spectralon").expect("preset");
    let wl = Wavelength::from_nm(550.0).expect("wavelength");
    let mut compared = 0;
    for row in rows {
        let f: Vec<&str> = row.split(',').collect();
        let num = |name: &str| {
            f[col(name)]
                .parse::<f64>()
                .unwrap_or_else(|e| panic!("{name} in {row}: {e}"))
        };
        assert_eq!(f[col("flags")], "", "a valid point: {row}");
        let wi = Direction::from_spherical_deg(num("theta_i_deg"), num("phi_i_deg"));
        let wo = Direction::from_spherical_deg(num("theta_o_deg"), num("phi_o_deg"));
        let truth = material.eval(&wi, &wo, wl).expect("eval");
        let measured = num("brdf_sr");
        assert!(
            (measured - truth).abs() <= 0.03 * truth,
            "measured {measured} vs spectralon {truth} 1/sr at {row}"
        );
        compared += 1;
    }
    assert!(compared >= 10, "only {compared} points");

    sim.close_stdin();
    nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(sim.child.id() as i32),
        nix::sys::signal::Signal::SIGTERM,
    )
    .expect("send SIGTERM");
    let status = sim.child.wait().expect("wait sim");
    assert!(status.success(), "gonio sim exit {status}");
}
