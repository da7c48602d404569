"""Convex programs stated to Clarabel in its own form, ``min 1/2 x^T P x + q^T x`` subject to ``b - A x`` in a
product of cones: the export's steps, the CAD prior's and the payload's projection. Through cvxpy each such command
paid for cvxpy's import (1.2 to 1.4 s, its atoms importing SciPy's statistics) and for its compilation of every
program (0.5 s of the servicer's 0.6 s solve); the programs are small enough to state by hand.
``tests/test_export.py`` and ``tests/test_payload.py`` check the export's and the payload's against the same
programs stated in cvxpy (a test dependency only); ``tests/test_prior.py`` the prior's by its estimates.
"""

from __future__ import annotations

import numpy as np

CLARABEL_TOLERANCES = {"tol_gap_abs": 1e-13, "tol_gap_rel": 1e-13, "tol_feas": 1e-12, "tol_ktratio": 1e-10}
"""Clarabel's tolerances for these programs: its defaults (1e-8) leave ~5e-5 of noise in the
whitened solution (a log-det objective is flat to second order), enough to keep the steps from settling."""


WHOLE_CONES = {"chordal_decomposition_enable": False}
"""Clarabel's settings for a second attempt at a program whose first failed: its positive semidefinite cones whole,
not split into their chordal parts. On planar random robot 311720 (13 bodies, 121 parameters, the estimate at 1e-3
of noise) the export's program with its log-det objective, its 22 cones split into 55, stopped on insufficient
progress at every step, and the export was refused although the true robot lay inside the ellipsoid; whole, the
same program solved to Clarabel's tolerances (and to SCS's optimum, 44.1139)."""


def solver_panicked(exc: BaseException) -> bool:
    """Whether ``exc`` is a panic of Clarabel's Rust core (pyo3's ``PanicException``, a ``BaseException``), which it
    raises on some ill-posed cones: a failed solve, where any other ``BaseException`` (an interrupt) propagates."""
    return type(exc).__name__ == "PanicException"


ORDER = ("ZeroConeT", "NonnegativeConeT", "SecondOrderConeT", "PSDTriangleConeT", "ExponentialConeT")
"""The order of the cones in a program given to Clarabel (cvxpy's)."""
SOLVED = ("Solved", "AlmostSolved")
"""Clarabel's statuses of a solution (cvxpy's optimal and optimal but inaccurate)."""
PANICKED = "the solver failed"
"""The status :func:`conic_solution` gives when Clarabel's core panicked."""
FAILED = ("NumericalError", "InsufficientProgress", "Unsolved", PANICKED)
"""Clarabel's statuses of a failed solve (cvxpy's solver error) and a panic, which :func:`solved_tightly` tries once
more with the cones whole; an infeasible program or an iteration limit is an answer."""


def triangle(d: int) -> tuple:
    """``(i, j, weight)`` of the entries of a symmetric ``(d, d)`` matrix in Clarabel's positive semidefinite cone:
    its upper triangle column by column (``i <= j``), the off-diagonal entries scaled by ``sqrt 2`` so that the
    vectors' inner product is the matrices'."""
    i, j = np.array([(i, j) for j in range(d) for i in range(j + 1)]).T
    return i, j, np.where(i == j, 1.0, np.sqrt(2.0))


def cone(kind: str, size: int = 0):
    """The Clarabel cone ``kind`` (``zero``, ``nonnegative``, ``soc``, ``psd`` of ``size`` x ``size`` matrices,
    ``exp``) of ``size`` entries."""
    import clarabel

    return {"zero": clarabel.ZeroConeT, "nonnegative": clarabel.NonnegativeConeT, "soc": clarabel.SecondOrderConeT,
            "psd": clarabel.PSDTriangleConeT}[kind](size) if kind != "exp" else clarabel.ExponentialConeT()


def conic_solution(P, q, rows: list, options: dict) -> tuple:
    """``(x, status)``: Clarabel's solution ``x (n,)`` of ``min 1/2 x^T P x + q^T x`` subject to ``b - A x`` in
    the cones, ``rows`` a list of ``(A (m, n), b (m,), cone)`` (``P (n, n)`` symmetric or None: a linear program),
    with ``options`` its settings, or None when it found none (infeasible, or failed: its panic too), and its status
    in words."""
    import clarabel
    from scipy import sparse

    n = len(q)
    rows = sorted(rows, key=lambda row: ORDER.index(type(row[2]).__name__))
    A = sparse.csc_matrix(np.vstack([a for a, _, _ in rows]))
    b = np.concatenate([v for _, v, _ in rows])
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    for name, value in options.items():
        setattr(settings, name, value)
    P = sparse.csc_matrix((n, n)) if P is None else sparse.triu(sparse.csc_matrix(P), format="csc")
    solver = clarabel.DefaultSolver(P, np.asarray(q, float), A, b, [c for _, _, c in rows], settings)
    try:
        solution = solver.solve()
    except BaseException as exc:
        if not solver_panicked(exc):
            raise
        return None, PANICKED
    status = str(solution.status)
    return (np.array(solution.x, float) if status in SOLVED else None), status


def solved_tightly(P, q, rows: list) -> np.ndarray | None:
    """:func:`conic_solution` at :data:`CLARABEL_TOLERANCES`, once more with the cones whole
    (:data:`WHOLE_CONES`) when the solver fails (:data:`FAILED`, or a panic): the solution,
    or None."""
    for settings in ({}, WHOLE_CONES):
        x, status = conic_solution(P, q, rows, CLARABEL_TOLERANCES | settings)
        if x is not None or status not in FAILED:
            return x
    return None


class Unknowns:
    """A program's unknowns in named blocks of the given sizes, in order (``n`` in all): ``rows(m, **blocks)`` is
    ``(m, n)`` rows holding each ``(m, size)`` block (or a scalar) at its unknowns' columns, zero elsewhere;
    ``of(x, name)`` that block of a solution ``x (n,)``."""

    def __init__(self, **sizes):
        self.sizes = sizes
        self.at = dict(zip(sizes, np.cumsum([0, *sizes.values()]).tolist()))
        self.n = sum(sizes.values())

    def rows(self, m: int, **blocks) -> np.ndarray:
        out = np.zeros((m, self.n))
        for name, block in blocks.items():
            out[:, self.at[name] : self.at[name] + self.sizes[name]] = block
        return out

    def of(self, x: np.ndarray, name: str) -> np.ndarray:
        return x[self.at[name] : self.at[name] + self.sizes[name]]


def duplication(nb: int) -> np.ndarray:
    """``E (16 nb, 10 nb)``: the stacked ``vec X_b`` (each column by column, as :func:`~spaceid.models._pseudo.
    pseudo_whitening` takes them) from the upper triangles of the symmetric ``X_b`` (:func:`triangle`'s order)."""
    i, j, _ = triangle(4)
    one = np.zeros((16, 10))
    one[4 * j + i, np.arange(10)] = one[4 * i + j, np.arange(10)] = 1.0
    return np.kron(np.eye(nb), one)


def physical_rows(unknowns: Unknowns, z: np.ndarray) -> list:
    """The rows that keep every body physical, on the unknowns ``x`` (the ``X_b``'s upper triangles, ``10 nb``):
    ``X_b - MARGIN 1`` positive semidefinite, body by body, and the declared zeros ``Z vec X = 0`` (``z (n_zero, 16
    nb)``, :func:`~spaceid.models._pseudo.pseudo_whitening`'s)."""
    from ._pseudo import MARGIN

    nb = unknowns.sizes["x"] // 10
    i, j, w = triangle(4)
    out = [(part, -MARGIN * (i == j), cone("psd", 4)) for part in np.split(unknowns.rows(10 * nb, x=-np.diag(
        np.tile(w, nb))), nb)]  # fmt: skip
    if len(z):
        out.append((unknowns.rows(len(z), x=z @ duplication(nb)), np.zeros(len(z)), cone("zero", len(z))))
    return out
