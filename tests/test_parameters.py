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


def test_a_value_in_another_unit_is_named_with_its_si_value(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """An inertia in g*m^2 (J1 = 150) or a stiffness in N*m/deg (the reference file's own
    comment gives c12 as 5.2 N*m/deg) was taken as a vehicle beyond any car; a value outside a
    passenger car's range is now named, with what it is in SI where the other unit fits. The
    reference vehicle is not named."""
    with caplog.at_level("WARNING"):
        load_parameters(_write(tmp_path, _reference_body()))
    assert not caplog.text
    with caplog.at_level("WARNING"):
        load_parameters(_write(tmp_path, _reference_body(J1="150", c12="5.2", T_loss="900")))
    assert "J1 = 150 kg*m^2 lies outside 0.03-1.5 kg*m^2" in caplog.text
    assert "if it is in g*m^2, it is 0.15 kg*m^2" in caplog.text
    assert "if it is in N*m/deg, it is 297.9 N*m/rad" in caplog.text
    assert "T_loss = 900 N*m lies outside 0-150 N*m" in caplog.text


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
