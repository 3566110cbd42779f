"""Vehicle data the model needs besides the drivetrain parameters: the engine's crank train.

The identification's model engine produces the paper's pulsating torque (eqs. 1-5). The
pulsation is not in the band, and the speed filter removes it from the measured FRF, but it
dithers the DMF's free play at the firing frequency, and a free play dithered harder looks
narrower: with the product's reference engine in the model, an independent vehicle's truth fitted
its 5 N*m run with an NRMSE of 0.134; with that vehicle's own engine data, 0.047 (the same
drivetrain parameters). The crank-train data are on the engine's data sheet, so an engineer gives
them; without them the model uses the reference engine and says so.

The speed sensor's arithmetic is vehicle data too: a tooth timer adds up the tooth times of
half a revolution (the window's angle over its time, the default: an engine ECU's
crank-synchronous speed), eq. (9) read literally averages the step speeds
(:data:`dtid.simulator.kernel.SPEED_AVERAGES`). Which one a vehicle has is in its ECU's
software documentation; its recording does not tell, because the identified drivetrain absorbs
the difference (the optima of both fit alike), at the price of its parameters: the model with
the wrong one fits random vehicles' truths worse on 6 of 7 (docs/model-assumptions.md).

How the model integrates eq. (6) is the last choice here: the paper fixes the angle step
(pi/30, eq. 8), not the scheme. ``"euler"`` (the default) is the paper's angle-discrete model,
first order; ``"verlet"`` is second order, within 0.02 dB of the continuous plant where Euler
is off by up to 0.3 dB near a stiff drivetrain's resonances (:mod:`dtid.simulator.kernel`).
Recordings of a real vehicle come from a continuous plant; recordings simulated with the
paper's model (as ``../shared/independent`` evidently are) from a discrete one
(docs/model-assumptions.md).

``engine_lag`` says whether the model's engine delivers the request at once (``"none"``, the
default, the paper's eq. 3) or through the lag measured on the recording's runs
(``"measured"``: T/T_ecu fitted as the ``torque_lag`` mechanism, ``frf.engine_lag``),
which then also enters the strokes' K, combustion variation and sensor noise
(:func:`dtid.identification.model.idle_loop.idle_loop`). A recording with no lag is modelled
alike either way.

A vehicle file is TOML. Its ``[engine]`` table holds any of the keys below, named as in the
paper (eqs. 4-5); a key not given keeps the reference engine's value; its ``[sensors]`` table
may give ``speed_average``, its ``[model]`` table ``integration`` and ``engine_lag``. Other
tables (a ``[drivetrain]`` table, which ``--prior`` reads
(:func:`dtid.simulator.parameters.load_parameters`),
the truths of a simulated vehicle) are not read here::

    [engine]
    N_cyl = 4            # -: cylinders (the model is a four-cylinder four-stroke engine)
    bore = 0.0825        # m: cylinder bore
    r = 0.0421           # m: crank radius (half the stroke)
    l = 0.144            # m: connecting-rod length
    eps_c = 9.6          # -: compression ratio V_z / V_c
    kappa = 1.3          # -: polytropic exponent of compression and expansion
    p_l = 35000.0        # Pa: intake-manifold pressure at idle
    m_osc = 0.55         # kg: oscillating mass per cylinder (piston + 1/3 of the rod)
    firing_order = [1, 3, 4, 2]   # the model's cylinders are alike: any order of 1-4

    [sensors]
    speed_average = "times"      # "times" (a tooth timer, the default) or "speeds" (eq. 9)

    [model]
    integration = "euler"        # "euler" (eq. 8's discrete model, the default) or "verlet"
    engine_lag = "none"          # "none" (the default) or "measured"
"""

from __future__ import annotations

import dataclasses
import difflib
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from dtid.errors import ConfigError
from dtid.simulator.angle_grid import N_CYL
from dtid.simulator.engine import EngineGeometry
from dtid.simulator.kernel import INTEGRATION, SPEED_AVERAGES
from dtid.simulator.parameters import VEHICLE_TABLES, read_toml
from dtid.simulator.simulate import SimulationOptions

ENGINE_LAG = ("none", "measured")
"""The ``[model] engine_lag`` choices (see the module notes)."""

ENGINE_KEYS: dict[str, tuple[str, str, float, float]] = {
    "bore": ("bore_m", "m", 0.05, 0.15),
    "r": ("crank_radius_m", "m", 0.02, 0.1),
    "l": ("rod_length_m", "m", 0.08, 0.35),
    "eps_c": ("compression_ratio", "1", 6.0, 25.0),
    "kappa": ("isentropic_exponent", "1", 1.1, 1.67),
    "p_l": ("manifold_pressure_pa", "Pa", 1.0e4, 3.5e5),
    "m_osc": ("oscillating_mass_kg", "kg", 0.1, 5.0),
}
"""``[engine]`` key (the paper's symbol) -> (:class:`EngineGeometry` field, unit, and the range
of four-cylinder car and van engines, wide: bores of 50-150 mm, strokes of 40-200 mm, petrol to
diesel compression, a throttled to a boosted manifold, the ratio of specific heats of air and
burnt gas up to a monatomic gas's). A value outside it is refused: it is mostly a unit slip
(the bore in mm, the manifold pressure in bar), which the model would take as an engine of
another size and fit garbage to."""


@dataclass(frozen=True)
class VehicleData:
    """What the model knows of the vehicle besides its drivetrain parameters.

    Attributes
    ----------
    engine
        Crank-train data (the reference engine's where not given).
    speed_average
        The speed sensor's arithmetic, ``"speeds"`` or ``"times"``
        (:class:`dtid.simulator.simulate.SimulationOptions`).
    given
        The ``[engine]``, ``[sensors]`` and ``[model]`` keys the file gave.
    source
        The file, or ``"reference engine"``.
    integration
        How the model integrates eq. (6), ``"euler"`` or ``"verlet"`` (see the module notes).
    engine_lag
        ``"none"`` or ``"measured"``: whether the model's engine lags its request as measured
        (see the module notes).
    """

    engine: EngineGeometry = dataclasses.field(default_factory=EngineGeometry)
    speed_average: str = SPEED_AVERAGES[0]
    given: tuple[str, ...] = ()
    source: str = "reference engine"
    integration: str = "euler"
    engine_lag: str = "none"

    def simulated(self, options: SimulationOptions) -> SimulationOptions:
        """``options`` with this vehicle's engine, speed sensor and integration."""
        return dataclasses.replace(
            options,
            engine=self.engine,
            speed_average=self.speed_average,
            integration=self.integration,
        )

    def describe(self) -> str:
        """One line on where the vehicle data come from."""
        if not self.given:
            return "vehicle data: the reference engine and tooth-timer speed sensor (no --vehicle)"
        return f"vehicle data: {', '.join(self.given)} from {self.source}, the rest the reference's"

    def as_dict(self) -> dict[str, dict[str, object]]:
        """The JSON entry ``vehicle_data``: the crank-train data by ``[engine]`` key (SI units),
        the speed sensor's arithmetic and the model's integration."""
        return {
            "engine": {key: getattr(self.engine, spec[0]) for key, spec in ENGINE_KEYS.items()},
            "sensors": {"speed_average": self.speed_average},
            "model": {"integration": self.integration, "engine_lag": self.engine_lag},
        }


def load_vehicle_data(path: str | Path) -> VehicleData:
    """Read a vehicle file's ``[engine]`` table (see the module notes).

    Raises
    ------
    ConfigError
        If the file is missing or not TOML, or its ``[engine]`` table has an unknown key, a
        value that is not a positive number, or an engine the model cannot be.
    """
    path = Path(path)
    document = read_toml(path, "vehicle file")
    tables = [document.get(name, {}) for name in VEHICLE_TABLES]
    if not all(isinstance(t, dict) for t in tables) or not any(tables):
        found = [name for name, value in document.items() if isinstance(value, dict)]
        near = {
            name: close[0]
            for name in found
            if (close := difflib.get_close_matches(name, VEHICLE_TABLES, n=1))
        }
        has = (
            f" (it has {', '.join(f'[{name}]' for name in found)}"
            + "".join(f"; [{name}] for [{meant}]?" for name, meant in near.items())
            + ")"
            if found
            else ""
        )
        raise ConfigError(
            f"vehicle file {path} has no [engine] table{has}; give the crank-train data there "
            f"({', '.join(ENGINE_KEYS)}), the speed sensor's arithmetic in [sensors] and the "
            "model's integration in [model]"
        )
    return vehicle_data_from_tables(document, str(path))


def vehicle_data_from_tables(document: Mapping[str, object], source: str) -> VehicleData:
    """Vehicle data from a vehicle file's tables (``engine``, ``sensors``, ``model``), as a
    vehicle file or an identification JSON's ``vehicle_data`` holds them; ``source`` names
    them in messages.

    Raises
    ------
    ConfigError
        As :func:`load_vehicle_data`.
    """
    tables = [document.get(name, {}) for name in VEHICLE_TABLES]
    if not all(isinstance(t, dict) for t in tables):
        raise ConfigError(f"{source}: {', '.join(VEHICLE_TABLES)} must be tables")
    table, sensors, model = tables
    unknown = [key for key in sensors if key != "speed_average"]
    average = sensors.get("speed_average", SPEED_AVERAGES[0])
    if unknown or average not in SPEED_AVERAGES:
        raise ConfigError(f'{source}: [sensors] takes speed_average = "times" or "speeds" only')
    integration = model.get("integration", "euler")
    lag = model.get("engine_lag", "none")
    unknown = [key for key in model if key not in ("integration", "engine_lag")]
    if unknown or integration not in INTEGRATION or lag not in ENGINE_LAG:
        names = " or ".join(f'"{name}"' for name in INTEGRATION)
        lags = " or ".join(f'"{name}"' for name in ENGINE_LAG)
        raise ConfigError(
            f"{source}: [model] takes integration = {names} and engine_lag = {lags} only"
        )
    given = tuple(k for k in table if k in ENGINE_KEYS) + tuple(sensors) + tuple(model)
    engine = parse_engine(table, source)
    return VehicleData(engine, average, given, source, integration, lag)


def parse_engine(table: dict[str, object], source: str) -> EngineGeometry:
    """An ``[engine]`` table to crank-train data, keys not given from the reference engine."""
    values = {}
    for key, value in table.items():
        if key == "N_cyl":
            if value != N_CYL:
                raise ConfigError(
                    f"{source}: [engine] N_cyl = {value!r}: the model is a {N_CYL}-cylinder "
                    "four-stroke engine"
                )
        elif key == "firing_order":
            if not (isinstance(value, list) and sorted(value) == list(range(1, N_CYL + 1))):
                raise ConfigError(
                    f"{source}: [engine] firing_order must list the cylinders 1-{N_CYL} once "
                    f"each, got {value!r}"
                )
        elif key in ENGINE_KEYS:
            field, unit, lower, upper = ENGINE_KEYS[key]
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ConfigError(f"{source}: [engine] {key} must be a number in {unit}")
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"{source}: [engine] {key} = {value} must be > 0 {unit}")
            if not lower <= value <= upper:
                raise ConfigError(
                    f"{source}: [engine] {key} = {value:g} lies outside {lower:g}-{upper:g} "
                    f"{unit}, the range of car engines: give it in {unit}"
                )
            values[field] = float(value)
        else:
            raise ConfigError(
                f"{source}: unknown [engine] key {key!r}; the keys are N_cyl, "
                f"{', '.join(ENGINE_KEYS)}, firing_order"
            )
    engine = EngineGeometry(**values)
    if engine.crank_radius_m >= engine.rod_length_m:
        raise ConfigError(f"{source}: [engine] the rod l must be longer than the crank radius r")
    if engine.compression_ratio <= 1:
        raise ConfigError(f"{source}: [engine] eps_c must exceed 1")
    return engine
