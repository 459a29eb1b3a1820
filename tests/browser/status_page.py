#!/usr/bin/env python3
"""The daemon's live status page in a real headless Chromium, driven through the DevTools protocol.

Usage: status_page.py GONIO_BINARY [CHROMIUM_BINARY]

Starts `gonio daemon` (with a token, on an ephemeral loopback port, a temporary data directory, the simulated
instrument slowed down enough to watch), submits dry-run campaigns through the HTTP API, opens the page and
checks, against the API as the independent reference:
  - without the token the page asks for it; given in the form, the page loads the data;
  - given once as /#token=..., the token leaves the address bar and the page shows the campaign, its state and
    the operator's message; the Confirm button answers the operator prompts;
  - progress increases and the polar plot gains circles as server-sent events arrive (with no other fetch of
    the points); every stored point is one circle, placed where the plot's definition puts it (computed here
    from the stored points), in the log and linear scales of the in-plane view and in the hemisphere view;
  - Pause makes the campaign paused (API), Resume makes it continue, the last readings match the stored points;
  - the campaign completes with every point on the plot; a second campaign is followed automatically and two
    clicks on Abort abort it;
  - no script error, no CSP violation.
GONIO_BROWSER_SCREENSHOT=FILE.png saves a picture of the page once the first campaign has completed.
Exits 0 when every check passes, 1 with a message otherwise. Only the standard library: Chromium is driven
over --remote-debugging-pipe (NUL-separated JSON on file descriptors 3 and 4), so no WebSocket client and no
debugging port are needed.
"""

import base64
import fcntl
import json
import math
import os
import select
import shutil
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request

TOKEN = "browser-test-token-6f1d"
# Simulated seconds per real second: slow enough that a person (and this test) sees the points arrive.
TIME_SCALE = os.environ.get("GONIO_BROWSER_TIME_SCALE", "10")
WAIT_S = 60.0


class Fail(Exception):
    pass


def campaign_toml(name, simulate_operator, theta_o_from, theta_o_to, step):
    return f"""[campaign]
id = "{name}"

[sample]
radius_mm = 12.5

[plan]
bands_nm = [550.0]
repeats = 1
reciprocity = false

[plan.grid]
kind = "in-plane"
theta_i_deg = [30.0]
theta_o_deg = {{ from = {theta_o_from}, to = {theta_o_to}, step = {step} }}

[plan.calibration]
dark_every_points = 1000
reference_every_s = 100000.0
reference_pose_deg = {{ light = -90.0, detector = 90.0 }}

[calibration]
method = "absolute"
simulate_operator = {"true" if simulate_operator else "false"}

[acquisition]
averaging = 2

[material]
preset = "coloured-plastic"
"""


# ---------------------------------------------------------------------------------------------------------------
# The daemon and its API.


class Daemon:
    def __init__(self, gonio, workdir):
        self.log_path = os.path.join(workdir, "daemon.log")
        out_path = os.path.join(workdir, "daemon.out")
        env = dict(os.environ)
        env.pop("GONIO_TOKEN", None)
        with open(out_path, "wb") as out, open(self.log_path, "wb") as err:
            self.proc = subprocess.Popen(
                [gonio, "daemon", "--listen", "127.0.0.1:0", "--data", os.path.join(workdir, "data"),
                 "--token", TOKEN, "--sim-time-scale", TIME_SCALE, "--shutdown-grace-s", "2"],
                stdout=out, stderr=err, stdin=subprocess.DEVNULL, env=env)
        deadline = time.monotonic() + 30
        self.url = None
        while self.url is None:
            if self.proc.poll() is not None:
                raise Fail(f"gonio daemon exited with {self.proc.returncode}: {self.log_tail()}")
            if time.monotonic() > deadline:
                raise Fail("gonio daemon did not print its address within 30 s")
            with open(out_path, encoding="utf-8", errors="replace") as f:
                for line in f:
                    if line.startswith("gonio daemon listening on "):
                        self.url = line.split()[4]
            time.sleep(0.05)
        # The proxy variables of the environment must not apply to loopback.
        self.opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))

    def log_tail(self):
        try:
            with open(self.log_path, encoding="utf-8", errors="replace") as f:
                return f.read()[-3000:]
        except OSError:
            return ""

    def request(self, method, path, body=None):
        data = body.encode() if body is not None else None
        req = urllib.request.Request(self.url + path, data=data, method=method)
        req.add_header("Authorization", f"Bearer {TOKEN}")
        try:
            with self.opener.open(req, timeout=30) as r:
                return r.status, r.read().decode()
        except urllib.error.HTTPError as e:
            return e.code, e.read().decode()

    def json(self, method, path, body=None):
        status, text = self.request(method, path, body)
        if status >= 300:
            raise Fail(f"{method} {path}: {status} {text}")
        return json.loads(text)

    def campaign(self, cid):
        return self.json("GET", f"/api/campaigns/{cid}")

    def points(self, cid):
        status, text = self.request("GET", f"/api/campaigns/{cid}/points.csv")
        if status != 200:
            raise Fail(f"points.csv: {status} {text}")
        lines = [l for l in text.splitlines() if l]
        header = lines[0].split(",")
        rows = []
        for line in lines[1:]:
            cells = dict(zip(header, line.split(",")))
            # Numbers, but for the text columns (the flags and the uncertainty budget's compact form).
            rows.append({k: (float(v) if v and k not in ("flags", "budget") else (v or None))
                         for k, v in cells.items()})
        return rows

    def stop(self):
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


# ---------------------------------------------------------------------------------------------------------------
# Chromium over the DevTools protocol, on a pipe.


class Browser:
    def __init__(self, chromium, workdir):
        to_chrome_r, self.to_chrome = os.pipe()
        self.from_chrome, from_chrome_w = os.pipe()
        # Copies above the low numbers, so that placing them on 3 and 4 in the child cannot clobber each other.
        high_r = fcntl.fcntl(to_chrome_r, fcntl.F_DUPFD_CLOEXEC, 10)
        high_w = fcntl.fcntl(from_chrome_w, fcntl.F_DUPFD_CLOEXEC, 10)

        def place_fds():
            os.dup2(high_r, 3, inheritable=True)
            os.dup2(high_w, 4, inheritable=True)

        self.stderr_path = os.path.join(workdir, "chromium.log")
        with open(self.stderr_path, "wb") as err:
            self.proc = subprocess.Popen(
                [chromium, "--headless=new", "--remote-debugging-pipe", "--no-sandbox", "--disable-gpu",
                 "--disable-dev-shm-usage", "--no-first-run", "--no-default-browser-check", "--no-proxy-server",
                 "--disable-extensions", "--disable-background-networking", "--disable-sync",
                 "--disable-background-timer-throttling", "--disable-renderer-backgrounding",
                 "--disable-backgrounding-occluded-windows", "--mute-audio", "--window-size=1280,1400",
                 f"--user-data-dir={os.path.join(workdir, 'profile')}", "about:blank"],
                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err, preexec_fn=place_fds,
                # Python's descriptors are not inheritable (PEP 446): only 3 and 4, made so above, are passed.
                # (close_fds would close them again after preexec_fn.)
                close_fds=False)
        for fd in (to_chrome_r, from_chrome_w, high_r, high_w):
            os.close(fd)
        self.buffer = b""
        self.next_id = 0
        self.events = []

    def close(self):
        if self.proc.poll() is None:
            try:
                self.send("Browser.close")
                self.proc.wait(timeout=10)
            except (Fail, OSError, subprocess.TimeoutExpired):
                self.proc.kill()
                self.proc.wait()
        for fd in (self.to_chrome, self.from_chrome):
            try:
                os.close(fd)
            except OSError:
                pass

    def send(self, method, params=None, session=None):
        self.next_id += 1
        message = {"id": self.next_id, "method": method, "params": params or {}}
        if session:
            message["sessionId"] = session
        try:
            os.write(self.to_chrome, json.dumps(message).encode() + b"\0")
        except BrokenPipeError as e:
            raise Fail(f"chromium is gone ({e}): {self.stderr_tail()}") from e
        return self.next_id

    def stderr_tail(self):
        try:
            with open(self.stderr_path, encoding="utf-8", errors="replace") as f:
                return f.read()[-2000:]
        except OSError:
            return ""

    def read_message(self, deadline):
        """The next message, or None at the deadline."""
        while b"\0" not in self.buffer:
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            ready, _, _ = select.select([self.from_chrome], [], [], left)
            if not ready:
                return None
            chunk = os.read(self.from_chrome, 1 << 20)
            if not chunk:
                raise Fail(f"chromium closed the DevTools pipe: {self.stderr_tail()}")
            self.buffer += chunk
        raw, self.buffer = self.buffer.split(b"\0", 1)
        return json.loads(raw)

    def call(self, method, params=None, session=None, timeout=30.0):
        wanted = self.send(method, params, session)
        deadline = time.monotonic() + timeout
        while True:
            message = self.read_message(deadline)
            if message is None:
                raise Fail(f"no answer to {method} within {timeout} s")
            if message.get("id") == wanted:
                if "error" in message:
                    raise Fail(f"{method}: {message['error']}")
                return message.get("result", {})
            if "method" in message:
                self.events.append(message)

    def drain(self):
        while (message := self.read_message(time.monotonic() + 0.01)) is not None:
            if "method" in message:
                self.events.append(message)


class Tab:
    def __init__(self, browser):
        self.browser = browser
        self.target = browser.call("Target.createTarget", {"url": "about:blank"})["targetId"]
        self.session = browser.call("Target.attachToTarget", {"targetId": self.target, "flatten": True})[
            "sessionId"]
        for domain in ("Page", "Runtime", "Log", "Network"):
            self.call(f"{domain}.enable")

    def call(self, method, params=None, timeout=30.0):
        return self.browser.call(method, params, self.session, timeout)

    def close(self):
        self.browser.call("Target.closeTarget", {"targetId": self.target})

    def navigate(self, url):
        result = self.call("Page.navigate", {"url": url})
        if result.get("errorText"):
            raise Fail(f"cannot load {url}: {result['errorText']}")

    def events(self, method):
        return [e["params"] for e in self.browser.events if e.get("sessionId") == self.session
                and e.get("method") == method]

    def check_no_errors(self):
        """Script exceptions, console errors and CSP violations fail the test; failed network requests do not
        (the 401 of the first, token-less load is expected)."""
        self.browser.drain()
        problems = []
        for e in self.events("Runtime.exceptionThrown"):
            details = e.get("exceptionDetails", {})
            problems.append(f"exception: {details.get('exception', {}).get('description') or details.get('text')}")
        for e in self.events("Runtime.consoleAPICalled"):
            if e.get("type") in ("error", "assert"):
                problems.append(f"console.{e['type']}: {[a.get('value') for a in e.get('args', [])]}")
        for e in self.events("Log.entryAdded"):
            entry = e.get("entry", {})
            if entry.get("level") == "error" and entry.get("source") != "network":
                problems.append(f"{entry.get('source')}: {entry.get('text')}")
        if problems:
            raise Fail("the page reported errors:\n  " + "\n  ".join(problems))

    def eval(self, expression):
        result = self.call("Runtime.evaluate", {"expression": expression, "returnByValue": True,
                                                "awaitPromise": True})
        if "exceptionDetails" in result:
            raise Fail(f"evaluating {expression!r}: {result['exceptionDetails']}")
        return result.get("result", {}).get("value")

    def wait_for(self, what, expression, timeout=WAIT_S, daemon=None):
        deadline = time.monotonic() + timeout
        value = None
        # While the page loads, its elements may not exist yet: that is "not yet", not an error.
        guarded = f"(() => {{ try {{ return ({expression}); }} catch (e) {{ return false; }} }})()"
        while time.monotonic() < deadline:
            value = self.eval(guarded)
            if value:
                return value
            time.sleep(0.1)
        api = ""
        if daemon is not None:
            api = "\nAPI: " + json.dumps(daemon.json("GET", "/api/campaigns"))
        raise Fail(f"timed out ({timeout} s) waiting for {what}; last value {value!r}\npage: {self.page_text()}{api}")

    def page_text(self):
        try:
            return self.eval("document.body.innerText")[:3000]
        except Fail as e:
            return str(e)

    def click(self, selector):
        """A real mouse click at the element's centre, after checking it is enabled and not covered."""
        where = self.eval(f"""(() => {{
            const e = document.querySelector({json.dumps(selector)});
            if (!e) return null;
            e.scrollIntoView({{block: 'center'}});
            const r = e.getBoundingClientRect();
            const x = r.left + r.width / 2, y = r.top + r.height / 2;
            return {{x, y, disabled: !!e.disabled, hit: document.elementFromPoint(x, y) === e}};
        }})()""")
        if where is None:
            raise Fail(f"no element {selector}")
        if where["disabled"]:
            raise Fail(f"{selector} is disabled; page: {self.page_text()}")
        if not where["hit"]:
            raise Fail(f"{selector} is covered by another element")
        for kind in ("mouseMoved", "mousePressed", "mouseReleased"):
            self.call("Input.dispatchMouseEvent", {"type": kind, "x": where["x"], "y": where["y"],
                                                   "button": "left", "clickCount": 1})

    def text(self, selector):
        return self.eval(f"document.querySelector({json.dumps(selector)}).textContent")

    def circles(self):
        """The plot's points: index, centre (SVG units), classes."""
        return self.eval("""[...document.querySelectorAll('#polar circle.pt')].map((c) => ({
            index: Number(c.dataset.index), x: Number(c.getAttribute('cx')), y: Number(c.getAttribute('cy')),
            cls: c.getAttribute('class')}))""")

    def count_requests(self, fragment):
        self.browser.drain()
        return sum(1 for e in self.events("Network.requestWillBeSent") if fragment in e["request"]["url"])


# ---------------------------------------------------------------------------------------------------------------
# The checks.


def signed_theta_o(row):
    delta = (row["phi_o_deg"] - row["phi_i_deg"]) % 360.0
    if row["theta_o_deg"] < 1e-6:
        return 0.0
    if abs(delta - 180.0) < 0.5:
        return row["theta_o_deg"]
    if delta < 0.5 or delta > 359.5:
        return -row["theta_o_deg"]
    raise Fail(f"point {row['index']} is not in the plane: {row}")


def nice_ceil(v):
    """The top of the plot's scale: the smallest 1, 2, 2.5, 5 or 10 times a power of ten at or above v."""
    power = 10.0 ** math.floor(math.log10(v))
    return next(m * power for m in (1, 2, 2.5, 5, 10) if m * power >= v * (1 - 1e-12))


def check_plot_geometry(tab, rows):
    """Every stored point is one circle, placed where the plot's definition says, computed here from the stored
    points (not from the page's numbers). In-plane: at the signed theta_o from the vertical, at radius
    100 * BRDF / top (linear) or 100 * (log10(BRDF / top) + 3) / 3 (log, three decades); hemisphere: at radius
    100 * theta_o / 90 and angle phi_o. Returns the plot's mode and scale."""
    mode, scale = tab.eval("[document.getElementById('polar').dataset.mode, "
                           "document.getElementById('polar').dataset.scale]")
    circles = tab.circles()
    by_index = {int(r["index"]): r for r in rows}
    if sorted(c["index"] for c in circles) != sorted(by_index):
        raise Fail(f"the plot shows points {sorted(c['index'] for c in circles)}, the store has {sorted(by_index)}")
    values = [r["brdf_sr"] for r in rows if r["brdf_sr"] is not None and r["brdf_sr"] > 0]
    top = nice_ceil(max(values)) if values else 1.0
    for c in circles:
        row = by_index[c["index"]]
        if mode == "in-plane":
            v = row["brdf_sr"]
            if v is None or v <= 0:
                radius = 100.0  # invalid points sit on the rim
            elif scale == "linear":
                radius = 100.0 * v / top
            elif scale == "log":
                radius = 100.0 * min(1.0, max(0.0, (math.log10(v / top) + 3.0) / 3.0))
            else:
                raise Fail(f"unknown plot scale {scale!r}")
            a = math.radians(signed_theta_o(row))
            x, y = radius * math.sin(a), -radius * math.cos(a)
        elif mode == "hemisphere":
            radius = 100.0 * min(row["theta_o_deg"], 90.0) / 90.0
            a = math.radians(row["phi_o_deg"])
            x, y = radius * math.cos(a), -radius * math.sin(a)
        else:
            raise Fail(f"unknown plot mode {mode!r}")
        # Coordinates are written with two decimals.
        if abs(c["x"] - x) > 0.011 or abs(c["y"] - y) > 0.011:
            raise Fail(f"{mode} plot ({scale}): point {c['index']} at ({c['x']}, {c['y']}), expected "
                       f"({x:.3f}, {y:.3f}) for {row}")
    return mode, scale


def check_readings(tab, rows):
    """The 'last readings' table: the most recent stored points, newest first, with their values."""
    shown = tab.eval("""[...document.querySelectorAll('#readings tbody tr')].map((tr) =>
        [...tr.children].map((td) => td.textContent))""")
    if not shown:
        raise Fail("the last readings table is empty")
    expected = sorted(rows, key=lambda r: r["index"], reverse=True)[: len(shown)]
    if len(shown) != min(12, len(rows)):
        raise Fail(f"{len(shown)} readings shown for {len(rows)} stored points")
    for cells, row in zip(shown, expected):
        if int(cells[0]) != int(row["index"]):
            raise Fail(f"readings row {cells} is not point {int(row['index'])}")
        for col, key, tolerance in ((1, "band_nm", 0.06), (2, "theta_i_deg", 0.006), (4, "theta_o_deg", 0.006),
                                    (5, "phi_o_deg", 0.006)):
            if abs(float(cells[col]) - row[key]) > tolerance:
                raise Fail(f"readings row {cells}: {key} should be {row[key]}")
        for col, key in ((6, "signal_w"), (7, "brdf_sr")):
            if row[key] is None:
                continue
            if abs(float(cells[col]) - row[key]) > 1e-4 * abs(row[key]):
                raise Fail(f"readings row {cells}: {key} should be {row[key]}")


def answer_operator_prompts(tab, daemon, cid, until):
    """Confirm every operator prompt with the page's Confirm button until `until(view)`; returns the view."""
    deadline = time.monotonic() + WAIT_S * 2
    confirmed = 0
    while time.monotonic() < deadline:
        view = daemon.campaign(cid)
        if until(view):
            return view, confirmed
        if view["state"] == "waiting-operator":
            message = view["operator_message"]
            # The page shows the prompt before the operator can answer it.
            tab.wait_for("the operator's message on the page", f"""(() => {{
                const m = document.getElementById('c-message');
                return !m.hidden && m.textContent.includes({json.dumps(message)})
                    && document.getElementById('c-state').textContent === 'waiting-operator'
                    && !document.getElementById('btn-confirm').disabled; }})()""", daemon=daemon)
            tab.click("#btn-confirm")
            confirmed += 1
            # Wait until the daemon has taken this confirmation (state or message changes).
            tab_deadline = time.monotonic() + WAIT_S
            while time.monotonic() < tab_deadline:
                now = daemon.campaign(cid)
                if now["state"] != "waiting-operator" or now["operator_message"] != message:
                    break
                time.sleep(0.05)
            else:
                raise Fail(f"Confirm on the page did not answer the prompt {message!r}")
        if view["state"] in ("completed", "aborted", "failed"):
            raise Fail(f"campaign {cid} ended {view['state']} early: {view}")
        time.sleep(0.05)
    raise Fail(f"campaign {cid} never reached the expected state: {daemon.campaign(cid)}")


def run(gonio, chromium, workdir):
    started = time.monotonic()
    daemon = Daemon(gonio, workdir)
    browser = None
    try:
        browser = Browser(chromium, workdir)
        version = browser.call("Browser.getVersion")
        print(f"browser: {version.get('product')}; daemon: {daemon.url}")
        first = daemon.json("POST", "/api/campaigns", campaign_toml("browser-sweep", False, -70.0, 70.0, 2.5))["id"]

        # 1. Without the token: the page asks for it; given in the form, it shows the data.
        tab = Tab(browser)
        tab.navigate(daemon.url + "/")
        tab.wait_for("the token prompt", """document.getElementById('connection').dataset.state === 'token'
            && !document.getElementById('token-panel').hidden""")
        tab.eval(f"document.getElementById('token-input').focus()")
        tab.call("Input.insertText", {"text": TOKEN})
        tab.click("#token-form button")
        tab.wait_for("the campaign after giving the token in the form",
                     "document.getElementById('c-name').textContent === 'browser-sweep'", daemon=daemon)
        tab.check_no_errors()
        tab.close()
        print(f"ok: token prompt and form ({time.monotonic() - started:.1f} s)")

        # 2. The token in the URL fragment: used, then removed from the address bar.
        tab = Tab(browser)
        tab.navigate(daemon.url + "/#token=" + TOKEN)
        tab.wait_for("the live event stream", "document.getElementById('connection').dataset.state === 'live'",
                     daemon=daemon)
        if tab.eval("location.href") != daemon.url + "/":
            raise Fail(f"the token is still in the address: {tab.eval('location.href')}")
        tab.wait_for("the campaign's name and state", """document.getElementById('c-name').textContent ===
            'browser-sweep' && document.getElementById('c-state').textContent !== ''""", daemon=daemon)
        print(f"ok: token from the URL fragment, page live ({time.monotonic() - started:.1f} s)")

        # 3. The operator prompts of the direct-beam calibration, answered with Confirm on the page.
        view, confirmed = answer_operator_prompts(tab, daemon, first, lambda v: v["points_done"] >= 2)
        if confirmed < 2:
            raise Fail(f"expected the two direct-beam prompts before the first points, confirmed {confirmed}")
        total = view["total_points"]
        print(f"ok: {confirmed} operator prompts confirmed on the page; {total} points planned")

        # 4. Progress and the plot grow with the event stream, without fetching the points again.
        tab.wait_for("points on the plot", "document.querySelectorAll('#polar circle.pt').length >= 2")
        csv_fetches = tab.count_requests("points.csv")
        # A fetch of points.csv sent when the page opened may still be on its way: its points, drawn later, would
        # grow the plot without an event. Count from when every fetch sent so far has been answered and drawn.
        tab.wait_for("the points fetched so far drawn",
                     f"Number(document.body.dataset.drawnLoads || 0) >= {csv_fetches}", daemon=daemon)
        # The drawing and the events it shows, read together: events received while a redraw is held back
        # (a few a second at most) are not on the plot yet, and their points would grow it after.
        drawn = ("[document.querySelectorAll('#polar circle.pt').length, "
                 "Number(document.body.dataset.drawnEvents || 0)]")
        n1, events_before = tab.eval(drawn)
        p1 = tab.eval("document.getElementById('c-progress').value")
        tab.wait_for("more points on the plot", f"""document.querySelectorAll('#polar circle.pt').length >= {n1 + 3}
            && document.getElementById('c-progress').value > {p1}""", daemon=daemon)
        if tab.count_requests("points.csv") != csv_fetches:
            raise Fail("the page fetched points.csv again: the plot should grow from server-sent events")
        _, events_after = tab.eval(drawn)
        if events_after < events_before + 3:
            raise Fail(f"server-sent events counted {events_before} -> {events_after}")
        if tab.eval("document.getElementById('polar').dataset.mode") != "in-plane":
            raise Fail("in-plane data should be drawn as an in-plane polar plot")
        if tab.text("#c-state") != "running":
            raise Fail(f"state shown {tab.text('#c-state')!r} while the campaign runs")
        if not tab.text("#c-eta").startswith("ETA "):
            raise Fail(f"no ETA shown: {tab.text('#c-eta')!r}")
        p2 = tab.eval("document.getElementById('c-progress').value")
        print(f"ok: plot {n1} -> {len(tab.circles())} points, progress {p1} -> {p2}, SSE events "
              f"{events_before} -> {events_after}, points.csv fetched {csv_fetches} time(s) in all")

        # 5. Pause: the campaign pauses (API), the page says so, nothing more is measured.
        tab.click("#btn-pause")
        deadline = time.monotonic() + WAIT_S
        while daemon.campaign(first)["state"] != "paused":
            if time.monotonic() > deadline:
                raise Fail(f"Pause did not pause the campaign: {daemon.campaign(first)}")
            time.sleep(0.05)
        tab.wait_for("'paused' on the page", """document.getElementById('c-state').textContent === 'paused'
            && !document.getElementById('btn-resume').disabled && document.getElementById('btn-pause').disabled""")
        paused_done = daemon.campaign(first)["points_done"]
        time.sleep(1.0)
        if daemon.campaign(first)["points_done"] != paused_done:
            raise Fail("points are still measured while paused")
        rows = daemon.points(first)
        tab.wait_for("every stored point on the plot",
                     f"document.querySelectorAll('#polar circle.pt').length === {len(rows)}")
        check_plot_geometry(tab, rows)
        check_readings(tab, rows)
        print(f"ok: paused at {paused_done}/{total}; plot and last readings match the stored points")

        # 6. Resume: measuring continues.
        # A resumed campaign calibrates the direct beam again, so the operator is asked again.
        tab.click("#btn-resume")
        _, confirmed = answer_operator_prompts(tab, daemon, first, lambda v: v["points_done"] > paused_done)
        tab.wait_for("points after the pause on the plot",
                     f"document.querySelectorAll('#polar circle.pt').length > {paused_done}")
        print(f"ok: resumed ({confirmed} operator prompts confirmed on the page)")

        # 7. To the end (the closing calibration asks the operator again), every point on the plot.
        view, _ = answer_operator_prompts(tab, daemon, first, lambda v: v["state"] == "completed")
        rows = daemon.points(first)
        if len(rows) != view["points_done"] or view["points_done"] != total:
            raise Fail(f"completed with {len(rows)} stored points, {view['points_done']} done of {total}")
        # The completed campaign's values (its completion corrects them) are read once more and drawn.
        tab.wait_for("'completed' with every point", f"""document.getElementById('c-state').textContent ===
            'completed' && document.querySelectorAll('#polar circle.pt').length === {total}
            && document.getElementById('c-progress').value === {total}
            && document.body.dataset.finalPoints === '{first}'""", daemon=daemon)
        if os.environ.get("GONIO_BROWSER_SCREENSHOT"):
            shot = tab.call("Page.captureScreenshot", {"format": "png", "captureBeyondViewport": True})
            with open(os.environ["GONIO_BROWSER_SCREENSHOT"], "wb") as f:
                f.write(base64.b64decode(shot["data"]))
        shown = [check_plot_geometry(tab, rows)]
        # The other scale, then the hemisphere view: still every point, each where it belongs.
        tab.click("#plot-scale")
        tab.wait_for("the other scale", f"document.getElementById('polar').dataset.scale !== '{shown[0][1]}'")
        shown.append(check_plot_geometry(tab, rows))
        tab.click("#plot-mode")
        tab.wait_for("the hemisphere view", "document.getElementById('polar').dataset.mode === 'hemisphere'")
        shown.append(check_plot_geometry(tab, rows))
        check_readings(tab, rows)
        latest = [c for c in tab.circles() if "latest" in c["cls"].split()]
        if [c["index"] for c in latest] != [max(int(r["index"]) for r in rows)]:
            raise Fail(f"the latest point should be highlighted, got {latest}")
        print(f"ok: completed, {total} points on the plot, checked in {shown} ({time.monotonic() - started:.1f} s)")


        # 8. A second campaign is followed automatically; Abort needs two clicks.
        second = daemon.json("POST", "/api/campaigns", campaign_toml("browser-abort", True, 0.0, 70.0, 2.5))["id"]
        tab.wait_for("the page following the new campaign", """document.getElementById('c-name').textContent
            === 'browser-abort' && document.getElementById('c-state').textContent === 'running'
            && document.querySelectorAll('#polar circle.pt').length >= 1""", daemon=daemon)
        tab.click("#btn-abort")
        if tab.text("#btn-abort") != "Really abort?":
            raise Fail(f"the first click on Abort should ask again, button says {tab.text('#btn-abort')!r}")
        if daemon.campaign(second)["state"] in ("aborted",):
            raise Fail("one click on Abort aborted the campaign")
        tab.click("#btn-abort")
        deadline = time.monotonic() + WAIT_S
        while daemon.campaign(second)["state"] != "aborted":
            if time.monotonic() > deadline:
                raise Fail(f"Abort did not abort the campaign: {daemon.campaign(second)}")
            time.sleep(0.05)
        # The campaign's actions are off; its report (it has points) stays on.
        tab.wait_for("'aborted' on the page with the action buttons off and Report on", """document.getElementById(
            'c-state').textContent === 'aborted' && [...document.querySelectorAll('#campaign .buttons button')]
            .filter((b) => b.id !== 'btn-report').every((b) => b.disabled)
            && !document.getElementById('btn-report').disabled""")
        rows = daemon.points(second)
        tab.wait_for("the second campaign's points only",
                     f"document.querySelectorAll('#polar circle.pt').length === {len(rows)}")
        check_plot_geometry(tab, rows)
        tab.check_no_errors()
        print(f"ok: followed campaign {second}, aborted it after {len(rows)} points")
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
    print(f"PASS: status page in {version.get('product')}, {time.monotonic() - started:.1f} s")


def main(run_checks=None, doc=None, prefix="gonio-browser-"):
    """Run `run_checks(gonio, chromium, workdir)` (default: this file's `run`) with the command line's binaries
    in a fresh temporary directory; the exit code of the checks. console_panel.py runs its own checks through
    this too."""
    run_checks = run_checks or run
    if len(sys.argv) not in (2, 3):
        print(doc or __doc__, file=sys.stderr)
        return 2
    gonio = sys.argv[1]
    chromium = sys.argv[2] if len(sys.argv) == 3 else (shutil.which("chromium") or shutil.which("chromium-browser"))
    if not chromium:
        print("FAIL: no chromium binary (install Debian's chromium package)", file=sys.stderr)
        return 1
    with tempfile.TemporaryDirectory(prefix=prefix) as workdir:
        try:
            run_checks(gonio, chromium, workdir)
        except Fail as e:
            print(f"FAIL: {e}", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
