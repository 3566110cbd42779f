"""The Python API (``dtid.read_recording``, ``dtid.frf``, ``dtid.identify``) and its page."""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import os
import re
from pathlib import Path

import pytest

import dtid
from dtid.cli import main
from dtid.errors import AnalysisError, RecordingError
from dtid.identification.search.parameterization import theta_from_parameters
from dtid.simulator.parameters import reference_parameters

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The reference vehicle's test, as `dtid simulate` writes it (5, 10, 2 N*m)."""
    path = tmp_path_factory.mktemp("api") / "test.blf"
    assert main(["simulate", str(path), "--duration", "40"]) == 0
    return path


def test_frf_of_a_recording_read_and_of_its_path(recording: Path) -> None:
    read = dtid.read_recording(recording)
    estimates = dtid.frf(read)
    assert [round(e.run.amplitude_nm) for e in estimates] == [5, 10, 2]
    # eq. (24) per run: the identifying amplitudes within 5 %, the 2 N*m chirp (seven times
    # the torque sensor's noise) within 7 % (+5.3 %, +4.4 % with eq. 9's speed sensor)
    for estimate, within in zip(estimates, (0.05, 0.05, 0.07), strict=True):
        assert estimate.engine_gain == pytest.approx(reference_parameters().K, rel=within)
    again = dtid.frf(recording)
    assert all((a.drv_db == b.drv_db).all() for a, b in zip(estimates, again, strict=True))


def test_user_mistakes_are_dtid_errors(tmp_path: Path, recording: Path) -> None:
    with pytest.raises(RecordingError):
        dtid.read_recording(tmp_path / "missing.blf")
    read = dtid.read_recording(recording)
    request = read.roles["test_torque"]
    silent = dataclasses.replace(request, values=0.0 * request.values)
    idle = dataclasses.replace(read, roles={**read.roles, "test_torque": silent})
    with pytest.raises(AnalysisError, match="no chirp"):
        dtid.frf(idle)


def test_an_unknown_name_is_an_attribute_error() -> None:
    with pytest.raises(AttributeError, match="no attribute 'identfy'"):
        dtid.identfy  # noqa: B018


@pytest.mark.slow
def test_the_api_page_runs_and_identifies(recording: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """docs/api.md's code blocks, in order, in the folder of a recording of the reference."""
    blocks = re.findall(r"```python\n(.*?)```", (ROOT / "docs" / "api.md").read_text(), re.S)
    assert len(blocks) == 2
    monkeypatch.chdir(recording.parent)
    namespace: dict[str, object] = {}
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        for block in blocks:
            exec(compile(block, "docs/api.md", "exec"), namespace)
    assert "5.0 N*m  K = 0.90" in printed.getvalue()
    truth = theta_from_parameters(reference_parameters())
    found = namespace["parameters"]
    for name in ("J_sum", "x1", "x12", "c12"):
        assert found[name] == pytest.approx(truth[name], rel=0.05), name  # type: ignore[index]
    document = json.loads(Path("result.json").read_text())
    assert document["parameters"] == pytest.approx(found)
    assert os.path.getsize("fit.png") > 10_000
    assert namespace["figure"].axes  # type: ignore[attr-defined]
