"""Log CSVs parsed in blocks of rows (issue 15): the same table, values and errors whatever the
block size, as the whole-text parse gives; the text held bounded by a block; the limits."""

import csv
import io
import tracemalloc

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from spaceid import SpaceidError
from spaceid import _inputs, _memory
from spaceid.data import _tables, follow_log, read_log, read_joint_trajectory
from conftest import examples

JOINTS = ("left_shoulder", "left_elbow")
HEADER = "t,base_yaw,base_wz,q_left_shoulder,q_left_elbow,qd_left_shoulder,qd_left_elbow"


def _rows(n, start=0):
    return [f"{0.01 * i:.2f},{0.001 * i},0.01,{0.002 * i},-0.3,0.2,-0.5" for i in range(start, start + n)]


def _csv(tmp_path, lines, end="\n", name="log.csv"):
    path = tmp_path / name
    path.write_bytes(end.join(lines).encode() + end.encode())
    return path


def _whole(text):
    """The table as the reader before issue 15 made it from the whole text: the non-blank rows,
    their lines, and each column as floats (None when a cell is not a number)."""
    reader = csv.reader(io.StringIO(text, newline=""))
    rows, lines = zip(*[(row, reader.line_num) for row in reader if row])
    cells = np.array(rows[1:], dtype=str)
    columns = []
    for j in range(cells.shape[1]):
        try:
            columns.append(cells[:, j].astype(float))
        except ValueError:
            columns.append(None)
    return [name.strip() for name in rows[0]], list(lines[1:]), columns


def _outcome(path, block_rows):
    """The table read ``block_rows`` rows at a time (header, lines, columns with their first
    non-number's line and cell), or the message of the error."""
    try:
        table = _tables._read_csv(path, what="log", block_rows=block_rows)
    except SpaceidError as err:
        return str(err)
    text = {j: (int(table.lines[i]), cell) for j, (i, cell) in table.text.items()}
    values = table.values.copy()
    values[list(text)] = 0.0  # a column holding text: no values
    return table.header, table.lines.tolist(), values.shape, values.tobytes(), text


CELLS = ["0", "1.5", "-2e-3", " 7 ", "nan", "inf", "", "abc", '"3"', '"a,b"', '"x\ny"', "1e999"]


@st.composite
def csv_texts(draw):
    """Small CSVs: a header of 2-3 columns, rows of chosen cells, blank lines, any line ends; some
    rows ragged or with a stray quote."""
    n_cols = draw(st.integers(2, 3))
    lines = [",".join(f"c{j}" for j in range(n_cols))]
    for _ in range(draw(st.integers(0, 12))):
        kind = draw(st.sampled_from(["row"] * 8 + ["blank", "ragged", "quote"]))
        cells = [draw(st.sampled_from(CELLS)) for _ in range(n_cols)]
        lines.append({"row": ",".join(cells), "blank": "", "ragged": ",".join(cells[:-1]),
                      "quote": ",".join(cells) + 'x"y'}[kind])
    return draw(st.sampled_from(["\n", "\r\n", "\r"])).join(lines) + draw(st.sampled_from(["\n", ""]))


@settings(max_examples=examples(300, 40), deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=csv_texts())
def test_any_block_size_reads_what_the_whole_text_gives(tmp_path, text):
    path = tmp_path / "fuzz.csv"
    path.write_bytes(text.encode())
    whole = _outcome(path, 10**6)
    for block_rows in (1, 2, 3):
        assert _outcome(path, block_rows) == whole
    if isinstance(whole, str):
        return
    header, lines, columns = _whole(text)
    assert whole[0] == header and whole[1] == lines
    values = np.frombuffer(whole[3]).reshape(whole[2])
    for j, column in enumerate(columns):
        if column is None:  # the first cell that is not a number is named (the column's values are not used)
            assert j in whole[4]
        else:
            assert j not in whole[4]
            np.testing.assert_array_equal(values[j], column)


def test_a_log_read_in_blocks_equals_the_whole_read(tmp_path, monkeypatch):
    """Blank lines, CRLF ends, a text column and quoted cells, across block boundaries."""
    lines = [HEADER + ",note"] + [row + ',"ok, fine"' for row in _rows(10)]
    lines[4:4] = ["", ""]
    path = _csv(tmp_path, lines, end="\r\n")
    whole = read_log(path, joints=JOINTS, planar=True)
    monkeypatch.setattr(_tables, "BLOCK_ROWS", 3)
    blocked = read_log(path, joints=JOINTS, planar=True)
    for name in ("t", "q", "qd", "base_quat", "base_w"):
        np.testing.assert_array_equal(getattr(blocked, name), getattr(whole, name))
    assert blocked.meta["columns"] == whole.meta["columns"] == HEADER.split(",") + ["note"]
    np.testing.assert_array_equal(blocked.t, 0.01 * np.round(np.arange(10), 2))
    assert _tables._read_csv(path, what="log", block_rows=3).lines.tolist() == [2, 3, 4, 7, 8, 9, 10, 11, 12, 13]


BAD_LATER = {  # line 9 of the file (a blank line 5 before it), in the third block of 3 rows
    "not a number": ("0.07,0,0.01,abc,0,0,0", r"line 9, column 'q_left_shoulder': 'abc' is not a number"),
    "NaN": ("0.07,0,0.01,0,nan,0,0", r"column 'q_left_elbow' holds nan \(first at line 9\)"),
    "ragged": ("0.07,0,0.01,0,0,0", r"line 9 has 6 fields but the header has 7"),
    "malformed": ("0.07,0,0.01,0,0,0," + "1" * 200_000, r"line 9: malformed CSV \(field larger than field limit"),
    "time order": ("0.01,0,0.01,0,0,0,0", r"t = 0\.01 at line 9 follows t = 0\.05"),
}


@pytest.mark.parametrize("case", BAD_LATER)
def test_an_error_in_a_later_block_names_its_line(tmp_path, monkeypatch, case):
    row, message = BAD_LATER[case]
    path = _csv(tmp_path, [HEADER, *_rows(3), "", *_rows(3, 3), row, *_rows(4, 8)])
    for block_rows in (3, 10**6):
        monkeypatch.setattr(_tables, "BLOCK_ROWS", block_rows)
        with pytest.raises(SpaceidError, match=message):
            read_log(path, joints=JOINTS, planar=True)


def test_the_text_held_is_one_block(tmp_path, monkeypatch):
    """Peak memory while reading is the float table (8 bytes a cell) and one block of rows; the
    whole text (2.5 times the floats here) held at once would exceed it."""
    n = 5000
    rows = np.random.default_rng(0).uniform(0.1, 1, (n, 7)).cumsum(axis=0)
    path = _csv(tmp_path, [HEADER] + [",".join(f"{x:.17g}" for x in row) for row in rows])
    floats = n * 7 * 8
    assert path.stat().st_size > 2 * floats
    monkeypatch.setattr(_tables, "BLOCK_ROWS", 100, raising=False)
    monkeypatch.setattr(_inputs, "READ_BLOCK", 1 << 12, raising=False)  # the line count's blocks
    tracemalloc.start()
    try:
        table = _tables._read_csv(path, what="log")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 2 * floats, peak
    np.testing.assert_array_equal(table.values, rows.T)


def test_limits_of_a_table(tmp_path, monkeypatch):
    path = _csv(tmp_path, [HEADER, *_rows(3)])
    monkeypatch.setattr(_memory, "available_memory", lambda: 8.0 * _tables.TABLE_COPIES * 27)  # 4 lines of 7
    with pytest.raises(SpaceidError, match=r"log\.csv: 4 lines of 7 columns would need about .* GiB of memory, more "
                                           r"than the .* available: split the run, downsample it or drop columns"):
        read_log(path, joints=JOINTS, planar=True)
    monkeypatch.setattr(_memory, "available_memory", lambda: 8.0 * _tables.TABLE_COPIES * 28)
    read_log(path, joints=JOINTS, planar=True)
    monkeypatch.setattr(_tables, "count_input_lines", lambda *args, **kwargs: (1, 0))  # the file grew since
    with pytest.raises(SpaceidError, match=r"log\.csv: the log grew while it was read: read it once it is complete"):
        read_log(path, joints=JOINTS, planar=True)


def test_a_byte_not_utf8_is_named_across_read_blocks(tmp_path, monkeypatch):
    """Counted from the file's start, with a character cut between two blocks before it."""
    monkeypatch.setattr(_inputs, "READ_BLOCK", 4)
    path = tmp_path / "log.csv"
    path.write_bytes("t,é\n".encode() + b"0,\xff\n")  # 'é' is bytes 2-3: cut between blocks 1 and 2
    with pytest.raises(SpaceidError, match=r"log\.csv: not a UTF-8 text file \(byte 7 cannot be decoded\)"):
        read_log(path, joints=(), planar=True, require_rates=False)
    path.write_bytes("t,é\n0,1\n".encode() + b"\xc3")  # a character cut by the end of the file
    with pytest.raises(SpaceidError, match=r"byte 9 cannot be decoded"):
        read_log(path, joints=(), planar=True, require_rates=False)
    assert _inputs.count_input_lines(_csv(tmp_path, ["t,é", "0,1", "1,2"], end="\r\n"), "log", 100) == (3, 3)


def test_a_joint_trajectory_is_read_in_blocks(tmp_path, monkeypatch):
    header = "t,q_left_shoulder,q_left_elbow,qd_left_shoulder,qd_left_elbow"
    path = _csv(tmp_path, [header] + [f"{i},0.{i},0,0,0" for i in range(7)] + ["7,x,0,0,0"])
    monkeypatch.setattr(_tables, "BLOCK_ROWS", 2)
    with pytest.raises(SpaceidError, match=r"line 9, column 'q_left_shoulder': 'x' is not a number"):
        read_joint_trajectory(path, joints=JOINTS)


def test_follow_shares_the_parser(tmp_path):
    """A complete file followed gives read_log's rows; its errors name the same lines, and a
    header naming a column twice is refused as read_log refuses it."""
    path = _csv(tmp_path, [HEADER, "", *_rows(5)], end="\r\n")
    followed = list(follow_log(path, joints=JOINTS, planar=True, timeout=0.2, poll=0.01))
    np.testing.assert_array_equal(np.concatenate([log.q for log in followed]),
                                  read_log(path, joints=JOINTS, planar=True).q)
    for lines, message in (([HEADER, *_rows(3), "", "0.5,0,0,0,x,0,0"], r"line 6, column 'q_left_elbow': 'x'"),
                           ([HEADER + ",t", "0,0,0,0,0,0,0,1"], r"column 't' appears twice in the header")):
        path = _csv(tmp_path, lines)
        for read in (lambda: read_log(path, joints=JOINTS, planar=True),
                     lambda: list(follow_log(path, joints=JOINTS, planar=True, timeout=0.2, poll=0.01))):
            with pytest.raises(SpaceidError, match=message):
                read()
