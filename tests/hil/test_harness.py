"""The harness itself: scenario configuration files and the process group of a scenario."""

from __future__ import annotations

import os
import signal
import tomllib
from pathlib import Path

import pytest

from dtid.acquisition.config import AcquisitionConfig
from hil.config import toml_document, toml_value, write_scenario_config
from hil.namespace import ROOT, HilBus, parse_hil_bus
from hil.processes import Processes


def test_scenario_config_loads_with_the_bus_and_private_endpoints(tmp_path: Path) -> None:
    bus = parse_hil_bus("udp_multicast:239.74.163.2:43999")
    path, config = write_scenario_config(
        tmp_path,
        bus,
        {"test": {"amplitudes_nm": [5, 10], "duration_s": 20.0}, "bus": {"time_factor": 20.0}},
    )
    assert isinstance(config, AcquisitionConfig)
    assert (config.bus.interface, config.bus.channel) == ("udp_multicast", "239.74.163.2")
    assert config.bus.options == {"port": 43999}
    assert config.bus.time_factor == 20.0
    assert config.test.amplitudes_nm == (5.0, 10.0) and config.test.duration_s == 20.0
    assert config.output.directory == tmp_path / "runs" and config.output.directory.is_dir()
    for name in ("blocks", "replay", "results"):
        assert getattr(config.pipeline, name) == f"ipc://{tmp_path}/ipc/{name}"
    assert (tmp_path / "ipc").is_dir()
    assert tomllib.loads(path.read_text())["bus"]["receive_buffer_bytes"] == 4 << 20


def test_scenario_config_refuses_an_endpoint_too_long_for_a_unix_socket(tmp_path: Path) -> None:
    deep = tmp_path / ("x" * 120)
    with pytest.raises(ValueError, match="longer than a Unix socket path"):
        write_scenario_config(deep, HilBus("socketcan", "vcan0"))


def test_toml_values_round_trip() -> None:
    document = {
        "a": {"s": 'q"uote\\', "i": 3, "f": 0.25, "b": True, "l": [1, 2.5], "t": {"port": 1}},
        "empty": {"options": {}},
    }
    assert tomllib.loads(toml_document(document)) == document
    with pytest.raises(ValueError, match="finite"):
        toml_value(float("nan"))


def test_processes_run_the_work_tree_and_stop_together(tmp_path: Path) -> None:
    with Processes(tmp_path, env={"DTID_MARK": "x"}) as procs:
        procs.python(
            "probe", "-c", "import os, dtid; print(dtid.__file__, os.environ['DTID_MARK'])"
        )
        assert procs.wait("probe", timeout=60) == 0
        procs.python("echo", "-c", "print('got', input(), flush=True)", stdin=True)
        procs.send_line("echo", "hello")
        assert procs.wait_for_line("echo", "got", timeout=60) == "got hello"
        procs.python("sleeper", "-c", "import time; print('up', flush=True); time.sleep(60)")
        assert procs.wait_for_line("sleeper", "up", timeout=60) == "up"
        with pytest.raises(TimeoutError, match="still running"):
            procs.wait("sleeper", timeout=0.1)
    path, mark = procs.output("probe").split()
    assert Path(path).resolve().is_relative_to(ROOT) and mark == "x"
    assert procs.running["sleeper"].returncode == -signal.SIGTERM  # stopped on leaving
    assert "DTID_MARK" not in os.environ


def test_wait_for_line_reports_a_process_that_ended_without_it(tmp_path: Path) -> None:
    with Processes(tmp_path) as procs:
        procs.python("quits", "-c", "import sys; sys.exit('bad config')")
        with pytest.raises(TimeoutError, match=r"quits ended without printing 'ready'(.|\n)*bad"):
            procs.wait_for_line("quits", "ready", timeout=60)
