"""The installed distribution carries every package and data file the source tree has."""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]
TOP_PACKAGES = ("acquisition", "identification", "simulator", "dbc", "dtid")


@pytest.mark.slow
def test_wheel_holds_all_packages_and_data(tmp_path: Path) -> None:
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp_path), str(ROOT)],
        check=True,
    )
    (wheel,) = tmp_path.glob("drivetrain_id-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    expected = {
        str(path.relative_to(ROOT))
        for top in TOP_PACKAGES
        for path in (ROOT / top).rglob("*")
        if path.suffix in {".py", ".dbc", ".toml"} and "__pycache__" not in path.parts
    }
    assert expected - names == set()
