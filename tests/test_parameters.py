"""Parameter sets: names, TOML loading and the errors a user sees."""

from __future__ import annotations

from pathlib import Path

import pytest

from dtid.errors import ConfigError
from dtid.simulator.parameters import (
    NAMES,
    DrivetrainParameters,
    load_parameters,
    reference_parameters,
)

PAPER_NAMES = "J1 J2 J3 c12 c23 d12 d23 Tc12 eps12 eps23 T_loss K".split()


def _write(tmp_path: Path, body: str) -> Path:
    path = tmp_path / "vehicle.toml"
    path.write_text(body)
    return path


def _reference_body(**changes: str) -> str:
    values = reference_parameters().as_dict()
    lines = [f"{k} = {changes.pop(k, v)}" for k, v in values.items()]
    lines += [f"{k} = {v}" for k, v in changes.items()]
    return "\n".join(lines) + "\n"


def test_names_are_the_papers() -> None:
    assert list(NAMES) == PAPER_NAMES


def test_reference_round_trips_through_toml(tmp_path: Path) -> None:
    loaded = load_parameters(_write(tmp_path, _reference_body()))
    assert loaded == reference_parameters()
    assert DrivetrainParameters.from_array(loaded.as_array()) == loaded


def test_unknown_key_is_named(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="unknown parameter 'J4'"):
        load_parameters(_write(tmp_path, _reference_body(J4="1.0")))


def test_missing_key_is_named(tmp_path: Path) -> None:
    body = "\n".join(line for line in _reference_body().splitlines() if not line.startswith("c23"))
    with pytest.raises(ConfigError, match="missing parameter 'c23'"):
        load_parameters(_write(tmp_path, body))


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("J1", "-0.1", "J1 = -0.1 is not physical"),
        ("K", "0.0", "K = 0.0 is not physical"),
        ("eps12", "-0.01", "eps12 = -0.01 is not physical"),
        ("c12", '"stiff"', "c12 must be a number"),
        ("d12", "nan", "d12 must be finite"),
    ],
)
def test_non_physical_value_is_named(tmp_path: Path, key: str, value: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        load_parameters(_write(tmp_path, _reference_body(**{key: value})))


def test_missing_file_and_bad_toml(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="does not exist"):
        load_parameters(tmp_path / "nope.toml")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_parameters(_write(tmp_path, "J1 = = 3\n"))


def test_a_vehicle_file_gives_its_drivetrain_in_a_table(tmp_path: Path) -> None:
    """One vehicle file for --prior and --vehicle: [drivetrain] beside [engine], [sensors] and
    [model]; anything else beside it, or a bad key inside it, is named with the table."""
    engine = '[engine]\nbore = 0.08\n[sensors]\nspeed_average = "times"\n'
    path = _write(tmp_path, engine + "[drivetrain]\n" + _reference_body(c12="300.0"))
    loaded = load_parameters(path)
    assert loaded.c12 == 300.0
    assert loaded.J1 == reference_parameters().J1
    with pytest.raises(ConfigError, match=r"\[drivetrain\]: unknown parameter 'n_set'"):
        load_parameters(_write(tmp_path, "[drivetrain]\n" + _reference_body(n_set="850.0")))
    with pytest.raises(ConfigError, match="'noise' beside \\[drivetrain\\]"):
        load_parameters(_write(tmp_path, "[noise]\ncv = 0.02\n[drivetrain]\n" + _reference_body()))
