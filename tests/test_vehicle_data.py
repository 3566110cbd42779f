"""Vehicle data for the model engine: the [engine] table of a vehicle file."""

from __future__ import annotations

from pathlib import Path

import pytest

from dtid.cli import main
from dtid.errors import ConfigError
from dtid.simulator.engine import EngineGeometry
from dtid.simulator.vehicle_data import load_vehicle_data

TRUTH_LIKE = """
[drivetrain]  # another table (a truth, a prior): not read here
J1 = 0.16
n_set = 850.0

[engine]
N_cyl = 4
bore = 0.082
r = 0.045
l = 0.14
eps_c = 10.0
firing_order = [1, 3, 4, 2]

[sensors]
speed_average = "times"
"""


def _file(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "vehicle.toml"
    path.write_text(text)
    return path


def test_given_keys_replace_the_reference_engines(tmp_path: Path) -> None:
    data = load_vehicle_data(_file(tmp_path, TRUTH_LIKE))
    reference = EngineGeometry()
    assert (data.engine.bore_m, data.engine.crank_radius_m) == (0.082, 0.045)
    assert (data.engine.rod_length_m, data.engine.compression_ratio) == (0.14, 10.0)
    assert data.engine.isentropic_exponent == reference.isentropic_exponent  # not given
    assert data.given == ("bore", "r", "l", "eps_c", "speed_average")
    assert data.as_dict()["engine"]["p_l"] == reference.manifold_pressure_pa
    assert data.as_dict()["sensors"] == {"speed_average": "times"}
    assert "bore, r, l, eps_c, speed_average from" in data.describe()
    assert data.integration == "euler"  # eq. (8)'s discrete model unless [model] says otherwise
    assert data.as_dict()["model"] == {"integration": "euler", "engine_lag": "none"}


def test_the_model_table_chooses_the_integration(tmp_path: Path) -> None:
    data = load_vehicle_data(_file(tmp_path, '[model]\nintegration = "verlet"\n'))
    assert (data.integration, data.given) == ("verlet", ("integration",))
    assert data.engine == EngineGeometry()


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[engine]\nstroke = 0.09\n", "unknown \\[engine\\] key 'stroke'"),
        ("[engine]\nbore = -0.08\n", "bore = -0.08 must be > 0 m"),
        ("[engine]\nbore = 'big'\n", "bore must be a number in m"),
        ("[engine]\nN_cyl = 6\n", "4-cylinder four-stroke"),
        ("[engine]\nfiring_order = [1, 2, 2, 4]\n", "firing_order must list"),
        ("[engine]\nr = 0.09\nl = 0.085\n", "longer than the crank radius"),
        ("[engine]\nbore = 82\n", "bore = 82 lies outside 0.05-0.15 m.*give it in m"),  # mm
        ("[engine]\np_l = 0.35\n", "p_l = 0.35 lies outside 10000-350000 Pa.*in Pa"),  # bar
        ("[drivetrain]\nJ1 = 0.1\n", "has no \\[engine\\] table"),
        ("[engin]\nbore = 0.08\n", r"it has \[engin\]; \[engin\] for \[engine\]\?"),
        ("[sensors]\nspeed_average = 'mean'\n", "times.* or .*speeds"),
        ("[model]\nintegration = 'rk4'\n", "euler.* or .*verlet"),
        ("[model]\nengine_lag = 'yes'\n", "engine_lag = .*none.* or .*measured"),
        ("[engine\n", "not valid TOML"),
    ],
)
def test_a_wrong_vehicle_file_is_named(tmp_path: Path, text: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        load_vehicle_data(_file(tmp_path, text))


def test_a_missing_vehicle_file_is_a_one_line_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["identify", str(tmp_path / "x.blf"), "--vehicle", str(tmp_path / "no.toml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"error: vehicle file {tmp_path / 'no.toml'} does not exist"]


def test_a_command_given_an_identification_takes_its_vehicle_data(tmp_path: Path) -> None:
    """`dtid diagnose --identification` and `dtid plan --prior ID.json` build the model the
    identification was made with: its ``vehicle_data``, unless --vehicle says the same."""
    import argparse
    import json

    from dtid.cli.commands.common import vehicle_data

    lagging = tmp_path / "lagging.toml"
    lagging.write_text('[engine]\nbore = 0.09\n[model]\nengine_lag = "measured"\n')
    identified = load_vehicle_data(lagging)
    document = json.loads(json.dumps({"parameters": {}, "vehicle_data": identified.as_dict()}))
    path = tmp_path / "id.json"
    taken = vehicle_data(argparse.Namespace(vehicle=None), (path, document))
    assert taken.as_dict() == identified.as_dict()
    assert taken.engine_lag == "measured" and taken.engine.bore_m == 0.09
    assert taken.given == ("bore", "engine_lag")  # those unlike the reference's
    assert "(the identification's)" in taken.describe()
    same = vehicle_data(argparse.Namespace(vehicle=lagging), (path, document))
    assert same.as_dict() == identified.as_dict()
    other = tmp_path / "other.toml"
    other.write_text("[engine]\nbore = 0.09\n")
    with pytest.raises(
        ConfigError, match='identified with \\(engine_lag = "none" against "measured"\\)'
    ):
        vehicle_data(argparse.Namespace(vehicle=other), (path, document))
    # an identification written before its vehicle data were recorded: --vehicle or the reference
    assert vehicle_data(argparse.Namespace(vehicle=None), (path, {"parameters": {}})).given == ()
