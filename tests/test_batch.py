"""`dtid batch` on a two-worker local Dask cluster: the same results as `dtid identify`, one
table, and a fleet view that finds the worn and the odd vehicle."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from dtid.acquisition.metadata import sidecar_path
from dtid.cli import main
from dtid.simulator.parameters import reference_parameters

pytest.importorskip("distributed")

FREE = ["J_sum=0.28", "x1=0.625", "x12=0.857", "c23=80", "d12=1.0", "d23=0.3", "Tc12=0.3",
        "eps12=0.02", "eps23=0.012"]  # fmt: skip
"""Everything held but c12 (the reference's values): the search takes seconds per test."""
BUDGET = ["--generations", "2", "--popsize", "4", "--polish-evaluations", "40", "--seed", "1",
          "--profile-points", "0"]  # fmt: skip
FLEET = {  # vehicle -> (date, true c12) per test
    "van-a": [("2026-01-05", 300.0), ("2026-04-05", 270.0), ("2026-07-05", 240.0)],
    "van-b": [("2026-02-01", 300.0), ("2026-06-01", 300.0)],
    "van-c": [("2026-03-01", 120.0)],
}


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """Six simulated tests of three vehicles (FLEET/VEHICLE/TEST.blf, dated through their
    metadata), a broken one, and the batch's output."""
    root = tmp_path_factory.mktemp("fleet")
    tests = []
    for vehicle, history in FLEET.items():
        (root / vehicle).mkdir()
        for index, (date, c12) in enumerate(history):
            params = root / f"{vehicle}-{index}.toml"
            values = reference_parameters().replace(c12=c12)
            params.write_text("\n".join(f"{k} = {v!r}" for k, v in values.as_dict().items()) + "\n")
            path = root / vehicle / f"test{index}.blf"
            assert main(["simulate", str(path), "--duration", "20", "--seed", str(index),
                         "--params", str(params)]) == 0  # fmt: skip
            metadata = json.loads(sidecar_path(path).read_text())
            metadata["started_utc"] = f"{date}T09:00:00+00:00"
            sidecar_path(path).write_text(json.dumps(metadata))
            tests.append(path)
    broken = root / "van-b" / "idle.log"
    broken.write_text(
        "(0.000000) can0 1A0#0000000000000000\n(0.010000) can0 1A0#0000000000000000\n"
    )
    out = root / "out"
    # exit status 1: one test (the broken one) failed
    assert main(["batch", *map(str, tests), str(broken), "--out", str(out), "--workers", "2",
                 "--diagnose", "--fix", *FREE, *BUDGET]) == 1  # fmt: skip
    with (out / "fleet.csv").open() as file:
        rows = list(csv.DictReader(file))
    return {"tests": tests, "broken": broken, "out": out, "rows": rows}


def test_every_test_is_a_row_with_its_vehicle_and_date(fleet: dict) -> None:
    rows = fleet["rows"]
    assert len(rows) == 7
    assert [r["vehicle"] for r in rows[:6]] == ["van-a"] * 3 + ["van-b"] * 2 + ["van-c"]
    assert [r["date"][:10] for r in rows[:6]] == [d for h in FLEET.values() for d, _ in h]
    assert all(r["status"] == "ok" for r in rows[:6])
    truths = [c12 for history in FLEET.values() for _, c12 in history]
    for row, c12 in zip(rows[:6], truths, strict=True):
        assert float(row["c12"]) == pytest.approx(c12, rel=0.06)
        assert row["J_sum_verdict"] == "fixed"
    broken = rows[6]
    assert broken["status"] == "error" and "idle" in broken["test"]
    assert broken["error"]  # the reason, as dtid identify would say it
    # --diagnose: each test's mismatch map, in its row and its JSON
    for row in rows[:6]:
        document = json.loads(
            (fleet["out"] / "tests" / f"{row['test']}.diagnosis.json").read_text()
        )
        assert row["adequate"] == str(document["adequate"])
        assert int(row["mismatch_bands"]) == len(document["mismatch"])


def test_a_task_gives_what_dtid_identify_gives(fleet: dict, tmp_path: Path) -> None:
    """The same options on the same file: the same parameters, fit and labels."""
    path = fleet["tests"][1]
    single = tmp_path / "single.json"
    assert main(["identify", str(path), "--json", str(single), "--fix", *FREE, *BUDGET]) == 0
    expected = json.loads(single.read_text())
    batched = json.loads((fleet["out"] / "tests" / "test1.json").read_text())
    assert batched["parameters"] == pytest.approx(expected["parameters"], rel=1e-9)
    for role in ("fit", "validation"):  # labelled with the client's paths
        assert batched["nrmse"][role] == pytest.approx(expected["nrmse"][role], rel=1e-9)


def test_the_fleet_view_finds_wear_and_the_odd_vehicle(fleet: dict) -> None:
    from dtid.identification.fleet import outliers, trends

    rows = [
        {
            **r,
            **{k: float(r[k]) for k in ("c12", "eps12", "d12", "Tc12", "c23", "eps23") if r.get(k)},
        }
        for r in fleet["rows"]
    ]
    flagged = outliers(rows)
    assert [(o.vehicle, o.parameter) for o in flagged] == [("van-c", "c12")]
    wear = {(t.vehicle, t.parameter): t for t in trends(rows)}
    # 300 -> 240 N*m/rad over six months: about -3.7 % of the mean per 30 days
    assert wear[("van-a", "c12")].percent_per_30_days == pytest.approx(-3.7, abs=0.6)
    assert abs(wear[("van-b", "c12")].percent_per_30_days) < 0.6
    page = (fleet["out"] / "fleet.html").read_text()
    assert "id='fig-fleet'" in page and "van-c" in page and "idle" in page
    assert (fleet["out"] / "fleet.png").stat().st_size > 20_000


@pytest.mark.slow
def test_profiles_are_spread_over_the_cluster_and_match_dtid_identify(
    fleet: dict, tmp_path: Path
) -> None:
    """c12 and eps12 free, three-point profiles: two profile tasks of their own, and the same
    intervals and verdicts as `dtid identify` computing them one after the other."""
    free_two = [f for f in FREE if not f.startswith("eps12")]
    budget = [*BUDGET[:-1], "3"]  # --profile-points 3
    path = fleet["tests"][0]
    out = tmp_path / "out"
    assert main(["batch", str(path), "--out", str(out), "--workers", "2", "--fix", *free_two,
                 *budget]) == 0  # fmt: skip
    with (out / "fleet.csv").open() as file:
        (row,) = list(csv.DictReader(file))
    assert row["status"] == "ok" and row["profile_tasks"] == "2"
    single = tmp_path / "single.json"
    assert main(["identify", str(path), "--json", str(single), "--fix", *free_two, *budget]) == 0
    expected = json.loads(single.read_text())
    batched = json.loads((out / "tests" / "test0.json").read_text())
    assert set(batched["intervals"]) == {"c12", "eps12"}
    for name in ("c12", "eps12"):
        for side in ("lower", "upper"):
            assert batched["intervals"][name][side] == pytest.approx(
                expected["intervals"][name][side], rel=1e-9
            )
        assert batched["identifiable"][name] == expected["identifiable"][name]


def test_an_existing_scheduler_serves(fleet: dict, tmp_path: Path) -> None:
    """`--scheduler ADDRESS`: the batch runs on a cluster somebody else started (here a
    one-worker local one), and gives the local cluster's result."""
    from distributed import LocalCluster

    path = fleet["tests"][3]
    out = tmp_path / "out"
    with LocalCluster(n_workers=1, threads_per_worker=1, dashboard_address=None) as cluster:
        assert main(["batch", str(path), "--out", str(out), "--scheduler",
                     cluster.scheduler_address, "--fix", *FREE, *BUDGET]) == 0  # fmt: skip
    with (out / "fleet.csv").open() as file:
        (row,) = list(csv.DictReader(file))
    local = fleet["rows"][3]  # the same test in the local cluster's batch
    assert row["status"] == "ok" and row["vehicle"] == "van-b"
    assert float(row["c12"]) == pytest.approx(float(local["c12"]), rel=1e-9)


def test_an_unreachable_scheduler_is_named(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    import dtid.batch

    monkeypatch.setattr(dtid.batch, "SCHEDULER_TIMEOUT_S", 1.0)  # the product tries for 10 s
    recording = tmp_path / "van" / "t.blf"
    recording.parent.mkdir()
    assert main(["simulate", str(recording), "--duration", "20"]) == 0
    assert main(["batch", str(recording), "--scheduler", "tcp://127.0.0.1:9", "--out",
                 str(tmp_path / "out")]) == 2  # fmt: skip
    assert "cannot reach the Dask scheduler tcp://127.0.0.1:9" in capsys.readouterr().err
    assert main(["batch", str(recording), str(recording.parent / "." / "t.blf")]) == 2
    assert "is given twice" in capsys.readouterr().err
    (tmp_path / "file").touch()  # --out names a folder
    assert main(["batch", str(recording), "--out", str(tmp_path / "file")]) == 2
    assert "cannot make the output folder" in capsys.readouterr().err
