"""Issue 29, third pass: same-meaning and wrong-unit property tests (hypothesis) for the readers of
``tests/test_fuzz_readers2.py`` (which damages them; ``tests/test_fuzz_trust.py`` does both for events, points,
trajectory CSV and rig files).

* **Same meaning, same result.**  The skyrig EO CSV, measurements CSV and raw scan CSV with their columns in
  another order (header and rows together), Windows line ends, a byte-order mark, blank lines, spaces after the
  commas; the IGN .OPK / .app / .mes files with tabs for spaces and Windows line ends: the reader returns exactly
  what it returns for the original.
* **SBET fields in another unit: a refusal naming the field, or the original trajectory.**  A flight simulated
  here (two strips flown both ways with a climb between them, at 10 Hz, velocities, accelerations, angular
  rates and the wander angle filled in as Applanix documents them), written with one group of fields in the
  unit a producer may have used instead (positions or angles in degrees, the altitude in feet, velocities in
  km/h or knots, accelerations in mg, angular rates in deg/s, time in GPS seconds since 1980 or in ms, the heading
  relative to the wander-angle frame, the wander angle 20 deg or more).  The rule: a :class:`~skyrig.errors.SkyrigError` naming the file and one
  of the changed fields, or a trajectory equal to the original's (accelerations and angular rates are not used:
  a plausible value there changes nothing).  And the same flight with its velocities turned into another wander
  frame, or zeroed as skyrig's own writer leaves them, reads as the original.

Bounded in ``make test``; ``pytest -m fuzz -s`` runs 300 examples per rule and prints the counts.
"""

from __future__ import annotations

import sys
import warnings
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
import test_fuzz_readers2 as fr2  # noqa: E402

from skyrig.errors import SkyrigError  # noqa: E402

SHORT = settings(max_examples=8, deadline=None, derandomize=True,
                 suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
LONG = settings(max_examples=300, deadline=None, derandomize=False,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

# ------------------------------------------------------------------------------------ same meaning: text readers
CSV_KINDS = ("eo", "mes", "raw")
WS_KINDS = ("opk", "app", "imes")


def _split(text: str) -> tuple[list[str], str, list[str]]:
    lines = text.splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.strip() and not ln.startswith("#"))
    return lines[:k], lines[k], lines[k + 1:]


@st.composite
def same_meaning(draw: st.DrawFn, kind: str) -> tuple[str, bytes]:
    text = fr2.GOOD[kind].decode()
    done = []
    if kind in CSV_KINDS:
        if draw(st.booleans()):
            head, cols, rows = _split(text)
            names = cols.split(",")
            order = draw(st.permutations(range(len(names))))
            cells = [r.split(",") for r in rows]
            text = "\n".join(head + [",".join(names[i] for i in order)]
                             + [",".join(c[i] for i in order) for c in cells]) + "\n"
            done.append("columns")
        if draw(st.booleans()):
            head, cols, rows = _split(text)
            text = "\n".join(head + [cols] + [r + ("\n" if draw(st.booleans()) else "") for r in rows]) + "\n"
            done.append("blank lines")
        if draw(st.booleans()):
            head, cols, rows = _split(text)
            text = "\n".join(head + [cols] + [r.replace(",", ", ") for r in rows]) + "\n"
            done.append("spaces")
        if draw(st.booleans()):
            text = "\ufeff" + text
            done.append("bom")
    elif draw(st.booleans()):
        lines = text.splitlines()
        text = "\n".join(lines[:1] + [" ".join(ln.split()).replace(" ", draw(st.sampled_from(["\t", "  ", " \t"])))
                                       for ln in lines[1:]]) + "\n"
        done.append("tabs")
    if draw(st.booleans()):
        text = text.replace("\n", "\r\n")
        done.append("crlf")
    return "+".join(done) or "as is", text.encode()


def check_same(kind: str, tmp: Path, what: str, data: bytes) -> None:
    p = tmp / fr2.FILE_NAME[kind]
    p.write_bytes(data)
    got = fr2._rows(fr2.read(kind, p))
    assert got == fr2.original(kind, tmp), (what, data)


@pytest.mark.parametrize("kind", CSV_KINDS + WS_KINDS)
def test_same_meaning_same_result(tmp_path, kind):
    @SHORT
    @given(case=same_meaning(kind))
    def check(case: tuple[str, bytes]) -> None:
        check_same(kind, tmp_path, *case)

    check()


# ------------------------------------------------------------------------------------ SBET: units of each field
def flight(seed: int) -> np.ndarray:
    """A simulated SBET (structured records): two strips at ``speed`` flown both ways with a climb between them,
    10 Hz; velocities in the wander-angle frame (x, y turned from north, east by the wander angle, z down), body
    accelerations without gravity, angular rates from the attitude's change."""
    from skyrig.io.sbet import SBET_DTYPE

    rng = np.random.default_rng(seed)
    lat0, lon0 = np.radians(rng.uniform(30, 60)), np.radians(rng.uniform(5, 30))
    az = rng.uniform(0, 2 * np.pi)
    # a wander angle under about 10 deg cannot be told from a crab angle (the reader's stated limit): 20 deg or more
    speed, h0, wander = rng.uniform(40, 80), rng.uniform(300, 3000), rng.choice([-1, 1]) * rng.uniform(0.35, 1.2)
    dt, n_strip, n_climb = 0.1, 200, 100
    legs = [(az, 0.0, n_strip), (az + np.pi / 2, 4.0, n_climb), (az + np.pi, 0.0, n_strip)]
    n = sum(leg[2] for leg in legs)
    vn, ve, vu = np.zeros(n), np.zeros(n), np.zeros(n)
    k = 0
    for a, climb, m in legs:
        vn[k:k + m], ve[k:k + m], vu[k:k + m] = speed * np.cos(a), speed * np.sin(a), climb
        k += m
    north, east = np.cumsum(vn) * dt, np.cumsum(ve) * dt
    rec = np.zeros(n, dtype=SBET_DTYPE)
    rec["time"] = 345600.0 + rng.uniform(0, 3000) + dt * np.arange(n)
    rec["latitude"] = lat0 + north / 6_371_000.0
    rec["longitude"] = lon0 + east / (6_371_000.0 * np.cos(lat0))
    rec["altitude"] = h0 + np.cumsum(vu) * dt
    c, s = np.cos(wander), np.sin(wander)
    rec["x_velocity"], rec["y_velocity"], rec["z_velocity"] = c * vn + s * ve, -s * vn + c * ve, -vu
    crab = np.radians(rng.uniform(-4, 4))
    rec["heading"] = (np.arctan2(ve, vn) + crab + np.pi) % (2 * np.pi) - np.pi
    rec["roll"] = np.radians(rng.normal(0, 1.5, n))
    rec["pitch"] = np.radians(2.0 + rng.normal(0, 1.0, n))
    rec["wander"] = wander
    for f in ("x_acceleration", "y_acceleration", "z_acceleration"):
        rec[f] = rng.normal(0, 0.4, n)
    for f in ("x_angular_rate", "y_angular_rate", "z_angular_rate"):
        rec[f] = rng.normal(0, 0.03, n)
    return rec


#: (name, fields, change) of the units a producer may have written instead; fields: those the change touches.
_DEG = 180.0 / np.pi
UNIT_CHANGES = {
    "angles in degrees": (("roll", "pitch", "heading", "wander"), lambda r: _scale(r, ("roll", "pitch", "heading",
                                                                                     "wander"), _DEG)),
    "position in degrees": (("latitude", "longitude"), lambda r: _scale(r, ("latitude", "longitude"), _DEG)),
    "altitude in feet": (("altitude",), lambda r: _scale(r, ("altitude",), 1 / 0.3048)),
    "velocities in km/h": (("x_velocity", "y_velocity", "z_velocity"),
                           lambda r: _scale(r, ("x_velocity", "y_velocity", "z_velocity"), 3.6)),
    "velocities in knots": (("x_velocity", "y_velocity", "z_velocity"),
                            lambda r: _scale(r, ("x_velocity", "y_velocity", "z_velocity"), 1 / 0.514444)),
    "accelerations in mg": (("x_acceleration", "y_acceleration", "z_acceleration"),
                            lambda r: _scale(r, ("x_acceleration", "y_acceleration", "z_acceleration"), 1000 / 9.81)),
    "angular rates in deg/s": (("x_angular_rate", "y_angular_rate", "z_angular_rate"),
                               lambda r: _scale(r, ("x_angular_rate", "y_angular_rate", "z_angular_rate"), _DEG)),
    "time since 1980": (("time",), lambda r: _shift(r, "time", 2300 * 604800.0)),
    "time in ms": (("time",), lambda r: _scale(r, ("time",), 1000.0)),
    "heading in the wander frame": (("heading",), lambda r: _shift(r, "heading", -r["wander"])),
}


def _scale(rec: np.ndarray, fields: tuple[str, ...], f: float) -> np.ndarray:
    out = rec.copy()
    for name in fields:
        out[name] = rec[name] * f
    return out


def _shift(rec: np.ndarray, field: str, by) -> np.ndarray:  # noqa: ANN001
    out = rec.copy()
    out[field] = rec[field] + by
    return out


def _trajectory(path: Path):  # noqa: ANN202
    from skyrig.io.sbet import read_sbet

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_sbet(path)


def _same_trajectory(a, b) -> bool:  # noqa: ANN001
    return (np.array_equal(a.time_s, b.time_s) and np.allclose(a.lat_deg, b.lat_deg, atol=1e-12, rtol=0)
            and np.allclose(a.lon_deg, b.lon_deg, atol=1e-12, rtol=0) and np.allclose(a.h_m, b.h_m, atol=1e-9)
            and np.allclose(a.ned_from_body_q, b.ned_from_body_q, atol=1e-12))


def check_unit_change(tmp: Path, seed: int, change: str) -> str:
    fields, make = UNIT_CHANGES[change]
    rec = flight(seed)
    good, bad = tmp / "sbet_good.out", tmp / "sbet_unit.out"
    good.write_bytes(rec.tobytes())
    orig = _trajectory(good)
    bad.write_bytes(make(rec).tobytes())
    try:
        got = _trajectory(bad)
    except SkyrigError as exc:
        msg = str(exc)
        assert bad.name in msg and any(f"field '{f}'" in msg for f in fields), (change, msg)
        return "refused"
    assert _same_trajectory(got, orig), (change, seed)
    return "same"


@st.composite
def unit_change(draw: st.DrawFn) -> tuple[int, str]:
    return draw(st.integers(0, 2**16)), draw(st.sampled_from(sorted(UNIT_CHANGES)))


def test_the_simulated_flight_reads(tmp_path):
    """The baseline: every seed's flight is read without a word (a reader refusing everything would pass)."""
    for seed in range(6):
        p = tmp_path / "sbet.out"
        p.write_bytes(flight(seed).tobytes())
        from skyrig.io.sbet import read_sbet

        with warnings.catch_warnings():
            warnings.simplefilter("error")
            assert len(read_sbet(p)) == 500


@pytest.mark.parametrize("change", sorted(UNIT_CHANGES))
def test_sbet_field_in_another_unit_is_refused_or_harmless(tmp_path, change):
    """Every change on two flights; those skyrig uses (positions, angles, time) and the velocities must be
    refused, the others may be read as the original."""
    outcomes = {check_unit_change(tmp_path, seed, change) for seed in (3, 11)}
    if change not in ("accelerations in mg", "angular rates in deg/s"):
        assert outcomes == {"refused"}, (change, outcomes)


def test_sbet_unit_changes_property(tmp_path):
    @SHORT
    @given(case=unit_change())
    def check(case: tuple[int, str]) -> None:
        check_unit_change(tmp_path, *case)

    check()


@st.composite
def sbet_same_meaning(draw: st.DrawFn) -> tuple[int, str, float]:
    return (draw(st.integers(0, 2**16)), draw(st.sampled_from(["wander frame", "zeroed", "written by skyrig"])),
            draw(st.floats(-3.0, 3.0)))


def check_sbet_same(tmp: Path, seed: int, how: str, angle: float) -> None:
    from skyrig.io.sbet import write_sbet

    rec = flight(seed)
    good, other = tmp / "sbet_good.out", tmp / "sbet_same.out"
    good.write_bytes(rec.tobytes())
    orig = _trajectory(good)
    out = rec.copy()
    if how == "wander frame":  # velocities in a wander frame turned by another angle: the same motion
        c, s = np.cos(angle), np.sin(angle)
        out["x_velocity"], out["y_velocity"] = c * rec["x_velocity"] + s * rec["y_velocity"], \
            -s * rec["x_velocity"] + c * rec["y_velocity"]
        out["wander"] = rec["wander"] + angle
        other.write_bytes(out.tobytes())
    elif how == "zeroed":
        for f in ("x_velocity", "y_velocity", "z_velocity", "wander", "x_acceleration", "y_acceleration",
                  "z_acceleration", "x_angular_rate", "y_angular_rate", "z_angular_rate"):
            out[f] = 0.0
        other.write_bytes(out.tobytes())
    else:
        write_sbet(other, orig)
    assert _same_trajectory(_trajectory(other), orig), (how, seed)


def test_sbet_same_meaning_same_result(tmp_path):
    @SHORT
    @given(case=sbet_same_meaning())
    def check(case: tuple[int, str, float]) -> None:
        check_sbet_same(tmp_path, *case)

    check()


@pytest.mark.slow
@pytest.mark.fuzz
def test_fuzz_long_profile(tmp_path):
    """``pytest -m fuzz -s``: 300 examples per rule; prints the counts."""
    count: Counter = Counter()

    @LONG
    @given(case=unit_change())
    def units(case: tuple[int, str]) -> None:
        count[f"sbet {case[1]}: {check_unit_change(tmp_path, *case)}"] += 1

    @LONG
    @given(case=sbet_same_meaning())
    def same_sbet(case: tuple[int, str, float]) -> None:
        count[f"sbet same: {case[1]}"] += 1
        check_sbet_same(tmp_path, *case)

    units()
    same_sbet()
    def same_text(kind: str):  # noqa: ANN202
        @LONG
        @given(case=same_meaning(kind))
        def run(case: tuple[str, bytes]) -> None:
            count[f"{kind} same"] += 1
            check_same(kind, tmp_path, *case)

        return run

    for kind in CSV_KINDS + WS_KINDS:
        same_text(kind)()
    print("\n" + "\n".join(f"{k}: {v}" for k, v in sorted(count.items())))
