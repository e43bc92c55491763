"""Issue 29, second pass: property-based tests of the remaining readers (hypothesis).

Same rule as ``tests/test_fuzz_trust.py``: a damaged file (NUL bytes, bytes that are not UTF-8, the file cut at
any byte, bytes inserted, an empty file) is either refused with a :class:`~skyrig.errors.SkyrigError` whose message
names the file (never another exception), or read as records each of which equals a record of the undamaged file
(the last one may hold a prefix of its last number when the file was cut inside it: the stated limit of a file
without a final newline).  Readers: skyrig EO CSV, IGN .OPK / .app / .mes / camera, ODM geo.txt and gcp_list.txt,
measurements CSV, raw scan CSV, SBET (binary: cut and inserted bytes, whole records of garbage).

Bounded in ``make test`` (derandomized, a few examples per reader); ``pytest -m fuzz -s`` runs 300 per reader
and prints the counts.
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
import warnings
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, example, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
import test_bad_input_readers as base  # noqa: E402
from test_fuzz_trust import _prefix_of_number  # noqa: E402

from skyrig.errors import SkyrigError  # noqa: E402

TEXT_KINDS = ("eo", "mes", "opk", "app", "imes", "cam", "gcp", "geo", "raw")
GOOD: dict[str, bytes] = {
    "eo": base.EO, "mes": base.MES, "opk": base.OPK, "app": base.APP, "imes": base.IMES, "cam": base.CAM,
    "gcp": base.GCP, "geo": base.GEO, "raw": base.RAW}
GOOD = {k: v.encode() for k, v in GOOD.items()}
SHORT = settings(max_examples=6, deadline=None, derandomize=True,
                 suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
LONG = settings(max_examples=300, deadline=None, derandomize=False,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


def _sbet_bytes() -> bytes:
    from skyrig.io.sbet import SBET_DTYPE

    rec = np.zeros(4, dtype=SBET_DTYPE)
    rec["time"] = 345600.0 + np.arange(4) * 0.005
    rec["latitude"] = np.radians(48.3)
    rec["longitude"] = np.radians(9.0) + np.arange(4) * 1e-7
    rec["altitude"] = 1200.0
    rec["roll"], rec["pitch"], rec["heading"] = 0.01, -0.02, 1.5
    return rec.tobytes()


GOOD["sbet"] = _sbet_bytes()
KINDS = TEXT_KINDS + ("sbet",)
FILE_NAME = {**base.FILE_NAME, "sbet": "sbet_fuzz.out"}


def _reader(kind: str):
    if kind == "sbet":
        from skyrig.io.sbet import read_sbet
        return read_sbet
    return base._reader(kind)


def _cell(v: object) -> object:
    if isinstance(v, (float, np.floating)):
        return None if not math.isfinite(float(v)) else float(v)
    if isinstance(v, (np.integer, int)) and not isinstance(v, bool):
        return int(v)
    if isinstance(v, np.str_):
        return str(v)
    return v


def _rows(obj: object) -> list[tuple]:
    """Any reader's result as comparable records: rows of its per-record arrays (a lone object: one row)."""
    if isinstance(obj, tuple):
        return [(k, *r) for k, part in enumerate(obj) for r in _rows(part)]
    if isinstance(obj, dict):
        return [("meta", tuple(sorted(obj.items())))]
    names = ([f.name for f in dataclasses.fields(obj)] if dataclasses.is_dataclass(obj)
             else sorted(n for n in vars(obj) if not n.startswith("_")))
    vals = {n: getattr(obj, n) for n in names}
    arrays = {n: np.asarray(v) for n, v in vals.items() if isinstance(v, np.ndarray) and v.ndim >= 1}
    if not arrays:
        return [tuple(_cell(v) for n, v in vals.items() if isinstance(v, (str, int, float, np.number)))]
    n = max(a.shape[0] for a in arrays.values())
    cols = [a for a in arrays.values() if a.shape[0] == n]
    return [tuple(_cell(x) for c in cols for x in np.ravel(c[i])) for i in range(n)]


def read(kind: str | None, path: Path, reader=None) -> object:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return (reader or _reader(kind))(path)


ORIGINAL: dict[str, list[tuple]] = {}


def original(kind: str, tmp: Path) -> list[tuple]:
    if kind not in ORIGINAL:
        p = tmp / ("orig_" + FILE_NAME[kind])
        p.write_bytes(GOOD[kind])
        ORIGINAL[kind] = _rows(read(kind, p))
    return ORIGINAL[kind]


@st.composite
def damaged(draw: st.DrawFn, kind: str) -> tuple[str, bytes]:
    data = GOOD[kind]
    ops = ["nul", "not-utf8", "cut", "empty", "insert"] + (["garbage-record"] if kind == "sbet" else [])
    op = draw(st.sampled_from(ops))
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
    elif op == "insert":
        i = draw(st.integers(0, len(data)))
        junk = (st.binary(min_size=1, max_size=12) if kind == "sbet"  # text: control bytes (a digit is a new value)
                else st.lists(st.sampled_from([bytes([c]) for c in (*range(1, 9), 11, 12, *range(14, 32), 127)]),
                              min_size=1, max_size=4).map(b"".join))
        data = data[:i] + draw(junk) + data[i:]
    else:  # a whole SBET record of arbitrary bytes inserted between two records
        from skyrig.io.sbet import SBET_RECORD_SIZE
        k = draw(st.integers(0, len(data) // SBET_RECORD_SIZE)) * SBET_RECORD_SIZE
        data = data[:k] + draw(st.binary(min_size=SBET_RECORD_SIZE, max_size=SBET_RECORD_SIZE)) + data[k:]
    return op, data


#: Formats whose lines may end early (optional trailing fields): a line cut after a field is a valid line.
OPTIONAL_TAIL = {"gcp", "geo"}


def check_damage(kind: str, tmp: Path, op: str, data: bytes) -> None:
    p = tmp / FILE_NAME[kind]
    p.write_bytes(data)
    try:
        got = read(kind, p)
    except SkyrigError as exc:
        msg = str(exc)
        assert p.name in msg, (op, msg)
        assert "Traceback" not in msg and "np.float64" not in msg, msg
        return
    orig = original(kind, tmp)
    rec = _rows(got)
    tail = GOOD[kind][len(data):].split(b"\n")[0]
    in_last_field = op == "cut" and GOOD[kind].startswith(data) and data[-1:] not in b"\n" \
        and (kind in OPTIONAL_TAIL or not any(c in tail for c in b" \t,"))
    for k, r in enumerate(rec):
        if r in orig or (in_last_field and (k == len(rec) - 1 or kind in OPTIONAL_TAIL)):  # eo: angles compared as a rotation
            continue
        # a file cut inside its last number or name: that record may hold a prefix of it (the stated limit)
        assert op == "cut" and any(len(r) <= len(o) and all(_prefix(a, b) for a, b in zip(r, o)) for o in orig), \
            (op, data, r, orig)


def _prefix(a: object, b: object) -> bool:
    if isinstance(a, int) and isinstance(b, int):
        return str(b).startswith(str(a))
    return _prefix_of_number(a, b)


@pytest.mark.parametrize("kind", KINDS)
def test_original_reads(tmp_path, kind):
    """The baseline itself is read (a reader refusing everything would pass the damage rule)."""
    assert len(original(kind, tmp_path)) >= 1


@pytest.mark.parametrize("kind", KINDS)
def test_damage_is_refused_in_words_or_reads_the_original(tmp_path, kind):
    @SHORT
    @given(case=damaged(kind))
    @example(case=("empty", b""))
    @example(case=("not-utf8", b"\xff" + GOOD[kind]))
    @example(case=("nul", GOOD[kind][:-1] + b"\x00" + GOOD[kind][-1:]))
    def check(case: tuple[str, bytes]) -> None:
        check_damage(kind, tmp_path, *case)

    check()


@pytest.mark.slow
@pytest.mark.fuzz
@pytest.mark.parametrize("kind", KINDS)
def test_fuzz_long_profile(tmp_path, kind):
    """``pytest -m fuzz -s``: up to 300 damaged files per reader; prints the counts by damage."""
    count: Counter = Counter()

    @LONG
    @given(case=damaged(kind))
    def damage(case: tuple[str, bytes]) -> None:
        count[case[0]] += 1
        check_damage(kind, tmp_path, *case)

    damage()
    print(f"\nfuzz {kind}: " + ", ".join(f"{k} {v}" for k, v in sorted(count.items())))
    assert sum(count.values()) >= 100


#: Failures the fuzzing found (each was read without a word before the fix), kept as regression cases.
FOUND = [
    ("eo", "insert", GOOD["eo"].replace(b"\nimg1", b"\n\x01img1")),  # a control byte read into an image name
    ("imes", "insert", b"\x01" + GOOD["imes"]),
    ("raw", "insert", GOOD["raw"].replace(b"\n3456", b"\n\x0b3456", 1)),  # \x0b splits a line in str.splitlines
    ("cam", "cut", GOOD["cam"][:-3]),  # 'height = 3' with PPAy 1499.5: principal point outside the image
    ("sbet", "garbage-record", bytes(136) + GOOD["sbet"]),  # a blank record at time 0 before the flight
    ("sbet", "garbage-record", b"\x00" * 32 + b"\x01" + bytes(103) + GOOD["sbet"]),  # 5e-324 rad: (0, 0) too
]


def test_sbet_jump_between_records_is_refused(tmp_path):
    """A record 6.4 km from its neighbours 5 ms apart (1.3e6 m/s) is damage, not flight; 200 m/s is flight."""
    from skyrig.io.sbet import SBET_DTYPE

    for dlon, ok in ((1e-3, False), (200 * 0.005 / 6.4e6 / math.cos(math.radians(48.3)), True)):
        rec = np.frombuffer(GOOD["sbet"], dtype=SBET_DTYPE).copy()
        rec["longitude"][2:] += dlon
        p = tmp_path / "sbet_jump.out"
        p.write_bytes(rec.tobytes())
        if ok:
            assert len(read("sbet", p).time_s) == 4
        else:
            with pytest.raises(SkyrigError, match="record 3 is .* m/s from the previous"):
                read("sbet", p)


@pytest.mark.parametrize("kind,op,data", FOUND, ids=[f"{k}-{i}" for i, (k, _, _) in enumerate(FOUND)])
def test_found_cases_are_refused(tmp_path, kind, op, data):
    p = tmp_path / FILE_NAME[kind]
    p.write_bytes(data)
    with pytest.raises(SkyrigError, match=p.name):
        read(kind, p)


# --------------------------------------------------------------------------------------- block file manifest
#: Values no manifest key can mean where another was written: wrong JSON types and magnitudes beyond any block
#: (a plausible number in place of another, say a lever arm of -1 m, is another block, not damage).
BAD_VALUES = [None, "x", "", 1e300, -1e300, "NaN", [], {}, True, [1, 2], {"a": 1}]


@pytest.fixture(scope="module")
def block_dir(tmp_path_factory):
    from skyrig.adjust import AdjustConfig
    from skyrig.adjust.config import ReliabilityOptions
    from skyrig.adjust.synthetic import synthetic_block
    from skyrig.io.block_file import read_block, write_block

    block, _ = synthetic_block(seed=1, n_strips=1, n_per_strip=3, n_points=20)
    d = tmp_path_factory.mktemp("blk")
    write_block(d / "block.json", block, AdjustConfig(reliability=ReliabilityOptions(snooping=True)))
    return d, json.loads((d / "block.json").read_text()), _block_key(read_block(d / "block.json"))


def _block_key(bf: object) -> tuple:
    """Everything a read block holds (every field of the Block, the adjustment configuration, the frame)."""
    b = bf.block  # type: ignore[attr-defined]
    out = [repr(bf.config), repr(getattr(bf, "frame", None))]  # type: ignore[attr-defined]

    def walk(v: object) -> None:  # the block's parts and each observation type's rows, down to their arrays
        if dataclasses.is_dataclass(v) and not isinstance(v, type) and not type(v).__module__.startswith("skyrig.camera"):
            for f in dataclasses.fields(v):
                walk(getattr(v, f.name))
        elif isinstance(v, dict):
            for k in sorted(v):
                out.append(repr(k))
                walk(v[k])
        else:
            out.append(np.round(v, 9).tobytes() if isinstance(v, np.ndarray) and v.dtype.kind == "f"
                       else (v.tobytes() if isinstance(v, np.ndarray) else repr(v)))

    walk(b)
    return tuple(out)


def _paths(obj: object, prefix: tuple = ()) -> list[tuple]:
    if isinstance(obj, dict):
        return [prefix] * bool(prefix) + [p for k, v in obj.items() for p in _paths(v, prefix + (k,))]
    if isinstance(obj, list):
        return [prefix] * bool(prefix) + [p for i, v in enumerate(obj) for p in _paths(v, prefix + (i,))]
    return [prefix]


@st.composite
def manifest_edit(draw: st.DrawFn, man: dict) -> tuple[tuple, object]:
    path = draw(st.sampled_from([p for p in _paths(man) if p and p[0] not in ("checksums", "format")]))
    return path, draw(st.sampled_from(BAD_VALUES))


def check_manifest(block_dir, path: tuple, value: object) -> None:
    import copy

    from skyrig.io.block_file import read_block

    d, man, want = block_dir
    if (path in (("adjustment",), ("adjustment", "reliability")) and value == {}) or (
            path == ("frame",) and isinstance(value, str)):
        return  # valid files: the adjustment's (or a part's) defaults; a free-text frame description
    man = copy.deepcopy(man)
    node = man
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = value
    p = d / "fuzz_block.json"
    p.write_text(json.dumps(man))
    try:
        got = read(None, p, reader=read_block)
    except SkyrigError as exc:
        assert p.name in str(exc) or "block_" in str(exc), (path, value, str(exc))  # the manifest or a table
        return
    assert _block_key(got) == want, (path, value)


def test_block_manifest_wrong_values_refused_or_same(block_dir):
    @SHORT
    @given(edit=manifest_edit(block_dir[1]))
    @example(edit=(("cameras", 0, "pp_col"), -1e300))  # found: a principal point off the image was read
    @example(edit=(("lever_arm_m",), 1e300))  # found: ValueError (reshape) instead of a refusal
    @example(edit=(("tables", "stations"), None))  # found: TypeError (path / None)
    @example(edit=(("frame",), None))  # found: a null frame read as the text 'None'
    @example(edit=(("cameras", 0, "focal_px"), True))  # a boolean read as focal 1 px
    def check(edit: tuple[tuple, object]) -> None:
        check_manifest(block_dir, *edit)

    check()


@pytest.mark.slow
@pytest.mark.fuzz
def test_block_manifest_long_profile(block_dir):
    count = Counter()

    @LONG
    @given(edit=manifest_edit(block_dir[1]))
    def check(edit: tuple[tuple, object]) -> None:
        count[edit[0][0]] += 1
        check_manifest(block_dir, *edit)

    check()
    print("\nfuzz block manifest: " + ", ".join(f"{k} {v}" for k, v in sorted(count.items())))
