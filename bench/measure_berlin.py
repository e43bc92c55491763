"""The measuring aid on real images: OpenSfM berlin's 10 natural-point GCPs (ODM ``gcp_list.txt``, published
image measurements in 2-3 phone images each).

What the page does for a natural point, driven through :class:`skyrig.web.measure.MeasureSession` (no browser):

* **one image measured** (the published measurement of image A accepted as the user's click): the page predicts
  the point in every other image B (from the surveyed coordinates through the orientations) and ``propose(...,
  "lsm")`` refines it there (least-squares matching against A, the library function the page calls);
* **leave one out** (points measured in 3 images): the two others accepted, B predicted by their intersection,
  then refined the same way.

Each proposal is compared with the published measurement in B: the count within 2 px and the RMS, next to the
unrefined prediction's error.  Two consistency lines follow (points in 3 images): the intersection residuals of
the three published measurements, and of one published measurement with the two proposals; and the first again
through OpenSfM's own reconstruction of the images (:func:`opensfm_consistency`: independent of skyrig's
orientation).  The orientations are a ``skyrig adjust-uav --no-gps`` block of the three images
(``bench/real.py`` ``berlin()``: half the GCPs control, half check; rerun here when absent).

    PYTHONPATH=src .venv/bin/python bench/measure_berlin.py [--work /tmp/skyrig-real] [--run 0]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def published(folder: Path) -> dict[tuple[str, str], np.ndarray]:
    """``{(point, image): (column, row)}`` from the ODM file, points named g01.. in order of first appearance
    (the names ``bench/real.py`` gives them)."""
    names: dict[tuple[str, str, str], str] = {}
    out = {}
    for line in (folder / "gcp_list.txt_from_commit_c7d5152_parent").read_text().splitlines()[1:]:
        if line.strip():
            lon, lat, h, col, row, img = line.split()[:6]
            out[names.setdefault((lon, lat, h), f"g{len(names) + 1:02d}"), img] = np.array([float(col), float(row)])
    return out


def ensure_block(data: Path, work: Path, run: int) -> Path:
    """The adjusted block folder (``work/berlin/adjust<run>``), made by ``bench/real.py`` when absent."""
    out = work / "berlin" / f"adjust{run}"
    if not (out / "manifest.json").exists():
        sys.path.insert(0, str(ROOT / "bench"))
        from real import berlin

        berlin(data, work, 1600)
    return out


def session(data: Path, work: Path, run: int, output: Path):
    from skyrig.cli._common import load_cameras, load_eo, load_points
    from skyrig.web.inputs import merge_points
    from skyrig.web.measure import MeasureSession

    adj = ensure_block(data, work, run)
    eo = load_eo(adj / "eo.csv", None, None, None)
    cams = load_cameras([str(adj / "camera.yaml")])
    ctl = load_points(work / "berlin" / f"control{run}.csv", None, default_crs=eo.frame.crs)
    chk = load_points(work / "berlin" / f"check{run}.csv", None, default_crs=eo.frame.crs)
    pts, roles = merge_points(ctl, chk, "check")
    files = {str(n): data / "opensfm" / "berlin" / "images" / str(n) for n in eo.image}
    return MeasureSession(eo, cams, pts, roles, files, output, operator="bench", lock=False, target_kinds=())


def _pred(state: dict, image: str, key: str) -> tuple[np.ndarray, float]:
    """The prediction of a point in an image and the search radius the page would use around it: 3 times the
    prediction ellipse's major semi-axis, at least 8 px (like ``MeasureSession.detect``), at most 80 px."""
    p = next(p for p in state["predictions"] if p["image"] == image)[key]
    return np.array([p["column"], p["row"]], dtype=np.float64), float(np.clip(3.0 * (p["a"] or 0.0), 8.0, 80.0))


def evaluate(data: Path, work: Path, run: int = 0) -> dict[str, list[dict]]:
    """The two experiments; every case as ``{point, image, given (images measured), role, start_px, refined,
    error_px, method, note}`` with ``start_px`` the prediction's and ``error_px`` the proposal's distance to
    the published measurement."""
    pub = published(data / "opensfm" / "berlin")
    by_point: dict[str, list[str]] = {}
    for (p, i) in pub:
        by_point.setdefault(p, []).append(i)
    out: dict[str, list[dict]] = {"one": [], "loo": [], "consistency": [], "proposal_consistency": [], "chain": []}
    with tempfile.TemporaryDirectory() as td:
        s = session(data, work, run, Path(td) / "m.csv")
        try:
            # the intersection-consistent positions: every published measurement of a point in, intersected, and
            # the intersection projected into each of its images (the nearest positions the block can confirm)
            consistent = {}
            for p, imgs in by_point.items():
                _reset(s, p, imgs, pub)
                for q in s.point_state(p)["predictions"]:
                    if q["image"] in imgs and q.get("intersection") and q["intersection"]["column"] is not None:
                        consistent[p, q["image"]] = np.array([q["intersection"]["column"], q["intersection"]["row"]])
                _reset(s, p, [], pub)
            for p, imgs in by_point.items():
                for a in imgs:  # the user measured A only
                    _reset(s, p, [a], pub)
                    st = s.point_state(p)
                    for b in imgs:
                        if b != a:
                            c = _case(s, p, b, [a], *_pred(st, b, "ray"), pub)
                            c["ground_px"] = float(np.linalg.norm(_pred(st, b, "ground")[0] - pub[p, b]))
                            out["one"].append(c)
                if len(imgs) >= 3:
                    for b in imgs:  # the others measured, B predicted by their intersection
                        given = [i for i in imgs if i != b]
                        _reset(s, p, given, pub)
                        out["loo"].append(_case(s, p, b, given, *_pred(s.point_state(p), b, "intersection"), pub))
                if len(imgs) >= 3:  # the proposals' consistency: A published, the two others as proposed, intersected
                    for a in imgs:
                        props = [c for c in out["one"] if c["point"] == p and c["given"] == a and c["refined"]]
                        if len(props) == len(imgs) - 1:
                            _reset(s, p, [a], pub)
                            for c in props:
                                s.accept(p, c["image"], *c["xy"], method="lsm", refined=True, sigma_px=1.0)
                            out["proposal_consistency"] += [_resid(p, m) for m in s.point_state(
                                p, with_predictions=False)["measurements"]]
                if len(imgs) >= 3:  # the matcher's own consistency: A -> B directly against A -> C -> B
                    out["chain"] += _chains(s, p, imgs, [c for c in out["one"] if c["point"] == p], pub)
                if len(imgs) >= 3:  # the published measurements' own consistency: all in, intersection residuals
                    _reset(s, p, imgs, pub)
                    out["consistency"] += [_resid(p, m) for m in s.point_state(p, with_predictions=False)[
                        "measurements"]]
                _reset(s, p, [], pub)
        finally:
            s.close()
    out["reversal"] = _reversals(data, work, run, out["one"], pub)
    for c in out["one"] + out["loo"]:
        k = (c["point"], c["image"])
        c["error_consistent_px"] = float(np.linalg.norm(np.array(c["xy"]) - consistent[k])) if k in consistent \
            else float("nan")
        c["published_consistent_px"] = float(np.linalg.norm(pub[k] - consistent[k])) if k in consistent \
            else float("nan")
    return out


def _reversals(data: Path, work: Path, run: int, ones: list[dict], pub: dict) -> list[dict]:
    """For every pair of images both of whose proposals were refined (A -> B and B -> A): if the matching finds the
    homologue of the click it starts from, A -> B errs by ``M n_A - n_B`` (``n`` the clicks' errors, ``M`` the local
    map A -> B) and B -> A by ``-M^-1`` of that, so ``e_AB + M e_BA`` vanishes whatever the clicks' errors; ``M``
    the map the plane facing both cameras induces (:func:`skyrig.match.propagate.plane_maps`)."""
    from skyrig.match.propagate import plane_maps

    got = {(c["point"], c["given"], c["image"]): c for c in ones if c["refined"]}
    out = []
    with tempfile.TemporaryDirectory() as td:
        s = session(data, work, run, Path(td) / "m.csv")
        try:
            for (p, a, b), c in got.items():
                back = got.get((p, b, a))
                if back is None or a > b:
                    continue
                X = s.xyz_l[s.pidx[p]]
                rows = np.array([s.iidx[a], s.iidx[b]])
                _, _, jx = s._project(X, rows)
                M = plane_maps(jx[0], jx[1], X - s.eo_l.centre[rows[0]], X - s.eo_l.centre[rows[1]])["facing"]
                e_ab = np.array(c["xy"]) - pub[p, b]
                e_ba = np.array(back["xy"]) - pub[p, a]
                out.append({"point": p, "pair": f"{a}<>{b}", "error_px": float(np.linalg.norm(e_ab)),
                            "back_error_px": float(np.linalg.norm(e_ba)),
                            "closure_px": float(np.linalg.norm(e_ab + M @ e_ba))})
        finally:
            s.close()
    return out


def _chains(s, point: str, imgs: list[str], ones: list[dict], pub: dict) -> list[dict]:
    """For a point in three images: the proposal in B from A's published measurement against the proposal in B
    from the proposal in C (itself from A), both matched: their distance measures the matching alone (no
    published measurement of B or C enters)."""
    got = {(c["given"], c["image"]): c for c in ones if c["refined"]}
    out = []
    for a in imgs:
        for c in imgs:
            for b in imgs:
                if len({a, b, c}) < 3 or (a, c) not in got or (a, b) not in got:
                    continue
                _reset(s, point, [], pub)
                s.accept(point, c, *got[a, c]["xy"], method="lsm", refined=True, sigma_px=1.0)
                start, search = _pred(s.point_state(point), b, "ray")
                prop = s.propose(point, b, float(start[0]), float(start[1]), method="lsm", search_px=search)
                if prop["refined"]:
                    out.append({"point": point, "chain": f"{a}>{c}>{b}", "difference_px": float(np.hypot(
                        prop["column"] - got[a, b]["xy"][0], prop["row"] - got[a, b]["xy"][1]))})
    return out


def _resid(point: str, m: dict) -> dict:
    return {"point": point, "image": m["image"], "residual_px": float(np.hypot(m["vs_intersection"]["dcolumn"],
                                                                               m["vs_intersection"]["drow"]))}


def _reset(s, point: str, images: list[str], pub: dict) -> None:
    for i in list({i for (q, i) in s.records if q == point}):
        s.delete(point, i)
    for i in images:
        s.accept(point, i, *pub[point, i], method="click", sigma_px=1.0)


def _case(s, point: str, image: str, given: list[str], start: np.ndarray, search: float, pub: dict) -> dict:
    prop = s.propose(point, image, float(start[0]), float(start[1]), method="lsm", search_px=search)
    xy = np.array([prop["column"], prop["row"]])
    truth = pub[point, image]
    return {"point": point, "image": image, "given": "+".join(given), "role": s.roles[point],
            "start_px": float(np.linalg.norm(start - truth)), "search_px": search, "refined": bool(prop["refined"]),
            "error_px": float(np.linalg.norm(xy - truth)), "xy": xy.tolist(), "method": prop["method"], "note": prop["note"]}


def summary(cases: list[dict], tol: float = 2.0, against: str = "published") -> dict:
    """Counts and RMS of the proposals' errors ``against`` the published measurements, or the
    intersection-consistent positions (``"consistent"``)."""
    e = np.array([c["error_px" if against == "published" else "error_consistent_px"] for c in cases])
    s0 = np.array([c["start_px"] for c in cases])
    ref = np.array([c["refined"] for c in cases])
    return {"cases": len(cases), "refined": int(ref.sum()), "within_tol": int(np.sum(e <= tol)),
            "rms_px": float(np.sqrt(np.mean(e**2))), "median_px": float(np.median(e)),
            "rms_refined_px": float(np.sqrt(np.mean(e[ref] ** 2))) if ref.any() else float("nan"),
            "start_rms_px": float(np.sqrt(np.mean(s0**2))), "start_within_tol": int(np.sum(s0 <= tol))}


def opensfm_consistency(data: Path, measurements: dict | None = None) -> list[dict]:
    """The published measurements against OpenSfM's own reconstruction of the three images
    (``reconstruction_example.json``, the peer's orientation, not skyrig's): each point seen in two or more images
    intersected from its published measurements (least squares on the reprojection errors, OpenSfM's cameras and
    poses as skyrig reads them), every measurement's residual ``{point, image, n_images, residual_px}``.  No
    ground coordinate enters: only how the clicks agree with each other through that orientation.
    ``measurements``: ``{(point, image): (column, row)}`` to judge instead of the published ones (default)."""
    from scipy.optimize import least_squares

    from skyrig.io.opensfm import read_opensfm

    folder = data / "opensfm" / "berlin"
    rec = read_opensfm(folder / "reconstruction_example.json")[0]
    pub = published(folder) if measurements is None else measurements
    names = [str(n) for n in rec.image_name]
    out = []
    for p in sorted({p for p, _ in pub}):
        k = [names.index(i) for i in names if (p, i) in pub]
        if len(k) < 2:
            continue
        obs = np.array([pub[p, names[j]] for j in k])
        cams = [rec.cameras[rec.image_camera_id[j]] for j in k]
        poses = [rec.world_from_camera[j] for j in k]

        def res(X: np.ndarray) -> np.ndarray:
            return np.concatenate([c.world_to_pixel(q, X[None])[0] - o for c, q, o in zip(cams, poses, obs)])

        ray = poses[0].rotation @ cams[0].rays_from_pixels(obs[:1])[0]
        fits = [least_squares(res, poses[0].translation + d * ray / np.linalg.norm(ray)) for d in (5, 10, 20, 40, 80)]
        r = min(fits, key=lambda f: f.cost).fun.reshape(-1, 2)
        out += [{"point": p, "image": names[j], "n_images": len(k), "residual_px": float(np.hypot(*v))}
                for j, v in zip(k, r)]
    return out


def opensfm_proposal_consistency(data: Path, ones: list[dict]) -> list[dict]:
    """The matched homologues through OpenSfM's own reconstruction: for each point in three images and each of its
    published measurements A whose two proposals (from A) were refined, A's measurement and the two proposals
    intersected (:func:`opensfm_consistency`), every residual ``{point, anchor, image, residual_px}``: near the
    orientation's own fit where the proposals are images of the point A's click is on."""
    pub = published(data / "opensfm" / "berlin")
    out = []
    for p in sorted({p for p, _ in pub}):
        imgs = [i for q, i in pub if q == p]
        if len(imgs) < 3:
            continue
        for a in imgs:
            props = {c["image"]: np.array(c["xy"]) for c in ones if c["point"] == p and c["given"] == a and c["refined"]}
            if len(props) == len(imgs) - 1:
                m = {(p, a): pub[p, a], **{(p, b): v for b, v in props.items()}}
                out += [{**c, "anchor": a} for c in opensfm_consistency(data, m)]
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    ap.add_argument("--work", type=Path, default=Path("/tmp/skyrig-real"))
    ap.add_argument("--run", type=int, default=0, choices=(0, 1), help="which control / check split of real.py")
    a = ap.parse_args(argv)
    res = evaluate(a.data, a.work, a.run)
    for key, words in (("one", "one image measured, the others predicted along its ray (depth from the surveyed point)"),
                       ("loo", "leave one out: predicted by the intersection of the others")):
        print(f"\n{words}")
        print(f"{'point':6s} {'role':8s} {'image':7s} {'given':16s} {'start px':>9s} {'search':>7s} {'refined':>8s} {'error px':>9s}  note")
        for c in res[key]:
            print(f"{c['point']:6s} {c['role']:8s} {c['image']:7s} {c['given']:16s} {c['start_px']:9.2f} {c['search_px']:7.1f} "
                  f"{'yes' if c['refined'] else 'no':>8s} {c['error_px']:9.2f}  {c['note']}")
        sm = summary(res[key])
        print(f"-> {sm['within_tol']} / {sm['cases']} within 2 px (prediction alone: {sm['start_within_tol']}); "
              f"RMS {sm['rms_px']:.2f} px (median {sm['median_px']:.2f}; refined {sm['refined']}, their RMS "
              f"{sm['rms_refined_px']:.2f}); prediction RMS {sm['start_rms_px']:.2f} px")
        sc = summary(res[key], against="consistent")
        pc = np.array([c["published_consistent_px"] for c in res[key]])
        print(f"-> against the intersection-consistent positions (all published measurements of the point "
              f"intersected, projected back): {sc['within_tol']} / {sc['cases']} within 2 px, RMS {sc['rms_px']:.2f} px "
              f"(refined: RMS {sc['rms_refined_px']:.2f}); the published measurements themselves: "
              f"{int(np.sum(pc <= 2.0))} / {len(pc)} within 2 px, RMS {np.sqrt(np.mean(pc**2)):.2f} px")
    print("\nper point (one image measured): proposals within 2 px of the published measurement / refined / cases, "
          "RMS of the refined")
    for p in sorted({c["point"] for c in res["one"]}):
        sp = summary([c for c in res["one"] if c["point"] == p])
        print(f"  {p}: {sp['within_tol']} / {sp['refined']} / {sp['cases']}, RMS {sp['rms_refined_px']:.2f} px")
    d = np.array([c["difference_px"] for c in res["chain"]])
    if len(d):
        print(f"the matching's own consistency (A -> B directly against A -> C -> B, points in 3 images): "
              f"{int(np.sum(d <= 2.0))} / {len(d)} within 2 px, RMS {np.sqrt(np.mean(d**2)):.2f} px, median "
              f"{np.median(d):.2f} px")
    rv = res["reversal"]
    if rv:
        e = np.array([[c["error_px"], c["back_error_px"]] for c in rv])
        cl = np.array([c["closure_px"] for c in rv])
        print(f"there and back (A -> B and B -> A both refined, {len(rv)} pairs): errors {np.sqrt(np.mean(e**2)):.2f} px "
              f"RMS against the published, yet e_AB + M e_BA (zero when the matching lands on the homologue of the "
              f"click it starts from, whatever the clicks' errors) {np.sqrt(np.mean(cl**2)):.2f} px RMS")
    r = np.array([c["residual_px"] for c in res["consistency"]])
    print(f"\nthe published measurements themselves (points in 3 images, all three intersected): residual RMS "
          f"{np.sqrt(np.mean(r**2)):.2f} px, max {r.max():.2f} px over {len(r)} measurements")
    r = np.array([c["residual_px"] for c in res["proposal_consistency"]])
    if len(r):
        print(f"one published + the two proposals (where both refined), intersected: residual RMS "
              f"{np.sqrt(np.mean(r**2)):.2f} px, max {r.max():.2f} px over {len(r)} measurements")
    oc = opensfm_consistency(a.data)
    r = np.array([c["residual_px"] for c in oc if c["n_images"] >= 3])
    print(f"the published measurements through OpenSfM's own reconstruction (reconstruction_example.json; points in "
          f"3 images): residual RMS {np.sqrt(np.mean(r**2)):.2f} px, max {r.max():.2f} px, {int(np.sum(r <= 2.0))} / "
          f"{len(r)} within 2 px of their own intersection")
    r = np.array([c["residual_px"] for c in opensfm_proposal_consistency(a.data, res["one"])])
    if len(r):
        print(f"one published measurement + its two proposals through OpenSfM's reconstruction: residual RMS "
              f"{np.sqrt(np.mean(r**2)):.2f} px, max {r.max():.2f} px, {int(np.sum(r <= 2.0))} / {len(r)} within 2 px")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
