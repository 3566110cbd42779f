"""The ``dtid`` command line: contracts (JSON keys, exit codes) and the errors a user sees."""

from __future__ import annotations

import argparse
import io
import json
import shutil
from pathlib import Path

import pytest
from conftest import HELD
from json_schemas import validate

from dtid.cli import main
from dtid.cli.commands.common import ProgressBar
from dtid.cli.commands.identify import follow_up_command, unprofiled_note
from dtid.cli.commands.inspect import no_runs_reason
from dtid.errors import RecordingError
from dtid.identification.gain_choice import gain_warning

DATA = Path(__file__).parent / "data"
ROOT = Path(__file__).resolve().parents[1]
SHORT = ["--amplitudes", "5", "10", "--duration", "12", "--seed", "2"]


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("cli") / "test.blf"
    assert main(["simulate", str(path), *SHORT]) == 0
    return path


def _error(capsys: pytest.CaptureFixture[str], argv: list[str]) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: "), err
    return err[0]


def test_inspect_reports_roles_and_runs(recording: Path, tmp_path: Path) -> None:
    out = tmp_path / "inspect.json"
    assert main(["inspect", str(recording), "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    for role in ("speed", "mean_torque", "test_torque", "torque_request"):
        assert set(report["roles"][role]) >= {"count", "rate_hz", "min", "max", "max_gap_s"}
    assert report["roles"]["speed"]["rate_hz"] == pytest.approx(66.7, rel=0.02)
    assert report["roles"]["mean_torque"]["rate_hz"] == pytest.approx(33.3, rel=0.02)
    assert report["roles"]["test_torque"]["max_gap_s"] == pytest.approx(0.01, abs=1e-4)
    runs = report["runs"]
    assert [r["amplitude_nm"] for r in runs] == pytest.approx([5.0, 10.0])
    for run in runs:
        assert set(run) == {"start_s", "end_s", "amplitude_nm", "f1_hz", "f2_hz"}
        assert run["f1_hz"] == pytest.approx(1.0, abs=0.05)
        assert run["f2_hz"] == pytest.approx(15.0, abs=0.05)
        assert run["end_s"] - run["start_s"] == pytest.approx(12.0, abs=0.05)


def test_inspect_through_a_dbc_that_decodes_nothing_fails(
    recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A DBC whose measured roles' messages the recording does not hold (here the product's own
    with those identifiers moved; the tool's heartbeat still decodes) gets the report, its JSON,
    and a non-zero exit naming the likely cause."""
    own = Path(__file__).parents[1] / "dbc"
    dbc = tmp_path / "other.dbc"
    text = (own / "drivetrain.dbc").read_text()
    for old, new in (("416", "516"), ("417", "517"), ("418", "518"), ("1696", "1796")):
        text = text.replace(f"BO_ {old} ", f"BO_ {new} ")
    dbc.write_text(text)
    out = tmp_path / "inspect.json"
    signals = own / "drivetrain_signals.toml"
    argv = ["inspect", str(recording), "--dbc", str(dbc), "--signals", str(signals)]
    message = _error(capsys, [*argv, "--json", str(out)])
    assert "no frame of the speed's, the mean torque's or the test torque's message" in message
    assert "--dbc and --signals" in message
    assert json.loads(out.read_text())["roles"]["speed"]["count"] == 0


def test_frf_json_and_plot(recording: Path, tmp_path: Path) -> None:
    out, plot = tmp_path / "frf.json", tmp_path / "frf.png"
    assert main(["frf", str(recording), "--json", str(out), "--plot", str(plot)]) == 0
    runs = json.loads(out.read_text())["runs"]
    assert len(runs) == 2
    for entry in runs:
        assert {"amplitude_nm", "frequency_hz", "drv_db", "eng_db", "coherence"} <= set(entry)
        n = len(entry["frequency_hz"])
        assert n > 10 and len(entry["drv_db"]) == n == len(entry["coherence"])
    assert plot.stat().st_size > 10_000


def test_identify_names_an_engine_that_lags_its_request(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, capsys: pytest.CaptureFixture[str]
) -> None:
    """A concealed 60 ms torque lag: each identifying run's T/T_ecu gives it back within 15 %
    (`engine_lag` in the JSON), and the log says what it does to eq. (24)'s K and the
    drivetrain and that `dtid diagnose` fits it. The gain trades with the lag on 12 s chirps:
    0.70-1.04 for 0.9 over seeds 2-6 with either speed sensor (2026-12-01)."""
    recording, out = tmp_path / "lagging.blf", tmp_path / "identify.json"
    assert main(["simulate", str(recording), *SHORT, "--effect", "torque_lag:tau_m=0.06"]) == 0
    fix = [*HELD, "eps12=0.02", "c12=300", "d12=1.0"]
    argv = ["identify", str(recording), "--fix", *fix, "--profile-points", "0"]
    with caplog.at_level("WARNING"):
        assert main([*argv, "--json", str(out)]) == 0
    document = json.loads(out.read_text())
    validate(document, "identification")
    lags = [lag for runs in document["engine_lag"].values() for lag in runs]
    assert len(lags) == 2 and all(lag is not None for lag in lags), lags
    for lag in lags:
        assert lag["tau_s"] == pytest.approx(0.06, rel=0.15)
        assert lag["gain"] == pytest.approx(0.9, rel=0.2)
    assert "the engine lags its torque request" in caplog.text
    assert "dtid diagnose` fits the lag" in caplog.text
    printed = capsys.readouterr().out  # every parameter held: no intervals to miss
    assert "no intervals" not in printed
    frf = tmp_path / "frf.json"  # the FRF's own page says it per run too
    assert main(["frf", str(recording), "--json", str(frf)]) == 0
    assert "engine lag 0.0" in capsys.readouterr().out
    runs = json.loads(frf.read_text())["runs"]
    validate({"runs": runs}, "frf")
    assert [run["engine_lag"]["tau_s"] for run in runs] == pytest.approx([0.06, 0.06], rel=0.15)


def test_a_result_without_profiles_says_what_it_lacks_and_the_command_that_predicts_it() -> None:
    """With --profile-points 0 the report names what it lacks and the `dtid plan` command that
    predicts the precision; without --json that command needs the result written first, and
    the sentence says so (it read "predicted by write this result with --json ...")."""
    args = argparse.Namespace(
        json=None, recordings=[Path("r.blf")], dbc=Path("v.dbc"), signals=None, vehicle=None
    )
    note = unprofiled_note(follow_up_command(args))
    assert note.startswith("no intervals (--profile-points 0)")
    assert note.endswith(
        "predicted by dtid plan --prior ID.json --after r.blf --dbc v.dbc (with this result "
        "written by --json ID.json)"
    )
    args.json = Path("id.json")
    assert follow_up_command(args) == "dtid plan --prior id.json --after r.blf --dbc v.dbc"


@pytest.mark.parametrize(
    "options", [["--bounds", "c12=100:400"], ["--generations", "3"], ["--profile-points", "5"]]
)
def test_diagnose_refuses_the_identifications_options_beside_an_identification(
    options: list[str], recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """With --identification the identification is given: its options were ignored silently."""
    identification = tmp_path / "id.json"
    identification.write_text('{"parameters": {}}')
    argv = ["diagnose", str(recording), "--identification", str(identification), *options]
    message = _error(capsys, argv)
    assert f"{options[0]} sets the identification" in message and "drop one" in message


def test_a_recording_without_chirps_says_what_its_test_torque_did() -> None:
    """`dtid inspect` of a log whose test torque sat at its raw minimum (-131072 N*m) said
    "the test torque is zero or absent"."""
    summary = {"count": 500, "min": -131072.0, "max": -131072.0}
    assert "holds -131072 N*m throughout: a raw value" in no_runs_reason(summary)
    assert "absent" in no_runs_reason(None) and "absent" in no_runs_reason({"count": 0})
    assert "no test was run" in no_runs_reason({"count": 9, "min": 0.0, "max": 0.0})
    assert "holds no chirp" in no_runs_reason({"count": 9, "min": -2.0, "max": 3.0})


def test_the_global_options_may_follow_the_command(
    recording: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`dtid inspect X --debug` was refused as an unknown argument; before the command or after
    it, --debug shows the traceback of an error and -v logs more."""
    with pytest.raises(RecordingError):
        main(["inspect", str(recording.with_name("absent.blf")), "--debug"])
    assert main(["inspect", str(recording), "-v"]) == 0
    assert "error" not in capsys.readouterr().err


def test_frf_refuses_a_band_upside_down_and_a_recording_twice(
    recording: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    message = _error(capsys, ["frf", str(recording), "--band", "12", "3"])
    assert "give the lower frequency first" in message
    assert "given twice" in _error(capsys, ["frf", str(recording), str(recording)])


@pytest.mark.slow  # two searches of the paper's 60 s chirps (31 s)
def test_a_measured_engine_lag_in_the_model_halves_the_misfit(tmp_path: Path) -> None:
    """A concealed 30 ms torque lag, the paper's 60 s chirps, c12, d12 and eps12 free: with
    the model's engine prompt (the default) eq. (24) reads K 0.61 for 0.9 and the fit ends at
    eq. 17 0.17; with ``[model] engine_lag = "measured"`` the model's engine lags as the runs'
    strokes measured it (0.0297 s; T/T_ecu's fit read 0.0306 s), K is read stroke by stroke
    through the lag (0.899; through T/T_ecu's lag 0.911), eq. 17 falls to 0.09 and c12, d12 and
    eps12 land within issue 15's targets (measured 2026-12-03: +1.7, +3.6, +3.5 %; with T/T_ecu's
    lag +1.2, +3.8, +2.6 %, at the same eq. 17 to 2e-5: one recording's spread, not the lag's)."""
    recording = tmp_path / "lagging.blf"
    command = ["simulate", str(recording), "--amplitudes", "5", "10", "--duration", "60"]
    assert main([*command, "--seed", "2", "--effect", "torque_lag:tau_m=0.03"]) == 0
    vehicle = tmp_path / "vehicle.toml"
    vehicle.write_text('[model]\nengine_lag = "measured"\n')
    argv = ["identify", str(recording), "--fix", *HELD, "--profile-points", "0", "--json"]
    documents = {}
    for name, extra in (("prompt", []), ("lagging", ["--vehicle", str(vehicle)])):
        assert main([*argv, str(tmp_path / f"{name}.json"), *extra]) == 0
        documents[name] = json.loads((tmp_path / f"{name}.json").read_text())
    prompt, lagging = documents["prompt"], documents["lagging"]
    validate(lagging, "identification")
    (loop,) = lagging["idle_loop"].values()
    assert loop["engine_lag_s"] == pytest.approx(0.03, rel=0.05)
    assert lagging["vehicle_data"]["model"]["engine_lag"] == "measured"
    assert lagging["parameters"]["K"] == pytest.approx(0.9, rel=0.01)
    assert prompt["parameters"]["K"] < 0.8  # eq. (24) under the lag
    assert lagging["objective"] < 0.7 * prompt["objective"]
    for name, truth, within in (("c12", 300.0, 0.05), ("d12", 1.0, 0.25), ("eps12", 0.02, 0.05)):
        assert lagging["parameters"][name] == pytest.approx(truth, rel=within), name


def test_simulate_never_overwrites_a_recording(
    recording: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    before = recording.read_bytes()
    message = _error(capsys, ["simulate", str(recording), *SHORT])
    assert "--force" in message
    assert recording.read_bytes() == before


def test_simulate_takes_the_engine_of_a_vehicle_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A --params vehicle file's [engine] was ignored without a word: the plant is now simulated
    with it (or with --vehicle's), and says so."""
    from dtid.acquisition.logfile import read_log
    from dtid.simulator.parameters import reference_parameters

    values = reference_parameters().as_dict()
    drivetrain = "".join(f"{name} = {value!r}\n" for name, value in values.items())
    (tmp_path / "plain.toml").write_text(drivetrain)
    (tmp_path / "vehicle.toml").write_text(f"[drivetrain]\n{drivetrain}[engine]\nbore = 0.1\n")
    runs = {
        "plain": ["--params", "plain.toml"],
        "vehicle": ["--params", "vehicle.toml"],
        "given": ["--params", "plain.toml", "--vehicle", "vehicle.toml"],
    }
    data = {}
    for name, options in runs.items():
        paths = [str(tmp_path / o) if o.endswith(".toml") else o for o in options]
        assert main(["simulate", str(tmp_path / f"{name}.blf"), "--duration", "5", *paths]) == 0
        assert ("bore from" in capsys.readouterr().out) == (name != "plain"), name
        data[name] = [bytes(frame.data) for frame in read_log(tmp_path / f"{name}.blf")]
    assert data["vehicle"] == data["given"] != data["plain"]


def test_simulate_through_another_dbc(tmp_path: Path) -> None:
    path = tmp_path / "other.asc"
    interface = ["--dbc", str(DATA / "other_vehicle.dbc")]
    signals = ["--signals", str(DATA / "other_vehicle_signals.toml")]
    assert main(["simulate", str(path), *SHORT, *interface, *signals]) == 0
    assert main(["frf", str(path), *interface, *signals]) == 0


def test_truncated_recording(
    recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    broken = tmp_path / "broken.blf"
    broken.write_bytes(recording.read_bytes()[:100])
    assert "broken.blf" in _error(capsys, ["frf", str(broken)])


def test_unreadable_recording(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    garbage = tmp_path / "garbage.log"
    garbage.write_bytes(bytes(range(256)) * 4)
    assert "garbage.log" in _error(capsys, ["inspect", str(garbage)])
    assert "does not exist" in _error(capsys, ["frf", str(tmp_path / "missing.blf")])


def test_dbc_without_the_mapped_message(
    recording: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    message = _error(capsys, ["frf", str(recording), "--dbc", str(DATA / "other_vehicle.dbc")])
    assert "EngineSpeed" in message and "--signals" in message


def test_map_naming_an_unknown_signal(
    recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "bad.toml"
    text = (DATA / "other_vehicle_signals.toml").read_text()
    bad.write_text(text.replace('"CrankSpeed"', '"CrankSped"'))
    message = _error(
        capsys,
        [
            "inspect",
            str(recording),
            "--dbc",
            str(DATA / "other_vehicle.dbc"),
            "--signals",
            str(bad),
        ],
    )
    assert "CrankSped" in message and "CrankSpeed" in message


def test_recording_without_chirp(
    tmp_path: Path, recording: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from dtid.acquisition.logfile import read_log, write_log

    quiet = tmp_path / "quiet.blf"
    write_log(quiet, [f for f in read_log(recording) if f.timestamp < 2.5])
    assert "no chirp" in _error(capsys, ["frf", str(quiet)])
    assert main(["inspect", str(quiet)]) == 0  # inspect reports, it does not refuse


def test_chirp_too_short_for_the_band(recording: Path, capsys: pytest.CaptureFixture[str]) -> None:
    message = _error(capsys, ["frf", str(recording), "--resolution", "0.1"])
    assert "too short" in message
    message = _error(capsys, ["frf", str(recording), "--band", "0.2", "14"])
    assert "not inside the chirp's sweep" in message


def test_bad_parameter_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    params = tmp_path / "vehicle.toml"
    shutil.copy(Path(__file__).parents[1] / "simulator" / "reference_vehicle.toml", params)
    params.write_text(params.read_text().replace("J2 = 0.09", "J2 = -0.09"))
    message = _error(capsys, ["simulate", str(tmp_path / "x.blf"), "--params", str(params)])
    assert "J2 = -0.09 is not physical" in message


def test_inspect_a_real_log_through_an_example_map(tmp_path: Path, realdata: Path) -> None:
    out = tmp_path / "genesis.json"
    maps = Path(__file__).parents[1] / "dbc" / "maps"
    assert (
        main(
            [
                "inspect",
                str(realdata / "genesis_autolog.log"),
                "--dbc",
                str(realdata / "opendbc_hyundai_kia_generic.dbc"),
                "--signals",
                str(maps / "opendbc_hyundai_kia_generic.toml"),
                "--json",
                str(out),
            ]
        )
        == 0
    )
    report = json.loads(out.read_text())
    assert report["roles"]["speed"]["count"] == 3645
    assert 750 <= report["roles"]["speed"]["min"] < report["roles"]["speed"]["max"] <= 2050
    assert report["missing_roles"] == ["test_torque"] and report["runs"] == []


def test_demo_into_an_unwritable_place(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    message = _error(capsys, ["demo", "--out", str(blocker / "x")])
    assert "cannot create the output folder" in message


def test_identify_json_contract(recording: Path, tmp_path: Path) -> None:
    out, plot = tmp_path / "identify.json", tmp_path / "fit.png"
    fix = [
        "J_sum=0.28",
        "x1=0.625",
        "x12=0.857",
        "c23=80",
        "d23=0.3",
        "Tc12=0.3",
        "eps23=0.012",
        "eps12=0.02",
    ]
    argv = [
        "identify",
        str(recording),
        "--fix",
        *fix,
        "--generations",
        "2",
        "--profile-points",
        "3",
        "--bounds",
        "c12=150:450",
        "--compare",
        str(ROOT / "simulator" / "reference_vehicle.toml"),  # the truth: c12 300, d12 1.0
        "--json",
        str(out),
        "--plot",
        str(plot),
    ]
    assert main(argv) == 0
    document = json.loads(out.read_text())
    validate(document, "identification")  # with intervals and verdicts, and the comparison
    compared = document["comparison"]
    assert compared["source"].endswith("reference_vehicle.toml")
    assert compared["degrees_of_freedom"] == 2 and len(compared["held"]) == 8
    assert compared["draws"] == 99 and compared["critical"] > 0
    assert compared["theta"]["c12"] == 300.0 and compared["theta"]["eps12"] == 0.02
    assert not compared["fits_worse"]  # the recording's own vehicle
    assert compared["sentence"].startswith("the drivetrain of ")
    assert set(compared["outside_intervals"]) <= {"c12", "d12"}  # the profiled ones only
    assert 150 <= document["parameters"]["c12"] <= 450
    assert all(
        value is None or 150 <= value <= 450 for value in document["intervals"]["c12"].values()
    )
    assert document["identifiability_notes"] == {}  # two amplitudes separate c12 from eps12
    # the simulator's engine delivers its request without a lag: none is named
    assert [lag for lags in document["engine_lag"].values() for lag in lags] == [None, None]
    names = {"J_sum", "x1", "x12", "c12", "c23", "d12", "d23", "Tc12", "eps12", "eps23"}
    assert set(document["parameters"]) == names | {"J1", "J2", "J3", "K"}
    assert set(document["intervals"]) == {"c12", "d12"}  # the free ones
    for interval in document["intervals"].values():
        assert set(interval) == {"lower", "upper"}
    assert set(document["identifiable"].values()) <= {"structural", "practical", "no"}
    assert set(document["nrmse"]) == {"fit", "validation"}
    assert len(document["nrmse"]["fit"]) == 2  # 5 and 10 N*m identify
    assert document["parameters"]["K"] == pytest.approx(0.9, rel=0.03)
    # beside the contract, the data: with the rest at the truth, 12 s chirps pin the DMF spring
    assert document["parameters"]["c12"] == pytest.approx(300.0, rel=0.05)
    (loop,) = document["idle_loop"].values()
    assert loop["mode"] == "recorded_request" and loop["latch_events"] == 3
    assert set(document["vehicle_data"]["engine"]) == {
        "bore",
        "r",
        "l",
        "eps_c",
        "kappa",
        "p_l",
        "m_osc",
    }
    assert plot.stat().st_size > 10_000


def test_a_drivetrain_to_compare_is_read_before_the_search(
    recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A --compare file that cannot be read stops the command at once, naming it and what it
    should hold; an identification JSON is read as one."""
    missing = tmp_path / "sheet.toml"
    message = _error(capsys, ["identify", str(recording), "--compare", str(missing)])
    assert "sheet.toml does not exist" in message
    typo = tmp_path / "typo.toml"
    typo.write_text(
        (ROOT / "simulator" / "reference_vehicle.toml").read_text().replace("c12", "c21")
    )
    assert "c21" in _error(capsys, ["identify", str(recording), "--compare", str(typo)])
    other = tmp_path / "other.json"
    other.write_text('{"plan": []}')
    message = _error(capsys, ["identify", str(recording), "--compare", str(other)])
    assert "--compare" in message and "not an identification JSON" in message


def test_a_k_far_above_one_is_not_read_as_a_lagging_engine() -> None:
    """A lag lowers eq. (24)'s K; a K of 4 (a torque map's scale too large) is a unit matter
    only, and the warning no longer calls it low."""
    assert "this low" in (gain_warning(0.2) or "") and "torque_lag" in (gain_warning(0.2) or "")
    high = gain_warning(4.04) or ""
    assert "different units or scales" in high and "this low" not in high


def test_a_mean_torque_in_per_cent_is_named_by_its_k(
    recording: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """The reference's test with its mean torque read in per cent of 450 N*m (a map without
    its `scale`): eq. (24) reads K 0.20, which the log names as a unit mismatch; read right,
    K 0.90 is not named."""
    text = (ROOT / "dbc" / "drivetrain_signals.toml").read_text()
    signals = tmp_path / "per-cent.toml"
    torque = 'signal = "MeanTorque"\n'
    signals.write_text(text.replace(torque, torque + "scale = 0.2222\n"))
    held = [*HELD, "c12=300", "d12=1.0", "eps12=0.02"]  # nothing searched: K is read before
    argv = ["identify", str(recording), "--profile-points", "0", "--fix", *held]
    for map_args, named in (([], False), (["--signals", str(signals)], True)):
        caplog.clear()
        assert main([*argv, *map_args]) == 0
        assert (
            "the mean torque and the torque request are most likely in different units"
            in caplog.text
        ) == named
    assert "K 0.2: the engine delivers 20 % of the torque its ECU requests" in caplog.text


def test_identify_says_when_a_parameter_ends_on_its_search_box(
    recording: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A box that leaves out the truth (c12 300 N*m/rad, the box 150-250): the estimate ends on
    its upper edge, and the JSON, the log and the table say so; d12's lower bound is zero, a
    physical end, and is not called an edge."""
    out = tmp_path / "identify.json"
    fix = ["J_sum=0.28", "x1=0.625", "x12=0.857", "c23=80", "d23=0.3", "Tc12=0.3"]
    argv = ["identify", str(recording), "--fix", *fix, "eps23=0.012", "eps12=0.02"]
    argv += ["--generations", "2", "--profile-points", "0", "--bounds", "c12=150:250"]
    assert main([*argv, "--json", str(out)]) == 0
    document = json.loads(out.read_text())
    validate(document, "identification")
    assert document["parameters"]["c12"] == pytest.approx(250.0, rel=1e-3)
    assert document["at_bounds"] == {"c12": {"side": "upper", "lower": 150.0, "upper": 250.0}}
    assert "c12 ended at the upper end of its search box (150 to 250 N*m/rad)" in caplog.text
    assert "--bounds c12=150:500" in caplog.text
    table = capsys.readouterr().out.splitlines()
    (line,) = [row for row in table if row.lstrip().startswith("c12 =")]
    assert line.endswith("(at the search box's upper end)")


def test_a_model_that_cannot_idle_is_written_reported_and_not_diagnosed(
    recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Every parameter held at a drivetrain of a fourteenth of the recording's inertia (an
    engineer checking a data sheet against the recording): the model's engine leaves the speed
    range on every run. The identification JSON is still written (the runs' NRMSE 10, their
    model curves null: a NaN once made the JSON unwritable and the result was lost), the report
    draws it, and the diagnosis refuses, naming the runs, instead of blaming the noise model."""
    out = tmp_path / "identify.json"
    fix = ["J_sum=0.02", "x1=0.5", "x12=0.9", "c12=300", "c23=75", "d12=1", "d23=0.2"]
    fix += ["Tc12=0.3", "eps12=0.02", "eps23=0.01"]
    argv = ["identify", str(recording), "--fix", *fix, "--profile-points", "0"]
    assert main([*argv, "--json", str(out)]) == 0
    document = json.loads(out.read_text())
    validate(document, "identification")
    scores = [v for role in document["nrmse"].values() for v in role.values()]
    assert scores == [10.0, 10.0]  # 5 and 10 N*m
    assert [curve["model_db"] for curve in document["curves"]] == [None, None]
    report = tmp_path / "report.html"
    assert main(["report", str(recording), "--identification", str(out), "-o", str(report)]) == 0
    assert "Measured and identified |G_DRV|" in report.read_text()
    message = _error(capsys, ["diagnose", str(recording), "--identification", str(out)])
    assert "could not idle through" in message and "@ 5 N*m" in message


def test_a_recording_given_twice_is_refused(
    recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Twice would weigh its runs double in eq. (17) and narrow the intervals as if the test had
    been repeated, while the report labelled the runs once."""
    message = _error(capsys, ["identify", str(recording), str(recording)])
    assert f"{recording} is given twice" in message
    copy = tmp_path / "copy.blf"
    shutil.copyfile(recording, copy)
    message = _error(capsys, ["diagnose", str(recording), str(copy)])
    assert f"{copy} is the same recording as {recording}" in message


def test_identify_rejects_a_bad_fix(recording: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert "expected NAME=VALUE" in _error(capsys, ["identify", str(recording), "--fix", "J9=1"])
    assert "is not a number" in _error(capsys, ["identify", str(recording), "--fix", "c12=stiff"])
    for bad in ("c12=nan", "c12=inf", "c12=-5"):  # nan and inf were tracebacks in the search
        message = _error(capsys, ["identify", str(recording), "--fix", bad])
        assert "must be a finite number >= 0" in message, bad
    twice = _error(capsys, ["identify", str(recording), "--fix", "c12=500", "c12=600"])
    assert "--fix gives c12 twice (500, 600)" in twice
    both = ["identify", str(recording), "--fix", "c23=80", "--bounds", "c23=10:70"]
    assert "c23 is both held (--fix) and searched within bounds" in _error(capsys, both)


@pytest.mark.parametrize(
    ("options", "why"),
    [
        (["--fix", "x1=1.5"], "--fix x1=1.5: x1 = 1.5 is the mass ratio J1/(J1+J2)"),
        (["--fix", "x12=1"], "x12 = 1 is the mass ratio (J1+J2)/(J1+J2+J3)"),
        (["--bounds", "x1=0:0.5"], "--bounds x1=0:0.5: x1 = 0 is the mass ratio"),
        (["--fix", "J_sum=0"], "J_sum, the total inertia, must be > 0"),
        (["--fix", "K=0"], "the engine gain K must be > 0"),
    ],
)
def test_identify_refuses_a_mass_ratio_or_inertia_no_vehicle_has(
    options: list[str], why: str, recording: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """x1 = 1.5 made J2 negative: the search ran for a minute and failed on "J2 = -0.065 is not
    physical", a parameter the user had not given."""
    assert why in _error(capsys, ["identify", str(recording), *options])


def test_a_stiffness_no_drivetrain_has_is_named_not_a_scipy_traceback(
    recording: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """c12 = 1e300 (a unit slip) overflowed the substep count inside scipy's differential
    evolution, which re-raised it as "the map-like callable must be of the form f(func,
    iterable)"."""
    for option, value in (
        (["--fix", "c12=1e300"], "c12 1e+300"),
        (["--bounds", "c12=0:1e300"], ""),
    ):
        argv = ["identify", str(recording), *option, "--profile-points", "0"]
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: the parameter set's fastest mode"), option
        assert value in err and "check the units" in err


@pytest.mark.parametrize(
    ("command", "why"),
    [
        (["identify", "REC", "--seed", "-1"], "-1 must lie in 0 .. 4294967295"),
        (["simulate", "out.blf", "--seed", "4294967296"], "must lie in 0 .. 4294967295"),
        (["plan", "--validation", "nan"], "nan must be a number >= 0"),
    ],
)
def test_a_seed_or_amplitude_out_of_range_is_a_usage_error(
    command: list[str], why: str, recording: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A negative seed was numpy's traceback; a NaN validation amplitude was planned for and
    failed 25 s later on writing the JSON."""
    with pytest.raises(SystemExit) as status:
        main([word.replace("REC", str(recording)) for word in command])
    assert status.value.code == 2 and why in capsys.readouterr().err


def test_identify_rejects_bad_bounds(recording: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for bad in ("c12=100", "c99=1:2", "c12=low:high"):
        message = _error(capsys, ["identify", str(recording), "--bounds", bad])
        assert "expected NAME=LOWER:UPPER" in message, bad
    message = _error(capsys, ["identify", str(recording), "--bounds", "c12=600:100"])
    assert "bounds of c12 must satisfy 0 <= lower < upper" in message
    for points in ("1", "2"):  # half-open intervals of every parameter, called verdicts
        message = _error(capsys, ["identify", str(recording), "--profile-points", points])
        assert "must be 0 (no profiles) or at least 3" in message
    with pytest.raises(SystemExit) as status:  # argparse's own usage error
        main(["identify", str(recording), "--span", "0"])
    assert status.value.code == 2 and "must be a number > 0" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("command", "why"),
    [
        (["identify", "REC", "--json", "missing/result.json"], "the folder missing does not exist"),
        (["identify", "REC", "--plot", "."], ". is a folder"),
        (["diagnose", "REC", "--plot", "missing/map.png"], "the folder missing does not exist"),
        (["diagnose", "REC", "--mechanisms", "belt_slip"], "invalid choice: 'belt_slip'"),
        (["frf", "REC", "--json", "missing/frf.json"], "the folder missing does not exist"),
        (["inspect", "REC", "--json", "missing/inspect.json"], "the folder missing does not exist"),
        (["profile", "REC", "--json", "missing/p.json"], "the folder missing does not exist"),
        (["plan", "--plot", "missing/plan.png"], "the folder missing does not exist"),
        (["report", "REC", "-o", "missing/report.html"], "the folder missing does not exist"),
        (["simulate", "missing/test.blf"], "the folder missing does not exist"),
        (["frf", "REC", "--json", "REC"], "is a CAN recording: the result would be written over"),
        (["inspect", "REC", "--json", "REC.json"], "holds the metadata of the recording"),
        (["report", "REC", "-o", "REC"], "is a CAN recording"),
        (["report", "REC", "-o", "report.pdf"], "the report is one HTML page"),
        (["identify", "REC", "--plot", "fit.txt"], "cannot plot to fit.txt: give a file name"),
        (["vehicle", "--report", "REC"], "is a CAN recording"),  # it wrote the report over it
        (["vehicle", "--report", "REC.json"], "holds the metadata of the recording"),
        (["worker", "--once", "--json", "REC"], "is a CAN recording"),
        (["worker", "--once", "--plot", "missing/fit.png"], "the folder missing does not exist"),
        (["vehicle", "--speedup", "1e9"], "1e9 is above 20"),  # Ctrl-C could not stop it
        (["monitor", "--refresh", "3e6"], "3e6 s is above 10 s"),  # ZeroMQ's poll overflowed
        (["plan", "--max-time", "7200"], "7200 s is above 3600 s"),  # its plan, refused at the end
        (["identify", "REC", "--json", "/proc/result.json"], "cannot write /proc/result.json"),
        (["diagnose", "REC", "--json", "/proc/d.json"], "cannot write /proc/d.json"),
    ],
)
def test_an_output_nowhere_to_write_is_refused_before_the_work(
    command: list[str],
    why: str,
    recording: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A result file in a folder that does not exist, or a folder for a file, or a mechanism
    the library lacks, is named when the command is read: `dtid identify --json results/v1.json`
    without results/ wrote nothing after its minutes of search before. A result is never
    written over a recording or its metadata (`dtid frf X.blf --json X.blf` had replaced the
    recording by the FRFs' JSON)."""
    monkeypatch.chdir(tmp_path)
    before = recording.read_bytes()
    with pytest.raises(SystemExit) as status:
        main([word.replace("REC", str(recording)) for word in command])
    assert status.value.code == 2 and why in capsys.readouterr().err
    assert not (tmp_path / "missing").exists()
    assert recording.read_bytes() == before


@pytest.mark.parametrize(
    ("command", "why"),
    [
        (["identify", "REC", "--dbc", "DBC", "--json", "DBC"], "read by this command (--dbc)"),
        (["diagnose", "REC", "--identification", "ID", "--json", "ID"], "(--identification)"),
        (["plan", "--prior", "ID", "--json", "ID"], "read by this command (--prior)"),
        (["identify", "REC", "--json", "fit.png", "--plot", "fit.png"], "given to both"),
    ],
)
def test_a_result_is_not_written_over_what_the_command_reads(
    command: list[str],
    why: str,
    recording: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """`dtid diagnose REC --identification id.json --json id.json` replaced the identification
    by the diagnosis, `dtid identify --dbc my.dbc --json my.dbc` the DBC by the result, and
    `--json fit.png --plot fit.png` the JSON by the figure; now each is refused before any
    work, and the file is left as it was."""
    dbc, identification = tmp_path / "vehicle.dbc", tmp_path / "id.json"
    dbc.write_bytes((ROOT / "dbc" / "drivetrain.dbc").read_bytes())
    identification.write_text('{"parameters": {}}')
    before = {path: path.read_bytes() for path in (dbc, identification)}
    words = {"REC": str(recording), "DBC": str(dbc), "ID": str(identification)}
    argv = [words.get(word, word) for word in command]
    argv = [str(tmp_path / word) if word == "fit.png" else word for word in argv]
    assert why in _error(capsys, argv)
    assert {path: path.read_bytes() for path in before} == before
    assert not (tmp_path / "fit.png").exists()


@pytest.mark.parametrize(
    "command",
    [
        ["diagnose", "REC", "--identification", "REC"],
        ["identify", "REC", "--prior", "REC"],
        ["identify", "REC", "--vehicle", "REC"],
        ["identify", "REC", "--signals", "REC"],
        ["simulate", "out.blf", "--plan", "REC"],
        ["acquire", "--config", "REC"],
    ],
)
def test_a_binary_file_where_text_belongs_is_named(
    command: list[str],
    recording: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A recording given for a JSON or TOML file (a slip of the shell's completion) is named
    as not JSON or TOML; it was a UnicodeDecodeError's traceback."""
    monkeypatch.chdir(tmp_path)
    message = _error(capsys, [str(recording) if word == "REC" else word for word in command])
    assert f"{recording}" in message and ("not JSON" in message or "not valid TOML" in message)


def test_a_recording_given_as_the_dbc_is_named(
    recording: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    message = _error(capsys, ["inspect", str(recording), "--dbc", str(recording)])
    assert message.endswith("is a binary file, not a DBC (a text file of BO_ and SG_ lines): "
                            "was a recording given as the database?")  # fmt: skip


def test_profile_needs_a_setup_or_recordings(
    recording: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert "or recordings to profile" in _error(capsys, ["profile"])
    assert "not both" in _error(capsys, ["profile", str(recording), "--setup", "2"])


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_the_progress_bar_keeps_a_log_file_readable() -> None:
    """Off a terminal (a log file, the journal) a stage writes a line at each quarter, not a
    redrawn bar; on one, a stage that stopped early (a converged polish) keeps its line."""
    calls = [("global", step, 8, 0.5 - 0.01 * step) for step in range(1, 9)]
    calls += [("local", 50, 150, 0.2), ("local", 100, 150, 0.19), ("local", 50, 150, 0.18)]
    log = io.StringIO()
    bar = ProgressBar(log)
    for call in calls:
        bar(*call)
    lines = log.getvalue().splitlines()
    assert "\r" not in log.getvalue()
    assert [line.split()[0] for line in lines] == ["global"] * 5 + ["local"] * 3
    assert lines[4] == " global [##############################] 8/8 objective 0.4200"
    screen = _Terminal()
    bar = ProgressBar(screen)
    for call in calls:
        bar(*call)
    kept = screen.getvalue().split("\n")  # the lines left on the screen, each its last redraw
    assert [line.rsplit("\r", 1)[-1].split()[:3] for line in kept[:3]] == [
        ["global", "[##############################]", "8/8"],
        ["local", "[####################..........]", "100/150"],
        ["local", "[##########....................]", "50/150"],
    ]
    bar.finish()  # before the result is printed: the last bar stopped early
    assert screen.getvalue().endswith("50/150 objective 0.1800\n")


def test_a_worker_serving_sessions_takes_no_single_result_file(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """Without --once, `dtid worker --json id.json` wrote every session's result over the
    previous session's."""
    message = _error(capsys, ["worker", "--json", str(tmp_path / "id.json")])
    assert "--json and --plot name one file, for one session: give them with --once" in message


def test_ctrl_c_while_the_libraries_load_says_interrupted(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The commands' modules load numpy, scipy and numba for seconds; an operator's Ctrl-C then
    (a just-started `dtid acquire` aborted) was a traceback through importlib. The commands
    are now imported inside main(), where the interrupt is caught."""
    import dtid.cli

    def interrupted() -> tuple:
        raise KeyboardInterrupt

    monkeypatch.setattr(dtid.cli, "command_modules", interrupted)
    assert main(["acquire", "--help"]) == 130
    assert capsys.readouterr().err == "interrupted\n"
