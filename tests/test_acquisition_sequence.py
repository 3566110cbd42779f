"""The tool's frames of a test: the same as a simulated test's; phases; the DBC's tool states."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from dtid.acquisition.plan import TestPlan, tool_requests
from dtid.acquisition.sequence import ToolFrames, phases
from dtid.dbc import tool_state
from dtid.dbc.checksum import verify_checksum
from dtid.dbc.loader import load_interface
from dtid.errors import ConfigError
from dtid.simulator.vehicle_frames import simulation_frames

INTERFACE = load_interface()
PLAN = TestPlan(
    amplitudes_nm=(5.0, 10.0, 2.0), validation_nm=0.0, duration_s=1.0, settle_s=0.3, pause_s=0.2
)


def tool_frames_of_a_simulated_test(plan: TestPlan) -> list[tuple[int, bytes, float]]:
    """The tool's frames :func:`simulation_frames` writes for a test (no ECU frames)."""
    request_t, request_nm = tool_requests(plan)
    empty = np.zeros(0)
    result = SimpleNamespace(
        plan=plan,
        request_t=request_t,
        test_torque_nm=request_nm,
        speed_t=empty,
        speed_rpm=empty,
        torque_request_nm=empty,
        torque_t=empty,
        mean_torque_nm=empty,
        cylinder=empty,
    )
    frames = simulation_frames(result, INTERFACE)
    return [(f.arbitration_id, bytes(f.data), f.timestamp) for f in frames]


def test_daemon_sends_the_frames_of_a_simulated_test() -> None:
    tool = ToolFrames(INTERFACE, PLAN)
    requests = [tool.request(k, k, t) for k, t in enumerate(tool.request_times)]
    beats = [
        tool.heartbeat(int(state), j, t)
        for j, (t, state) in enumerate(
            zip(tool.heartbeat_times, tool.heartbeat_states, strict=True)
        )
    ]
    frames = sorted(requests + beats, key=lambda frame: frame.timestamp)
    ours = [(f.arbitration_id, bytes(f.data), f.timestamp) for f in frames]
    assert ours == tool_frames_of_a_simulated_test(PLAN)
    assert not any(f.is_rx for f in frames)
    assert all(verify_checksum(f.data) for f in requests)
    counters = INTERFACE.decode(requests)["test_torque"].extra["counter"]
    assert counters.tolist() == [k % 16 for k in range(len(requests))]


def test_zero_request_disables_and_keeps_the_counter() -> None:
    tool = ToolFrames(INTERFACE, PLAN)
    frame = tool.zero_request(37, 1.0)
    decoded = INTERFACE.decode([frame])["test_torque"]
    assert decoded.values.tolist() == [0.0]
    assert decoded.extra["enable"].tolist() == [0]
    assert decoded.extra["counter"].tolist() == [37 % 16]
    assert verify_checksum(frame.data)


def test_phases_follow_the_plan() -> None:
    names = [(p.name, p.chirp, p.amplitude_nm) for p in phases(PLAN)]
    assert names == [
        ("settle", None, None),
        ("chirp", 0, 5.0),
        ("pause", None, None),
        ("chirp", 1, 10.0),
        ("pause", None, None),
        ("chirp", 2, 2.0),
        ("pause", None, None),
        ("done", None, None),
    ]
    starts = [p.start_s for p in phases(PLAN)]
    assert starts == sorted(starts) and starts[-1] == PLAN.end_s


def test_phases_without_settle_and_pauses() -> None:
    plan = TestPlan(
        amplitudes_nm=(5.0, 10.0), validation_nm=0.0, duration_s=1.0, settle_s=0.0, pause_s=0.0
    )
    assert [(p.name, p.start_s) for p in phases(plan)] == [
        ("chirp", 0.0),
        ("chirp", 1.0),
        ("done", 2.0),
    ]


def test_tool_states_are_the_dbc_value_table() -> None:
    signal = INTERFACE.database.get_message_by_name("ToolHeartbeat").get_signal_by_name("ToolState")
    table = {int(value): str(name) for value, name in signal.choices.items()}
    assert table == {
        tool_state.TOOL_IDLE: "idle",
        tool_state.TOOL_SETTLING: "settling",
        tool_state.TOOL_CHIRP: "chirp",
        tool_state.TOOL_ABORT: "abort",
        tool_state.TOOL_DONE: "done",
    }
    message = INTERFACE.database.get_message_by_name("ToolHeartbeat")
    assert message.cycle_time == round(tool_state.HEARTBEAT_PERIOD_S * 1000)


def test_request_the_dbc_cannot_carry_is_refused_before_the_test() -> None:
    with pytest.raises(ConfigError, match="TestTorque"):
        ToolFrames(INTERFACE, TestPlan(amplitudes_nm=(400.0,), validation_nm=0.0))


@pytest.mark.parametrize(
    ("fields", "why"),
    [
        ({"duration_s": 0.5}, "a chirp of 0.5 s holds less than one period of its start frequency"),
        ({"duration_s": 0.5, "f1_hz": 2.0}, None),  # one period of 2 Hz: a (short) chirp
        ({"duration_s": 1e6}, "take 3.00001e+06 s, more than the 3600 s a test at idle may"),
        ({"pause_s": 1200.0}, "more than the 3600 s"),
    ],
)
def test_a_plan_shorter_than_a_period_or_longer_than_an_hour_is_refused(
    fields: dict[str, float], why: str | None
) -> None:
    """`dtid simulate --duration 1e6` computed for days; `--duration 0.01` wrote a recording
    of chirps that sweep nothing."""
    if why is None:
        assert TestPlan(**fields).chirps[0].duration_s == fields["duration_s"]
        return
    with pytest.raises(ConfigError, match=why.replace("+", r"\+")):
        TestPlan(**fields)
