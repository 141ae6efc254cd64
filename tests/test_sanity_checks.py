"""Input that is surely wrong is refused with its likely cause (exit 2 on the command line, 422 on
the API's import paths: both are InputError); input that may be right gets a warning diagnostic."""

from __future__ import annotations

import csv
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from calib_core import InputError, SimulatedRobot, calibrate, load_profile, read_dataset

ROOT = Path(__file__).resolve().parents[1]
FEB = ROOT / "sample_sessions" / "motoman-ctu" / "leica_feb2019.csv"
MOTOMAN_YAML = ROOT / "calib_core" / "model" / "profiles" / "motoman.yaml"


def radians_copy(path: Path) -> None:
    """The Feb 2019 tracker file with every joint reading in radians (the columns still say _deg)."""
    with FEB.open(newline="") as f:
        rows = list(csv.DictReader(f))
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        for r in rows:
            w.writerow({k: (str(math.radians(float(v))) if k.endswith("_deg") and v else v) for k, v in r.items()})


@pytest.mark.subprocess
def test_radians_in_a_degree_profile_exit_2_naming_file_and_column(tmp_path: Path) -> None:
    # Before this check the solve "succeeded": 308 mm RMS after calibration, exit 0.
    radians_copy(tmp_path / "rad.csv")
    args = ["solve", "--robot", "motoman", "--mode", "offsets", "--data", "rad.csv", "--out", "x.json"]
    proc = subprocess.run(
        [sys.executable, "-m", "app.cli", *args, "--where", "leica_frame_group=A", "--where", "reflector_arm=right"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"},
        timeout=120,
        check=False,
    )
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    assert "rad.csv" in proc.stderr and "column '" in proc.stderr
    assert "look like radians but the profile says joint_unit: deg" in proc.stderr
    assert not (tmp_path / "x.json").exists()


def test_degrees_in_a_radian_profile_name_the_line_and_column(tmp_path: Path) -> None:
    text = MOTOMAN_YAML.read_text().replace("joint_unit: deg", "joint_unit: rad")
    (tmp_path / "motoman-rad.yaml").write_text(text)
    profile = load_profile(tmp_path / "motoman-rad.yaml")
    with pytest.raises(InputError, match="look like degrees but the profile says joint_unit: rad") as err:
        read_dataset(profile, FEB)
    assert err.value.line is not None and err.value.column is not None and str(FEB) in str(err.value)
    # The same file read as degrees is fine, and so are radians read as radians.
    read_dataset(load_profile("motoman"), FEB)
    radians_copy(tmp_path / "rad.csv")
    assert (
        read_dataset(profile, tmp_path / "rad.csv").n_observations
        == read_dataset(load_profile("motoman"), FEB).n_observations
    )


def test_a_file_whose_later_half_is_in_radians_is_refused_naming_its_lines(tmp_path: Path) -> None:
    """Half the Feb 2019 tracker file's rows in radians: before this check it imported with no note and
    calibrated "done" to 63.5 cm. The check is per configuration; a file all in degrees still reads."""
    with FEB.open(newline="") as f:
        rows = list(csv.DictReader(f))
    half = len(rows) // 2
    with (tmp_path / "mixed.csv").open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        for i, r in enumerate(rows):
            w.writerow(
                {
                    k: (str(math.radians(float(v))) if i >= half and k.endswith("_deg") and v else v)
                    for k, v in r.items()
                }
            )
    with pytest.raises(InputError, match=r"configurations read like radians although the profile says joint_unit: deg"):
        read_dataset(load_profile("motoman"), tmp_path / "mixed.csv")
    with pytest.raises(InputError) as err:
        read_dataset(load_profile("motoman"), tmp_path / "mixed.csv")
    message = str(err.value)
    assert f"{len(rows) - half} of {len(rows)} configurations" in message
    assert f"lines {half + 2}, {half + 3}," in message  # the first radian row is line half + 2 (after the header)
    read_dataset(load_profile("motoman"), FEB)


def test_residuals_far_above_the_declared_noise_are_warned_about() -> None:
    # Mode `full` holds every error of the simulated Motoman (`offsets` does not: its residuals are 14
    # times the noise, rightly warned about), so only the noise differs.
    mm = load_profile("motoman")
    robot = SimulatedRobot.from_profile(mm, seed=2)
    robot.point_noise = 0.01  # 10 mm per axis where the profile declares 0.05 mm
    noisy = calibrate(mm, robot.simulate(80).data, "full")
    assert [d.code for d in noisy.diagnostics].count("noise-excess") == 1
    assert "tracker" in next(d.message for d in noisy.diagnostics if d.code == "noise-excess")
    quiet = calibrate(mm, SimulatedRobot.from_profile(mm, seed=2).simulate(80).data, "full")
    assert "noise-excess" not in [d.code for d in quiet.diagnostics]
    assert np.isfinite(quiet.figures["after"].rms)


def test_diagnostics_group_one_line_per_kind_the_decisive_ones_first() -> None:
    """Weak and held parameters after what changes whether to apply (a fit that did not converge, residuals above
    the noise); a kind of several is one line naming its parameters, each message kept; notes after warnings."""
    from calib_core.estimation import Diagnostic, Severity
    from calib_core.estimation.reports import group_diagnostics

    def warn(code: str, message: str, *parameters: str) -> Diagnostic:
        return Diagnostic(Severity.WARNING, code, message, parameters)

    found = [
        warn("weak", "a, b: weakly determined", "a", "b"),
        Diagnostic(Severity.INFO, "model-error", "3 observations kept"),
        warn("held-fixed", "c held", "c"),
        warn("weak", "d: weakly determined", "d"),
        warn("noise-excess", "the residuals of 'tracker' are 40 times the noise"),
        warn("held-fixed", "e held", "e"),
        warn("not-converged", "the solver did not converge"),
    ]
    groups = group_diagnostics(found)
    assert [(g.severity, g.code) for g in groups] == [
        (Severity.WARNING, "not-converged"),
        (Severity.WARNING, "noise-excess"),
        (Severity.WARNING, "weak"),
        (Severity.WARNING, "held-fixed"),
        (Severity.INFO, "model-error"),
    ]
    assert groups[0].title == "the solver did not converge" and groups[0].messages == ("the solver did not converge",)
    assert groups[2].title.startswith("3 parameters weakly determined") and groups[2].title.endswith(": a, b, d")
    assert groups[2].messages == ("a, b: weakly determined", "d: weakly determined")
    assert groups[3].parameters == ("c", "e") and groups[3].title.endswith(": c, e")
