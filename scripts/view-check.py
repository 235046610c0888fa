#!/usr/bin/env python3
"""The bench console (`fpc-sim view`) driven in headless Chromium, as an operator uses it.

For the simulated board and for the recorded bench session (`--replay
docs/examples/bench-session`): start the console on a free port, load the page, press Home
then Start at pressure ratio 3.1, and read from the page itself that

  * the position trace spans at least 150 mm within 3 s of Start, and the state reads
    "running";
  * the displayed rate keeps up with the 2 kHz stream for 30 s: the frames the page counts
    come at 2000/s ± 5 %, the rate it shows (over 2 s) stays within 20 % of 2000 frames/s
    and its mean within 5 %, the display lag does not grow by more than 0.25 s, no batch is
    dropped for a page that fell behind;
  * Stop brings the state to "holding";
  * the console's end is said on the page ("connection lost").

Screenshots go to --shots (CI keeps target/ci-view/). A missing browser or driver is a
failure, never a skip. Usage:

    python3 scripts/view-check.py --fpc-sim target/release/fpc-sim [--shots DIR] [--seconds 30]

Needs: Debian's chromium and chromium-driver, Python's selenium (.ci/run installs them).
"""

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time

from selenium import webdriver
from selenium.webdriver.chrome.options import Options
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.by import By

RATE_HZ = 2000.0


SHOTS = {"dir": None, "driver": None, "name": ""}


def fail(msg):
    print(f"view-check: FAIL: {msg}", flush=True)
    d = SHOTS["driver"]
    if d is not None and SHOTS["dir"]:
        d.save_screenshot(os.path.join(SHOTS["dir"], f"view-{SHOTS['name']}-failed.png"))
    sys.exit(1)


def find(name, env):
    path = os.environ.get(env) or shutil.which(name)
    if not path:
        fail(f"{name} is not installed (apt-get install chromium chromium-driver); "
             f"this check is never skipped")
    return path


def browser():
    options = Options()
    options.binary_location = find("chromium", "CHROMIUM")
    for a in ["--headless=new", "--no-sandbox", "--disable-gpu", "--window-size=1500,1100",
              "--disable-dev-shm-usage"]:
        options.add_argument(a)
    return webdriver.Chrome(service=Service(find("chromedriver", "CHROMEDRIVER")),
                            options=options)


def start_console(fpc_sim, args, workdir):
    proc = subprocess.Popen([fpc_sim, "view", "--port", "0"] + args, cwd=workdir,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = proc.stdout.readline()
    m = re.search(r"http://127\.0\.0\.1:\d+/", line)
    if not m:
        proc.kill()
        fail(f"fpc-sim view printed no address: {line!r} {proc.stderr.read()!r}")
    return proc, m.group(0)


def text(d, id_):
    return d.find_element(By.ID, id_).text.strip()


def number(d, id_):
    m = re.search(r"-?\d+(\.\d+)?", text(d, id_))
    return float(m.group(0)) if m else None


def wait(what, limit_s, cond, d):
    end = time.monotonic() + limit_s
    while time.monotonic() < end:
        got = cond()
        if got:
            return got
        time.sleep(0.05)
    fail(f"{what}: not within {limit_s} s (state {text(d, 'state')!r}, span {text(d, 'span')!r}, "
         f"rate {text(d, 'rate-shown')!r}, log: {text(d, 'log')[-400:]!r})")


def span_mm(d):
    m = re.search(r"span ([\d.]+) mm", text(d, "span"))
    return float(m.group(1)) if m else 0.0


def check(name, fpc_sim, extra, shots, seconds):
    work = tempfile.mkdtemp(prefix=f"view-check-{name}-")
    proc, url = start_console(fpc_sim, extra + ["--out", os.path.join(work, "rec")], work)
    d = browser()
    SHOTS.update(dir=shots, driver=d, name=name)
    try:
        d.get(url)
        wait("the page connects", 10, lambda: text(d, "source") != "connecting…", d)
        d.find_element(By.ID, "home").click()
        if name == "sim":
            wait("homed and holding", 30,
                 lambda: text(d, "homed") == "homed" and text(d, "state") == "holding", d)
        pr = d.find_element(By.ID, "pr")
        pr.clear()
        pr.send_keys("3.1")
        d.find_element(By.ID, "start").click()
        started = time.monotonic()
        seen = {"running": False}

        def running_and_spanning():
            seen["running"] |= text(d, "state") == "running"
            return seen["running"] and span_mm(d) >= 150.0
        wait("running with the position spanning 150 mm", 3.0, running_and_spanning, d)
        took = time.monotonic() - started
        print(f"view-check {name}: running, position span {span_mm(d):.1f} mm, "
              f"{took:.2f} s after Start", flush=True)
        d.save_screenshot(os.path.join(shots, f"view-{name}-running.png"))
        # The stream for `seconds`: rate and lag read every 5 s once settled.
        time.sleep(max(0.0, 5.0 - took))
        samples = []
        end = time.monotonic() + seconds
        while True:
            # The frame count with the page's own clock, read in one call: the count per
            # second is the page's, not delayed by the driver's round trips on a loaded host.
            page_s, frames = d.execute_script(
                "return [performance.now() / 1000, document.getElementById('frames').textContent]")
            m = re.search(r"\d+", frames or "")
            samples.append((page_s, number(d, "rate-shown"), number(d, "lag"),
                            float(m.group(0)) if m else None))
            if time.monotonic() >= end:
                break
            time.sleep(5.0)
        for t, rate, lag, frames in samples:
            print(f"view-check {name}: +{t - samples[0][0] + 5.0:5.1f} s: {rate:.0f} frames/s shown, "
                  f"display lag {lag:.0f} ms, {frames:.0f} frames", flush=True)
        rates = [r for _, r, _, _ in samples]
        lags = [l for _, _, l, _ in samples]
        # The frames the page counted over the whole watch, and the rate it showed: both
        # keep up with the stream (a display behind it would count fewer frames).
        (t0, _, _, f0), (t1, _, _, f1) = samples[0], samples[-1]
        counted = (f1 - f0) / (t1 - t0)
        if abs(counted - RATE_HZ) > 0.05 * RATE_HZ:
            fail(f"{name}: the page counted {counted:.0f} frames/s over {t1 - t0:.0f} s, "
                 f"not 2000 ± 5 %")
        if any(r is None or abs(r - RATE_HZ) > 0.2 * RATE_HZ for r in rates) \
                or abs(sum(rates) / len(rates) - RATE_HZ) > 0.05 * RATE_HZ:
            fail(f"{name}: the rate shown left 2000 frames/s (each within 20 %, their mean "
                 f"within 5 %): {rates}")
        growth = lags[-1] - lags[0]
        if growth > 250.0:
            fail(f"{name}: the display lag grew by {growth:.0f} ms over {seconds} s: {lags}")
        if text(d, "lost") != "0":
            fail(f"{name}: the page fell behind: {text(d, 'lost')} not shown")
        print(f"view-check {name}: kept up for {t1 - t0:.0f} s: {counted:.0f} frames/s counted, "
              f"{min(rates):.0f}-{max(rates):.0f} frames/s shown, lag growth {growth:.0f} ms",
              flush=True)
        d.find_element(By.ID, "stop").click()
        wait("holding after Stop", 5, lambda: text(d, "state") == "holding", d)
        print(f"view-check {name}: Stop: holding", flush=True)
        d.save_screenshot(os.path.join(shots, f"view-{name}-stopped.png"))
        proc.terminate()
        proc.wait(10)
        wait("the lost connection said", 5,
             lambda: "connection lost" in text(d, "conn") and d.find_element(By.ID, "conn").is_displayed(), d)
        d.save_screenshot(os.path.join(shots, f"view-{name}-lost.png"))
        print(f"view-check {name}: the console's end shows as a lost connection", flush=True)
    finally:
        d.quit()
        if proc.poll() is None:
            proc.kill()
        shutil.rmtree(work, ignore_errors=True)


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--fpc-sim", required=True)
    p.add_argument("--shots", default="target/ci-view")
    p.add_argument("--seconds", type=float, default=30.0)
    p.add_argument("--only", choices=["sim", "replay"])
    a = p.parse_args()
    fpc_sim = os.path.abspath(a.fpc_sim)
    os.makedirs(a.shots, exist_ok=True)
    shots = os.path.abspath(a.shots)
    replay = os.path.abspath("docs/examples/bench-session")
    cases = [("sim", []), ("replay", ["--replay", replay])]
    for name, extra in cases:
        if a.only in (None, name):
            check(name, fpc_sim, extra, shots, a.seconds)
    print("view-check: passed", flush=True)


if __name__ == "__main__":
    main()
