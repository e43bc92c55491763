"""The measurement / point CSV readers parse whole columns at once: checked against a plain row-by-row
reading of the same text (blank rows, padded fields, line numbers in errors)."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from skyrig.errors import InputFormatError
from skyrig.io.points_csv import read_measurements_csv_lines


def _text(rng: np.random.Generator, n: int) -> str:
    rows = ["# made by a test", "point, image ,column,row"]
    for k in range(n):
        rows.append(f"p{k % 97}, im{k // 97} ,{rng.uniform(0, 4000):.3f}, {rng.uniform(0, 3000):.3f}")
        if k % 13 == 0:
            rows.append("")  # an empty line
        if k % 29 == 0:
            rows.append(" , ,, ")  # empty fields only
    return "\n".join(rows) + "\n"


def test_bulk_reading_equals_a_row_by_row_reading(tmp_path):
    text = _text(np.random.default_rng(3), 2000)
    f = tmp_path / "m.csv"
    f.write_text(text)
    m, ln = read_measurements_csv_lines(f)
    want = []
    for k, row in enumerate(csv.reader(text.splitlines()), start=1):
        if k <= 2 or not any(c.strip() for c in row):
            continue
        want.append((row[0].strip(), row[1].strip(), float(row[2]), float(row[3]), k))
    assert len(m.point) == len(want)
    assert [str(p) for p in m.point] == [w[0] for w in want]
    assert [str(i) for i in m.image] == [w[1] for w in want]
    assert np.array_equal(m.pixel, np.array([w[2:4] for w in want]))
    assert ln.tolist() == [w[4] for w in want]


@pytest.mark.parametrize("bad, field", [("abc", "column"), ("nan", "row"), ("inf", "column")])
def test_the_first_bad_number_is_named_with_its_line(tmp_path, bad, field):
    text = _text(np.random.default_rng(4), 300).splitlines()
    k = 150  # a data line (1-based line k + 1)
    parts = text[k].split(",")
    parts[2 if field == "column" else 3] = bad
    text[k] = ",".join(parts)
    f = tmp_path / "m.csv"
    f.write_text("\n".join(text) + "\n")
    with pytest.raises(InputFormatError) as e:
        read_measurements_csv_lines(f)
    assert f"line {k + 1}" in str(e.value) and field in str(e.value)
