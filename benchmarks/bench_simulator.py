"""Simulator speed benchmark: simulated seconds per wall second, single and batched, and the
same closed loop integrated with ``scipy.integrate.solve_ivp`` for comparison and agreement.

Run from the repository root::

    PYTHONPATH=. python benchmarks/bench_simulator.py [--quick]

Measures (wall time with ``time.perf_counter``, best of N repeats for the kernel, a single run
for solve_ivp, whose seconds make timer noise irrelevant; numba compilation excluded and
reported separately, measured in a fresh interpreter with an empty numba cache):

(a) :func:`dtid.simulator.simulate.simulate` for the reference vehicle and the default test plan
    (192 s simulated, engine pulsation, combustion variation and sensor noise on), one thread;
(b) :func:`dtid.simulator.simulate.simulate_batch` with 64 parameter sets (the identification's
use),
    on one thread and on all cores;
(c) :func:`benchmarks.solve_ivp_plant.simulate_solve_ivp` (RK45, and LSODA) on a 10 N*m chirp
    with clean options, against the kernel on the same chirp, and the agreement of the two:
    filtered-speed difference and |G_DRV| of
    :func:`dtid.identification.frf.closed_loop.estimate_frf`.

Prints a markdown table for the README and writes the figures to
``benchmarks/results/simulator.json``. A benchmark, not a test: nothing is asserted.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numba
import numpy as np
import scipy
from scipy.interpolate import CubicSpline

import dtid.simulator.simulate as simulate_module
from benchmarks.solve_ivp_plant import IvpSettings, simulate_solve_ivp
from dtid.acquisition.plan import TestPlan
from dtid.errors import AnalysisError
from dtid.identification.frf.closed_loop import FrfEstimate, estimate_frf
from dtid.identification.frf.runs import find_runs
from dtid.identification.samples.testdata import Series, from_simulation
from dtid.simulator.angle_grid import STEPS_PER_SPEED_SAMPLE
from dtid.simulator.parameters import INDEX, reference_parameters
from dtid.simulator.simulate import SimulationOptions, SimulationResult, simulate, simulate_batch

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results" / "simulator.json"

BATCH_JOBS = 64
"""Jobs of the batched measurement: one differential-evolution generation of the identification."""
BATCH_SPREAD = 0.2
"""Parameter sets of the batch: the reference times exp(U(-0.2, 0.2)) on the coupling parameters."""
BATCH_AMPLITUDES_NM = (5.0, 10.0)
"""The two identification amplitudes, alternating over the batch's jobs, N*m."""
AGREEMENT_AMPLITUDE_NM = 10.0
"""Chirp amplitude of the solve_ivp comparison, N*m."""
COHERENCE_MIN = 0.9
"""|G_DRV| is compared where both estimates have at least this coherence (the top bins of a
clean chirp fall below it: the response there is dominated by the engine orders and the
nonlinearity, not by the chirp, and both estimates scatter by dB)."""

COMPILE_PROBE = """
import json, time
t0 = time.perf_counter()
import numpy as np
from dtid.acquisition.plan import TestPlan
from dtid.simulator.parameters import reference_parameters
from dtid.simulator.simulate import simulate, simulate_batch
t1 = time.perf_counter()
p = reference_parameters()
plan = TestPlan(amplitudes_nm=(5.0,), validation_nm=0.0, duration_s=1.0, settle_s=0.5, pause_s=0.5)
laps = []
for _ in range(2):
    s = time.perf_counter(); simulate(p, plan); laps.append(time.perf_counter() - s)
params = np.repeat(p.as_array()[None, :], 2, axis=0)
for _ in range(2):
    s = time.perf_counter(); simulate_batch(params, np.ones(2), plan)
    laps.append(time.perf_counter() - s)
print(json.dumps({"import_s": t1 - t0, "single_s": laps[0] - laps[1],
                  "batch_s": laps[2] - laps[3]}))
"""


def best_of(function: Callable[[], object], repeats: int) -> tuple[float, object]:
    """Run ``function`` ``repeats`` times; return the shortest wall time, s, and the last result."""
    best = float("inf")
    result = None
    for _ in range(repeats):
        start = time.perf_counter()
        result = function()
        best = min(best, time.perf_counter() - start)
    return best, result


def cpu_model() -> str:
    """The CPU's model name from /proc/cpuinfo (the platform's processor string elsewhere)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def environment() -> dict[str, Any]:
    """Machine, versions, date and the load before the run."""
    return {
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "cpu_model": cpu_model(),
        "logical_cpus": os.cpu_count(),
        "numba_threads_max": numba.config.NUMBA_NUM_THREADS,
        "load_average_1min_at_start": os.getloadavg()[0],
        "python": platform.python_version(),
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "numba": numba.__version__,
        "platform": platform.platform(),
    }


def measure_compile() -> dict[str, float]:
    """Numba compile times from an empty cache, measured in a fresh interpreter, s."""
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache, "PYTHONPATH": str(REPO)}
        done = subprocess.run(
            [sys.executable, "-c", COMPILE_PROBE],
            env=env,
            capture_output=True,
            text=True,
            check=True,
            cwd=REPO,
        )
    return json.loads(done.stdout.strip().splitlines()[-1])


def measure_single(repeats: int) -> dict[str, float]:
    """(a) simulate(): reference vehicle, default plan and options, one thread."""
    parameters, plan, options = (
        reference_parameters(),
        TestPlan(amplitudes_nm=(2.0, 5.0, 10.0), validation_nm=0.0),
        SimulationOptions(),
    )
    kernel_times: list[float] = []
    original = simulate_module.run_plant

    def timed_kernel(*args: object) -> object:
        start = time.perf_counter()
        out = original(*args)
        kernel_times.append(time.perf_counter() - start)
        return out

    wall, result = best_of(lambda: simulate(parameters, plan, options), repeats)
    simulate_module.run_plant = timed_kernel  # the kernel's share of simulate()
    try:
        best_of(lambda: simulate(parameters, plan, options), repeats)
    finally:
        simulate_module.run_plant = original
    steps = len(result.speed_t) * STEPS_PER_SPEED_SAMPLE
    kernel = min(kernel_times)
    return {
        "simulated_s": plan.end_s,
        "angle_steps": steps,
        "wall_s": wall,
        "realtime_factor": plan.end_s / wall,
        "ns_per_step": wall / steps * 1e9,
        "kernel_wall_s": kernel,
        "kernel_realtime_factor": plan.end_s / kernel,
        "kernel_ns_per_step": kernel / steps * 1e9,
    }


def batch_inputs(n_jobs: int) -> tuple[np.ndarray, np.ndarray]:
    """Parameter sets spread around the reference vehicle and their chirp amplitudes."""
    rng = np.random.default_rng(1)
    params = np.repeat(reference_parameters().as_array()[None, :], n_jobs, axis=0)
    for name in ("c12", "c23", "d12", "d23", "Tc12", "eps12", "eps23"):
        params[:, INDEX[name]] *= np.exp(rng.uniform(-BATCH_SPREAD, BATCH_SPREAD, n_jobs))
    amplitudes = np.resize(np.array(BATCH_AMPLITUDES_NM), n_jobs)
    return params, amplitudes


def measure_batch(threads: int, repeats: int, n_jobs: int) -> dict[str, float]:
    """(b) simulate_batch() of ``n_jobs`` single-chirp tests on ``threads`` threads."""
    plan = TestPlan(amplitudes_nm=(2.0, 5.0, 10.0), validation_nm=0.0)
    params, amplitudes = batch_inputs(n_jobs)
    numba.set_num_threads(threads)
    try:
        wall, batch = best_of(lambda: simulate_batch(params, amplitudes, plan), repeats)
    finally:
        numba.set_num_threads(1)
    simulated = n_jobs * (plan.settle_s + plan.duration_s + plan.pause_s)  # one chirp per job
    return {
        "threads": threads,
        "jobs": n_jobs,
        "simulated_s_per_job": simulated / n_jobs,
        "failed_jobs": int(np.count_nonzero(batch.status)),
        "wall_s": wall,
        "jobs_per_s": n_jobs / wall,
        "realtime_factor": simulated / wall,
    }


def agreement_plan(quick: bool) -> TestPlan:
    """The chirp of the solve_ivp comparison: 10 N*m, 1-15 Hz, 30 s (10 s with --quick)."""
    return TestPlan(
        amplitudes_nm=(AGREEMENT_AMPLITUDE_NM,),
        validation_nm=0.0,
        duration_s=10.0 if quick else 30.0,
        settle_s=3.0,
        pause_s=3.0,
    )


def frf(result: SimulationResult) -> FrfEstimate:
    """|G_DRV| of the one chirp run of a simulated test."""
    data = from_simulation(result)
    runs = find_runs(Series(result.request_t, result.test_torque_nm))
    return estimate_frf(data, runs[0])


def compare(kernel: SimulationResult, other: SimulationResult) -> dict[str, float]:
    """Filtered-speed and |G_DRV| differences, kernel minus ``other``."""
    n = min(len(kernel.speed_t), len(other.speed_t))
    diff = kernel.speed_rpm[:n] - other.speed_rpm[:n]  # same crank angle, sample by sample
    inside = kernel.speed_t < other.speed_t[-1]
    aligned = kernel.speed_rpm[inside] - CubicSpline(other.speed_t, other.speed_rpm)(
        kernel.speed_t[inside]
    )
    out = {
        "speed_rms_rpm": float(np.sqrt(np.mean(diff**2))),
        "speed_max_rpm": float(np.max(np.abs(diff))),
        "speed_mean_rpm": float(np.mean(diff)),
        "speed_rms_time_aligned_rpm": float(np.sqrt(np.mean(aligned**2))),
        "speed_response_rms_rpm": float(np.std(kernel.speed_rpm[:n])),
        "time_skew_at_end_s": float(kernel.speed_t[n - 1] - other.speed_t[n - 1]),
        "delta12_rms_rad": float(
            np.sqrt(np.mean((kernel.delta12_rad[:n] - other.delta12_rad[:n]) ** 2))
        ),
    }
    try:
        mine, theirs = frf(kernel), frf(other)
    except AnalysisError as error:  # a run too short for the FRF: report it, go on
        out["frf_error"] = str(error)
        return out
    db = mine.drv_db - theirs.drv_db
    coherent = (mine.coherence >= COHERENCE_MIN) & (theirs.coherence >= COHERENCE_MIN)
    out.update(
        {
            "frf_band_hz": [float(mine.frequency_hz[0]), float(mine.frequency_hz[-1])],
            "frf_bins": len(db),
            "drv_db_rms_all_bins": float(np.sqrt(np.mean(db**2))),
            "drv_db_max_all_bins": float(np.max(np.abs(db))),
            "coherent_bins": int(np.count_nonzero(coherent)),
            "drv_db_rms": float(np.sqrt(np.mean(db[coherent] ** 2))),
            "drv_db_max": float(np.max(np.abs(db[coherent]))),
            "drv_db_mean": float(np.mean(db[coherent])),
        }
    )
    return out


def measure_solve_ivp(quick: bool, repeats: int) -> dict[str, Any]:
    """(c) kernel vs solve_ivp (RK45, LSODA) on the same clean chirp: speed and agreement."""
    parameters, plan = reference_parameters(), agreement_plan(quick)
    options = SimulationOptions.clean()
    wall, kernel = best_of(lambda: simulate(parameters, plan, options), repeats)
    out: dict[str, Any] = {
        "plan": {
            "amplitude_nm": AGREEMENT_AMPLITUDE_NM,
            "duration_s": plan.duration_s,
            "f1_hz": plan.f1_hz,
            "f2_hz": plan.f2_hz,
            "simulated_s": plan.end_s,
        },
        "kernel": {"wall_s": wall, "realtime_factor": plan.end_s / wall},
    }
    results: dict[str, SimulationResult] = {}
    for label, settings in (("rk45", IvpSettings()), ("lsoda", IvpSettings.lsoda())):
        result, stats = simulate_solve_ivp(parameters, plan, options, settings=settings)
        results[label] = result
        out[label] = {
            **stats.as_dict(),
            "realtime_factor": plan.end_s / stats.wall_s,
            "kernel_speedup": stats.wall_s / wall,
            "agreement_with_kernel": compare(kernel, result),
        }
    out["rk45_vs_lsoda"] = compare(results["rk45"], results["lsoda"])
    if not quick:  # diagnosis: the engine tables read as the kernel reads them
        result, stats = simulate_solve_ivp(
            parameters, plan, options, settings=IvpSettings(hold_table=True)
        )
        out["rk45_table_hold"] = {
            **stats.as_dict(),
            "agreement_with_kernel": compare(kernel, result),
        }
    return out


def markdown(report: dict[str, Any]) -> str:
    """The README table of the measured figures."""
    single, batch1, batchn = report["single"], report["batch_1_thread"], report["batch_all_threads"]
    ivp = report["solve_ivp"]
    compile_s = report["compile"]
    plan = ivp["plan"]
    rk45, lsoda = ivp["rk45"], ivp["lsoda"]
    rows = [
        "| Measurement | Simulated | Wall | Simulated s / wall s | Notes |",
        "|---|---|---|---|---|",
        "| `simulate()`, reference vehicle, default plan, 1 thread "
        f"| {single['simulated_s']:.0f} s "
        f"| {single['wall_s'] * 1e3:.1f} ms | **{single['realtime_factor']:,.0f}x** "
        f"| {single['ns_per_step']:.0f} ns per angle step ({single['angle_steps']:,} steps); "
        f"kernel alone {single['kernel_realtime_factor']:,.0f}x, "
        f"{single['kernel_ns_per_step']:.0f} ns/step |",
    ]
    for b in (batch1, batchn):
        rows.append(
            f"| `simulate_batch()`, {b['jobs']} jobs, {b['threads']} "
            f"thread{'s' if b['threads'] > 1 else ''} "
            f"| {b['jobs']} x {b['simulated_s_per_job']:.0f} s | {b['wall_s']:.2f} s "
            f"| **{b['realtime_factor']:,.0f}x** | {b['jobs_per_s']:.0f} jobs/s |"
        )
    sim = plan["simulated_s"]
    rows.append(
        f"| kernel, {plan['amplitude_nm']:.0f} N*m chirp {plan['duration_s']:.0f} s, clean "
        f"| {sim:.0f} s | {ivp['kernel']['wall_s'] * 1e3:.1f} ms "
        f"| {ivp['kernel']['realtime_factor']:,.0f}x | same chirp as the solve_ivp rows |"
    )
    for label, r in (("RK45", rk45), ("LSODA", lsoda)):
        rows.append(
            f"| `solve_ivp` {label}, rtol {r['rtol']:g}, atol {r['atol']:g}, same chirp "
            f"| {sim:.0f} s | {r['wall_s']:.1f} s | {r['realtime_factor']:.1f}x "
            f"| kernel **{r['kernel_speedup']:,.0f}x** faster; {r['steps']:,} steps, "
            f"{r['nfev']:,} RHS calls |"
        )
    rows.append("")
    rows.append(
        f"Targets: 10,000x real time on one core, reached {single['realtime_factor']:,.0f}x; "
        f"at least 300x faster than solve_ivp, reached {rk45['kernel_speedup']:,.0f}x (RK45) "
        f"and {lsoda['kernel_speedup']:,.0f}x (LSODA). Compilation with an empty numba cache, "
        f"excluded above: first `simulate()` {compile_s['single_s']:.1f} s, first "
        f"`simulate_batch()` {compile_s['batch_s']:.1f} s; loading from the cache "
        f"{report['warmup_s']:.2f} s."
    )
    rows.append("")
    rows.append(
        "| Agreement with the kernel (same chirp) | Speed RMS diff | Speed max diff "
        f"| \\|G_DRV\\| RMS / max diff, coherence >= {COHERENCE_MIN} "
        "| \\|G_DRV\\| RMS / max diff, all bins |"
    )
    rows.append("|---|---|---|---|---|")
    pairs = [
        ("solve_ivp RK45", rk45["agreement_with_kernel"]),
        ("solve_ivp LSODA", lsoda["agreement_with_kernel"]),
    ]
    if "rk45_table_hold" in ivp:
        pairs.append(
            (
                "solve_ivp RK45, tables held per step as in the kernel",
                ivp["rk45_table_hold"]["agreement_with_kernel"],
            )
        )
    pairs.append(("RK45 vs LSODA (solver spread)", ivp["rk45_vs_lsoda"]))
    for label, a in pairs:
        frf_cells = (
            f"{a['drv_db_rms']:.2f} / {a['drv_db_max']:.2f} dB ({a['coherent_bins']} of "
            f"{a['frf_bins']} bins) | {a['drv_db_rms_all_bins']:.2f} / "
            f"{a['drv_db_max_all_bins']:.2f} dB"
            if "drv_db_rms" in a
            else f"n/a: {a.get('frf_error', '')} | n/a"
        )
        rows.append(
            f"| {label} | {a['speed_rms_rpm']:.3f} rpm (response {a['speed_response_rms_rpm']:.1f} "
            f"rpm rms) | {a['speed_max_rpm']:.2f} rpm | {frf_cells} |"
        )
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark, print the table, write the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--quick",
        action="store_true",
        help="fewer repeats and a 10 s chirp for solve_ivp (about a minute)",
    )
    parser.add_argument("--output", type=Path, default=RESULTS, help="JSON file to write")
    args = parser.parse_args(argv)
    repeats = 3 if args.quick else 10
    all_threads = numba.config.NUMBA_NUM_THREADS

    report: dict[str, Any] = {"environment": environment(), "quick": args.quick}
    print(
        f"# simulator benchmark on {report['environment']['cpu_model']} "
        f"({all_threads} threads), numba {numba.__version__}, scipy {scipy.__version__}",
        flush=True,
    )
    report["compile"] = measure_compile()
    start = time.perf_counter()  # warm-up: load the compiled kernels from numba's cache
    simulate(reference_parameters(), agreement_plan(True))
    simulate_batch(*batch_inputs(2), TestPlan(duration_s=1.0, settle_s=0.5, pause_s=0.5))
    report["warmup_s"] = time.perf_counter() - start
    numba.set_num_threads(1)
    report["single"] = measure_single(repeats)
    print(f"(a) simulate(): {report['single']['realtime_factor']:,.0f}x real time", flush=True)
    report["batch_1_thread"] = measure_batch(1, max(1, repeats // 3), BATCH_JOBS)
    report["batch_all_threads"] = measure_batch(all_threads, max(1, repeats // 3), BATCH_JOBS)
    print("(b) simulate_batch() done", flush=True)
    report["solve_ivp"] = measure_solve_ivp(args.quick, repeats)
    print("(c) solve_ivp done\n", flush=True)

    table = markdown(report)
    report["markdown"] = table
    print(table)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(report, indent=2) + "\n")
    print(f"\nwritten {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
