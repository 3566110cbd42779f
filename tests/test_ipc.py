"""The ipc folder of the pipeline: made private, refused when another user could own it."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from dtid.acquisition.ipc import private_folder
from dtid.errors import ConfigError


def test_a_missing_folder_is_made_private(tmp_path: Path) -> None:
    folder = private_folder(tmp_path / "run" / "dtid")
    assert stat.S_IMODE(folder.stat().st_mode) == 0o700


def test_a_shared_service_folder_passes(tmp_path: Path) -> None:
    folder = tmp_path / "dtid"
    folder.mkdir(mode=0o750)
    assert private_folder(folder) == folder


@pytest.mark.parametrize(
    "problem",
    ["writable by every user", "writable by its group", "symbolic link", "not a directory"],
)
def test_an_unsafe_folder_is_refused(tmp_path: Path, problem: str) -> None:
    folder = tmp_path / "dtid"
    if problem.startswith("writable"):
        folder.mkdir()
        folder.chmod(0o777 if "every" in problem else 0o770)
    elif problem == "symbolic link":
        (tmp_path / "elsewhere").mkdir()
        folder.symlink_to(tmp_path / "elsewhere")
    else:
        folder.write_text("")
    with pytest.raises(ConfigError, match=problem):
        private_folder(folder)


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to give the folder to another user")
def test_a_folder_another_user_made_first_is_refused(tmp_path: Path) -> None:
    """The attack on a predictable /tmp/dtid-UID: someone else creates it before us."""
    folder = tmp_path / "dtid-1000"
    folder.mkdir(mode=0o700)
    os.chown(folder, 65534, 65534)
    with pytest.raises(ConfigError, match="belongs to user id 65534"):
        private_folder(folder)
