#!/usr/bin/env python3
"""The official Zaber host library (zaber-motion) drives the simulator's Zaber ASCII chain.

Starts `gonio sim`, opens the printed pseudo-terminal of the Zaber chain ("stage") with the library, detects the
devices, homes, moves (absolute, relative, velocity), reads positions and settings, and checks a rejected move and
reply checksums. Exits non-zero with a message on any failure; the simulator is stopped in every case.

Offline note: the library identifies devices through Zaber's online device database, which is not reachable here,
so devices are detected with identify_devices=False and driven in native units (microsteps, velocity data units).

Usage: python3 tests/zaber_host_library.py [path/to/gonio]   (default: $CARGO_TARGET_DIR or target, debug/gonio)
"""

import json
import os
import select
import signal
import subprocess
import sys
import tempfile
import time

from zaber_motion import Library, LogOutputMode
from zaber_motion.ascii import Connection
from zaber_motion.exceptions import BadDataException

TIME_SCALE = 20.0  # simulated seconds per real second
MICROSTEP_DEG = 0.000234375  # config/instruments/simulated.toml, both stage axes
VELOCITY_DATA_PER_USTEP_S = 1.6384  # Zaber velocity data units per microstep/s


class Failure(Exception):
    pass


def check(condition, message):
    if not condition:
        raise Failure(message)


def gonio_binary():
    if len(sys.argv) > 1:
        return sys.argv[1]
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    target = os.environ.get("CARGO_TARGET_DIR", os.path.join(root, "target"))
    return os.path.join(target, "debug", "gonio")


def start_sim(binary, deadline_s=30.0):
    """Start `gonio sim`; return (process, {device: path}) once it prints {"ready": true}."""
    check(os.path.exists(binary), f"gonio binary not found at {binary} (run `cargo build -p gonio` first)")
    sim = subprocess.Popen(
        [binary, "sim", "--time-scale", str(TIME_SCALE)],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
    )
    # Raw reads (no Python buffering) so that select() sees every line.
    paths, pending, end = {}, b"", time.monotonic() + deadline_s
    while True:
        while b"\n" in pending:
            line, pending = pending.split(b"\n", 1)
            msg = json.loads(line)
            if msg.get("ready"):
                return sim, paths
            paths[msg["device"]] = msg["path"]
        left = end - time.monotonic()
        if left <= 0 or not select.select([sim.stdout], [], [], left)[0]:
            sim.kill()
            raise Failure(f"gonio sim printed no ready line within {deadline_s} s")
        chunk = os.read(sim.stdout.fileno(), 4096)
        if not chunk:
            raise Failure(f"gonio sim exited early with status {sim.wait()}")
        pending += chunk


def wait_s(sim_seconds):
    time.sleep(sim_seconds / TIME_SCALE)


def exercise(port):
    with Connection.open_serial_port(port) as conn:
        conn.enable_alerts()
        devices = conn.detect_devices(identify_devices=False)
        check([d.device_address for d in devices] == [1, 2], f"detected {devices}, expected devices 1 and 2")
        for device in devices:
            serial = device.settings.get("system.serial")
            check(serial > 0, f"device {device.device_address}: system.serial {serial}")
            axis = device.get_axis(1)
            name = f"device {device.device_address} axis 1"
            check(axis.settings.get("resolution") == 64, f"{name}: resolution is not 64")
            check(not axis.is_homed(), f"{name}: reports homed before homing")

            axis.home()  # waits until idle
            check(axis.is_homed(), f"{name}: not homed after home()")
            check(axis.get_position() == 0, f"{name}: position {axis.get_position()} after homing, expected 0")

            target = round(10.0 / MICROSTEP_DEG)  # 10 degrees in microsteps
            axis.move_absolute(target)
            pos = axis.get_position()
            check(pos == target, f"{name}: position {pos} after move_absolute({target})")
            axis.move_relative(-1000)
            pos = axis.get_position()
            check(pos == target - 1000, f"{name}: position {pos} after move_relative(-1000)")

            limit_max = axis.settings.get("limit.max")
            try:
                axis.move_absolute(limit_max + 1)
                raise Failure(f"{name}: a move past limit.max ({limit_max}) was accepted")
            except BadDataException:
                pass

            # Turn at 5 deg/s for 0.5 simulated s, then stop: the axis has moved forward and comes to rest.
            speed = round(5.0 / MICROSTEP_DEG * VELOCITY_DATA_PER_USTEP_S)
            before = axis.get_position()
            axis.move_velocity(speed)
            wait_s(0.5)
            axis.stop()  # waits until idle
            after = axis.get_position()
            check(not axis.is_busy(), f"{name}: busy after stop()")
            check(after > before, f"{name}: move_velocity({speed}) did not move forward ({before} -> {after})")

            # Replies carry a checksum once comm.checksum is 1; the library verifies it.
            device.settings.set("comm.checksum", 1)
            check(axis.get_position() == after, f"{name}: position changed while idle (checksummed reply)")
            device.settings.set("comm.checksum", 0)
            print(f"ok: {name}: detected, homed, moved to {target}, {target - 1000}, velocity move to {after}")


def main():
    signal.alarm(120)  # the whole run is bounded; SIGALRM ends it with a non-zero status
    log = tempfile.NamedTemporaryFile(prefix="zaber-motion-", suffix=".log", delete=False).name
    Library.set_log_output(LogOutputMode.FILE, log)
    sim = None
    try:
        sim, paths = start_sim(gonio_binary())
        check("stage" in paths, f"gonio sim printed no Zaber device 'stage': {paths}")
        exercise(paths["stage"])
    except Exception as e:  # any library exception is a failure too
        print(f"FAIL: {type(e).__name__}: {e}", file=sys.stderr)
        with open(log) as f:
            tail = f.readlines()[-40:]
        print("last exchanges (zaber-motion log):\n" + "".join(tail), file=sys.stderr)
        return 1
    finally:
        if sim is not None:
            sim.terminate()
            try:
                sim.wait(timeout=10)
            except subprocess.TimeoutExpired:
                sim.kill()
    os.remove(log)
    print("zaber host library: 1 passed, 0 failed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
