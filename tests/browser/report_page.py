#!/usr/bin/env python3
"""`gonio report`'s page in a real headless Chromium (the browser and tab drivers of status_page.py).

Usage: report_page.py GONIO_BINARY [CHROMIUM_BINARY]

Runs the demo campaign on the simulated instrument three ways - ideal, realistic.toml, and realistic.toml with
the calibration `gonio align` made for it - writes each run's report with `gonio report`, opens each page from
its file and checks:
  - every section of the page is there (the truth section in these dry-runs) and shows text; every figure's
    SVG is drawn with a size; the calibrated run's alignment section names the alignment and the
    characterisation it used, and its uncertainty section its largest budget components;
  - the page asks for nothing: the only request is the file itself (no script, style sheet, font or image from
    anywhere), and there is no console error, script exception or CSP violation;
then, against `gonio daemon` (with a token), that the status page's Report button downloads the same report
for a completed campaign. GONIO_REPORT_SCREENSHOT=FILE.png saves a picture of the calibrated run's page.
Exits 0 when every check passes, 1 with a message otherwise.
"""

import base64
import json
import os
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import status_page  # noqa: E402
from status_page import TOKEN, Browser, Daemon, Fail, Tab, campaign_toml  # noqa: E402

ROOT = os.path.abspath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
DEMO = os.path.join(ROOT, "config", "campaigns", "demo.toml")
REALISTIC = os.path.join(ROOT, "config", "instruments", "realistic.toml")
SECTIONS = ["summary", "sample", "instrument", "plan", "calibration", "alignment", "plots", "sweeps", "uncertainty",
            "fit", "truth", "reproduce"]


def gonio_cmd(gonio, *args):
    done = subprocess.run([gonio, *args], stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=600)
    if done.returncode != 0:
        raise Fail(f"gonio {' '.join(args)} exited {done.returncode}: {done.stderr[-2000:]}")
    return done.stdout


def make_reports(gonio, workdir):
    """The three demo runs and their reports: {name: report path}."""
    cal = os.path.join(workdir, "cal.toml")
    gonio_cmd(gonio, "align", "--instrument", REALISTIC, "--out", cal)
    runs = {
        "ideal": [],
        "realistic": ["--instrument", REALISTIC],
        "calibrated": ["--instrument", REALISTIC, "--calibration", cal],
    }
    reports = {}
    for name, extra in runs.items():
        out = os.path.join(workdir, name)
        gonio_cmd(gonio, "run", DEMO, "--quiet", "--out", out, *extra)
        reports[name] = gonio_cmd(gonio, "report", out).strip()
    return reports


def check_page(browser, path, name, screenshot=None):
    tab = Tab(browser)
    url = "file://" + path
    tab.navigate(url)
    tab.wait_for(f"the {name} report loaded", "document.readyState === 'complete'")
    missing = tab.eval(f"""{json.dumps(SECTIONS)}.filter((id) => {{
        const s = document.querySelector('section#' + id);
        return !s || s.innerText.trim().length < 40;
    }})""")
    if missing:
        raise Fail(f"{name}: sections missing or empty: {missing}")
    figures = tab.eval("""[...document.querySelectorAll('figure')].map((f) => {
        const svg = f.querySelector('svg');
        const r = svg ? svg.getBoundingClientRect() : null;
        return {id: f.id, drawn: !!r && r.width > 100 && r.height > 100,
                marks: svg ? svg.querySelectorAll('circle, rect, path, polyline, line, text').length : 0};
    })""")
    ids = [f["id"] for f in figures]
    if ids != ["coverage", "drift", "brdf"]:
        raise Fail(f"{name}: figures {ids}, expected coverage, drift, brdf")
    for f in figures:
        if not f["drawn"] or f["marks"] < 20:
            raise Fail(f"{name}: figure {f['id']} is not drawn: {f}")
    time.sleep(0.3)
    browser.drain()
    # The only request a self-contained page makes is for itself.
    requests = [e["request"]["url"] for e in tab.events("Network.requestWillBeSent")]
    elsewhere = [u for u in requests if u != url and not u.startswith(("data:", "about:"))]
    if elsewhere:
        raise Fail(f"{name}: the page asked for {elsewhere}")
    tab.check_no_errors()
    text = {s: tab.eval(f"document.querySelector('section#{s}').innerText") for s in ("alignment", "uncertainty")}
    if screenshot:
        shot = tab.call("Page.captureScreenshot", {"format": "png", "captureBeyondViewport": True})
        with open(screenshot, "wb") as f:
            f.write(base64.b64decode(shot["data"]))
    tab.close()
    print(f"ok: {name} report: {len(SECTIONS)} sections, figures {', '.join(ids)}, requests {len(requests)} "
          f"(the file only), no errors")
    return text


def check_daemon_download(gonio, browser, workdir):
    daemon = Daemon(gonio, workdir)
    try:
        cid = daemon.json("POST", "/api/campaigns", campaign_toml("report-download", True, 0.0, 70.0, 10.0))["id"]
        deadline = time.monotonic() + 120
        while daemon.campaign(cid)["state"] != "completed":
            if time.monotonic() > deadline:
                raise Fail(f"the campaign did not complete: {daemon.campaign(cid)}")
            time.sleep(0.2)
        downloads = os.path.join(workdir, "downloads")
        os.makedirs(downloads, exist_ok=True)
        browser.call("Browser.setDownloadBehavior", {"behavior": "allow", "downloadPath": downloads})
        tab = Tab(browser)
        tab.navigate(daemon.url + "/#token=" + TOKEN)
        tab.wait_for("the Report button enabled", """document.getElementById('c-name').textContent
            === 'report-download' && !document.getElementById('btn-report').disabled""", daemon=daemon)
        tab.click("#btn-report")
        expected = os.path.join(downloads, f"report-download-{cid}-report.html")
        deadline = time.monotonic() + 60
        while not os.path.isfile(expected):
            if time.monotonic() > deadline:
                raise Fail(f"no download at {expected}; there: {os.listdir(downloads)}; page: {tab.page_text()}")
            time.sleep(0.1)
        time.sleep(0.5)
        with open(expected, encoding="utf-8") as f:
            page = f.read()
        for s in SECTIONS:
            if f'<section id="{s}">' not in page:
                raise Fail(f"the downloaded report has no section {s}")
        status, direct = daemon.request("GET", f"/api/campaigns/{cid}/report.html")
        strip = lambda p: [l for l in p.splitlines() if " written " not in l]  # noqa: E731
        if status != 200 or strip(direct) != strip(page):
            raise Fail("the downloaded report is not the API's")
        tab.check_no_errors()
        tab.close()
        print(f"ok: the status page's Report button downloaded campaign {cid}'s report ({len(page)} bytes)")
    except Fail:
        print("--- daemon log (tail) ---\n" + daemon.log_tail(), file=sys.stderr)
        raise
    finally:
        daemon.stop()


def run(gonio, chromium, workdir):
    started = time.monotonic()
    reports = make_reports(gonio, workdir)
    browser = Browser(chromium, workdir)
    try:
        for name, path in reports.items():
            shot = os.environ.get("GONIO_REPORT_SCREENSHOT") if name == "calibrated" else None
            text = check_page(browser, path, name, shot)
            if name == "calibrated":
                for expected in ("sample_tilt_x_deg", "corrected by the meter ranges", "subtracted from every value"):
                    if expected not in text["alignment"]:
                        raise Fail(f"the calibrated report's alignment section lacks {expected!r}")
                for component in ("solid-angle", "range", "stray-light"):
                    if component not in text["uncertainty"]:
                        raise Fail(f"the calibrated report's uncertainty section lacks {component!r}")
            elif "No alignment or characterisation was applied" not in text["alignment"]:
                raise Fail(f"the {name} report should say no calibration was applied")
        check_daemon_download(gonio, browser, workdir)
    finally:
        browser.close()
    print(f"PASS: the report page in headless Chromium, {time.monotonic() - started:.1f} s")


if __name__ == "__main__":
    sys.exit(status_page.main(run, __doc__, "gonio-report-"))
