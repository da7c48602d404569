"""Readable definitions of the minimal parameters in physical terms.

Planar trees: each parameter is the coefficient of one body-pair function (see
:mod:`spaceid.dynamics`), derived symbolically with SymPy from the barycentric form of the
momentum: with ``s_i`` written as a sum of body-fixed vectors ``v`` (joint offsets and CoM
offsets), and ``mu_v`` the mass of the bodies whose CoM position contains ``v``,

    h = sum_b Iczz_b w_b + sum_{v, w} (mu_vw - mu_v mu_w / M) (w_a + w_b) (R_a v . R_b w)

over unordered pairs of vectors (``v`` fixed in body a, ``w`` in body b, each pair once, a
vector with itself counted once with a half weight). Symbols: ``m_<body>`` mass [kg],
``cx_<body>``, ``cy_<body>`` CoM in the body frame [m], ``Iczz_<body>`` inertia about the CoM
[kg m^2] (``c`` for CoM: ``Izz_<body>`` is the standard parameter, about the body frame origin),
``x_<joint>``, ``y_<joint>`` the joint's position in its parent's frame [m], ``M`` the total
mass. A test evaluates every definition and compares it with the numerical parameter values.
"""

from __future__ import annotations

import functools
import operator
from collections import Counter

import numpy as np

from ..models import Model
from ..models.internal import inertia_matrix, symbol_suffix

__all__ = ["planar_definitions", "planar_symbol_values", "column_definitions"]


def _sym(name, present):
    """A symbol, or exact zero where it is known to vanish (keeps definitions short)."""
    import sympy as sp

    return sp.Symbol(name, real=True) if present else sp.Integer(0)


def planar_symbol_values(model: Model) -> dict:
    """Numerical values of the symbols used in planar definitions."""
    values = {"M": model.mass}
    for b in model.bodies:
        i_com = inertia_matrix(b.inertial) - b.mass * (b.com @ b.com * np.eye(3) - np.outer(b.com, b.com))
        body = symbol_suffix(b.name)
        values.update({f"m_{body}": b.mass, f"cx_{body}": b.com[0], f"cy_{body}": b.com[1],
                       f"Iczz_{body}": i_com[2, 2]})
        if b.joint:
            joint = symbol_suffix(b.joint)
            values.update({f"x_{joint}": b.translation[0], f"y_{joint}": b.translation[1]})
    return values


def _subtrees(model: Model):
    sub = [{i} for i in range(len(model.bodies))]
    for i in reversed(range(1, len(model.bodies))):
        sub[model.bodies[i].parent] |= sub[i]
    return sub


def planar_definitions(model: Model, terms) -> list:
    """Definitions (SymPy strings) of the coefficients of the planar body-pair ``terms``."""
    import sympy as sp  # here: importing it takes ~0.5 s, and spatial models do not need it
    bodies = model.bodies
    body = [symbol_suffix(b.name) for b in bodies]
    mass = [sp.Symbol(f"m_{n}", positive=True) for n in body]
    total = sum(mass)
    sub = _subtrees(model)
    vectors = [[] for _ in bodies]  # per body: (x, y, set of bodies whose CoM contains it)
    for i, b in enumerate(bodies):
        # CoM coordinates are unknowns unless declared zero; joint offsets are known geometry
        cx, cy = _sym(f"cx_{body[i]}", "mcx" not in b.known_zero), _sym(f"cy_{body[i]}", "mcy" not in b.known_zero)
        vectors[i].append((cx, cy, {i}))
        if b.parent >= 0:
            t, joint = b.translation, symbol_suffix(b.joint)
            vectors[b.parent].append((_sym(f"x_{joint}", abs(t[0]) > 0), _sym(f"y_{joint}", abs(t[1]) > 0), sub[i]))

    def mu(s):
        return sum((mass[i] for i in s), sp.Integer(0))

    def weight(sv, sw):
        return mu(sv & sw) - mu(sv) * mu(sw) / total

    rot = _zero_pose_rotations(model)
    out = []
    for kind, a, b in terms:
        if kind == "spin":
            spin = sp.Symbol(f"Iczz_{body[a]}", positive=True)
            expr = sp.Integer(0)
            vs = vectors[a]
            for p, (vx, vy, sv) in enumerate(vs):
                expr += weight(sv, sv) * (vx**2 + vy**2)
                for wx, wy, sw in vs[p + 1 :]:
                    expr += 2 * weight(sv, sw) * (vx * wx + vy * wy)
        else:
            # R_a^T R_b = Rz(D) diag(1, f, f): f = -1 where the frames' z axes are opposite
            rel = rot[a].T @ rot[b]
            f = round(np.linalg.det(rel[:2, :2]))
            expr = sp.Integer(0)
            for vx, vy, sv in vectors[a]:
                for wx, wy, sw in vectors[b]:
                    dot = vx * wx + f * vy * wy if kind == "cos" else vy * wx - f * vx * wy
                    expr += weight(sv, sw) * dot
        expr = sp.factor(sp.together(expr)).subs(total, sp.Symbol("M", positive=True))
        out.append(str(spin + expr if kind == "spin" else expr))
    return out


def _zero_pose_rotations(model: Model):
    rot = [np.eye(3)]
    for b in model.bodies[1:]:
        rot.append(rot[b.parent] @ b.rotation)
    return rot


def column_definitions(names, projection, *, digits: int = 6) -> list:
    """Definitions of column-basis parameters: a full parameter plus the dependent ones it absorbs.

    Terms with the same coefficient are grouped and the factors common to a group written once
    (``0.5*mcy_bus*(m_link1 + m_link2)/M``), so each definition is a valid SymPy expression in
    the names of ``full_parameter_names`` (``A`` or ``A*B/M``; coefficients to ``digits``
    digits). Plain string work: SymPy's own factoring took seconds for the servicer's 496.
    """
    terms = [(Counter(n.removesuffix("/M").split("*")), n.endswith("/M")) for n in names]
    out = []
    for row in projection:
        groups: dict = {}
        for coef, term in zip(row, terms):
            if coef != 0:
                groups.setdefault(float(f"{coef:.{digits}g}"), []).append(term)
        expr = ""
        for coef, group in groups.items():
            text = _factored(group)
            if abs(coef) != 1:
                text = f"{abs(coef):.{digits}g}*{text}"
            elif coef > 0 and text.startswith("(") and text.endswith(")"):  # a bare sum
                text = text[1:-1]
            expr += (" - " if coef < 0 else " + ") + text if expr else ("-" if coef < 0 else "") + text
        out.append(expr or "0")
    return out


def _factored(group) -> str:
    """``sum(group)`` with the factors common to all terms (and ``/M``) pulled out; a term is
    ``(Counter of factors, divided by M)``. A sum with nothing pulled out comes in
    parentheses, so that a coefficient may multiply it."""
    common = functools.reduce(operator.and_, (f for f, _ in group))
    over_m = all(m for _, m in group)
    rest = [_product(f - common) + ("/M" if m and not over_m else "") for f, m in group]
    inner = rest[0] if len(rest) == 1 else "(" + " + ".join(rest) + ")"
    if common:
        inner = _product(common) + ("" if inner == "1" else f"*{inner}")
    return inner + ("/M" if over_m else "")


def _product(factors: Counter) -> str:
    return "*".join(f if k == 1 else f"{f}**{k}" for f, k in sorted(factors.items())) or "1"
