"""The installed distribution carries every package and data file the source tree has, all of
it under the one import name ``dtid``."""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

ROOT = Path(__file__).parents[1]
INSTALLED_AS = {
    "api": "dtid",
    "cli": "dtid/cli",
    "acquisition": "dtid/acquisition",
    "dbc": "dtid/dbc",
    "simulator": "dtid/simulator",
    "identification": "dtid/identification",
}
"""Each source folder and where its files land in site-packages (pyproject's package-dir)."""


def test_wheel_holds_all_packages_and_data(tmp_path: Path) -> None:
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp_path), str(ROOT)],
        check=True,
    )
    (wheel,) = tmp_path.glob("drivetrain_id-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    expected = {
        f"{installed}/{path.relative_to(ROOT / folder).as_posix()}"
        for folder, installed in INSTALLED_AS.items()
        for path in (ROOT / folder).rglob("*")
        if path.suffix in {".py", ".dbc", ".toml"} and "__pycache__" not in path.parts
    }
    assert expected - names == set()
    tops = {name.split("/")[0] for name in names}
    assert tops == {
        "dtid",
        wheel.name.split("-")[0] + "-" + wheel.name.split("-")[1] + ".dist-info",
    }
