"""Issue 29: property-based tests of the events, points, trajectory and rig readers (hypothesis).

Two rules, checked on files generated from the good ones of ``tests/test_bad_input_readers.py``:

* **Same meaning, same result.**  Columns in another order (header and rows together), Windows line ends, a
  byte-order mark, blank lines: the reader returns exactly what it returns for the original.
* **Damage: a refusal in words or the original's records.**  NUL bytes, bytes that are not UTF-8, the file cut at
  any byte, an empty file, the header alone, two columns' values swapped in every row: either a
  :class:`~skyrig.errors.SkyrigError` whose message names the file (never another exception), or records each of
  which equals a record of the original.  One limit is stated, not hidden: a file cut inside the last number of
  its last line cannot be told from a file with that shorter number (a hand-written file may end without a
  newline), so the last record read may hold that prefix of the number; and swaps no reader can see are left out
  (:data:`ANGLES`: two angle columns of a geographic trajectory).

Bounded in ``make test`` (a few examples per reader and rule, derandomized); ``pytest -m fuzz`` runs the long
profile (400 examples each).  Failures found are kept as explicit ``@example`` regression cases.
"""

from __future__ import annotations

import math
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, example, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
import test_bad_input_readers as base  # noqa: E402

from skyrig.errors import SkyrigError  # noqa: E402

KINDS = ("events", "pts", "traj", "rig")
GOOD = {"events": base.EVENTS, "pts": base.PTS, "traj": base.TRAJ, "rig": base.RIG}
SHORT = settings(max_examples=8, deadline=None, derandomize=True,
                 suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
LONG = settings(max_examples=400, deadline=None, derandomize=False,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


def records(kind: str, obj: object) -> list[tuple]:
    """What a reader returned, as comparable records (name-like key first, then the numbers)."""
    if kind == "events":
        return [(str(n), str(h), float(t), float(b) if np.isfinite(b) else None, int(x)) for n, h, t, b, x in
                zip(obj.image_name, obj.head, obj.time_s, obj.beta_rad, obj.exposure_id)]  # type: ignore[attr-defined]
    if kind == "pts":
        return [(str(n), *map(float, p)) for n, p in zip(obj.name, obj.xyz)]  # type: ignore[attr-defined]
    if kind == "traj":
        return [(float(t), float(a), float(b), float(c)) for t, a, b, c in
                zip(obj.time_s, obj.lat_deg, obj.lon_deg, obj.h_m)]  # type: ignore[attr-defined]
    out = []
    for h in obj.heads.values():  # type: ignore[attr-defined]
        c = h.camera
        out.append((h.name, c.width, c.height, c.focal_mm, c.pixel_size_mm, *np.round(h.lever_arm_m, 12).tolist()))
    return out


def read(kind: str, path: Path) -> object:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return base._reader(kind)(path)


ORIGINAL: dict[str, list[tuple]] = {}


def original(kind: str, tmp: Path) -> list[tuple]:
    if kind not in ORIGINAL:
        p = tmp / ("orig_" + base.FILE_NAME[kind])
        p.write_text(GOOD[kind])
        ORIGINAL[kind] = records(kind, read(kind, p))
    return ORIGINAL[kind]


# --------------------------------------------------------------------------------------- same meaning
def _split(text: str) -> tuple[list[str], str, list[str]]:
    lines = text.splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.strip() and not ln.startswith("#"))
    return lines[:k], lines[k], lines[k + 1:]


@st.composite
def same_meaning(draw: st.DrawFn, kind: str) -> str:
    text = GOOD[kind]
    if kind != "rig" and draw(st.booleans()):  # columns in another order, header and rows together
        head, cols, rows = _split(text)
        names = cols.split(",")
        order = draw(st.permutations(range(len(names))))
        cells = [r.split(",") for r in rows]
        text = "\n".join(head + [",".join(names[i] for i in order)]
                         + [",".join(c[i] for i in order) for c in cells]) + "\n"
    if kind != "rig" and draw(st.booleans()):  # blank lines among the rows
        head, cols, rows = _split(text)
        text = "\n".join(head + [cols] + [r + ("\n" if draw(st.booleans()) else "") for r in rows]) + "\n"
    if draw(st.booleans()):
        text = text.replace("\n", "\r\n")
    if draw(st.booleans()):
        text = "\ufeff" + text
    return text


# --------------------------------------------------------------------------------------- damage
@st.composite
def damaged(draw: st.DrawFn, kind: str) -> tuple[str, bytes]:
    data = GOOD[kind].encode()
    op = draw(st.sampled_from(["nul", "not-utf8", "cut", "empty", "header-only", "swap-columns"]))
    if op == "nul":
        for _ in range(draw(st.integers(1, 3))):
            i = draw(st.integers(0, len(data)))
            data = data[:i] + b"\x00" * draw(st.integers(1, 4)) + data[i:]
    elif op == "not-utf8":
        i = draw(st.integers(0, len(data)))
        data = data[:i] + draw(st.sampled_from([b"\xff", b"\xe9", b"\xc3\x28", b"\x80\x80", b"\xfe\xff"])) + data[i:]
    elif op == "cut":
        data = data[:draw(st.integers(0, len(data) - 1))]
    elif op == "empty":
        data = b""
    elif op == "header-only":
        if kind == "rig":
            data = GOOD[kind].split("heads:")[0].encode()
        else:
            head, cols, _ = _split(GOOD[kind])
            data = ("\n".join(head + [cols]) + "\n").encode()
    elif kind != "rig":  # swap two columns' values in every row, header kept
        head, cols, rows = _split(GOOD[kind])
        names = cols.split(",")
        pairs = [(a, b) for a in range(len(names)) for b in range(a + 1, len(names))
                 if not {names[a], names[b]} <= ANGLES]
        i, j = draw(st.sampled_from(pairs))
        out = []
        for r in rows:
            c = r.split(",")
            c[i], c[j] = c[j], c[i]
            out.append(",".join(c))
        data = ("\n".join(head + [cols] + out) + "\n").encode()
    return op, data


#: Columns whose values swap unseen: two angles in degrees (latitude, longitude, roll, pitch, yaw of a geographic
#: trajectory): latitude 0.5 and roll 48.3 deg are a flight elsewhere on Earth, banked; the area of use of a
#: projected CRS catches swapped x/y (the points rule), a time or height column swapped with anything is refused.
ANGLES = {"lat", "lon", "roll", "pitch", "yaw"}


def _prefix_of_number(a: object, b: object) -> bool:
    """``a`` could be ``b`` with its text cut short (the stated limit of a file cut in its last number)."""
    if isinstance(a, float) and isinstance(b, float):
        return math.isfinite(a) and abs(a) <= abs(b) + 1e-9
    if isinstance(a, str) and isinstance(b, str):
        return b.startswith(a)
    return a == b or (a is None)


def check_damage(kind: str, tmp: Path, op: str, data: bytes) -> None:
    p = tmp / base.FILE_NAME[kind]
    p.write_bytes(data)
    try:
        got = read(kind, p)
    except SkyrigError as exc:
        msg = str(exc)
        assert p.name in msg, (op, msg)
        assert "Traceback" not in msg and "np.float64" not in msg, msg
        return
    # read: every record must be one of the original's (the last one may be cut short when the file was cut)
    orig = original(kind, tmp)
    rec = records(kind, got)
    for k, r in enumerate(rec):
        if r in orig:
            continue
        last = k == len(rec) - 1 and op == "cut" and k < len(orig)
        assert last and all(_prefix_of_number(a, b) for a, b in zip(r, orig[k])), (op, data, r, orig)


def _at_last_line(text: str, insert: str) -> str:
    k = text.rstrip("\n").rfind("\n") + 1
    return text[:k] + insert + text[k:]


# --------------------------------------------------------------------------------------- the tests
@pytest.mark.parametrize("kind", KINDS)
def test_same_meaning_same_result(tmp_path, kind):
    @SHORT
    @given(text=same_meaning(kind))
    def check(text: str) -> None:
        p = tmp_path / base.FILE_NAME[kind]
        p.write_bytes(text.encode())
        assert records(kind, read(kind, p)) == original(kind, tmp_path), text

    check()


@pytest.mark.parametrize("kind", KINDS)
def test_damage_is_refused_in_words_or_reads_the_original(tmp_path, kind):
    @SHORT
    @given(case=damaged(kind))
    @example(case=("nul", GOOD[kind].encode().replace(b"\n", b"\x00\n", 1)))
    @example(case=("nul", _at_last_line(GOOD[kind], "\x00").encode()))  # found: a NUL read into a name
    @example(case=("not-utf8", b"\xff" + GOOD[kind].encode()))
    @example(case=("empty", b""))
    def check(case: tuple[str, bytes]) -> None:
        check_damage(kind, tmp_path, *case)

    check()


@pytest.mark.slow
@pytest.mark.fuzz
@pytest.mark.parametrize("kind", KINDS)
def test_fuzz_long_profile(tmp_path, kind):
    """``pytest -m fuzz -s``: the two rules with up to 400 examples each; prints the counts by rule and damage."""
    from collections import Counter

    count: Counter = Counter()

    @LONG
    @given(text=same_meaning(kind))
    def same(text: str) -> None:
        count["same meaning"] += 1
        p = tmp_path / base.FILE_NAME[kind]
        p.write_bytes(text.encode())
        assert records(kind, read(kind, p)) == original(kind, tmp_path), text

    @LONG
    @given(case=damaged(kind))
    def damage(case: tuple[str, bytes]) -> None:
        count[case[0]] += 1
        check_damage(kind, tmp_path, *case)

    same()
    damage()
    print(f"\nfuzz {kind}: " + ", ".join(f"{k} {v}" for k, v in sorted(count.items())))
    assert sum(v for k, v in count.items() if k != "same meaning") >= 100
