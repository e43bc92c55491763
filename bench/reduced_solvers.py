"""Sparse factorisations of the reduced camera (Schur) system of a generated BAL block, compared.

    .venv/bin/python bench/reduced_solvers.py 1000            # cameras (200 points each, bench/bal.py's generator)
    .venv/bin/python bench/reduced_solvers.py 3000 --methods cholmod,splu

The block's ``S`` (Jacobi-scaled, damping 1e-4, as the first Levenberg-Marquardt step builds it) is
solved by each back end twice (the second call shows what a later iteration costs: CHOLMOD reuses its
symbolic analysis) and the relative residual checked.  Back ends: ``cholmod`` (CHOLMOD through cvxopt,
METIS order: skyrig's choice), ``splu`` (SuperLU, the fallback), ``cholespy`` (CHOLMOD on the reference
BLAS), ``pardiso`` (MKL PARDISO through pypardiso, when installed: not a skyrig dependency), ``pcg``
(Schur-Jacobi PCG to eta = 0.1, the inexact option).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main() -> None:
    from bal import generate, load

    from skyrig.adjust import AdjustConfig
    from skyrig.adjust.config import Unknowns
    from skyrig.adjust.linalg import ReducedSolver
    from skyrig.adjust.model import Model, State
    from skyrig.adjust.solver import SchurEngine

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("cameras", type=int)
    ap.add_argument("--methods", default="cholmod,splu,cholespy,pardiso,pcg")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "gen.txt"
        generate(p, a.cameras, 200 * a.cameras)
        block, _, _ = load(str(p), False)
    model = Model(block, AdjustConfig(unknowns=Unknowns(intrinsics="free", datum="none")))
    f = model.evaluate(State.from_block(block))
    eng = SchurEngine(f, model.layout, block.obs_image)
    eng.linearize(f)
    S, rhs, _ = eng.reduced_system(1e-4)
    del f
    n = eng.n_c
    s = 1.0 / np.sqrt(S[eng.diagpos])
    vals = S * s[eng.rows] * s[eng.indices]
    b = rhs * s
    A = sp.csr_matrix((vals, eng.indices, eng.indptr), shape=(n, n))
    print(f"{a.cameras} cameras: S {n} unknowns, {eng.nnz} nonzeros")
    for m in a.methods.split(","):
        times = []
        if m == "pardiso":
            try:
                import pypardiso
            except ImportError:
                print("pardiso: pypardiso not installed")
                continue
            U = sp.triu(A, format="csr")
            for _ in range(2):
                t = time.perf_counter()
                x = pypardiso.PyPardisoSolver(mtype=2).solve(U, b)
                times.append(time.perf_counter() - t)
            note = "MKL PARDISO (pypardiso), analysis + factorisation each call"
        else:
            t = time.perf_counter()
            rs = ReducedSolver(eng.indptr, eng.indices, m, dense_limit=0)
            t_init = time.perf_counter() - t
            for _ in range(2):
                t = time.perf_counter()
                x = rs.solve(vals, b)
                times.append(time.perf_counter() - t)
            note = f"set-up {t_init:.2f} s; {rs.reason}"
            if rs.symbolic is not None:
                note += (f"; predicted factor {rs.symbolic.factor_nnz / 1e6:.1f} M nonzeros, "
                         f"{rs.symbolic.flops / 1e9:.1f} GFlop")
        res = np.linalg.norm(A @ x - b) / np.linalg.norm(b)
        print(f"{m:9s} first {times[0]:7.2f} s  second {times[1]:7.2f} s  residual {res:.1e}  ({note})", flush=True)


if __name__ == "__main__":
    main()
