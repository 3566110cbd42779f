"""Mechanisms beyond the paper's model: physics a real drivetrain may have and eq. (6) leaves out.

Each mechanism is a physical term with named parameters (SI units, bounds and a *neutral* value
at which the term vanishes), written once here and in the numba kernel
(:mod:`dtid.simulator.kernel`, :mod:`dtid.simulator.couplings`). The simulator conceals a
mechanism in a recording (``dtid simulate --effect NAME:k=v``); the diagnosis adds it to an
identified model and refits it (:mod:`dtid.identification.diagnosis.refit`). With every
mechanism at its neutral values the kernel is the paper's plant.

The kernel takes one parameter vector per run: the twelve drivetrain parameters of
:data:`dtid.simulator.parameters.NAMES`, then :data:`EXTRA_NAMES` (:data:`KERNEL_WIDTH` values).
A mechanism's parameter is found there at :data:`EXTRA_INDEX` ``[name]``.

Adding a mechanism: append a :class:`Mechanism` to :data:`MECHANISMS` (its parameters get the
next kernel slots), read the slots in :func:`dtid.simulator.kernel.advance` and write the term
there or in :mod:`dtid.simulator.couplings`; the CLI, the diagnosis and its trial find it here
(docs/diagnosis.md, *Adding a mechanism*).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from dtid.errors import ConfigError
from dtid.simulator.parameters import INDEX, NAMES


@dataclass(frozen=True)
class MechanismParameter:
    """One parameter of a mechanism.

    Attributes
    ----------
    name
        Unique among all mechanisms' parameters (the kernel slot's name).
    unit, meaning
        SI unit and what it is.
    neutral
        The value at which the mechanism has no effect.
    lower, upper
        Bounds of a refit, SI units.
    typical
        Range of a physically sensible magnitude on a passenger car (the diagnosis trial draws
        concealed effects from it), SI units.
    """

    name: str
    unit: str
    meaning: str
    neutral: float
    lower: float
    upper: float
    typical: tuple[float, float]


@dataclass(frozen=True)
class Mechanism:
    """A physical term the paper's model leaves out.

    Attributes
    ----------
    name
        The name engineers and the CLI use.
    physics
        One sentence of physics.
    parameters
        Its parameters; the first is its *main* parameter (the magnitude of the effect).
    path
        Where it acts: ``"drivetrain"`` (between the measured mean torque and the measured
        speed: it shows in |G_DRV|), ``"engine"`` (between the ECU's torque request and the
        delivered mean torque: it shows in |G_ENG|, eq. 15, which the drivetrain parameters do
        not shape, while |G_DRV|, speed per *measured* torque, hardly sees it) or ``"strokes"``
        (in each stroke's torque by its place in the firing order, which the strokes' own
        torques show directly and the FRFs only by chance).
    stage_of
        For a spring's second stage: the names of the coupling's stiffness and free play
        whose spring it stiffens (``("c12", "eps12")``); None for the others. Beyond its knee
        such a spring is a stiffer one behind a wider play (:func:`behind_imitation`).
    """

    name: str
    physics: str
    parameters: tuple[MechanismParameter, ...]
    path: str = "drivetrain"
    stage_of: tuple[str, str] | None = None

    @property
    def main(self) -> MechanismParameter:
        """The parameter that sets the effect's magnitude."""
        return self.parameters[0]

    def names(self) -> tuple[str, ...]:
        """Its parameters' names."""
        return tuple(p.name for p in self.parameters)

    def search_bounds(self) -> list[tuple[float, float]]:
        """Where a refit searches each parameter, SI units, within its bounds: the main
        parameter up to twice the typical reach from neutral (both sides for a signed one), the
        others from half to twice their typical range. A search over the whole physical bounds
        spends its population on magnitudes no vehicle has (a quadratic damping of 30 where 1.5
        is typical)."""
        main = self.main
        reach = 2.0 * max(abs(t - main.neutral) for t in main.typical)
        out = [(max(main.lower, main.neutral - reach), min(main.upper, main.neutral + reach))]
        for spec in self.parameters[1:]:
            out.append(
                (max(spec.lower, 0.5 * spec.typical[0]), min(spec.upper, 2.0 * spec.typical[1]))
            )
        return out


def _p(
    name: str,
    unit: str,
    meaning: str,
    neutral: float,
    bounds: tuple[float, float],
    typical: tuple[float, float],
) -> MechanismParameter:
    return MechanismParameter(name, unit, meaning, neutral, bounds[0], bounds[1], typical)


MECHANISMS: tuple[Mechanism, ...] = (
    Mechanism(
        "progressive_spring",
        "The DMF arc springs reach a second, stiffer stage beyond a knee: the spring torque "
        "gains c12_2 times the deflection beyond knee12 (measured from the end of the free play).",
        (
            _p(
                "c12_2",
                "N*m/rad",
                "DMF second-stage stiffness added",
                0.0,
                (0.0, 3000.0),
                (300.0, 900.0),
            ),
            _p(
                "knee12",
                "rad",
                "DMF spring deflection where the second stage engages",
                0.008,
                (0.002, 0.2),
                (0.004, 0.012),
            ),
        ),
        stage_of=("c12", "eps12"),
    ),
    Mechanism(
        "asymmetric_play",
        "The DMF free play is unequal in drive and coast: the drive side's half-width is "
        "eps12/2 (1 + asym12), the coast side's eps12/2 (1 - asym12), the total unchanged.",
        (_p("asym12", "1", "DMF free-play asymmetry", 0.0, (-0.9, 0.9), (0.3, 0.8)),),
    ),
    Mechanism(
        "friction_hysteresis",
        "A DMF friction ring or control plate engages beyond a deflection: the Coulomb friction "
        "grows by Tc12_2 where |delta12| exceeds phi12_f.",
        (
            _p(
                "Tc12_2",
                "N*m",
                "DMF friction added beyond the engagement angle",
                0.0,
                (0.0, 20.0),
                (1.5, 5.0),
            ),
            _p(
                "phi12_f",
                "rad",
                "DMF deflection where the friction ring engages",
                0.02,
                (0.0, 0.2),
                (0.01, 0.03),
            ),
        ),
    ),
    Mechanism(
        "quadratic_damping",
        "The DMF damping grows with the relative speed (grease displaced in the spring "
        "channel): a torque d12_2 * w12 * |w12| adds to the viscous d12 * w12.",
        (
            _p(
                "d12_2",
                "N*m*s^2/rad^2",
                "DMF quadratic damping coefficient",
                0.0,
                (0.0, 30.0),
                (0.5, 2.5),
            ),
        ),
    ),
    Mechanism(
        "clutch_two_stage",
        "The clutch-disc damper reaches a second stage: the spring torque gains c23_2 times the "
        "twist beyond knee23.",
        (
            _p(
                "c23_2",
                "N*m/rad",
                "clutch second-stage stiffness added",
                0.0,
                (0.0, 2000.0),
                (80.0, 300.0),
            ),
            _p(
                "knee23",
                "rad",
                "clutch twist where the second stage engages",
                0.004,
                (0.001, 0.1),
                (0.002, 0.006),
            ),
        ),
        stage_of=("c23", "eps23"),
    ),
    Mechanism(
        "gearbox_drag",
        "Oil churning in the gearbox drags J3 against the housing: a torque d3 * w3 "
        "opposes its absolute speed (a mean load that preloads both couplings).",
        (
            _p(
                "d3",
                "N*m*s/rad",
                "gearbox drag coefficient against the housing",
                0.0,
                (0.0, 0.1),
                (0.008, 0.025),
            ),
        ),
    ),
    Mechanism(
        "accessory_mode",
        "A belt-driven accessory (alternator) of inertia J4, reflected to the crank, hangs on J1 "
        "through the belt's stiffness c14 and damping d14: an extra mode (above 100 Hz, "
        "beyond the band, it moves with the crank).",
        (
            _p(
                "J4",
                "kg*m^2",
                "accessory inertia reflected to the crank",
                0.0,
                (0.0, 0.1),
                (0.015, 0.04),
            ),
            _p(
                "c14",
                "N*m/rad",
                "belt stiffness reflected to the crank",
                130.0,
                (1.0, 3000.0),
                (60.0, 200.0),
            ),
            _p(
                "d14",
                "N*m*s/rad",
                "belt damping reflected to the crank",
                0.125,
                (0.0, 5.0),
                (0.05, 0.2),
            ),
        ),
    ),
    Mechanism(
        "torque_lag",
        "The engine delivers its requested mean torque with a first-order lag (air path, torque "
        "model): each stroke's torque moves towards K T_ecu with time constant tau_m.",
        (
            _p(
                "tau_m",
                "s",
                "lag from requested to delivered mean torque",
                0.0,
                (0.0, 0.5),
                (0.03, 0.15),
            ),
        ),
        path="engine",
    ),
    Mechanism(
        "torque_sensor_gain",
        "The indicated-torque measurement has a scale error: the sensor reports g_T times the "
        "mean torque delivered.",
        (_p("g_T", "1", "gain of the mean-torque measurement", 1.0, (0.5, 1.5), (0.85, 1.15)),),
    ),
    Mechanism(
        "cylinder_imbalance",
        "One cylinder delivers 1 + share times the mean torque and the other three 1 - share/3 "
        "(a half-order excitation; the simulator fires it first, the model of a recording where "
        "the recording's strokes show it).",
        (
            _p(
                "share",
                "1",
                "excess torque share of the odd cylinder",
                0.0,
                (-0.5, 0.5),
                (0.05, 0.25),
            ),
        ),
        path="strokes",
    ),
)
"""The library, in kernel order."""

BY_NAME: dict[str, Mechanism] = {m.name: m for m in MECHANISMS}
EXTRA: tuple[MechanismParameter, ...] = tuple(p for m in MECHANISMS for p in m.parameters)
EXTRA_NAMES: tuple[str, ...] = tuple(p.name for p in EXTRA)
EXTRA_INDEX: dict[str, int] = {name: len(NAMES) + i for i, name in enumerate(EXTRA_NAMES)}
"""Kernel slot of each mechanism parameter (after the twelve drivetrain parameters)."""
KERNEL_WIDTH = len(NAMES) + len(EXTRA)
"""Length of the kernel's parameter vector."""
NEUTRAL = np.array([p.neutral for p in EXTRA])
"""Every mechanism parameter at its neutral value, in kernel order."""

# Kernel slots by constant, for the numba kernel (checked against EXTRA_INDEX below).
P_C12_2, P_KNEE12, P_ASYM12, P_TC12_2, P_PHI12_F, P_D12_2 = 12, 13, 14, 15, 16, 17
P_C23_2, P_KNEE23, P_D3, P_J4, P_C14, P_D14, P_TAU_M, P_G_T, P_SHARE = (
    18,
    19,
    20,
    21,
    22,
    23,
    24,
    25,
    26,
)
assert [
    P_C12_2,
    P_KNEE12,
    P_ASYM12,
    P_TC12_2,
    P_PHI12_F,
    P_D12_2,
    P_C23_2,
    P_KNEE23,
    P_D3,
    P_J4,
    P_C14,
    P_D14,
    P_TAU_M,
    P_G_T,
    P_SHARE,
] == list(EXTRA_INDEX.values())


@dataclass(frozen=True)
class Effects:
    """Mechanisms present in a simulated vehicle, with their parameter values.

    Attributes
    ----------
    values
        ``{parameter name: value}`` of the mechanisms present (SI units); the rest are neutral.
    """

    values: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "values", dict(self.values))
        for name, value in self.values.items():
            spec = _spec(name)
            if not (math.isfinite(value) and spec.lower <= value <= spec.upper):
                raise ConfigError(
                    f"effect parameter {name} = {value} {spec.unit} is outside "
                    f"{spec.lower:g}..{spec.upper:g} ({spec.meaning})"
                )

    @property
    def mechanisms(self) -> tuple[str, ...]:
        """Names of the mechanisms present (a parameter away from neutral), library order."""
        present = {n for n, v in self.values.items() if v != _spec(n).neutral}
        return tuple(m.name for m in MECHANISMS if present & set(m.names()))

    def columns(self) -> np.ndarray:
        """The mechanism part of the kernel vector, (len(EXTRA),)."""
        out = NEUTRAL.copy()
        for name, value in self.values.items():
            out[EXTRA_INDEX[name] - len(NAMES)] = value
        return out

    def as_dict(self) -> dict[str, float]:
        """``{parameter: value}`` as given."""
        return dict(self.values)


def _spec(name: str) -> MechanismParameter:
    for spec in EXTRA:
        if spec.name == name:
            return spec
    raise ConfigError(f"unknown mechanism parameter {name!r}; known: {', '.join(EXTRA_NAMES)}")


def parse_effect(text: str) -> dict[str, float]:
    """Parse ``NAME[:k=v,...]`` into parameter values; the main parameter takes the middle of
    its typical range when not given.

    Raises
    ------
    ConfigError
        Naming an unknown mechanism or parameter, or a value that is not a number.
    """
    name, _, rest = text.partition(":")
    mechanism = BY_NAME.get(name.strip())
    if mechanism is None:
        raise ConfigError(
            f"unknown mechanism {name!r} in --effect {text!r}; the library: {', '.join(BY_NAME)}"
        )
    values = {p.name: p.neutral for p in mechanism.parameters[1:]}
    values[mechanism.main.name] = 0.5 * sum(mechanism.main.typical)
    given: set[str] = set()
    for item in filter(None, (part.strip() for part in rest.split(","))):
        key, sep, value = item.partition("=")
        if not sep or key.strip() not in mechanism.names():
            raise ConfigError(
                f"--effect {text!r}: {item!r} is not k=v with k one of "
                f"{', '.join(mechanism.names())}"
            )
        if key.strip() in given:
            raise ConfigError(f"--effect {text!r} gives {key.strip()} twice: give it once")
        given.add(key.strip())
        try:
            values[key.strip()] = float(value)
        except ValueError:
            raise ConfigError(f"--effect {text!r}: {value!r} is not a number") from None
    return values


def behind_imitation(
    mechanism: Mechanism, row: np.ndarray, second: float, knee: float
) -> np.ndarray | None:
    """The spring with a second stage that ``row``'s single-stage spring imitates.

    A spring of stiffness c behind a free play eps (half-width eps/2 each side) with a second
    stage c_2 from a deflection knee on transmits, beyond the knee, (c + c_2) d - c_2 knee for
    a deflection d past the play: what a single spring c + c_2 behind a play wider by
    2 c_2 knee / (c + c_2) transmits. A test whose deflections mostly pass the knee cannot tell
    the two apart (the blind trial's absorbed two-stage springs: docs/diagnosis.md). This
    undoes that imitation: the first stage c = c_1 - c_2 and play eps_1 - 2 c_2 knee / c_1
    behind ``row``'s spring c_1 and play eps_1.

    Parameters
    ----------
    mechanism
        A mechanism with :attr:`Mechanism.stage_of`.
    row
        A kernel row (:data:`KERNEL_WIDTH` values, SI units) with the mechanism neutral.
    second, knee
        The second stage's stiffness (N*m/rad) and knee (rad).

    Returns
    -------
    numpy.ndarray or None
        The row with the stage present and the first stage's stiffness and play that give
        ``row`` beyond the knee; None where ``row``'s spring is not stiffer than the stage or
        its play not wide enough (no such first stage).
    """
    if mechanism.stage_of is None:
        raise ValueError(f"{mechanism.name} is no spring's second stage")
    stiffness, play = (INDEX[name] for name in mechanism.stage_of)
    first = row[stiffness] - second
    narrower = row[play] - 2.0 * second * knee / row[stiffness]
    if first <= 0.0 or narrower < 0.0:
        return None
    out = row.copy()
    out[stiffness], out[play] = first, narrower
    out[EXTRA_INDEX[mechanism.parameters[0].name]] = second
    out[EXTRA_INDEX[mechanism.parameters[1].name]] = knee
    return out


def kernel_parameters(params: np.ndarray, effects: Effects | None = None) -> np.ndarray:
    """Parameter rows as the kernel takes them: twelve drivetrain columns get the mechanism
    columns of ``effects`` (neutral by default) appended; full rows pass unchanged.

    Parameters
    ----------
    params
        (n, 12) or (n, :data:`KERNEL_WIDTH`), or one such row.
    """
    params = np.asarray(params, dtype=np.float64)
    if params.shape[-1] == KERNEL_WIDTH:
        return np.ascontiguousarray(params)
    if params.shape[-1] != len(NAMES):
        raise ConfigError(
            f"params must have {len(NAMES)} or {KERNEL_WIDTH} columns, got {params.shape}"
        )
    extra = (effects or Effects()).columns()
    tail = np.broadcast_to(extra, params.shape[:-1] + extra.shape)
    return np.ascontiguousarray(np.concatenate([params, tail], axis=-1))
