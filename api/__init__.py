"""drivetrain-id: chirp-test identification of a vehicle drivetrain's physical parameters.

The Python API (:mod:`dtid.workflow`) is at the top of the package::

    import dtid

    recording = dtid.read_recording("test.blf", dbc="vehicle.dbc", signals="signals.toml")
    estimates = dtid.frf(recording)
    report = dtid.identify(["test.blf"], dbc="vehicle.dbc", signals="signals.toml")
    report.parameters, report.intervals, report.to_json("result.json"), report.plot()

The layers below it, in the order the data flow (docs/layout.md): :mod:`dtid.dbc` (the vehicle's
CAN interface), :mod:`dtid.acquisition` (the test on the bus, the recording),
:mod:`dtid.simulator` (the paper's plant and the virtual vehicle), :mod:`dtid.identification`
(samples, FRFs, the model side, the search, the uncertainty, the worker service), and
:mod:`dtid.cli` (the ``dtid`` command). The API is imported on first use, so that
``import dtid.errors`` from any layer stays cheap and free of cycles.
"""

from __future__ import annotations

from typing import Any

__all__ = ["frf", "identify", "measured_tests", "read_recording"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        from dtid import workflow

        return getattr(workflow, name)
    raise AttributeError(f"module 'dtid' has no attribute {name!r}")
