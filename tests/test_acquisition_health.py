"""Counter bookkeeping (lost, duplicated, out of order) and the echo filter of the daemon."""

from __future__ import annotations

import dataclasses
import threading

import can
import numpy as np
import pytest

from dtid.acquisition.health import CounterTracker, EchoFilter, Health, counter_moduli
from dtid.dbc.interface import RoleSeries
from dtid.dbc.loader import load_interface

INTERFACE = load_interface()


def tracked(counters: list[int], modulo: int = 256, blocks: int = 1) -> CounterTracker:
    """A tracker fed ``counters`` in ``blocks`` consecutive chunks."""
    tracker = CounterTracker(modulo)
    for chunk in np.array_split(np.array(counters), blocks):
        tracker.update(chunk)
    return tracker


def counts(tracker: CounterTracker) -> tuple[int, int, int]:
    return tracker.lost, tracker.duplicated, tracker.out_of_order


@pytest.mark.parametrize("blocks", [1, 3, 7])
def test_contiguous_counters_across_the_wrap_are_clean(blocks: int) -> None:
    counters = [i % 256 for i in range(200, 700)]
    assert counts(tracked(counters, blocks=blocks)) == (0, 0, 0)


@pytest.mark.parametrize("blocks", [1, 4])
def test_gaps_duplicates_and_reorders(blocks: int) -> None:
    counters = [*range(0, 10), *range(12, 20), 19, 20, 22, 21, *range(23, 30)]
    # 10 and 11 lost; 19 repeated; 21 arrives after 22
    assert counts(tracked(counters, blocks=blocks)) == (2, 1, 1)


def test_late_frame_fills_its_hole_across_the_wrap() -> None:
    counters = [*range(250, 256), 1, 0, *range(2, 10)]  # 0 arrives after 1
    assert counts(tracked(counters)) == (0, 0, 1)


def test_late_copy_of_a_frame_already_seen_is_a_duplicate() -> None:
    counters = [*range(0, 10), 5, *range(10, 15)]
    assert counts(tracked(counters)) == (0, 1, 0)


def test_very_late_frame_within_half_the_range_is_out_of_order() -> None:
    counters = [0, 1, 2, 3, *range(5, 120), 4]
    assert counts(tracked(counters)) == (0, 0, 1)


def test_16_bit_counter_wraps_at_65536() -> None:
    counters = [*range(65530, 65536), 0, 1, 3]
    assert counts(tracked(counters, modulo=65536)) == (1, 0, 0)


def test_counter_widths_come_from_the_dbc() -> None:
    moduli = counter_moduli(INTERFACE, ("speed", "mean_torque", "torque_request", "test_torque"))
    assert moduli == {"speed": 65536, "mean_torque": 256, "torque_request": 256, "test_torque": 16}


def _series(role: str, counters: list[int], n_bad: int = 0) -> RoleSeries:
    n = len(counters)
    extra = {"counter": np.array(counters, dtype=np.int64)}
    return RoleSeries(role, np.arange(n, dtype=float), np.zeros(n), extra, n_bad)


def test_health_sums_roles_and_bad_frames() -> None:
    health = Health(INTERFACE)
    health.update(
        {"speed": _series("speed", [0, 1, 3]), "mean_torque": _series("mean_torque", [7])}
    )
    health.update(
        {"speed": _series("speed", [3, 4], n_bad=2), "mean_torque": _series("mean_torque", [9])}
    )
    counts = health.counts
    assert (counts.lost, counts.duplicated, counts.out_of_order, counts.bad_frames) == (2, 1, 0, 2)
    # frames that carry no measurement ("Invalid", a validity flag at 0) are counted apart
    invalid = dataclasses.replace(_series("speed", [5, 6]), not_measured=3)
    health.update({"speed": invalid})
    assert (counts.not_measured, counts.bad_frames, counts.lost) == (3, 2, 2)
    assert counts.anomalies()[-1] == 3


def test_the_daemon_warns_once_a_session_of_each_kind_of_bad_block(tmp_path, caplog) -> None:
    """The daemon decodes four blocks a second: a frame of the wrong length in each would log
    four warnings a second. The first of each kind and role is logged; the health events count
    the rest. Another thread's warnings meanwhile pass untouched."""
    from dtid.acquisition.clock import BusClock
    from dtid.acquisition.framepath import FramePath
    from dtid.acquisition.recorder import Recorder
    from dtid.dbc.interface import logger as interface_logger

    class Server:
        count = 0

        def publish(self, kind: str, fields: dict) -> dict:
            self.count += 1
            return {"kind": kind, **fields}

    recorder = Recorder(tmp_path / "s.blf", 0.0, flush_period_s=0.05)
    tool = [INTERFACE.frame_key("test_torque"), INTERFACE.frame_key("heartbeat")]
    path = FramePath(INTERFACE, BusClock(), recorder, Server(), EchoFilter(tool), {"plan": {}})
    speed_id = INTERFACE.frame_key("speed")[0]
    with caplog.at_level("WARNING"):
        for block in range(5):
            path.take(
                can.Message(
                    timestamp=0.25 * block,
                    arbitration_id=speed_id,
                    is_extended_id=False,
                    data=bytes(7),  # one byte short
                )
            )
            path.publish_block()
        with path._first_warnings.on(interface_logger):
            for _ in range(2):
                interface_logger.warning("x %s", "y")  # the decoding thread's: once
                worker = threading.Thread(target=interface_logger.warning, args=("x %s", "y"))
                worker.start()
                worker.join()
    recorder.close()
    assert caplog.text.count("skipped 1 of 1 frames of message 'EngineSpeed'") == 1
    assert path.health.counts.bad_frames == 5
    assert caplog.text.count("x y") == 1 + 2  # another thread's each time


def _request(counter: int, value: float = 0.0) -> can.Message:
    return INTERFACE.encode("test_torque", value, 0.0, counter=counter, enable=0)


def test_echo_is_consumed_once_and_a_second_copy_is_foreign() -> None:
    echo = EchoFilter([INTERFACE.frame_key("test_torque")])
    frame = _request(3)
    echo.expect(frame)
    copy = can.Message(
        arbitration_id=frame.arbitration_id, is_extended_id=False, data=bytes(frame.data)
    )
    assert echo.is_tool_frame(copy)
    assert echo.is_echo(copy)
    assert not echo.is_echo(copy)
    assert echo.echoes == 1


def test_frame_never_sent_is_foreign_and_other_ids_are_not_tool_frames() -> None:
    echo = EchoFilter([INTERFACE.frame_key("test_torque")])
    echo.expect(_request(3))
    assert not echo.is_echo(_request(4))
    assert not echo.is_tool_frame(INTERFACE.encode("speed", 1000.0, 0.0, counter=1))


def test_error_and_remote_frames_on_the_tool_id_are_not_tool_frames() -> None:
    echo = EchoFilter([INTERFACE.frame_key("test_torque")])
    request_id, _ = INTERFACE.frame_key("test_torque")
    remote = can.Message(arbitration_id=request_id, is_extended_id=False, is_remote_frame=True)
    error = can.Message(arbitration_id=request_id, is_extended_id=False, is_error_frame=True)
    assert echo.is_tool_frame(_request(1))
    assert not echo.is_tool_frame(remote) and not echo.is_tool_frame(error)


def test_identical_frames_sent_twice_have_two_echoes() -> None:
    echo = EchoFilter([INTERFACE.frame_key("test_torque")])
    for _ in range(2):
        echo.expect(_request(5))
    assert echo.is_echo(_request(5)) and echo.is_echo(_request(5))
    assert not echo.is_echo(_request(5))


def test_echo_expected_too_long_ago_is_foreign() -> None:
    echo = EchoFilter([INTERFACE.frame_key("test_torque")], window_s=-1.0)
    echo.expect(_request(6))
    assert not echo.is_echo(_request(6))
