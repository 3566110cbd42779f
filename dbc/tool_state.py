"""Facts of the product DBC about the test tool's own messages.

``ToolHeartbeat`` (0x6A1) carries the state of the tool's test sequence; its ``VAL_`` table in
``drivetrain.dbc`` names the values below. The tool sends it every 100 ms
(``GenMsgCycleTime``); the test torque request ``TestTorqueRequest`` (0x6A0) goes every
``request_period_s`` of the test plan (10 ms by default).
"""

HEARTBEAT_PERIOD_S = 0.1
"""Period of the tool's heartbeat, s."""

TOOL_IDLE = 0
"""Heartbeat state: no test running."""
TOOL_SETTLING = 1
"""Heartbeat state: at idle before a chirp (settle phase and the pauses between chirps)."""
TOOL_CHIRP = 2
"""Heartbeat state: a chirp is being requested."""
TOOL_ABORT = 3
"""Heartbeat state: the test was aborted; the request is zero."""
TOOL_DONE = 4
"""Heartbeat state: the last chirp has ended."""
