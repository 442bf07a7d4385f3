"""docs/api.md and examples/api_tour.py run as written: the tour end to end, and every ```python block of the
page whose first line is ``# runs``, in order, in one namespace, in a temporary folder, with ``config_path`` the
tour's small config."""

from __future__ import annotations

import re
import runpy
import subprocess
import sys
from pathlib import Path

from campaign_helpers import SMALL_CAMPAIGN

ROOT = Path(__file__).resolve().parents[1]
TOUR = ROOT / "examples" / "api_tour.py"
API_PAGE = ROOT / "docs" / "api.md"
#: the first line that marks a block of docs/api.md to run
RUNS = "# runs"


def runnable_blocks(text: str) -> list[str]:
    """The ```python blocks of ``text`` whose first line is `RUNS`, in order."""
    blocks = re.findall(r"^```python\n(.*?)^```", text, flags=re.MULTILINE | re.DOTALL)
    return [block for block in blocks if block.splitlines()[:1] == [RUNS]]


def test_the_tour_runs_and_prints_its_figures(tmp_path):
    done = subprocess.run([sys.executable, str(TOUR), str(tmp_path / "tour")], capture_output=True, text=True,
                          timeout=300, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    out = done.stdout
    for figure in ("campaign: 18 trials", "learned): ripple", "validated): ripple", "floor", "motor time:",
                   "trial 1: 3072 samples", "identified: epsilon", "imported: 1 trial(s)", "from the log:",
                   "exported ilcpmac_compensation.h", "exported calibration.csv", "largest revolution harmonics",
                   "exported moteus_cogging.txt"):
        assert figure in out, out
    assert (tmp_path / "tour" / "run" / "summary.json").is_file()


def test_the_tour_config_is_the_tests_small_campaign():
    assert runpy.run_path(str(TOUR))["SMALL"] == SMALL_CAMPAIGN


def test_the_pages_runnable_blocks_run(tmp_path, monkeypatch, capsys):
    blocks = runnable_blocks(API_PAGE.read_text())
    assert len(blocks) >= 6  # campaign, summary, trials, simulate + identify, import, export
    monkeypatch.chdir(tmp_path)
    config_path = runpy.run_path(str(TOUR))["small_config"](tmp_path)
    namespace: dict = {"config_path": config_path}
    for i, block in enumerate(blocks, start=1):
        exec(compile(block, f"docs/api.md block {i}", "exec"), namespace)
    out = capsys.readouterr().out
    assert "ripple" in out and "floor" in out and "ilcpmac_compensation.h" in out
    assert (tmp_path / "firmware" / "ilcpmac_compensation.c").is_file()
    assert (tmp_path / "cogging" / "feedforward.csv").is_file()
