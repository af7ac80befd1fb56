"""read_json: the one JSON reader; malformed files are one line naming the file."""

import pytest

from featmap.errors import InputFileError
from featmap.io.jsonfile import read_json


@pytest.mark.parametrize("constant", ["NaN", "Infinity", "-Infinity"])
def test_read_json_refuses_non_finite_numbers(tmp_path, constant):
    path = tmp_path / "data.json"
    path.write_text(f'{{"a": [1.5, {{"b": {constant}}}]}}')
    with pytest.raises(InputFileError, match=f"data.json: not valid JSON \\({constant} is not a finite number\\)$") as err:
        read_json(path)
    assert err.value.path == path and "\n" not in str(err.value)


def test_read_json_reads_finite_numbers_and_names_missing_files(tmp_path):
    path = tmp_path / "data.json"
    path.write_text('{"a": [1e308, -0.0, 2], "NaN": "NaN"}')              # the words as keys and strings are fine
    assert read_json(path) == {"a": [1e308, -0.0, 2], "NaN": "NaN"}
    with pytest.raises(InputFileError, match="none.json: not here"):
        read_json(tmp_path / "none.json", "not here")
