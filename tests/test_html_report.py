"""The report as one HTML page (``ilcpmac report`` writes ``report.html``; docs/report.md).

A small campaign on the simulator with its real identification (so its standard errors), reported; the page is
checked to be self-contained and escaped, then opened in headless Chromium at 1280 and 800 px: every figure
loads and no text overflows, and a full-page screenshot is kept at RUN_DIR/plots/report-<width>.png. Without
Chromium (Debian's ``chromium`` package, which ``.ci/run`` installs where it can) the browser tests skip saying
so.
"""

from __future__ import annotations

import html
import json
import os
import re
import shlex
import shutil
import signal
import subprocess
from pathlib import Path

import pytest
from click.testing import CliRunner
from conftest import SEED_CONFIG
from PIL import Image

from ilcpmac.cli import main

#: the widths the page is checked at, CSS px
WIDTHS = (1280, 800)
#: the longest a Chromium run may take, s (it hangs on a closed network without the flags of `_chromium`)
CHROMIUM_TIMEOUT_S = 120
#: the tallest screenshot taken, px (a page longer than that is cut there)
MAX_SCREENSHOT_PX = 16000
#: a small campaign on top of configs/quick.toml: 1024 counts, a 2 x 2 grid, two learned points at one speed,
#: a validation point, two learning trials each (14 trials, some 5 s)
SMALL = """\
extends = "quick.toml"

[bench]
counts_per_rev = 1024

[excitation]
harmonics = 100

[trials]
torque_setpoints_nm = [2.0, 4.0]
speed_setpoints_hz = [0.6, 0.9]

[campaign]
learn_torques_nm = [2.0, 4.0]
learn_speeds_hz = [0.9]
learn_revolutions = [6]
learn_trials = 2
ripple_harmonics = 100
validate_torques_nm = [3.0]
validate_speeds_hz = [0.9]
validate_revolutions = 6

[stages.ilc]
q_cutoff_harmonic = 100
"""
#: appended to a copy of the page: once everything has loaded, what the test checks, as JSON in a <pre>
CHECK_SCRIPT = """
<script>
window.addEventListener("load", () => {
  const root = document.documentElement, width = root.clientWidth;
  const scrolls = (el) => ["auto", "scroll"].includes(getComputedStyle(el).overflowX);
  const name = (el) => el.tagName.toLowerCase() + (el.id ? "#" + el.id : "") +
    (el.className && typeof el.className === "string" ? "." + el.className.replace(/ +/g, ".") : "") +
    " " + JSON.stringify((el.textContent || "").trim().slice(0, 60));
  const overflowing = [], scrollBoxes = [];
  for (const el of document.body.querySelectorAll("*")) {
    if (el.clientWidth === 0 && el.clientHeight === 0) continue;  // inline: its box is its text's
    if (el.scrollWidth <= el.clientWidth + 1) continue;
    (scrolls(el) ? scrollBoxes : overflowing).push(name(el));
  }
  const images = [...document.querySelectorAll("img")].map((img) => ({
    id: img.closest("figure") ? img.closest("figure").id : "", complete: img.complete,
    naturalWidth: img.naturalWidth, right: img.getBoundingClientRect().right}));
  const out = document.createElement("pre");
  out.id = "ilcpmac-check";
  out.textContent = JSON.stringify({width: width, innerWidth: window.innerWidth, pageWidth: root.scrollWidth,
    pageHeight: root.scrollHeight, figures: document.querySelectorAll("figure").length,
    svgs: document.querySelectorAll("svg").length, images: images, overflowing: overflowing,
    scrollBoxes: scrollBoxes});
  document.body.appendChild(out);
});
</script>
"""


@pytest.fixture(scope="module")
def chromium() -> str:
    """The Chromium on PATH; the test skips, saying what to install, where there is none (before the campaign
    the other fixtures run)."""
    found = next((path for name in ("chromium", "chromium-browser") if (path := shutil.which(name))), None)
    if found is None:
        pytest.skip("no Chromium to render report.html: install Debian's chromium package "
                    "(apt-get install chromium; .ci/run does where it can)")
    return found


def _chromium(chromium: str, args: list[str], profile: Path) -> str:
    """Run headless ``chromium`` with ``args`` (a fresh ``profile``, nothing fetched from the network) and return
    its stdout; its whole process group is killed after `CHROMIUM_TIMEOUT_S`."""
    command = [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
               "--disable-background-networking", "--disable-component-update", "--disable-sync",
               "--disable-extensions", "--hide-scrollbars", "--mute-audio", f"--user-data-dir={profile}", *args]
    with subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                          start_new_session=True) as process:
        try:
            out, err = process.communicate(timeout=CHROMIUM_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.communicate()
            pytest.fail(f"chromium did not finish in {CHROMIUM_TIMEOUT_S} s: {' '.join(command)}")
    assert process.returncode == 0, f"chromium exited with {process.returncode}: {err[-2000:]}"
    return out


@pytest.fixture(scope="module")
def reported(tmp_path_factory) -> tuple[Path, str]:
    """A small campaign's run directory after ``ilcpmac report``, and what the command printed."""
    import ilcpmac.campaign

    folder = tmp_path_factory.mktemp("html-report")
    for name in ("quick.toml", SEED_CONFIG.name):
        shutil.copy(SEED_CONFIG.with_name(name), folder / name)
    (folder / "small.toml").write_text(SMALL)
    # a run directory named by a user, with characters HTML gives a meaning to
    result = ilcpmac.campaign.run(folder / "small.toml", out=folder / "run <b>&'\"")
    out = CliRunner().invoke(main, ["report", str(result.path)])
    assert out.exit_code == 0, out.output
    return result.path, out.output


def _figure_files(run_dir: Path) -> list[Path]:
    """The figures ``ilcpmac report`` wrote (the screenshots left out)."""
    return sorted(p for p in (run_dir / "plots").glob("*.png") if not p.name.startswith("report-"))


def test_the_report_is_one_self_contained_page(reported):
    run_dir, output = reported
    page = run_dir / "plots" / "report.html"
    assert f"wrote {page}" in " ".join(output.split())
    text = page.read_text()
    # everything inline: no script, no URL fetched, every image a data URI
    assert "<script" not in text.lower()
    assert not re.search(r"\b(?:src|href)=\"(?!data:|#)", text)
    assert not re.search(r"url\(|@import|https?://", text)
    figures = _figure_files(run_dir)
    assert len(figures) >= 4
    assert text.count('<img src="data:image/png;base64,') == len(figures)
    for path in figures:
        assert f'id="figure-{path.stem}"' in text
    # the sections, with units and the identification's standard errors
    for heading in ("Results", "Plan and motor time", "Ripple per operating point", "Identification", "Figures",
                    "Export the compensation"):
        assert f"<h2>{heading}</h2>" in text
    for unit in ("N m", "Hz", "% pp", "motor time (min)", "standard error", "kg m²"):
        assert html.escape(unit) in text
    assert text.count(" ± ") >= 10  # the report's method beside the joint fit, every estimate
    # the export commands of a run directory, its path quoted for a shell and escaped for HTML: a shell reads them
    # back as they were meant
    commands = [shlex.split(html.unescape(re.sub(r"<[^>]+>", "", code)))
                for code in re.findall(r"<pre><code>(.*?)</code></pre>", text, re.S)]
    start = ["ilcpmac", "export", str(run_dir.resolve())]
    assert commands == [[*start, "--format", "json", "--out", "DIR"], [*start, "--format", "csv", "--out", "DIR"],
                        [*start, "--format", "c", "--out", "DIR"],
                        [*start, "--format", "c", "--c-type", "float", "--out", "DIR"]]


def test_text_named_by_the_user_is_escaped(reported):
    run_dir, _ = reported
    text = (run_dir / "plots" / "report.html").read_text()
    assert "<b>&" not in text
    assert "Campaign report: run &lt;b&gt;&amp;&#x27;&quot;</h1>" in text


def test_a_run_stopped_early_gets_a_page_saying_what_is_missing(reported, tmp_path):
    """The grid half done: no identification, no point finished, no compensation.json; every section is there."""
    from ilcpmac.report.html import page
    from ilcpmac.report.plots import RunReport

    run_dir, _ = reported
    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy)
    summary = json.loads((copy / "summary.json").read_text())
    grid = [t for t in summary["trials"] if t["phase"] == "identify"][:3]
    (copy / "summary.json").write_text(json.dumps({"units": summary["units"], "trials": grid, "identification": None,
                                                   "final": {}, "validation": [], "points": [],
                                                   "motor_time_s": {}}))
    (copy / "compensation.json").unlink()
    text = page(RunReport.read(copy), {})
    for missing in ("No final figures yet", "No operating point has its final trial yet", "No identification yet",
                    "No figures.", "No compensation.json yet"):
        assert missing in text
    assert "<td>identify</td><td>3</td>" in text.replace(' class="text"', "")


@pytest.mark.parametrize("width", WIDTHS)
def test_the_report_renders_in_headless_chromium(chromium, reported, tmp_path, width):
    """Every figure loads and fits, no element's text runs out of its box (a box that scrolls on purpose
    aside), the page is no wider than the window; a full-page screenshot is kept beside the page."""
    run_dir, _ = reported
    page = run_dir / "plots" / "report.html"
    checked = tmp_path / "checked.html"
    checked.write_text(page.read_text().replace("</body>", CHECK_SCRIPT + "</body>"))
    dom = _chromium(chromium, [f"--window-size={width},900", "--virtual-time-budget=10000", "--dump-dom",
                     checked.as_uri()], tmp_path / "profile")
    found = re.search(r'<pre id="ilcpmac-check">(.*?)</pre>', dom, re.S)
    assert found, f"the check did not run: {dom[-500:]}"
    check = json.loads(html.unescape(found[1]))
    assert check["width"] == width, check
    figures = _figure_files(run_dir)
    assert check["figures"] == len(check["images"]) == len(figures)
    for image in check["images"]:
        assert image["complete"] and image["naturalWidth"] > 0, image
        assert image["right"] <= width + 1, image
    assert check["overflowing"] == [], check["overflowing"]
    assert check["pageWidth"] <= width, check

    shot = run_dir / "plots" / f"report-{width}.png"
    height = min(check["pageHeight"], MAX_SCREENSHOT_PX)
    _chromium(chromium, [f"--window-size={width},{height}", f"--screenshot={shot}", page.as_uri()],
              tmp_path / "profile")
    with Image.open(shot) as image:
        assert image.size == (width, height)
        assert len(image.convert("L").getcolors(256) or ()) > 10  # drawn, not blank
