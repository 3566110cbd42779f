"""`dtid demo`, the README's main job: vehicle, daemon and worker on a virtual bus, end to end."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest
from json_schemas import validate

from dtid.cli import main
from dtid.identification.search.parameterization import theta_from_parameters
from dtid.simulator.parameters import reference_parameters

pytestmark = pytest.mark.slow


def test_demo_identifies_the_reference_vehicle_and_writes_its_files(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--generations", "8"]) == 0
    printed = capsys.readouterr().out
    assert "end: completed" in printed and "identified" in printed
    # the plan dtid plan recommends for the reference vehicle (about 19 min) does not fit the
    # demo's budget, and the demo says so before it runs the paper's
    assert "too long for this demo: running the paper's plan" in printed
    (session,) = [p for p in out.iterdir() if p.is_dir()]
    assert (session / f"{session.name}.blf").stat().st_size > 0
    assert (session / "identification.png").exists() and (out / "frf.png").exists()
    # the session's report, which the worker rewrote from the log once the daemon closed it
    page = (session / "report.html").read_text()
    assert "closed cleanly" in page and "<td>ended</td><td>completed</td>" in page
    log_hash = hashlib.sha256((session / f"{session.name}.blf").read_bytes()).hexdigest()
    assert log_hash[:16] in page and "(being written)" not in page
    runs = json.loads((out / "frf.json").read_text())["runs"]
    assert [round(r["amplitude_nm"]) for r in runs] == [5, 10, 2]
    document = json.loads((session / "identification.json").read_text())
    validate(document, "identification")
    assert set(document) >= {"parameters", "intervals", "nrmse", "identifiable"}
    assert set(document["nrmse"]["validation"]) == {f"{session / session.name}.blf @ 2 N*m"}
    truth = reference_parameters()
    theta = theta_from_parameters(truth)
    # the vehicle's loop read off its own log: the product ECU's strokes report two crank
    # events after their start, having taken the request formed one before it
    (loop,) = document["idle_loop"].values()
    assert loop["mode"] == "recorded_request" and loop["latch_events"] == 3
    assert loop["latch_gain"] == pytest.approx(truth.K, rel=0.02)
    assert loop["combustion_variation"] == pytest.approx(0.03, rel=0.2)
    # the sensor noise told apart from the variation: on simulated recordings in bus time it
    # scatters 0.261-0.325 N*m (sd 0.022; test_combustion.py asserts that estimator on them);
    # the demo is paced by the wall clock, and on a loaded host its requests bunch and the split
    # moves (0.21 and 0.23 N*m measured with the machine busy): here only that it is a split,
    # neither all noise nor none
    assert 0.1 < loop["torque_noise_nm"] < 0.45
    # what the demo's reduced search (8 generations) pins on every run
    identified = document["parameters"]
    for name in ("J_sum", "x1", "x12"):
        assert identified[name] == pytest.approx(theta[name], rel=0.05), name
    assert identified["K"] == pytest.approx(truth.K, rel=0.05)
    assert max(document["nrmse"]["validation"].values()) < 0.3
