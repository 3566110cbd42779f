"""`dtid report`: one self-contained HTML file, checked in its text and in a real browser."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import CommandOutputs
from json_schemas import validate

from dtid.cli import main
from dtid.identification.html_report import _target_cell

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMIUM_ARGS = [  # as on this machine's closed network (docs/formats.md)
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
FIGURES = ("fig-frf", "fig-fit", "fig-profiles", "fig-diagnosis")


@pytest.fixture(scope="module")
def report(command_outputs: CommandOutputs, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The report of the commands' folder: a recording with its identification and diagnosis."""
    path = tmp_path_factory.mktemp("report") / "report.html"
    folder = command_outputs.folder
    assert main(["report", str(command_outputs.recording), "-o", str(path)]) == 0
    assert (folder / "diagnosis.png").exists()
    return path


def test_the_report_holds_the_identification_and_diagnosis(
    report: Path, command_outputs: CommandOutputs
) -> None:
    text = report.read_text()
    identification = command_outputs.documents["identification"]
    for name, value in identification["parameters"].items():
        assert re.search(rf"<td>{name}</td><td class='num'>{value:.4g}</td>", text), name
    for name, interval in identification["intervals"].items():
        assert f"{interval['lower']:.4g} - {interval['upper']:.4g}" in text, name
        assert f"<td>{identification['identifiable'][name]}</td>" in text
    for label, value in identification["nrmse"]["fit"].items():
        assert f"{value:.4f}" in text and label.split("/")[-1] in text
    assert command_outputs.documents["diagnosis"]["verdict"]["explanation"] in text
    for figure in FIGURES:
        assert f"id='{figure}'" in text
    assert "dtid simulate (seed 0)" in text  # the metadata travelled with the recording


def _report_of(document: dict, command_outputs: CommandOutputs, tmp_path: Path) -> str:
    """The report's text of the commands' recording with an edited identification JSON (checked
    against its schema first)."""
    validate(document, "identification")
    path = tmp_path / "identification.json"
    path.write_text(json.dumps(document))
    out = tmp_path / "report.html"
    command = ["report", str(command_outputs.recording), "--identification", str(path)]
    assert main([*command, "-o", str(out)]) == 0
    return out.read_text()


def test_a_compared_drivetrain_is_shown_with_its_verdict(
    command_outputs: CommandOutputs, tmp_path: Path
) -> None:
    """`dtid identify --compare sheet.toml`'s verdict is on the page, marked where the
    recordings reject the drivetrain."""
    document = json.loads((command_outputs.folder / "identification.json").read_text())
    sentence = "the drivetrain of sheet.toml fits these recordings significantly worse (p = 0.01)"
    document["comparison"] = {
        "source": "sheet.toml",
        "theta": {"c12": 330.0},
        "held": [],
        "objective": 0.2,
        "objective_identified": 0.1,
        "nrmse": {"fit": {}},
        "statistic": 80.0,
        "critical": 20.0,
        "draws": 99,
        "degrees_of_freedom": 2,
        "p_value": 0.01,
        "fits_worse": True,
        "outside_intervals": {"c12": {"value": 330.0, "lower": 290.0, "upper": 310.0}},
        "sentence": sentence,
    }
    page = _report_of(document, command_outputs, tmp_path)
    assert f"<p class='warn'>Compared: {sentence}.</p>" in page


def test_a_campaign_rounds_target_tests_are_shown_with_their_outcome(
    command_outputs: CommandOutputs, tmp_path: Path
) -> None:
    """An identification checked by target tests (a campaign round's): each tested parameter's
    outcome and, where it has no profile, the interval its test read."""
    document = json.loads((command_outputs.folder / "identification.json").read_text())
    estimate = document["parameters"]["eps12"]
    document["intervals"].pop("eps12")
    document["profiles"].pop("eps12")
    ends = [0.95 * estimate, 1.05 * estimate]
    document["target_tests"] = {
        "eps12": {
            "estimate": estimate,
            "ends": ends,
            "rejected": [True, False],
            "confirmed": False,
            "interval": {"lower": 0.97 * estimate, "upper": None},
            "bounds": [0.0, 4.0 * estimate],
            "values": [estimate, *ends],
            "statistic": [0.0, 9.1, 1.2],
            "margin": [0.0, 0.4, 0.3],
        }
    }
    text = _report_of(document, command_outputs, tmp_path)
    assert "<th>target test</th>" in text
    assert "not confirmed at +-5 %: the end above fits" in text
    assert f"{0.97 * estimate:.4g} - open" in text
    c12 = document["intervals"]["c12"]  # a profiled parameter keeps its profile's interval
    assert f"{c12['lower']:.4g} - {c12['upper']:.4g}</td><td>" in text
    # a friction identified at zero: no lower end to test, the half-width in N*m
    at_zero = {"estimate": 0.0, "ends": [None, 0.05], "rejected": [False, True]}
    assert _target_cell(at_zero) == "not confirmed at +-0.05: the estimate is at its bound below"


def test_a_parameter_on_the_edge_of_its_search_box_is_flagged(
    command_outputs: CommandOutputs, tmp_path: Path
) -> None:
    document = json.loads((command_outputs.folder / "identification.json").read_text())
    assert document["at_bounds"] == {}  # the reference vehicle lies inside the default box
    document["at_bounds"] = {"c23": {"side": "upper", "lower": 0.0, "upper": 300.0}}
    text = _report_of(document, command_outputs, tmp_path)
    assert "c23 ended at the upper end of its search box (0 - 300 N*m/rad)" in text


def test_the_report_is_self_contained(report: Path) -> None:
    """Nothing is fetched when it opens: no script, no style sheet, no image by address."""
    text = report.read_text()
    assert "<script" not in text and "<link" not in text
    sources = re.findall(r"src='([^']*)'", text)
    assert len(sources) == len(FIGURES)
    assert all(s.startswith("data:image/png;base64,") for s in sources)
    assert not re.search(r"(href|src)=['\"]?(https?:|//|file:)", text)


def test_a_recording_alone_says_what_is_missing(tmp_path: Path) -> None:
    recording = tmp_path / "alone.blf"
    assert main(["simulate", str(recording), "--duration", "20"]) == 0
    assert main(["report", str(recording)]) == 0
    text = (tmp_path / "report.html").read_text()
    assert "Not identified" in text and "dtid identify alone.blf --json" in text
    assert "Not diagnosed" in text and "id='fig-frf'" in text
    assert "id='fig-fit'" not in text


def test_a_document_of_another_kind_is_named(
    command_outputs: CommandOutputs, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The identification given as the diagnosis had been shown as "the model explains the
    recordings"; a parameter edited into text was a traceback."""
    recording, folder = str(command_outputs.recording), command_outputs.folder
    out = str(tmp_path / "r.html")
    given = ["--diagnosis", str(folder / "identification.json")]
    assert main(["report", recording, "-o", out, *given]) == 2
    assert "is not diagnosis JSON as `dtid diagnose --json` writes it" in capsys.readouterr().err
    edited = json.loads((folder / "identification.json").read_text())
    edited["parameters"]["c12"] = "abc"
    (tmp_path / "edited.json").write_text(json.dumps(edited))
    given = ["--identification", str(tmp_path / "edited.json")]
    assert main(["report", recording, "-o", out, *given]) == 2
    assert "is not identification JSON" in capsys.readouterr().err
    gutted = tmp_path / "gutted.json"  # its page read "fit NRMSE ." and "--profile-points 0"
    gutted.write_text(json.dumps({"parameters": {"J_sum": 0.28}}))
    assert main(["report", recording, "-o", out, "--identification", str(gutted)]) == 2
    assert "is not identification JSON" in capsys.readouterr().err
    assert not (tmp_path / "r.html").exists()


def test_bad_input_is_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["report", str(tmp_path / "missing.blf")]) == 2
    assert "missing.blf does not exist" in capsys.readouterr().err
    assert main(["report", str(tmp_path)]) == 2
    assert "holds no recording" in capsys.readouterr().err


def test_another_tests_identification_is_not_put_beside_these_frfs(
    command_outputs: CommandOutputs,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    caplog: pytest.LogCaptureFixture,
) -> None:
    """An identification of other recordings, given: refused, naming both; found beside the
    recording: left out with a warning, the report written without it."""
    document = json.loads(json.dumps(command_outputs.documents["identification"]))
    for runs in document["nrmse"].values():
        for label in list(runs):
            runs[label.replace("test.blf", "other.blf")] = runs.pop(label)
    recording = tmp_path / "this.blf"
    shutil.copyfile(command_outputs.recording, recording)
    foreign = tmp_path / "identification.json"
    foreign.write_text(json.dumps(document))
    argv = ["report", str(recording), "-o", str(tmp_path / "r.html")]
    assert main([*argv, "--identification", str(foreign)]) == 2
    error = capsys.readouterr().err
    assert "is the identification of other.blf, not of this.blf" in error
    assert main(argv) == 0
    assert "left out of the report" in caplog.text
    assert "Not identified" in (tmp_path / "r.html").read_text()


@pytest.mark.skipif(
    CHROMIUM is None, reason="Debian's chromium is not installed (apt install chromium)"
)
def test_the_report_renders_in_chromium(report: Path, tmp_path: Path) -> None:
    """Opened in headless Chromium: no console or page error, every image decoded, and the fit
    figure's screenshot shows the plot (coloured curves on white, not an empty box)."""
    sync_api = pytest.importorskip("playwright.sync_api")
    errors: list[str] = []
    with sync_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1200, "height": 900})
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda error: errors.append(str(error)))
            page.goto(report.as_uri())
            images = page.evaluate(
                "Array.from(document.images).map(i => [i.closest('figure').id, i.complete, "
                "i.naturalWidth, i.naturalHeight])"
            )
            shot = tmp_path / "fit.png"
            page.locator("#fig-fit img").screenshot(path=str(shot))
            title = page.title()
        finally:
            browser.close()
    assert errors == []
    assert sorted(i[0] for i in images) == sorted(FIGURES)
    assert all(complete and width > 300 and height > 150 for _, complete, width, height in images)
    assert title.startswith("drivetrain-id test report")
    from matplotlib.image import imread

    pixels = imread(shot)[..., :3]
    white = (pixels > 0.95).all(axis=-1)
    colour = pixels.max(axis=-1) - pixels.min(axis=-1) > 0.25  # the curves, not grey axes
    assert 0.5 < white.mean() < 0.97
    assert colour.mean() > 0.005
    assert np.unique(pixels.reshape(-1, 3), axis=0).shape[0] > 50
