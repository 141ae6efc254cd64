"""calib_core.dataset: the CSV formats of specs/robonaut-a.md and specs/nao.md.

Examples for both profiles (column order free, extra columns ignored, rows grouped by frame id, the
other leg's columns not needed on NAO rows, every error an InputError naming file, line and column),
a round trip through to_csv, and property-based tests: any mutation of a valid file either parses
or raises InputError, never another exception.
"""

from __future__ import annotations

import csv
import io
import math
from functools import cache

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from calib_core import Dataset, InputError, Profile, SimulatedRobot, load_profile, parse_dataset, read_dataset, to_csv

PROFILES = ("robonaut-a", "nao")


@cache
def profile(name: str) -> Profile:
    return load_profile(name)


@cache
def simulated_csv(name: str, n: int = 20) -> str:
    p = profile(name)
    return to_csv(p, SimulatedRobot.from_profile(p, seed=1).simulate(n).data)


def table(text: str) -> list[list[str]]:
    return list(csv.reader(io.StringIO(text)))


def untable(rows: list[list[str]]) -> str:
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerows(rows)
    return out.getvalue()


def set_cell(text: str, line: int, column: str, value: str) -> str:
    rows = table(text)
    rows[line - 1][rows[0].index(column)] = value
    return untable(rows)


def assert_same(a: Dataset, b: Dataset, atol: float = 1e-12) -> None:
    np.testing.assert_array_equal(a.frame_ids, b.frame_ids)
    np.testing.assert_allclose(a.joints, b.joints, rtol=0, atol=atol, equal_nan=True)
    np.testing.assert_array_equal(a.cfg, b.cfg)
    np.testing.assert_array_equal(a.target, b.target)
    np.testing.assert_allclose(a.point, b.point, rtol=0, atol=atol, equal_nan=True)
    np.testing.assert_array_equal(a.vertex, b.vertex)
    np.testing.assert_allclose(a.measured, b.measured, rtol=0, atol=atol)


ROBONAUT_HEADER = (
    "frame,shoulder_roll,shoulder_pitch,elbow_roll,elbow_pitch,wrist_roll,wrist_pitch,wrist_yaw,"
    "neck_yaw,neck_pitch,neck_roll,x,y,z"
)
ROBONAUT_TEXT = (
    ROBONAUT_HEADER + "\n"
    "1,10,20,30,40,50,60,70,5,-10,0,1.5,80.25,-3\n"
    "2,-10,-20,-30,-40,-50,-60,-70,-5,10,0,-2,75,4.5\n"
    "3,0,0,0,0,0,0,0,0,0,0,0,90,0\n"
)

NAO_HEADER = (
    "frame,chain,vertex,u,v,bx,by,bz,HeadYaw,HeadPitch,LHipYawPitch,LHipRoll,LHipPitch,LKneePitch,"
    "LAnklePitch,LAnkleRoll,RHipYawPitch,RHipRoll,RHipPitch,RKneePitch,RAnklePitch,RAnkleRoll"
)
NAO_TEXT = (
    NAO_HEADER + "\n"
    "1,left,0,248.5,237.6,-45.5,37.5,0,12.5,10.5,0.8,6.1,-82.9,16.7,-67.7,6.4,,,,,,\n"
    "1,left,1,250.5,230.6,-20.5,37.5,0,12.5,10.5,0.8,6.1,-82.9,16.7,-67.7,6.4,,,,,,\n"
    "2,right,5,300,200,-45.5,-37.5,0,-12.5,20,,,,,,,-1,-5,-80,12,-60,-4\n"
    "1,right,2,310,210,-20.5,-37.5,0,12.5,10.5,,,,,,,1,2,3,4,5,6\n"
)


# --- Robonaut -------------------------------------------------------------------------------------


def test_robonaut_rows_units_and_lines() -> None:
    p = profile("robonaut-a")
    d = parse_dataset(p, ROBONAUT_TEXT, "day.csv")
    assert d.robot == "robonaut-a"
    assert d.source == "day.csv"
    assert d.n_configurations == d.n_observations == 3
    np.testing.assert_array_equal(d.frame_ids, [1, 2, 3])
    np.testing.assert_array_equal(d.lines, [2, 3, 4])
    assert d.joints.shape == (3, len(p.joints))
    assert d.joints[0, p.joint("shoulder_roll")] == pytest.approx(math.radians(10))
    assert d.joints[1, p.joint("neck_pitch")] == pytest.approx(math.radians(10))
    assert p.length_unit == "cm"
    np.testing.assert_allclose(d.measured[0], [1.5, 80.25, -3])
    assert d.header == ROBONAUT_HEADER.split(",")
    assert d.rows[2] == ["3", *["0"] * 10, "0", "90", "0"]


def test_robonaut_column_order_is_free_and_extra_columns_are_ignored() -> None:
    p = profile("robonaut-a")
    reference = parse_dataset(p, ROBONAUT_TEXT)
    rows = table(ROBONAUT_TEXT)
    order = list(reversed(range(len(rows[0]))))
    shuffled = [[r[i] for i in order] for r in rows]
    assert_same(parse_dataset(p, untable(shuffled)), reference)
    extra = [["note", *rows[0], "operator"]] + [[f"text, with 'quotes' {i}", *r, "x"] for i, r in enumerate(rows[1:])]
    assert_same(parse_dataset(p, untable(extra)), reference)
    # spaces around the header names and values, a BOM-less CRLF file, blank lines
    spaced = ROBONAUT_TEXT.replace(",", " , ").replace("\n", "\r\n\r\n")
    assert_same(parse_dataset(p, spaced), reference)


def test_robonaut_rows_of_one_frame_share_the_configuration() -> None:
    p = profile("robonaut-a")
    lines = ROBONAUT_TEXT.splitlines()
    text = "\n".join([*lines, lines[1].replace("1.5,80.25,-3", "1.7,80,-2.5")]) + "\n"
    d = parse_dataset(p, text)
    assert d.n_configurations == 3
    assert d.n_observations == 4
    np.testing.assert_array_equal(d.cfg, [0, 1, 2, 0])
    np.testing.assert_array_equal(d.lines, [2, 3, 4, 5])


def test_robonaut_rows_of_one_frame_with_other_joint_angles_are_an_error() -> None:
    p = profile("robonaut-a")
    lines = ROBONAUT_TEXT.splitlines()
    text = "\n".join([*lines, lines[1].replace("1,10,20", "1,10,21")]) + "\n"
    with pytest.raises(InputError) as info:
        parse_dataset(p, text, "day.csv")
    e = info.value
    assert (e.file, e.line) == ("day.csv", 5)
    assert "line 2" in e.message  # the line it contradicts
    assert "day.csv, line 5" in str(e)


@pytest.mark.parametrize(
    ("line", "column", "value", "words"),
    [
        (3, "x", "abc", "'abc'"),
        (2, "elbow_roll", "nan", "finite"),
        (4, "neck_roll", "NaN", "finite"),
        (3, "z", "inf", "finite"),
        (2, "y", "-Infinity", "finite"),
        (4, "wrist_yaw", "", "empty"),
        (4, "wrist_yaw", "   ", "empty"),
        (2, "frame", "1.5", "integer"),
        (3, "frame", "one", "'one'"),
        (2, "x", "1e400", "finite"),
        (3, "shoulder_pitch", "12 deg", "'12 deg'"),
    ],
)
def test_robonaut_bad_value_names_line_and_column(line: int, column: str, value: str, words: str) -> None:
    text = set_cell(ROBONAUT_TEXT, line, column, value)
    with pytest.raises(InputError) as info:
        parse_dataset(profile("robonaut-a"), text, "day.csv")
    e = info.value
    assert (e.file, e.line, e.column) == ("day.csv", line, column)
    assert words in e.message
    assert str(e).startswith(f"day.csv, line {line}, column '{column}': ")


@pytest.mark.parametrize("column", ROBONAUT_HEADER.split(","))
def test_robonaut_every_column_is_required(column: str) -> None:
    rows = table(ROBONAUT_TEXT)
    i = rows[0].index(column)
    text = untable([r[:i] + r[i + 1 :] for r in rows])
    with pytest.raises(InputError) as info:
        parse_dataset(profile("robonaut-a"), text, "day.csv")
    assert (info.value.file, info.value.line, info.value.column) == ("day.csv", 1, column)
    assert "missing" in info.value.message


@pytest.mark.parametrize(
    ("text", "line", "words"),
    [
        ("", None, "empty"),
        ("\n \n,,,\n", None, "empty"),
        (ROBONAUT_HEADER + "\n", 1, "no data"),
        (ROBONAUT_HEADER + "\n\n\n", 1, "no data"),
        (ROBONAUT_TEXT + "4,1,2,3\n", 5, "4 fields"),
        (ROBONAUT_TEXT + "4,1,2,3,4,5,6,7,8,9,10,11,12,13,14\n", 5, "15 fields"),
        (ROBONAUT_TEXT.replace("\n2,", '\n"2,', 1), 3, "fields"),
    ],
)
def test_robonaut_file_level_errors(text: str, line: int | None, words: str) -> None:
    with pytest.raises(InputError) as info:
        parse_dataset(profile("robonaut-a"), text, "day.csv")
    assert info.value.file == "day.csv"
    assert info.value.line == line
    assert words in info.value.message


# --- NAO ------------------------------------------------------------------------------------------


def test_nao_rows_of_one_frame_share_the_configuration_and_the_other_leg_is_not_needed() -> None:
    p = profile("nao")
    d = parse_dataset(p, NAO_TEXT, "nao.csv")
    assert d.n_observations == 4
    assert d.n_configurations == 2
    np.testing.assert_array_equal(d.frame_ids, [1, 2])
    np.testing.assert_array_equal(d.cfg, [0, 0, 1, 0])
    np.testing.assert_array_equal(d.target, [p.data.target_values[c] for c in ("left", "left", "right", "right")])
    np.testing.assert_array_equal(d.vertex, [0, 1, 5, 2])
    np.testing.assert_array_equal(d.lines, [2, 3, 4, 5])
    np.testing.assert_allclose(d.measured[2], [300, 200])
    np.testing.assert_allclose(d.point[1], [-20.5, 37.5, 0])  # mm: the profile's length unit
    assert p.length_unit == "mm"
    # frame 1: the left leg from the left rows, the right leg from the right row, the head from all
    q = d.joints[0]
    assert q[p.joint("LKneePitch")] == pytest.approx(math.radians(16.7))
    assert q[p.joint("RAnkleRoll")] == pytest.approx(math.radians(6))
    assert q[p.joint("HeadPitch")] == pytest.approx(math.radians(10.5))
    assert np.all(np.isfinite(q))
    # frame 2: only the right leg was needed; the left leg's empty columns stay unknown
    q = d.joints[1]
    assert np.isnan(q[p.joint("LHipPitch")])
    assert q[p.joint("RHipPitch")] == pytest.approx(math.radians(-80))


def test_nao_other_leg_columns_may_hold_anything() -> None:
    p = profile("nao")
    reference = parse_dataset(p, NAO_TEXT)
    text = set_cell(set_cell(NAO_TEXT, 2, "RKneePitch", "n/a"), 4, "LAnkleRoll", "nan")
    assert_same(parse_dataset(p, text), reference)


def test_nao_column_order_is_free_and_extra_columns_are_ignored() -> None:
    p = profile("nao")
    reference = parse_dataset(p, NAO_TEXT)
    rows = table(NAO_TEXT)
    order = sorted(range(len(rows[0])), key=lambda i: rows[0][i].lower())
    rows2 = [[*(r[i] for i in order), "extra"] for r in rows]
    rows2[0][-1] = "comment"
    assert_same(parse_dataset(p, untable(rows2)), reference)


def test_nao_rows_of_one_frame_with_other_joint_angles_are_an_error() -> None:
    text = set_cell(NAO_TEXT, 3, "HeadPitch", "11")
    with pytest.raises(InputError) as info:
        parse_dataset(profile("nao"), text, "nao.csv")
    assert (info.value.file, info.value.line) == ("nao.csv", 3)
    assert "frame 1" in info.value.message and "line 2" in info.value.message
    # a head joint of a right row contradicting the left rows of the same frame
    text = set_cell(NAO_TEXT, 5, "HeadYaw", "-12.5")
    with pytest.raises(InputError) as info:
        parse_dataset(profile("nao"), text, "nao.csv")
    assert info.value.line == 5


@pytest.mark.parametrize(
    ("line", "column", "value"),
    [
        (2, "chain", "middle"),
        (3, "chain", ""),
        (2, "vertex", "30"),
        (2, "vertex", "24"),
        (3, "vertex", "-1"),
        (3, "vertex", "2.5"),
        (4, "u", "abc"),
        (4, "bz", "nan"),
        (2, "HeadPitch", "nan"),
        (2, "LHipRoll", ""),
        (4, "RKneePitch", "inf"),
    ],
)
def test_nao_bad_value_names_line_and_column(line: int, column: str, value: str) -> None:
    text = set_cell(NAO_TEXT, line, column, value)
    with pytest.raises(InputError) as info:
        parse_dataset(profile("nao"), text, "nao.csv")
    assert (info.value.file, info.value.line, info.value.column) == ("nao.csv", line, column)


@pytest.mark.parametrize("column", ["frame", "chain", "vertex", "u", "v", "bx", "by", "bz", "HeadYaw", "RAnkleRoll"])
def test_nao_required_columns(column: str) -> None:
    rows = table(NAO_TEXT)
    i = rows[0].index(column)
    with pytest.raises(InputError) as info:
        parse_dataset(profile("nao"), untable([r[:i] + r[i + 1 :] for r in rows]), "nao.csv")
    assert (info.value.line, info.value.column) == (1, column)


# --- files ----------------------------------------------------------------------------------------


def test_read_dataset_files(tmp_path) -> None:
    p = profile("robonaut-a")
    good = tmp_path / "day.csv"
    good.write_bytes(b"\xef\xbb\xbf" + ROBONAUT_TEXT.encode())  # a BOM, as spreadsheets write it
    d = read_dataset(p, good)
    assert_same(d, parse_dataset(p, ROBONAUT_TEXT))
    assert d.source == str(good)
    assert d.header[0] == "frame"

    cases = {
        tmp_path / "missing.csv": "not exist",
        tmp_path: "directory",
    }
    binary = tmp_path / "image.csv"
    binary.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)))
    cases[binary] = "UTF-8"
    for path, words in cases.items():
        with pytest.raises(InputError) as info:
            read_dataset(p, path)
        assert info.value.file == str(path)
        assert words in info.value.message


# --- round trip -----------------------------------------------------------------------------------


@pytest.mark.parametrize("name", PROFILES)
def test_to_csv_then_parse_round_trips_a_simulated_dataset(name: str) -> None:
    p = profile(name)
    data = SimulatedRobot.from_profile(p, seed=1).simulate(20).data
    text = to_csv(p, data)
    back = parse_dataset(p, text, "sim.csv")
    assert back.n_observations == data.n_observations
    assert back.n_configurations == data.n_configurations
    np.testing.assert_array_equal(back.frame_ids, data.frame_ids)
    np.testing.assert_array_equal(back.cfg, data.cfg)
    np.testing.assert_array_equal(back.target, data.target)
    np.testing.assert_array_equal(back.vertex, data.vertex)
    np.testing.assert_allclose(back.measured, data.measured, rtol=0, atol=1e-5)
    np.testing.assert_allclose(back.point, data.point, rtol=0, atol=1e-5, equal_nan=True)
    # joints the rows need come back; the others (NAO: the other leg) are unknown after parsing
    known = np.isfinite(back.joints)
    assert known.any(axis=0).sum() >= len(p.joints) - 1
    np.testing.assert_allclose(back.joints[known], data.joints[known], rtol=0, atol=1e-5)
    # a second round trip is exact
    assert to_csv(p, back) == to_csv(p, parse_dataset(p, to_csv(p, back)))


# --- property-based: no input crashes the reader --------------------------------------------------

TOKENS = [
    ",",
    ",,",
    '"',
    '""',
    "'",
    "\n",
    "\r",
    "\r\n",
    "\x00",
    "\ufeff",
    " ",
    "\t",
    "nan",
    "NaN",
    "-nan",
    "inf",
    "-inf",
    "Infinity",
    "1e400",
    "-1e400",
    "1e308",
    "-1e308",
    "1e200",
    "1e-320",
    "1" * 30,
    "0x10",
    "1_000",
    "\uff11\uff12",  # full-width digits: float() accepts them
    "abc",
    "None",
    "True",
    "-0",
    "2.5",
    "-1",
    "23",
    "24",
    "30",
    "left",
    "right",
    "middle",
    "frame",
    "x",
    "chain",
    "vertex",
    "é",
    "😀",
]

KINDS = ("delete", "insert", "truncate", "duplicate_line", "delete_line", "swap_lines", "replace_field", "join_lines")

mutation = st.tuples(
    st.sampled_from([True, True, True, False]),  # mostly the data rows: header damage ends the parse early
    st.sampled_from(KINDS),
    st.integers(min_value=0, max_value=1 << 20),
    st.integers(min_value=0, max_value=1 << 20),
    st.one_of(st.sampled_from(TOKENS), st.text(max_size=6)),
)


def mutate(text: str, ops: list[tuple[bool, str, int, int, str]]) -> str:
    for body_only, kind, a, b, token in ops:
        head, sep, body = text.partition("\n")
        if body_only and sep and body:
            text = head + sep + mutate(body, [(False, kind, a, b, token)])
            continue
        lines = text.split("\n")
        n = len(lines)
        if kind == "delete":
            i = a % (len(text) + 1)
            text = text[:i] + text[i + 1 + b % 6 :]
        elif kind == "insert":
            i = a % (len(text) + 1)
            text = text[:i] + token + text[i:]
        elif kind == "truncate":
            text = text[: a % (len(text) + 1)]
        elif kind == "duplicate_line":
            lines.insert(b % (n + 1), lines[a % n])
            text = "\n".join(lines)
        elif kind == "delete_line":
            del lines[a % n]
            text = "\n".join(lines)
        elif kind == "swap_lines":
            i, j = a % n, b % n
            lines[i], lines[j] = lines[j], lines[i]
            text = "\n".join(lines)
        elif kind == "replace_field":
            i = a % n
            fields = lines[i].split(",")
            fields[b % len(fields)] = token
            lines[i] = ",".join(fields)
            text = "\n".join(lines)
        elif kind == "join_lines" and n > 1:
            i = a % (n - 1)
            lines[i : i + 2] = [lines[i] + lines[i + 1]]
            text = "\n".join(lines)
    return text


@cache
def small_csv(name: str) -> str:
    """A valid file of a few rows: short, so that random edits hit every part of it."""
    lines = simulated_csv(name, 4).splitlines()
    if name == "nao":  # rows of both legs, and rows sharing a frame
        lefts = [ln for ln in lines[1:] if ",left," in ln][:3]
        rights = [ln for ln in lines[1:] if ",right," in ln][:2]
        lines = [lines[0], *lefts, *rights]
        assert len(lefts) == 3 and len(rights) == 2
    else:
        lines = lines[:5]
    return "\n".join(lines) + "\n"


def check_parses_or_input_error(name: str, text: str) -> None:
    p = profile(name)
    try:
        d = parse_dataset(p, text, "fuzz.csv")
    except InputError as exc:
        assert exc.file == "fuzz.csv"
        assert str(exc).startswith("fuzz.csv")
        assert exc.message
        return
    # what parses is usable: finite numbers, one observation per data row, lines in order
    assert d.n_observations >= 1
    assert np.all(np.isfinite(d.measured))
    assert d.measured.shape == (d.n_observations, len(p.data.measurement_columns))
    assert np.all(np.diff(d.lines) > 0)
    assert len(d.rows) == d.n_observations
    assert set(d.cfg.tolist()) == set(range(d.n_configurations))
    assert len(set(d.frame_ids.tolist())) == d.n_configurations
    needed = [np.isfinite(d.joints[c]) for c in d.cfg]
    assert all(n.any() for n in needed)


@pytest.mark.parametrize("name", PROFILES)
@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(ops=st.lists(mutation, min_size=1, max_size=6))
@example(ops=[(True, "replace_field", 3, 5, "nan")])
@example(ops=[(True, "replace_field", 2, 0, "1e400")])
@example(ops=[(False, "truncate", 0, 0, "")])
@example(ops=[(False, "insert", 0, 0, "\x00")])
@example(ops=[(True, "insert", 40, 0, '"')])
def test_mutated_files_parse_or_raise_input_error(name: str, ops: list) -> None:
    text = mutate(small_csv(name), ops)
    check_parses_or_input_error(name, text)


@pytest.mark.parametrize("name", PROFILES)
@settings(max_examples=100, deadline=None)
@given(cell=st.text(max_size=12), line=st.integers(2, 5), col=st.integers(0, 30))
def test_any_cell_value_parses_or_raises_input_error(name: str, cell: str, line: int, col: int) -> None:
    rows = table(small_csv(name))
    rows[line - 1][col % len(rows[0])] = cell
    check_parses_or_input_error(name, untable(rows))


@pytest.mark.parametrize("name", PROFILES)
@pytest.mark.parametrize("frame", ["1e19", "9" * 20, "-1e19", "1e308"])
def test_frame_id_beyond_int64_is_an_input_error(name: str, frame: str) -> None:
    text = set_cell(small_csv(name), 2, "frame", frame)
    with pytest.raises(InputError) as exc:
        parse_dataset(profile(name), text, "big.csv")
    assert (exc.value.line, exc.value.column) == (2, "frame")
