"""The shipped sample sessions read back whole, and their detections agree with their truth."""

from pathlib import Path

import numpy as np
import pytest

from calib_core import InputError, Problem, load_profile
from calib_core.io.session import read_session

SAMPLES = Path(__file__).resolve().parent.parent / "sample_sessions"


@pytest.mark.parametrize("name", ["robonaut-a-day1", "robonaut-a-day2", "nao"])
def test_sample_session_reads_and_matches_its_truth(name: str) -> None:
    s = read_session(SAMPLES / name)
    profile = load_profile(s.robot)
    measured = [f for f in s.frames if f.status == "measured"]
    assert len(measured) == s.data.n_configurations > 0
    assert all((SAMPLES / name / path).is_file() for f in s.frames for path in f.images.values())
    truth = profile.params_from_display(s.truth)
    err = np.linalg.norm(Problem(profile, s.data, [], truth).predict(truth) - s.data.measured, axis=1)
    # Detections sit within the measurement noise of the truth (1 cm / 2 px at most), the nominal model far off.
    assert np.median(err) < (0.5 if profile.name == "robonaut-a" else 1.0)
    nominal = profile.nominal()
    off = np.linalg.norm(Problem(profile, s.data, [], nominal).predict(nominal) - s.data.measured, axis=1)
    assert np.median(off) > 5 * np.median(err)


def test_a_folder_without_session_json_is_bad_input(tmp_path: Path) -> None:
    with pytest.raises(InputError, match=r"session\.json"):
        read_session(tmp_path)
