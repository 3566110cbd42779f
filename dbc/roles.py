"""The roles of a signal map: the quantities the analysis reads from or writes to the CAN bus."""

from collections.abc import Mapping
from types import MappingProxyType

#: Every role a signal map may define, in the order they are reported.
ROLES: tuple[str, ...] = ("speed", "mean_torque", "test_torque", "torque_request", "heartbeat")
#: Roles the analysis commands need.
REQUIRED_ROLES: tuple[str, ...] = ("speed", "mean_torque", "test_torque")
#: Canonical unit of each role's values; the heartbeat carries a raw state number.
CANONICAL_UNITS: Mapping[str, str | None] = MappingProxyType(
    {
        "speed": "rpm",
        "mean_torque": "N*m",
        "test_torque": "N*m",
        "torque_request": "N*m",
        "heartbeat": None,
    }
)
#: Keys naming further signals of the role's message, per role. ``counter`` is the message's
#: rolling counter (for speed: the crank event counter, for the test torque: the alive counter);
#: ``valid`` the ECU's validity flag of the value (a frame whose flag is not among the map's
#: ``valid_values`` carries no measurement).
EXTRA_SIGNAL_KEYS: Mapping[str, tuple[str, ...]] = MappingProxyType(
    {
        "speed": ("counter", "valid"),
        "mean_torque": ("cylinder", "counter", "valid"),
        "test_torque": ("counter", "enable", "checksum"),
        "torque_request": ("counter", "valid"),
        "heartbeat": ("counter",),
    }
)
#: Bus time without a valid test-torque request after which the engine ECU applies zero test
#: torque, s (five request periods of 10 ms): the product ECU's, and what the analysis assumes of
#: a vehicle whose signal map gives no ``timeout_s`` for its ``test_torque`` role.
DEFAULT_REQUEST_TIMEOUT_S: float = 0.05
#: Samples of the ``speed`` role per crank revolution: the ECU's filtered speed, once per crank
#: event (every pi/2, the paper's section II-C).
SPEED_SAMPLES_PER_REVOLUTION: int = 4
#: Relative departure of a role's samples per crank revolution from the expected beyond which it
#: is not crank-synchronous (lost frames and the speed's own swing move the count by far less).
CRANK_RATE_TOLERANCE: float = 0.15
