"""report.html in a real browser: headless Chromium (Debian's ``chromium``) loads the page with no
console error, shows Table 1 and every plot with a non-zero natural size; a screenshot is kept
beside the test's report (pytest's tmp dir) as an artifact.

A probe script is put in front of the page's own head (before its Content-Security-Policy, which
therefore still governs everything the page itself loads): it records errors, blocked loads and
``console.error`` calls, and on ``load`` writes them with every image's natural size into the DOM
that ``--dump-dom`` prints. A control page with a broken and a remote image shows the probe sees
what it should.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import cv2
import pytest
from crafted_run import write_crafted_run

from reports.report import make_report

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = pytest.mark.skipif(
    CHROMIUM is None,
    reason="headless Chromium is not installed (Debian: apt-get install chromium; `make test` installs it where apt works)",
)

PROBE = """<script>
window.__problems = [];
window.addEventListener("error", (e) => {
  window.__problems.push("error: " + (e.message || (e.target && (e.target.src || e.target.href)) || "?"));
}, true);
document.addEventListener("securitypolicyviolation", (e) => window.__problems.push("blocked: " + e.blockedURI));
const consoleError = console.error;
console.error = (...args) => { window.__problems.push("console: " + args.join(" ")); consoleError(...args); };
window.addEventListener("load", () => {
  const probe = document.createElement("pre");
  probe.id = "probe";
  probe.textContent = JSON.stringify({
    problems: window.__problems,
    images: Array.from(document.images).map((i) => [i.alt, i.naturalWidth, i.naturalHeight]),
    table_rows: document.querySelectorAll("table#table1 tbody tr").length,
    figures: document.querySelectorAll("figure").length,
  });
  document.body.appendChild(probe);
});
</script>"""


def chromium(page: Path, profile: Path, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [
            CHROMIUM,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-background-networking",
            "--disable-component-update",
            "--no-first-run",
            "--disable-quic",
            "--disable-sync",
            f"--user-data-dir={profile}",
            "--window-size=1280,900",
            "--hide-scrollbars",
            "--host-resolver-rules=MAP * ~NOTFOUND , EXCLUDE localhost",
            "--enable-logging=stderr",
            "--v=0",
            "--virtual-time-budget=5000",
            *extra,
            page.as_uri(),
        ],
        capture_output=True,
        text=True,
        timeout=240,
    )


def probe(page: Path, tmp_path: Path) -> tuple[dict, list[str]]:
    """Load a copy of ``page`` with the probe in front of its head; returns what the probe saw and
    the console lines Chromium logged."""
    probed = page.with_name(page.stem + ".probed.html")
    text = page.read_text()
    assert "<head>" in text
    probed.write_text(text.replace("<head>", "<head>" + PROBE, 1))
    result = chromium(probed, tmp_path / "profile-probe", "--dump-dom")
    assert result.returncode == 0, result.stderr[-2000:]
    found = re.search(r'<pre id="probe">(.*?)</pre>', result.stdout, re.S)
    assert found, "the probe wrote nothing: the page did not finish loading"
    seen = json.loads(found.group(1).replace("&quot;", '"').replace("&lt;", "<").replace("&gt;", ">").replace("&amp;", "&"))
    console = [line for line in result.stderr.splitlines() if "CONSOLE" in line]
    return seen, console


def test_the_report_loads_in_chromium_with_its_table_and_every_plot(tmp_path):
    run = write_crafted_run(tmp_path / "run")
    made = make_report([run])
    seen, console = probe(made.html, tmp_path)
    assert seen["problems"] == [] and console == []
    assert seen["table_rows"] == 4  # two systems, the paper's two rows
    pngs = [p for s in made.sections for p in s.plots + s.failures if p.png is not None]
    assert len(seen["images"]) == len(pngs) == seen["figures"] == 10  # seven plots, three failures' crops
    for alt, width, height in seen["images"]:
        assert width > 100 and height > 100, alt

    shot = tmp_path / "report-screenshot.png"  # the artifact, beside the report it shows
    result = chromium(made.html, tmp_path / "profile-shot", f"--screenshot={shot}")
    assert result.returncode == 0 and shot.is_file(), result.stderr[-2000:]
    image = cv2.imread(str(shot))
    assert image.shape[:2] == (900, 1280) and image.std() > 10  # not a blank page
    print(f"screenshot: {shot}")


def test_the_probe_sees_a_broken_image_and_a_blocked_load(tmp_path):
    run = write_crafted_run(tmp_path / "run")
    made = make_report([run])
    page = made.html.read_text()
    # one embedded image corrupted, one remote image added (the page's policy must block it)
    first = page.index("data:image/png;base64,") + len("data:image/png;base64,")
    page = page[:first] + "AAAA" + page[first + 4 :]
    page = page.replace("</body>", '<img alt="remote" src="https://example.com/x.png"></body>')
    control = tmp_path / "control.html"
    control.write_text(page)
    seen, console = probe(control, tmp_path)
    sizes = {alt: (width, height) for alt, width, height in seen["images"]}
    assert sizes["remote"] == (0, 0)
    assert sorted(sizes.values())[:2] == [(0, 0), (0, 0)]  # the corrupted one too
    assert any(p.startswith("blocked: https://example.com") for p in seen["problems"]), seen["problems"]
    assert any("error" in p for p in seen["problems"])
    assert any("Content Security Policy" in line for line in console)  # Chromium logs what the policy blocks
