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
    ("scan,x1,y1,x2,y2,x1\n0,1,2,3,4,9\n", r"s.csv:1: column 'x1' appears more than once in the header"),
    ("scan,x1,y1,x2,y2, scan\n0,1,2,3,4,5\n", r"s.csv:1: column 'scan' appears more than once"),
    ("scan,x1,y1,x2,y2\n0,1,2,3,4\n1e30,1,2,3,4\n", r"s.csv:3: column 'scan': 1e30 is outside the 64-bit integer range"),
    ("scan,x1,y1,x2,y2\n-1e30,1,2,3,4\n", r"s.csv:2: column 'scan': -1e30 is outside the 64-bit integer range"),
    ("scan,x1,y1,x2,y2\n9223372036854775808,1,2,3,4\n", r"s.csv:2: column 'scan': 9223372036854775808 is outside"),
    ("scan,x1,y1,x2,y2\n0,1,2,3,4\n2.5,1,2,3,4\n", r"s.csv:3: column 'scan': not an integer: 2.5"),
    ("scan,x1,y1,x2,y2,rms\n0,1,2,3,4,0.01\n1,1,2,3,4,-0.02\n", r"s.csv:3: column 'rms': -0.02 is negative"),
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


def test_fused_csv_with_a_repeated_column_or_fractional_support_fails(tmp_path):
    path = tmp_path / "f.csv"
    path.write_text("x1,y1,x2,y2,support,x2\n0,0,1,0,3,7\n")
    with pytest.raises(InputFileError, match=r"f.csv:1: column 'x2' appears more than once in the header"):
        read_fused_csv(path)
    path.write_text("x1,y1,x2,y2,support\n0,0,1,0,2.5\n")
    with pytest.raises(InputFileError, match=r"f.csv:2: column 'support': not an integer: 2.5"):
        read_fused_csv(path)


def test_scan_ids_are_read_exactly_over_the_whole_int64_range(tmp_path):
    path = tmp_path / "s.csv"
    path.write_text("scan,x1,y1,x2,y2\n9007199254740993,0,0,1,0\n9007199254740992,0,0,1,0\n"
                    "-9223372036854775808,0,0,2,0\n9223372036854775807,0,0,3,0\n1e3,0,0,4,0\n")
    table = read_segments_csv(path)
    assert table.scan.dtype == np.int64 and table.skipped_duplicates == 0
    assert table.scan.tolist() == [2 ** 53 + 1, 2 ** 53, -(2 ** 63), 2 ** 63 - 1, 1000]


def test_duplicate_rows_are_still_skipped_and_counted(tmp_path):
    path = tmp_path / "s.csv"
    path.write_text("scan,x1,y1,x2,y2\n1,0,0,1,0\n0,0,0,1,0\n1,0,0,1,0\n1,0,0,1,0\n0,0,0,2,0\n")
    table = read_segments_csv(path)
    assert table.scan.tolist() == [1, 0, 0] and table.skipped_duplicates == 2
    assert table.segments[:, 2].tolist() == [1, 1, 2]


def test_blank_lines_are_ignored(tmp_path):
    path = tmp_path / "s.csv"
    path.write_text("\nscan,x1,y1,x2,y2\n0,1,2,3,4\n  \n1,5,6,7,8\n\n \t\n")
    table = read_segments_csv(path)
    assert table.scan.tolist() == [0, 1] and table.segments.tolist() == [[1, 2, 3, 4], [5, 6, 7, 8]]
    path.write_text("x1,y1,x2,y2,support\n0,0,1,0,3\n\n")
    segments, support = read_fused_csv(path)
    assert segments.tolist() == [[0, 0, 1, 0]] and support.tolist() == [3]


def test_line_numbers_count_the_blank_lines(tmp_path):
    path = tmp_path / "s.csv"
    path.write_text("scan,x1,y1,x2,y2\n\n0,1,2,3,4\n\n1,1,abc,3,4\n")
    with pytest.raises(InputFileError, match=r"s.csv:5: column 'y1': not a number: 'abc'"):
        read_segments_csv(path)
    path.write_text("  \n\n")
    with pytest.raises(InputFileError, match=r"s.csv:1: empty file"):
        read_segments_csv(path)


def test_coordinates_too_large_for_the_geometry_are_one_line(tmp_path):
    path = tmp_path / "far.csv"
    path.write_text("scan,x1,y1,x2,y2\n0,1e300,0,-1e300,0\n1,500000.5,5400000.25,500010.5,5400000.25\n")
    with pytest.raises(InputFileError, match=r"far.csv: a coordinate beyond 1e\+12 m \(1e\+300\)"):
        read_segments_csv(path)
    path.write_text("scan,x1,y1,x2,y2\n1,500000.5,5400000.25,500010.5,5400000.25\n")     # UTM-sized: fine
    assert len(read_segments_csv(path)) == 1
