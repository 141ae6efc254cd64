"""The shipped sample sessions read back whole, and their detections agree with their truth."""

import json
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


def test_a_session_of_several_sensors_round_trips_in_the_observations_format(tmp_path: Path) -> None:
    """The Motoman's tracker and cameras in one session folder: written in the observations format
    (one pinned CSV format cannot hold them), read back equal, and a bad cell named by line and column."""
    from calib_core.io.ctu_motoman import recording
    from calib_core.io.observations_csv import parse_observations, to_observations_csv
    from calib_core.io.session import FrameRecord, write_session

    mm = load_profile("motoman")
    data = recording(
        mm, Path(__file__).resolve().parents[1] / "sample_sessions" / "motoman-ctu", "leica_rep_self1_dataset.mat"
    )
    assert data.sensors == [0, 1, 2]
    frames = [FrameRecord(int(f), {}, "measured", "ok", {}, {}) for f in data.frame_ids]
    write_session(tmp_path / "s", mm, name="n", description="d", made_by="test", data=data, frames=frames)
    meta = json.loads((tmp_path / "s" / "session.json").read_text())
    assert (meta["data"], meta["data_format"]) == ("observations.csv", "observations")
    back = read_session(tmp_path / "s").data
    for field in ("frame_ids", "cfg", "target", "vertex", "sensor"):
        np.testing.assert_array_equal(getattr(back, field), getattr(data, field), err_msg=field)
    np.testing.assert_allclose(back.measured, data.measured, rtol=1e-11, equal_nan=True)
    np.testing.assert_allclose(back.joints, data.joints, rtol=1e-11, atol=1e-12, equal_nan=True)
    lines = to_observations_csv(mm, data).splitlines()
    lines[3] = (
        lines[3].replace(",camera1,", ",camera3,").replace(",tracker,", ",camera3,").replace(",camera2,", ",camera3,")
    )
    with pytest.raises(InputError) as err:
        parse_observations(mm, "\n".join(lines), "obs.csv")
    assert str(err.value).startswith(
        "obs.csv, line 4, column 'sensor': 'camera3' is not one of tracker, camera1, camera2"
    )
