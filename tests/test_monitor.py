"""`dtid monitor`: the live view, folded from a session's events and read off a tmux screen."""

from __future__ import annotations

import shlex
import shutil
import subprocess
import sys
import tempfile
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from test_worker import (  # the worker tests' simulated session and fake daemon
    BUDGET,
    PLAN,
    FakeDaemon,
    SimulatedSession,
    _config_file,
    _pipeline,
    _serve,
    session,  # noqa: F401  (a fixture)
)

from dtid.dbc.loader import load_interface
from dtid.identification.frf.closed_loop import estimate_frf
from dtid.identification.frf.runs import find_runs
from dtid.identification.service.live import LiveSession
from dtid.identification.service.monitor import MonitorState, building_frf, render
from dtid.identification.service.worker import WorkerOptions

TMUX = shutil.which("tmux")


def test_the_page_follows_the_session(session: SimulatedSession) -> None:  # noqa: F811
    """Half-way: the phase, the swept frequency and the time left in bus time; at the end: done,
    nothing left, and how it ended."""
    state = MonitorState()
    events = session.events
    middle = next(
        i for i, e in enumerate(events) if e["kind"] == "phase" and e["chirp"] == 1
    )  # chirp 2 begins
    for event in events[: middle + 41]:  # 40 samples events of 0.25 s: 10 s into chirp 2
        state.apply_event(event)
    page = "\n".join(render(state))
    chirp = PLAN.chirps[1]
    assert f"phase chirp 2/3 at {chirp.amplitude_nm:g} N*m" in page
    tau = state.last_t - state.phase_t
    swept = chirp.f1_hz + (chirp.f2_hz - chirp.f1_hz) * tau / chirp.duration_s
    assert f"sweeping {swept:.1f} Hz" in page
    assert 9.0 < tau <= 10.5
    left = PLAN.end_s - (state.last_t - state.start_t)
    assert f"test time left {left:.0f} s of {PLAN.end_s:.0f} s" in page
    speed = next(
        e["roles"]["speed"]["value"][-1]
        for e in reversed(events[: middle + 41])
        if e["kind"] == "samples" and "speed" in e["roles"]
    )
    assert f"speed {speed:.1f} rpm" in page
    for event in reversed(events):  # the rest, in reverse: order does not matter
        state.apply_event(event)
    page = "\n".join(render(state))
    assert "phase done" in page and "test time left 0 s" in page
    assert "test ended: completed" in page
    assert len(state.seqs) == len(events)


def test_the_chirp_being_swept_shows_its_frf_so_far(session: SimulatedSession) -> None:  # noqa: F811
    """Fourteen seconds into the 20 s chirp 2 (1 -> 10.8 Hz swept, whole to 8 Hz): its |G_DRV|
    so far is the whole chirp's where neither sits at a segment's edge, and the page draws it."""
    events = session.events
    start = next(i for i, e in enumerate(events) if e["kind"] == "phase" and e["chirp"] == 1)
    live, state = LiveSession(events[0], load_interface()), MonitorState()
    for event in events[: start + 57]:
        state.apply_event(event)
        if event["kind"] != "session":
            live.apply(event)
    chirp = PLAN.chirps[1]
    building = building_frf(live, chirp, state.phase_t, state.last_t)
    assert building is not None and 10.3 < building["to_hz"] < 11.3
    for event in events[start + 57 :]:
        live.apply(event)
    data = live.test_data()
    whole = estimate_frf(data, find_runs(data.test_torque)[1])
    f, db = np.asarray(building["frequency_hz"]), np.asarray(building["drv_db"])
    sweep = (chirp.f2_hz - chirp.f1_hz) / chirp.duration_s / live.resolution_hz  # Hz a segment
    assert f[0] >= chirp.f1_hz and f[-1] <= building["to_hz"] - sweep + 1e-9 and len(f) > 20
    inner = f >= chirp.f1_hz + sweep  # the whole chirp's own estimate is edgy below
    difference = np.abs(db - np.interp(f, whole.frequency_hz, whole.drv_db))[inner]
    assert inner.sum() > 10 and difference.max() < 0.5
    state.building = building
    page = "\n".join(render(state, width=110))
    assert f"* = 10 N*m so far, to {building['to_hz']:.1f} Hz" in page
    assert "*" in "".join(line[9:] for line in page.splitlines() if line[7:9] == " |")


def test_an_abort_names_its_reason() -> None:
    state = MonitorState()
    state.apply_event({"kind": "session", "session": "s", "seq": 0, "plan": {}})
    state.apply_event({"kind": "end", "session": "s", "seq": 1, "status": "aborted",
                       "reason": "speed_window", "t_s": 3.0})  # fmt: skip
    page = "\n".join(render(state, width=200))
    assert "test ended: aborted (speed_window: the filtered engine speed left the window" in page


def test_a_monitor_that_missed_the_first_events_asks_the_replay_for_them(
    session: SimulatedSession,  # noqa: F811
) -> None:
    """Started before the daemon, the monitor asked the replay while it held nothing, and its
    subscription joined the stream after the session event: it asks again from the first event
    missing. (Without this, `dtid monitor --until-finished` ended on a busy host with a page
    that never left "waiting for the daemon", CI of 2026-12-07.)"""
    import json
    import threading

    import zmq

    from dtid.identification.service.monitor import Monitor

    folder = Path(tempfile.mkdtemp(prefix="dtidr-", dir="/tmp"))
    pipeline = _pipeline(folder)
    context = zmq.Context.instance()
    rep = context.socket(zmq.REP)
    rep.bind(pipeline.replay)
    asked: list[int] = []

    def serve() -> None:  # nothing kept at the first request; all of it at the next
        for answer in ([], session.events):
            if not rep.poll(20_000):
                return
            asked.append(json.loads(rep.recv())["from_seq"])
            rep.send(json.dumps([e for e in answer if e["seq"] >= asked[-1]]).encode())

    thread = threading.Thread(target=serve)
    thread.start()
    monitor = Monitor(pipeline)
    try:
        monitor.poll(0.5)  # the first request, answered with nothing
        for event in session.events[3:]:  # the stream as the late subscription saw it
            monitor._event(event)
        assert monitor.state.session is None
        for _ in range(100):  # a bound on the wait, not a timing asserted
            monitor.poll(0.2)
            if monitor.state.session is not None:
                break
    finally:
        monitor.close()
        thread.join(25)
        rep.close(linger=0)
        shutil.rmtree(folder, ignore_errors=True)
    assert asked == [0, 0]  # the gap starts at the session event, seq 0
    assert monitor.state.session == "s1" and monitor.state.end is not None


@pytest.fixture
def tmux() -> Iterator[list[str]]:
    """A tmux server of the test's own (its socket name), killed afterwards."""
    if TMUX is None:
        pytest.skip("tmux is not installed (apt install tmux)")
    command = [TMUX, "-L", f"dtid-{uuid.uuid4().hex[:8]}"]
    yield command
    subprocess.run([*command, "kill-server"], check=False, capture_output=True)


def _screen(tmux: list[str]) -> str:
    result = subprocess.run(
        [*tmux, "capture-pane", "-p", "-t", "monitor"], check=False, capture_output=True
    )
    return result.stdout.decode()


def _wait_for(tmux: list[str], *texts: str, timeout_s: float = 90.0) -> str:
    """The screen once it shows every text (a bound on a wait, not a timing asserted)."""
    deadline = time.monotonic() + timeout_s
    while True:
        screen = _screen(tmux)
        if all(text in screen for text in texts) or time.monotonic() > deadline:
            return screen
        time.sleep(0.2)


def test_the_monitor_in_tmux_shows_the_test_and_its_result(
    session: SimulatedSession,  # noqa: F811
    tmux: list[str],
) -> None:
    """`dtid monitor` in a 110 x 60 terminal while a paced session streams and the worker
    identifies: the screen read back holds the phase, the counters, the three chirps' |G_DRV|,
    the identified parameters and the end."""
    folder = Path(tempfile.mkdtemp(prefix="dtidm-", dir="/tmp"))
    pipeline = _pipeline(folder)
    config = _config_file(folder, pipeline)
    monitor = [sys.executable, "-m", "dtid.cli", "monitor", "--config", str(config),
               "--refresh", "0.2", "--until-finished"]  # fmt: skip
    shell = f"{shlex.join(monitor)}; echo monitor-exit=$?; sleep 600"
    subprocess.run(
        [*tmux, "new-session", "-d", "-s", "monitor", "-x", "110", "-y", "60", shell], check=True
    )
    daemon = None
    try:
        waiting = _wait_for(tmux, "waiting for the daemon", timeout_s=60.0)
        assert "waiting for the daemon" in waiting, waiting
        daemon = FakeDaemon(pipeline, session.events, bus_per_wall=20.0)
        daemon.go.set()
        out = folder / "out"
        out.mkdir()
        options = WorkerOptions(
            settings=BUDGET, profile_points=0, json_path=out / "id.json", plot=False
        )
        status, messages, _ = _serve(pipeline, options, timeout_s=120.0)
        assert status == 0
        screen = _wait_for(tmux, "monitor-exit=0")
    finally:
        if daemon is not None:
            daemon.close()
        shutil.rmtree(folder, ignore_errors=True)
    assert "monitor-exit=0" in screen, screen
    result = next(doc for topic, doc in messages if topic == "result")
    assert "session s1" in screen and "phase done" in screen
    assert "lost 0 | duplicated 0 | out of order 0" in screen
    assert "chirps (1 = 5 N*m, 2 = 10 N*m, 3 = 2 N*m)" in screen
    plot = [
        line for line in screen.splitlines() if " |" in line and line.strip()[0] in "-0123456789"
    ]
    assert len(plot) == 9 and all(mark in "".join(plot) for mark in "123")
    assert f"c12 {result['parameters']['c12']:.4g}" in screen
    validation = next(iter(result["nrmse"]["validation"].values()))
    assert f"validation NRMSE {validation:.3f}" in screen
    assert "test ended: completed" in screen
