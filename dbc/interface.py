"""The vehicle interface: a signal map bound to a CAN database, decoding and encoding roles."""

import difflib
import functools
import logging
import os
from collections import Counter
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING

import can
import numpy as np
from cantools.database import DecodeError, EncodeError
from cantools.database.can import Database, Message, Signal

from dtid.dbc.checksum import CHECKSUM_BYTE, PAYLOAD_LENGTH, apply_checksum, verify_checksum
from dtid.dbc.database import load_database
from dtid.dbc.resources import DEFAULT_DBC
from dtid.dbc.roles import REQUIRED_ROLES
from dtid.errors import ConfigError, DbcError

if TYPE_CHECKING:
    from dtid.dbc.signal_map import RoleSpec, SignalMap

logger = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class RoleSeries:
    """The decoded frames of one role.

    Attributes
    ----------
    role : str
        The role.
    timestamps : numpy.ndarray
        Receive time of each decoded frame, s, float64, as in the frames.
    values : numpy.ndarray
        The role's value in its canonical unit (speed: rpm; torques: N*m; heartbeat: raw state),
        float64, one per timestamp.
    extra : Mapping[str, numpy.ndarray]
        Raw integer values (int64, one per timestamp) of the further signals the map names for
        the role, keyed ``counter``, ``cylinder``, ``enable`` or ``checksum``; for a role whose
        frames carry the product's checksum also ``checksum_ok`` (1 where the payload's
        checksum verifies, 0 where it does not: what the receiving ECU checks).
    n_bad : int
        Frames of the role's message that were skipped because their length differs from the DBC
        or they could not be decoded.
    not_measured : int
        Frames of the role's message left out because they carry no measurement: a value the
        DBC names outside the signal's range, or the map's validity flag not valid.
    """

    role: str
    timestamps: np.ndarray
    values: np.ndarray
    extra: Mapping[str, np.ndarray]
    n_bad: int
    not_measured: int = 0


@dataclass(frozen=True)
class _BoundRole:
    spec: "RoleSpec"
    message: Message
    extra_signals: Mapping[str, Signal]
    product_checksum: bool
    named_values: Mapping[float, str]
    """Decoded values of the value signal that say the ECU had no measurement, with the names
    the DBC gives them (:func:`_not_measurements`)."""

    @property
    def signal_names(self) -> tuple[str, ...]:
        """The value signal, then the extra signals."""
        return (self.spec.signal, *(signal.name for signal in self.extra_signals.values()))

    @property
    def validity(self) -> tuple[int, Signal, frozenset[int]] | None:
        """Where the validity flag is in a decoded row (:attr:`signal_names`), its signal and
        the raw values that mean a measurement; None without a flag."""
        if "valid" not in self.extra_signals:
            return None
        position = 1 + list(self.extra_signals).index("valid")
        return position, self.extra_signals["valid"], frozenset(self.spec.valid_values)


@functools.cache
def _product_database() -> Database:
    return load_database(DEFAULT_DBC)


def _is_product_checksum(message: Message, signal: Signal) -> bool:
    """Tell whether ``signal`` is the CRC-8 checksum of the product's own message."""
    try:
        product = _product_database().get_message_by_name(message.name)
        product_signal = product.get_signal_by_name(signal.name)
    except KeyError:
        return False
    frame = (message.frame_id, message.is_extended_frame, message.length)
    layout = (signal.start, signal.length, signal.byte_order)
    return (
        frame == (product.frame_id, product.is_extended_frame, product.length)
        and layout == (product_signal.start, product_signal.length, product_signal.byte_order)
        and layout == (8 * CHECKSUM_BYTE, 8, "little_endian")
        and message.length == PAYLOAD_LENGTH
    )


def _similar(name: str, candidates: Iterable[str], what: str) -> str:
    close = difflib.get_close_matches(name, list(candidates), n=5, cutoff=0.6)
    if not close:
        return f"no {what} has a similar name"
    return f"{what}s with similar names: {', '.join(close)}"


def _default_value(signal: Signal) -> float:
    """Value of a signal that is not given: 0, or the nearest limit if 0 is out of range."""
    value = 0.0
    if signal.minimum is not None:
        value = max(value, signal.minimum)
    if signal.maximum is not None:
        value = min(value, signal.maximum)
    return value


def _not_measurements(signal: Signal, spec: "RoleSpec") -> dict[float, str]:
    """The decoded values of a measured role's signal that say the ECU had no measurement, with
    their names: the values the DBC names (``VAL_``) outside the signal's declared range, as a
    production DBC codes "Invalid", "Fault" or "Init" (Ford's engine speed: range 0-16383.5 rpm,
    65535 "Invalid" = 16383.75 rpm). A named value inside the range (0 "Stopped") is a value;
    without a declared range (``[0|0]``) none is judged. Empty for the heartbeat, whose states
    are its values."""
    low, high = signal.minimum, signal.maximum
    if spec.canonical_unit is None or not signal.choices or low is None or high is None:
        return {}
    if high <= low:
        return {}
    named = {}
    for raw, label in signal.choices.items():
        value = float(signal.conversion.raw_to_scaled(raw, decode_choices=False))
        if not low <= value <= high:
            named[value] = str(label)
    return named


def _raw(values: list[float], signal: Signal) -> np.ndarray:
    """Convert decoded (scaled) values of a signal back to raw integers."""
    scaled = np.asarray(values, dtype=np.float64)
    return np.rint((scaled - signal.offset) / signal.scale).astype(np.int64)


class VehicleInterface:
    """A signal map bound to a CAN database: decodes recordings and encodes frames by role.

    Create it with :meth:`dbc.SignalMap.bind`.

    Parameters
    ----------
    signal_map : SignalMap
        The signal map.
    database : cantools.database.can.Database
        The CAN database.
    dbc_source : str or os.PathLike, optional
        The database's file, named in error messages (attribute ``dbc_source``: Path or None).

    Raises
    ------
    DbcError
        If a mapped message is not in the database or a mapped signal is not in its message; the
        message suggests similar names.
    """

    def __init__(
        self,
        signal_map: "SignalMap",
        database: Database,
        dbc_source: str | os.PathLike[str] | None = None,
    ) -> None:
        self.signal_map = signal_map
        self.database = database
        self.dbc_source = Path(dbc_source) if dbc_source is not None else None
        self._dbc_name = str(dbc_source) if dbc_source is not None else "the CAN database"
        self._roles = {role: self._bind(spec) for role, spec in signal_map.roles.items()}
        self._roles_by_frame: dict[tuple[int, bool], list[_BoundRole]] = {}
        for bound in self._roles.values():
            key = (bound.message.frame_id, bound.message.is_extended_frame)
            self._roles_by_frame.setdefault(key, []).append(bound)
        for roles in self._roles_by_frame.values():
            if len({bound.spec.channel for bound in roles}) > 1:
                named = ", ".join(f"{b.spec.role} {b.spec.channel!r}" for b in roles)
                raise ConfigError(
                    f"signal map {signal_map.source}: the roles of message "
                    f"'{roles[0].message.name}' name different channels ({named}); a message "
                    "is read from one channel: give them the same"
                )

    def _bind(self, spec: "RoleSpec") -> _BoundRole:
        where = f"signal map {self.signal_map.source}: role '{spec.role}'"
        try:
            message = self.database.get_message_by_name(spec.message)
        except KeyError:
            names = (message.name for message in self.database.messages)
            raise DbcError(
                f"{where} names message '{spec.message}' which is not in {self._dbc_name}; "
                f"{_similar(spec.message, names, 'message')}"
            ) from None
        present = {signal.name for signal in message.signals}
        for key, name in {"signal": spec.signal, **spec.extra_signals()}.items():
            if name not in present:
                raise DbcError(self._missing_signal(where, key, name, message))
        signals = {
            key: message.get_signal_by_name(name) for key, name in spec.extra_signals().items()
        }
        product_checksum = "checksum" in signals and _is_product_checksum(
            message, signals["checksum"]
        )
        if "checksum" in signals and not product_checksum:
            logger.warning(
                "%s: checksum signal '%s' of message '%s' is not the checksum of the product's "
                "own DBC; encode() sends it as given (default 0)",
                where,
                signals["checksum"].name,
                message.name,
            )
        return _BoundRole(
            spec,
            message,
            MappingProxyType(signals),
            product_checksum,
            MappingProxyType(_not_measurements(message.get_signal_by_name(spec.signal), spec)),
        )

    def _missing_signal(self, where: str, key: str, name: str, message: Message) -> str:
        text = (
            f"{where} names signal '{name}' (key '{key}') which is not in message "
            f"'{message.name}' of {self._dbc_name}; "
            f"{_similar(name, (signal.name for signal in message.signals), 'signal')}"
        )
        elsewhere = [
            other.name
            for other in self.database.messages
            if any(signal.name == name for signal in other.signals)
        ]
        if elsewhere:
            text += f"; '{name}' is a signal of message {', '.join(elsewhere[:5])}"
        return text

    def checks_checksum(self, role: str) -> bool:
        """True when the role's frames carry the product's checksum (which
        :func:`dtid.dbc.checksum.verify_checksum` checks on a received payload)."""
        bound = self._roles.get(role)
        return bound is not None and bound.product_checksum

    def channel(self, role: str) -> str | None:
        """The recording's channel the role's message is read from (the signal map's
        ``channel``), None where not given."""
        self.signal_map.require(role)
        return self._roles[role].spec.channel

    def frame_key(self, role: str) -> tuple[int, bool]:
        """Arbitration ID and whether it is extended, of the role's message."""
        self.signal_map.require(role)
        message = self._roles[role].message
        return message.frame_id, message.is_extended_frame

    def present_roles(self) -> tuple[str, ...]:
        """Return the mapped roles."""
        return self.signal_map.present_roles()

    def missing_roles(self, required: Iterable[str] = REQUIRED_ROLES) -> tuple[str, ...]:
        """Return the roles of ``required`` (default: the analysis roles) the map lacks."""
        return self.signal_map.missing_roles(required)

    def decode(self, messages: Iterable[can.Message]) -> dict[str, RoleSeries]:
        """Decode the frames of every mapped role.

        Only data frames whose arbitration ID and ID type (standard or extended) belong to a
        mapped message are decoded. A frame whose length differs from the DBC's or that cantools
        cannot decode is skipped and counted in :attr:`RoleSeries.n_bad` (and logged). A value
        of a measured role's signal that the DBC names outside the signal's range (``VAL_``:
        "Invalid", "Fault", "Init"), or a validity flag (the map's ``valid``) not among the
        map's ``valid_values``, says that the ECU had no measurement: that frame is left out of
        the role (and logged).

        Parameters
        ----------
        messages : Iterable[can.Message]
            The recorded frames, in time order.

        Returns
        -------
        dict[str, RoleSeries]
            One series per mapped role (empty arrays when the recording lacks its message).
        """
        frames: dict[tuple[int, bool], list[can.Message]] = {
            key: [] for key in self._roles_by_frame
        }
        for frame in messages:
            bucket = frames.get((frame.arbitration_id, frame.is_extended_id))
            if bucket is not None and not (frame.is_error_frame or frame.is_remote_frame):
                bucket.append(frame)
        series: dict[str, RoleSeries] = {}
        for key, bucket in frames.items():
            for result in self._decode_message(self._roles_by_frame[key], bucket):
                series[result.role] = result
        return {role: series[role] for role in self._roles}

    def _decode_message(
        self, roles: list[_BoundRole], frames: list[can.Message]
    ) -> list[RoleSeries]:
        """Decode the frames of one message for every role it carries."""
        message = roles[0].message
        decode = message.decode
        length = message.length
        names = [role.signal_names for role in roles]
        checked = [role.product_checksum for role in roles]
        times: list[list[float]] = [[] for _ in roles]
        rows: list[list[tuple[float, ...]]] = [[] for _ in roles]
        verified: list[list[bool]] = [[] for _ in roles]
        undecodable = 0
        absent = [0] * len(roles)
        named = [role.named_values for role in roles]
        validity = [role.validity for role in roles]
        not_measured: list[Counter[str]] = [Counter() for _ in roles]
        for frame in frames:
            data = frame.data
            if len(data) != length:
                undecodable += 1
                continue
            try:
                decoded = decode(data, decode_choices=False, scaling=True)
            except (DecodeError, ValueError):
                undecodable += 1
                continue
            for index, signal_names in enumerate(names):
                try:
                    row = tuple([decoded[name] for name in signal_names])
                except KeyError:  # a multiplexed signal that this frame does not carry
                    absent[index] += 1
                    continue
                if named[index] and row[0] in named[index]:  # "Invalid", not a measurement
                    not_measured[index][repr(named[index][row[0]])] += 1
                    continue
                if validity[index] is not None:  # the ECU's own flag
                    position, flag, valid = validity[index]
                    raw = round((row[position] - flag.offset) / flag.scale)
                    if raw not in valid:
                        not_measured[index][f"with {flag.name} = {raw}"] += 1
                        continue
                rows[index].append(row)
                times[index].append(frame.timestamp)
                if checked[index]:
                    verified[index].append(verify_checksum(data))
        for role, counts in zip(roles, not_measured, strict=True):
            if counts:
                logger.warning(
                    "role '%s': left out %s of %d frames of message '%s' (0x%X): they carry no "
                    "measurement (a value the DBC names outside the signal's range, or the "
                    "ECU's validity flag)",
                    role.spec.role,
                    ", ".join(f"{n} {label}" for label, n in counts.items()),
                    len(frames),
                    message.name,
                    message.frame_id,
                )
        return [
            self._series(
                role,
                times[index],
                rows[index],
                undecodable + absent[index],
                len(frames),
                verified[index] if checked[index] else None,
                sum(not_measured[index].values()),
            )
            for index, role in enumerate(roles)
        ]

    @staticmethod
    def _series(
        role: _BoundRole,
        times: list[float],
        rows: list[tuple[float, ...]],
        n_bad: int,
        n_frames: int,
        verified: list[bool] | None,
        not_measured: int,
    ) -> RoleSeries:
        columns = list(zip(*rows, strict=True)) if rows else [[]] * len(role.signal_names)
        values = np.asarray(columns[0], dtype=np.float64) * role.spec.gain
        extra = {
            key: _raw(list(column), signal)
            for (key, signal), column in zip(role.extra_signals.items(), columns[1:], strict=True)
        }
        if verified is not None:
            extra["checksum_ok"] = np.asarray(verified, dtype=np.int64)
        if n_bad:
            logger.warning(
                "role '%s': skipped %d of %d frames of message '%s' (0x%X) with a wrong length "
                "or an undecodable payload",
                role.spec.role,
                n_bad,
                n_frames,
                role.message.name,
                role.message.frame_id,
            )
        return RoleSeries(
            role=role.spec.role,
            timestamps=np.asarray(times, dtype=np.float64),
            values=values,
            extra=MappingProxyType(extra),
            n_bad=n_bad,
            not_measured=not_measured,
        )

    def encode(self, role: str, value: float, timestamp: float, **signals: float) -> can.Message:
        """Encode a frame of a role's message.

        Parameters
        ----------
        role : str
            The role, e.g. ``"test_torque"``.
        value : float
            The role's value in its canonical unit (rpm or N*m; raw state for the heartbeat).
        timestamp : float
            Timestamp of the frame, s.
        **signals : float
            Further signals of the message, in DBC units, by signal name or by the map's key
            (``counter``, ``enable``, ``cylinder``, ``checksum``). Signals not given are 0, or
            their nearest limit when 0 is out of range.

        Returns
        -------
        can.Message
            The frame, with the ID type of the DBC. When the role names a checksum signal and the
            message is the product's own TestTorqueRequest, the checksum is computed over the
            encoded payload unless given explicitly (to inject a fault).

        Raises
        ------
        ConfigError
            If the role is not mapped, or a value is outside its signal's range.
        ValueError
            If a keyword names no signal of the message, or names one twice.
        """
        self.signal_map.require(role)
        bound = self._roles[role]
        message = bound.message
        data = {signal.name: _default_value(signal) for signal in message.signals}
        data[bound.spec.signal] = value / bound.spec.gain
        given: set[str] = set()
        for key, signal_value in signals.items():
            name = bound.extra_signals[key].name if key in bound.extra_signals else key
            if name not in data or name == bound.spec.signal or name in given:
                raise ValueError(
                    f"cannot set '{key}' when encoding role '{role}': message "
                    f"'{message.name}' has no such further signal, or it is given twice"
                )
            data[name] = signal_value
            given.add(name)
        try:
            payload = message.encode(data, scaling=True, strict=True)
        except (EncodeError, ValueError) as error:
            unit = f" {bound.spec.canonical_unit}" if bound.spec.canonical_unit else ""
            raise ConfigError(
                f"cannot encode role '{role}' = {value:g}{unit} into message '{message.name}': "
                f"{error}"
            ) from error
        if bound.product_checksum and bound.extra_signals["checksum"].name not in given:
            payload = apply_checksum(payload)
        return can.Message(
            timestamp=float(timestamp),  # a numpy float would be written as "np.float64(..)"
            arbitration_id=message.frame_id,
            is_extended_id=message.is_extended_frame,
            is_fd=message.is_fd,
            data=payload,
        )
