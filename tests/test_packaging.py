"""The installed package is the one imported from any folder, the clone's parent included (issue 26, item 1)."""

import subprocess
import sys
from pathlib import Path

import ilcpmac


def test_the_folder_holding_a_clone_named_ilcpmac_does_not_shadow_the_package(tmp_path: Path) -> None:
    clone = tmp_path / "ilcpmac"  # what `git clone` makes: a folder named like the package, with no __init__.py
    for folder in ("plugins", "tests", "benchmarks", "src"):
        (clone / folder).mkdir(parents=True)
    imported = subprocess.run([sys.executable, "-c", "import ilcpmac; print(ilcpmac.__file__)"],
                              cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert imported.returncode == 0, imported.stderr
    assert Path(imported.stdout.strip()) == Path(ilcpmac.__file__)
    stages = subprocess.run([sys.executable, "-m", "ilcpmac", "stages"],
                            cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert stages.returncode == 0, stages.stderr
    assert "current-sensor" in stages.stdout
