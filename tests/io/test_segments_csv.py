import numpy as np
import pytest

from featmap.errors import InputFileError
from featmap.io.segments_csv import (SegmentTable, read_fused_csv, read_segments_csv, write_fused_csv,
                                     write_segments_csv)


def test_segments_round_trip_is_exact(tmp_path):
    rng = np.random.default_rng(0)
    table = SegmentTable(scan=np.arange(5), segments=rng.normal(0, 100, (5, 4)),
                         extra={"n_points": np.arange(5) * 10.0, "rms": rng.uniform(0, 0.1, 5)})
    write_segments_csv(tmp_path / "segments.csv", table)
    back = read_segments_csv(tmp_path / "segments.csv")
    assert np.array_equal(back.scan, table.scan)
    assert np.array_equal(back.segments, table.segments)
    assert np.array_equal(back.extra["rms"], table.extra["rms"])


def test_fused_round_trip(tmp_path):
    segs = np.array([[0.5, 1.25, 3.0, -4.0], [1e3, 2e3, 1e3, 2.5e3]])
    write_fused_csv(tmp_path / "f.csv", segs, np.array([3, 40]))
    back, support = read_fused_csv(tmp_path / "f.csv")
    assert np.array_equal(back, segs) and support.tolist() == [3, 40]
    assert (tmp_path / "f.csv").read_text().splitlines()[0] == "x1,y1,x2,y2,support,length_m"


@pytest.mark.parametrize("content,match", [
    ("scan,x1,y1,x2\n0,1,2,3\n", r"s.csv:1: missing column\(s\) y2"),
    ("scan,x1,y1,x2,y2\n0,1,2,3,4\n1,1,abc,3,4\n", r"s.csv:3: column 'y1': not a number: 'abc'"),
    ("scan,x1,y1,x2,y2\n0,1,2,nan,4\n", r"s.csv:2: column 'x2': nan is not a finite number"),
    ("scan,x1,y1,x2,y2\n0,1,2,inf,4\n", r"s.csv:2: column 'x2': inf is not a finite number"),
    ("scan,x1,y1,x2,y2\n0,1,2,3\n", r"s.csv:2: expected 5 values, found 4"),
    ("", r"s.csv:1: empty file"),
    ("scan,x1,y1,x2,y2\n0.5,1,2,3,4\n", r"s.csv:2: column 'scan': not an integer"),
])
def test_malformed_segments_name_file_and_line(tmp_path, content, match):
    path = tmp_path / "s.csv"
    path.write_text(content)
    with pytest.raises(InputFileError, match=match):
        read_segments_csv(path)


def test_zero_length_rows_are_skipped_and_counted(tmp_path):
    path = tmp_path / "s.csv"
    path.write_text("scan,x1,y1,x2,y2\n0,1,2,3,4\n1,5,5,5,5\n2,0,0,1,0\n")
    table = read_segments_csv(path)
    assert len(table) == 2 and table.skipped_zero_length == 1
    assert table.scan.tolist() == [0, 2]


def test_missing_file(tmp_path):
    with pytest.raises(InputFileError, match="nope.csv: file not found"):
        read_segments_csv(tmp_path / "nope.csv")


def test_fused_csv_with_the_drives_of_a_merged_map_reads_back(tmp_path):
    segs = np.array([[0.0, 0.0, 3.0, 0.0], [0.0, 1.0, 0.0, 5.0]])
    write_fused_csv(tmp_path / "f.csv", segs, np.array([7, 2]), {"n_drives": [2, 1], "drives": ["a;b", "b"]})
    lines = (tmp_path / "f.csv").read_text().splitlines()
    assert lines[0] == "x1,y1,x2,y2,support,length_m,n_drives,drives" and lines[1].endswith(",2,a;b")
    back, support = read_fused_csv(tmp_path / "f.csv")
    assert np.array_equal(back, segs) and support.tolist() == [7, 2]
