"""Bad IGN files (.OPK, .mes, .app / _world.mes): clear InputFormatErrors naming file and line, never a PROJ crash
or a silent misreading (issue 13)."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

from skyrig.cli import main
from skyrig.errors import InputFormatError
from skyrig.georef.eo import WorldFrame
from skyrig.io.ign import read_ign_ground_points, read_ign_measurements, read_ign_opk

L93 = WorldFrame.map("EPSG:2154")
OPK_HEAD = "NOM\tX\tY\tZ\tO\tP\tK\tCAMERA\n"
OPK_1 = "img_01     650000.000    6860000.000       2500.000     0.1     -0.2     90.0     cam1\n"
OPK_2 = "img_02     650500.000    6860000.000       2500.000     0.1     -0.2     90.0     cam1\n"
APP = '"1003" 13 815601.510 6283629.280 54.960\n"1005" 3 833670.940 6281965.400 52.630\n'
MES = '"1003" img_01 24042.25 14781.17\n"1003" img_02 24120.2 10329.3\n"1005" img_01 22796.05 14371.27\n'


def _read(kind, path):
    return {"opk": lambda p: read_ign_opk(p, L93), "mes": read_ign_measurements,
            "app": lambda p: read_ign_ground_points(p, L93)}[kind](path)


CASES = [
    # id, kind, text, line, field, words
    ("opk-empty", "opk", "", None, None, "empty OPK file"),
    ("opk-header-only", "opk", OPK_HEAD, 1, None, "no image after the header"),
    ("opk-duplicate-line", "opk", OPK_HEAD + OPK_1 + OPK_2 + OPK_1, 4, "NOM", "'img_01' appears twice (first on line 2)"),
    ("opk-duplicate-name", "opk", OPK_HEAD + OPK_1 + OPK_1.replace("650000", "651000"), 3, "NOM", "appears twice"),
    ("opk-truncated", "opk", OPK_HEAD + OPK_1 + OPK_2[:40], 3, "Z", "truncated"),
    ("mes-empty", "mes", "", None, None, "no measurement in the file"),
    ("mes-blank-and-comments", "mes", "\n# only a comment\n\n", None, None, "no measurement in the file"),
    ("mes-truncated", "mes", MES[:-20], 3, None, "expected 4 fields"),
    ("mes-truncated-hint", "mes", MES + '"1005" img_02 2279', 4, None, "ends in the middle of this line"),
    ("mes-duplicate", "mes", MES + MES.splitlines()[1] + "\n", 4, "point",
     "'1003' is measured twice in image 'img_02' (first on line 2)"),
    ("app-empty", "app", "", None, None, "no point in the file"),
    ("app-truncated-to-4-fields", "app", APP + '"1006" 13 838561.350 6284600.330\n', 3, None,
     "expected 5 fields (name type X Y Z, as on line 1), found 4"),
    ("app-truncated-mid-line", "app", APP + '"1006" 13 8385', 3, None, "truncated"),
    ("app-duplicate", "app", APP + APP.splitlines()[0] + "\n", 3, "name", "'1003' appears twice (first on line 1)"),
    ("app-bad-number", "app", APP.replace("52.630", "52,630"), 2, "Z", "not a number"),
    ("world-mes-mixed", "app", '"a" 1.0 2.0 3.0\n"b" 3 1.0 2.0 3.0\n', 2, None, "expected 4 fields (name X Y Z"),
]


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_bad_ign_file_names_file_and_line(tmp_path, case):
    _, kind, text, line, field, words = case
    p = tmp_path / f"bad.{kind}"
    p.write_text(text, encoding="utf-8")
    with pytest.raises(InputFormatError) as ei:
        _read(kind, p)
    e = ei.value
    assert e.path == str(p) and e.line == line and e.field == field
    assert words in str(e)
    assert "np." not in str(e) and "array(" not in str(e)


def test_good_files_still_read(tmp_path):
    (tmp_path / "a.OPK").write_text(OPK_HEAD + OPK_1 + OPK_2)
    (tmp_path / "a.mes").write_text(MES)
    (tmp_path / "a.app").write_text(APP)
    (tmp_path / "a_world.mes").write_text('"a" 815601.0 6283629.0 3.0\nb 815604 6283625 6\n')
    assert len(_read("opk", tmp_path / "a.OPK")) == 2
    assert len(_read("mes", tmp_path / "a.mes")) == 3
    g = _read("app", tmp_path / "a.app")
    assert g.name.tolist() == ["1003", "1005"] and g.kind.tolist() == [13, 3]
    w = _read("app", tmp_path / "a_world.mes")
    assert w.name.tolist() == ["a", "b"] and w.kind is None


@pytest.mark.parametrize("which", ["points", "measurements", "eo"])
def test_cli_empty_or_duplicated_ign_input_is_a_clean_error(tmp_path, which):
    (tmp_path / "a.OPK").write_text(OPK_HEAD + OPK_1 + OPK_2 + (OPK_1 if which == "eo" else ""))
    (tmp_path / "cam.txt").write_text("Name = cam1\nPPAx = 1999.5\nPPAy = 1499.5\nfocal = 4000\nwidth = 4000\n"
                                      "height = 3000\n")
    (tmp_path / "g.app").write_text("" if which == "points" else APP)
    (tmp_path / "t.mes").write_text("" if which == "measurements" else MES)
    res = CliRunner().invoke(main, ["world-to-image", "--eo", str(tmp_path / "a.OPK"), "--eo-crs", "EPSG:2154",
                                    "--camera", str(tmp_path / "cam.txt"), "--points", str(tmp_path / "g.app"),
                                    "--measurements", str(tmp_path / "t.mes"), "-o", str(tmp_path / "o.csv")])
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output and "ProjError" not in res.output
    bad = {"points": "g.app", "measurements": "t.mes", "eo": "a.OPK, line 4"}[which]
    assert bad in res.output
