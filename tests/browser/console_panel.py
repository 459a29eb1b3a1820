#!/usr/bin/env python3
"""The status page's console panel in a real headless Chromium (the same daemon, browser and tab drivers as
status_page.py, imported from it).

Usage: console_panel.py GONIO_BINARY [CHROMIUM_BINARY]

Against `gonio daemon` on the simulated instrument, with the HTTP API as the independent reference:
  - the panel shows every axis; Home all references them (API state);
  - the + and - jog buttons move the axis by the step typed in the panel (API state, within the axis's
    tolerance), and the panel shows the new position;
  - choosing a filter turns the wheel there (API state);
  - the live trace draws readings from the reading stream and shows the latest power;
  - the alignment card aligns the instrument through the daemon and shows the calibration it made as current
    (API /api/calibrations);
  - while a campaign runs the controls are disabled with a reason naming it; the emergency stop is not, and
    clicking it halts the campaign (paused, "emergency stop" in the API) and gives the console back;
  - no script error, no CSP violation.
Exits 0 when every check passes, 1 with a message otherwise.
"""

import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import status_page  # noqa: E402
from status_page import TOKEN, Browser, Daemon, Fail, Tab, campaign_toml  # noqa: E402


def axis(state, name):
    for a in state["axes"]:
        if a["name"] == name:
            return a
    raise Fail(f"no axis {name} in {state}")


def run(gonio, chromium, workdir):
    started = time.monotonic()
    daemon = Daemon(gonio, workdir)
    browser = None
    try:
        browser = Browser(chromium, workdir)
        tab = Tab(browser)
        tab.navigate(daemon.url + "/#token=" + TOKEN)
        tab.wait_for("the console's axes", "document.querySelectorAll('#console-axes tbody tr').length === 4",
                     daemon=daemon)
        tab.wait_for("the panel enabled", "document.getElementById('console-card').dataset.enabled === 'true'")
        print(f"ok: the panel lists the 4 axes ({time.monotonic() - started:.1f} s)")

        # Home all, then jog the detector both ways by the step typed in.
        tab.click("#console-home")
        deadline = time.monotonic() + 60
        while not all(a["referenced"] for a in daemon.json("GET", "/api/console/state")["axes"]):
            if time.monotonic() > deadline:
                raise Fail("Home all did not reference every axis")
            time.sleep(0.2)
        tab.wait_for("the panel enabled after homing",
                     "document.getElementById('console-card').dataset.enabled === 'true'")
        def set_step(deg):
            tab.eval(f"""(() => {{ const s = document.getElementById('jog-step'); s.value = '{deg}';
                s.dispatchEvent(new Event('input')); }})()""")

        def jog(sign):
            tab.wait_for("the panel ready", "document.getElementById('console-card').dataset.enabled === 'true'")
            tab.eval("document.getElementById('console-status').textContent = ''")
            tab.click(f"#console-axes tr[data-axis='detector'] button[data-sign='{sign}']")
            said = tab.wait_for("the jog answered", """document.getElementById('console-card').dataset.enabled
                === 'true' && document.getElementById('console-status').textContent""")
            if not said.startswith("jog detector"):
                raise Fail(f"the jog was not done: {said!r}")

        # Homed, both arms are at their home; the first jog parts them by more than the safety separation.
        set_step(20)
        jog(1)
        set_step(2.5)
        before = axis(daemon.json("GET", "/api/console/state"), "detector")["position_deg"]
        for sign in (1, 1, 1, 1, -1):
            jog(sign)
        after = axis(daemon.json("GET", "/api/console/state"), "detector")["position_deg"]
        if abs(after - (before + 7.5)) > 0.01:
            raise Fail(f"four jogs up and one down by 2.5 deg moved the detector from {before} to {after}")
        shown = float(tab.text("#console-axes tr[data-axis='detector'] .pos"))
        if abs(shown - after) > 0.001:
            raise Fail(f"the panel shows the detector at {shown}, the API at {after}")
        print(f"ok: jogged the detector {before:.3f} -> {after:.3f} deg, shown on the panel")

        # The wheel.
        target = tab.eval("""(() => { const s = document.getElementById('console-filter');
            const o = [...s.options].find((o) => !o.selected && o.textContent.includes('nm'));
            s.value = o.value; s.dispatchEvent(new Event('change')); return Number(o.value); })()""")
        deadline = time.monotonic() + 30
        while daemon.json("GET", "/api/console/state")["wheel"]["position"] != target:
            if time.monotonic() > deadline:
                raise Fail(f"choosing filter {target} did not turn the wheel")
            time.sleep(0.2)
        print(f"ok: the wheel turned to position {target}")

        # The live trace.
        tab.click("#console-trace")
        tab.wait_for("readings on the trace", "Number(document.getElementById('trace').dataset.points) >= 5"
                     " && document.querySelector('#trace polyline') !== null")
        value = tab.text("#trace-value")
        if " W" not in value:
            raise Fail(f"the trace shows no power: {value!r}")
        tab.click("#console-trace")
        print(f"ok: live trace ({value})")

        # The alignment card: the daemon aligns the simulated instrument, and the card shows the calibration it
        # made as the current one (the API says the same).
        tab.wait_for("the align button enabled", "!document.getElementById('align-start').disabled")
        # The geometric alignment alone: the characterisation's hour of instrument time is the daemon tests'.
        tab.click("#align-characterise")
        tab.click("#align-start")
        tab.wait_for("the alignment completed on the card", """document.getElementById('align-state').dataset
            .state === 'completed' && document.getElementById('align-current').textContent
            .startsWith('Current calibration: 1,')""", timeout=240, daemon=daemon)
        calibrations = daemon.json("GET", "/api/calibrations")
        if [c["id"] for c in calibrations if c["current"]] != [1]:
            raise Fail(f"the API's current calibration is not the card's: {calibrations}")
        tab.wait_for("the panel enabled after the alignment",
                     "document.getElementById('console-card').dataset.enabled === 'true'", daemon=daemon)
        print(f"ok: alignment card: calibration 1 made and current ({time.monotonic() - started:.1f} s)")

        # A campaign owns the instrument: the controls are off with the reason; the emergency stop is not.
        cid = daemon.json("POST", "/api/campaigns", campaign_toml("panel-owner", True, -70.0, 70.0, 2.5))["id"]
        tab.wait_for("the panel disabled with the reason", f"""document.getElementById('console-card').dataset
            .enabled === 'false' && !document.getElementById('console-reason').hidden && document
            .getElementById('console-reason').textContent.includes('Campaign {cid} (panel-owner)')""", daemon=daemon)
        disabled = tab.eval("""[...document.querySelectorAll('#console-card .console-control')]
            .every((c) => c.disabled)""")
        if not disabled:
            raise Fail("some console control is enabled while a campaign owns the instrument")
        if tab.eval("document.getElementById('estop').disabled"):
            raise Fail("the emergency stop is disabled")
        tab.click("#estop")
        deadline = time.monotonic() + 30
        while True:
            view = daemon.campaign(cid)
            if view["state"] == "paused" and "emergency stop" in (view.get("last_error") or ""):
                break
            if time.monotonic() > deadline:
                raise Fail(f"the emergency stop did not halt the campaign: {view}")
            time.sleep(0.1)
        tab.wait_for("the panel back after the stop",
                     "document.getElementById('console-card').dataset.enabled === 'true'", daemon=daemon)
        tab.check_no_errors()
        print(f"ok: disabled with the reason while campaign {cid} ran; the emergency stop halted it")
        daemon.json("POST", f"/api/campaigns/{cid}/abort")
        tab.close()
    except Fail:
        log = daemon.log_tail()
        if log:
            print("--- daemon log (tail) ---\n" + log, file=sys.stderr)
        raise
    finally:
        if browser is not None:
            browser.close()
        daemon.stop()
    print(f"PASS: console panel, {time.monotonic() - started:.1f} s")


if __name__ == "__main__":
    sys.exit(status_page.main(run, __doc__, "gonio-console-"))
