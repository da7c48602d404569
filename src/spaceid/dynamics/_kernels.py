"""The compiled kernels of the dynamics: the kinematics and the momentum columns, sample by sample.

Each kernel works on one sample at a time, its kinematics and extended table (a few hundred
values) held in the L1 cache, and writes its results in order (:mod:`spaceid._jit`: no GIL, no
fastmath). They are all in this one file because Numba's on-disk cache checks only the file of
the kernel it loads: a kernel that called one from another file would keep running the old
code of that one after it changed.
"""

from __future__ import annotations

import numpy as np

from .._jit import kernel


@kernel
def _sample_frames(parents, revolute, joints, q, qd, w0, frames, omega, spin, work):
    """Kinematics of one sample, root to leaves (a body's parent comes before it).

    Parameters
    ----------
    parents, revolute, joints : ndarray
        :func:`spaceid.dynamics._kinematics._joint_arrays`.
    q, qd : ndarray of shape (n_joints,)
    w0 : ndarray of shape (3,)
    frames : ndarray of shape (>= 8 n_bodies, 3)
        Receives the pose and rate rows of a ``FrameTable`` (row ``4 b + f`` and
        ``4 n_bodies + 4 b + f``, components last) [m, m/s, 1/s].
    omega, spin : ndarray of shape (n_bodies, 3)
        Receive the absolute angular velocities in base and in body axes [rad/s].
    work : ndarray of shape (5, 3)
        Scratch.
    """
    nb = omega.shape[0]
    rate = 4 * nb
    for r in range(3):  # loops, not array assignments: those take seconds to compile
        for f in range(4):
            frames[f, r] = 1.0 if f == r + 1 else 0.0  # the base: origin, axes
            frames[rate + f, r] = 0.0  # its rate rows are set with every body's below
        omega[0, r] = w0[r]
    for j in range(nb - 1):
        p, b, m = parents[j], j + 1, joints[j]
        c, s = (np.cos(q[j]), np.sin(q[j])) if revolute[j] else (0.0, 0.0)
        for i in range(3):  # the joint frame C0 + cos C1 + sin C2 (parent axes) into work[:3]
            for k in range(3):
                work[i, k] = m[i, k] + c * m[i, 3 + k] + s * m[i, 6 + k]
        for r in range(3):  # row r of R_p [joint frame, t, a]: in base axes
            x, y, z = frames[4 * p + 1, r], frames[4 * p + 2, r], frames[4 * p + 3, r]
            for k in range(3):
                frames[4 * b + 1 + k, r] = x * work[0, k] + y * work[1, k] + z * work[2, k]
            axis = x * m[0, 10] + y * m[1, 10] + z * m[2, 10]
            offset = x * m[0, 9] + y * m[1, 9] + z * m[2, 9] + (0.0 if revolute[j] else axis * q[j])
            frames[4 * b, r] = frames[4 * p, r] + offset
            omega[b, r] = omega[p, r] + (axis * qd[j] if revolute[j] else 0.0)
            work[3, r], work[4, r] = offset, (0.0 if revolute[j] else axis * qd[j])  # prismatic: slide rate
        for r in range(3):  # v_b = v_p + w_p x offset (+ slide rate)
            i, k = (r + 1) % 3, (r + 2) % 3
            step = omega[p, i] * work[3, k] - omega[p, k] * work[3, i] + work[4, r]
            frames[rate + 4 * b, r] = frames[rate + 4 * p, r] + step
    for b in range(nb):
        for k in range(3):
            e = 4 * b + 1 + k  # the axis R e_k
            for r in range(3):  # its rate w x R e_k
                i, l = (r + 1) % 3, (r + 2) % 3
                frames[rate + e, r] = omega[b, i] * frames[e, l] - omega[b, l] * frames[e, i]
            spin[b, k] = frames[e, 0] * omega[b, 0] + frames[e, 1] * omega[b, 1] + frames[e, 2] * omega[b, 2]


_CHUNK = 64
"""Samples whose kinematics :func:`_frame_blocks` holds before laying them out samples last (so
that it writes the table in order; 180 kB for the servicer, in the level-2 cache)."""


@kernel
def _frame_blocks(parents, revolute, joints, q, qd, w0, table, omega, spin):
    """:func:`_sample_frames` of the samples ``q, qd (n, n_joints)``, ``w0 (n, 3)`` into ``table
    (n / block, 3, 8 n_bodies, block)``, ``omega`` and ``spin (n / block, 3, n_bodies, block)``."""
    n_blocks, _, n_rows, block = table.shape
    nb = omega.shape[2]
    frames, om, sp = np.empty((_CHUNK, n_rows, 3)), np.empty((_CHUNK, nb, 3)), np.empty((_CHUNK, nb, 3))
    work = np.empty((5, 3))
    for i in range(n_blocks):
        for start in range(0, block, _CHUNK):
            m = min(_CHUNK, block - start)
            for s in range(m):
                n = i * block + start + s
                _sample_frames(parents, revolute, joints, q[n], qd[n], w0[n], frames[s], om[s], sp[s], work)
            for r in range(3):  # samples last, each row written in order
                for k in range(n_rows):
                    for s in range(m):
                        table[i, r, k, start + s] = frames[s, k, r]
                for b in range(nb):
                    for s in range(m):
                        omega[i, r, b, start + s], spin[i, r, b, start + s] = om[s, b, r], sp[s, b, r]


@kernel
def _contracted_rows(parents, revolute, joints, q, qd, w0, dq, dqd, dw0, eps, u, d_table, crossed, tu, dtu, spin,
                     d_spin):
    """What :func:`spaceid.dynamics._regressor._contracted_tangent` contracts, for the samples ``q, qd (m,
    n_joints)``, ``w0 (m, 3)`` and their weights ``u (m, 3)``: the derivatives ``d_table (3, 8 n_bodies, m)`` of
    :func:`_frame_blocks`'s pose and rate rows ``T`` along ``(dq, dqd, dw0)`` by central differences of steps ``eps
    (m,)``, the rows crossed with the weights ``crossed`` (``T x u``, shaped alike), their products with the
    weights ``tu`` and ``dtu (8 n_bodies, m)`` (``u . T``, ``u . dT``), and the body-axes rates ``spin (3, n_bodies,
    m)`` with their derivatives ``d_spin``: three kinematics a sample, the states and sums formed as NumPy
    forms them (the results are NumPy's bit for bit)."""
    m, nj, n_rows, nb = q.shape[0], q.shape[1], d_table.shape[1], spin.shape[1]
    frames, sp = np.empty((3, _CHUNK, n_rows, 3)), np.empty((3, _CHUNK, nb, 3))
    om, work, qs, qds, ws = np.empty((nb, 3)), np.empty((5, 3)), np.empty(nj), np.empty(nj), np.empty(3)
    for start in range(0, m, _CHUNK):
        c = min(_CHUNK, m - start)
        for s in range(c):
            n = start + s
            for i in range(2):  # x + eps d, x - eps d
                sign = 1.0 - 2.0 * i
                for j in range(nj):
                    qs[j], qds[j] = q[n, j] + sign * eps[n] * dq[n, j], qd[n, j] + sign * eps[n] * dqd[n, j]
                for r in range(3):
                    ws[r] = w0[n, r] + sign * eps[n] * dw0[n, r]
                _sample_frames(parents, revolute, joints, qs, qds, ws, frames[i, s], om, sp[i, s], work)
            _sample_frames(parents, revolute, joints, q[n], qd[n], w0[n], frames[2, s], om, sp[2, s], work)
        for k in range(n_rows):  # samples last, each row written in order
            for s in range(c):
                n, t = start + s, frames[2, s, k]
                d0 = (frames[0, s, k, 0] - frames[1, s, k, 0]) / (2 * eps[n])
                d1 = (frames[0, s, k, 1] - frames[1, s, k, 1]) / (2 * eps[n])
                d2 = (frames[0, s, k, 2] - frames[1, s, k, 2]) / (2 * eps[n])
                d_table[0, k, n], d_table[1, k, n], d_table[2, k, n] = d0, d1, d2
                crossed[0, k, n] = t[1] * u[n, 2] - t[2] * u[n, 1]
                crossed[1, k, n] = t[2] * u[n, 0] - t[0] * u[n, 2]
                crossed[2, k, n] = t[0] * u[n, 1] - t[1] * u[n, 0]
                tu[k, n] = u[n, 0] * t[0] + u[n, 1] * t[1] + u[n, 2] * t[2]
                dtu[k, n] = u[n, 0] * d0 + u[n, 1] * d1 + u[n, 2] * d2
        for r in range(3):
            for b in range(nb):
                for s in range(c):
                    spin[r, b, start + s] = sp[2, s, b, r]
                    d_spin[r, b, start + s] = (sp[0, s, b, r] - sp[1, s, b, r]) / (2 * eps[start + s])


@kernel
def _spun_rows(ext, spin):
    """The rows ``R e_k wb_m`` of one sample's extended table ``ext (17 n_bodies, 3)`` (rows
    ``8 nb + 9 b + 3 k + m``) from its axes (rows ``4 b + 1 + k``) and ``spin (n_bodies, 3)``,
    the body-axes angular velocities ``wb``."""
    nb = spin.shape[0]
    for b in range(nb):
        for k in range(3):
            for m in range(3):
                for r in range(3):
                    ext[8 * nb + 9 * b + 3 * k + m, r] = ext[4 * b + 1 + k, r] * spin[b, m]


@kernel
def _column(ext, rows, c):
    """Momentum column ``c`` of one sample, ``X1 x Y1 + X2 x Y2`` with the rows ``rows[c]`` of its
    extended table ``ext (17 n_bodies, 3)``: a tuple of 3 components."""
    a, b, d, e = rows[c, 0], rows[c, 1], rows[c, 2], rows[c, 3]  # scalar loads: a view per row costs its refcount
    return (ext[a, 1] * ext[b, 2] - ext[a, 2] * ext[b, 1] + ext[d, 1] * ext[e, 2] - ext[d, 2] * ext[e, 1],
            ext[a, 2] * ext[b, 0] - ext[a, 0] * ext[b, 2] + ext[d, 2] * ext[e, 0] - ext[d, 0] * ext[e, 2],
            ext[a, 0] * ext[b, 1] - ext[a, 1] * ext[b, 0] + ext[d, 0] * ext[e, 1] - ext[d, 1] * ext[e, 0])  # fmt: skip


@kernel
def _sample_extended(parents, revolute, joints, q, qd, w0, ext, omega, spin, work):
    """One sample's extended table into ``ext (17 n_bodies, 3)`` (:func:`_sample_frames`'s
    arguments)."""
    _sample_frames(parents, revolute, joints, q, qd, w0, ext, omega, spin, work)
    _spun_rows(ext, spin)


@kernel
def _columns_of_states(parents, revolute, joints, q, qd, w0, rows, out):
    """Momentum columns ``rows (n_cols, 4)`` (a ``_Plan``'s) of the samples ``q, qd (n,
    n_joints)``, ``w0 (n, 3)`` into ``out (n, 3, n_cols)``. Each sample's tables (~17 n_bodies x 3
    values) stay in the L1 cache; the output is written in order."""
    nb = len(parents) + 1
    ext, omega, spin, work = np.empty((17 * nb, 3)), np.empty((nb, 3)), np.empty((nb, 3)), np.empty((5, 3))
    for n in range(len(q)):
        _sample_extended(parents, revolute, joints, q[n], qd[n], w0[n], ext, omega, spin, work)
        for c in range(rows.shape[0]):
            out[n, 0, c], out[n, 1, c], out[n, 2, c] = _column(ext, rows, c)


@kernel
def _momentum_of_states(parents, revolute, joints, q, qd, w0, rows, weights, out):
    """``sum_c weights_c column_c`` of :func:`_columns_of_states` into ``out (n, 3)``."""
    nb = len(parents) + 1
    ext, omega, spin, work = np.empty((17 * nb, 3)), np.empty((nb, 3)), np.empty((nb, 3)), np.empty((5, 3))
    for n in range(len(q)):
        _sample_extended(parents, revolute, joints, q[n], qd[n], w0[n], ext, omega, spin, work)
        h0 = h1 = h2 = 0.0
        for c in range(rows.shape[0]):
            x, y, z = _column(ext, rows, c)
            h0, h1, h2 = h0 + weights[c] * x, h1 + weights[c] * y, h2 + weights[c] * z
        out[n, 0], out[n, 1], out[n, 2] = h0, h1, h2


@kernel
def _tangent_columns(parents, revolute, joints, q, qd, w0, dq, dqd, dw0, eps, primal, rows, out):
    """The columns' derivative along ``(dq, dqd, dw0)`` (plus the columns with ``primal``) at the
    samples ``(q, qd, w0)`` into ``out (n, 3, n_cols)``; ``eps (n,)`` the steps (``_regressor._steps``).

    Every momentum column is ``X x Y`` summed over row pairs, ``X`` a pose row ``S`` (an origin
    or axis) and ``Y`` a rate row ``U`` or an extended row ``Q = R e_k wb_m``, so its derivative
    is the column of ``(S, dU, dQ)`` plus that of ``(dS, U, Q)``; with ``primal`` the first is
    ``(S, U + dU, Q + dQ)`` and the columns come with it. The kinematics are differenced, the
    columns never (they are bilinear in them): ``dQ = dR e_k wb_m + R e_k dwb_m``."""
    nb, nj = len(parents) + 1, len(parents)
    qs, qds, ws = np.empty((2, nj)), np.empty((2, nj)), np.empty((2, 3))  # the states x + eps d, x - eps d
    frames, spins, omega, work = np.empty((3, 8 * nb, 3)), np.empty((3, nb, 3)), np.empty((nb, 3)), np.empty((5, 3))
    rate, pose = np.empty((17 * nb, 3)), np.empty((17 * nb, 3))
    for n in range(len(q)):
        for i in range(2):
            sign = 1.0 - 2.0 * i
            for j in range(nj):
                qs[i, j], qds[i, j] = q[n, j] + sign * eps[n] * dq[n, j], qd[n, j] + sign * eps[n] * dqd[n, j]
            for r in range(3):
                ws[i, r] = w0[n, r] + sign * eps[n] * dw0[n, r]
            _sample_frames(parents, revolute, joints, qs[i], qds[i], ws[i], frames[i], omega, spins[i], work)
        _sample_frames(parents, revolute, joints, q[n], qd[n], w0[n], frames[2], omega, spins[2], work)
        for r in range(3):  # frames[0], spins[0]: the derivatives
            for k in range(8 * nb):
                frames[0, k, r] = (frames[0, k, r] - frames[1, k, r]) / (2 * eps[n])
            for b in range(nb):
                spins[0, b, r] = (spins[0, b, r] - spins[1, b, r]) / (2 * eps[n])
        for k in range(8 * nb):  # rate: S, dU (+ U); pose: dS, U
            for r in range(3):
                s, d = frames[2, k, r], frames[0, k, r]
                rate[k, r], pose[k, r] = (s, d) if k < 4 * nb else ((d + s if primal else d), s)
        for b in range(nb):  # rate: dQ (+ Q); pose: Q
            for k in range(3):
                for m in range(3):
                    i = 8 * nb + 9 * b + 3 * k + m
                    for r in range(3):
                        axis, d_axis = frames[2, 4 * b + 1 + k, r], frames[0, 4 * b + 1 + k, r]
                        pose[i, r] = axis * spins[2, b, m]
                        rate[i, r] = (d_axis * spins[2, b, m] + axis * spins[0, b, m]) + (pose[i, r] if primal else 0.0)
        for c in range(rows.shape[0]):
            x1, y1, z1 = _column(rate, rows, c)
            x2, y2, z2 = _column(pose, rows, c)
            out[n, 0, c], out[n, 1, c], out[n, 2, c] = x1 + x2, y1 + y2, z1 + z2


@kernel
def _body_features(T, WT, K, omega, features):
    """The per-body sums ``features (n_bodies, 45, m)`` of :func:`spaceid.dynamics._momentum_jacobian._chunk_jacobian`
    from :func:`~spaceid.dynamics._kinematics.frame_table`'s block ``T (3, 2, n_bodies, 4, m)`` (axis 1: the pose
    rows ``S``, the rate rows ``U``), its weighted sums ``WT`` (``Z = W S`` and ``V = W U``, laid out alike), the
    bodies' rotor inertias in their own axes ``K (n_bodies, 3, 3)`` and angular velocities ``omega (3, n_bodies,
    m)``: entries ``3 x + y`` of ``S V^T``, ``S Z^T`` and ``U Z^T`` summed over each body's four rows, of ``I = R K
    R^T`` (``R`` the body's axes, rows 1 to 3 of ``S``), then ``I w``, ``V_0`` and ``Z_0``; samples innermost."""
    nb, m = T.shape[2], T.shape[4]
    ks = np.empty((3, 3, m))  # K R^T of one body: the inertia's inner product formed once, not per entry
    for b in range(nb):
        for i in range(3):
            for y in range(3):
                for n in range(m):
                    ks[i, y, n] = K[b, i, 0] * T[y, 0, b, 1, n] + K[b, i, 1] * T[y, 0, b, 2, n] \
                        + K[b, i, 2] * T[y, 0, b, 3, n]
        for x in range(3):
            for y in range(3):
                k = 3 * x + y
                for n in range(m):
                    sv = sz = uz = 0.0
                    for f in range(4):
                        sv += T[x, 0, b, f, n] * WT[y, 1, b, f, n]
                        sz += T[x, 0, b, f, n] * WT[y, 0, b, f, n]
                        uz += T[x, 1, b, f, n] * WT[y, 0, b, f, n]
                    features[b, k, n], features[b, 9 + k, n], features[b, 18 + k, n] = sv, sz, uz
                    features[b, 27 + k, n] = (T[x, 0, b, 1, n] * ks[0, y, n] + T[x, 0, b, 2, n] * ks[1, y, n]
                                              + T[x, 0, b, 3, n] * ks[2, y, n])  # fmt: skip
        for x in range(3):
            for n in range(m):
                features[b, 36 + x, n] = (features[b, 27 + 3 * x, n] * omega[0, b, n]
                                          + features[b, 28 + 3 * x, n] * omega[1, b, n]
                                          + features[b, 29 + 3 * x, n] * omega[2, b, n])  # fmt: skip
                features[b, 39 + x, n], features[b, 42 + x, n] = WT[x, 1, b, 0, n], WT[x, 0, b, 0, n]


@kernel
def _subtree_sums(features, parents, summed):
    """``summed (n_joints, 45, m)``: each joint's sum of ``features (n_bodies, 45, m)`` over the bodies it moves
    (joint ``j`` moves body ``j + 1`` and its subtree; ``parents (n_joints,)`` of those bodies, each before its
    children), accumulated from the leaves: a body's sum is added once, to its parent's."""
    nj = summed.shape[0]
    summed[:] = features[1:]
    for j in range(nj - 1, -1, -1):
        if parents[j] > 0:
            summed[parents[j] - 1] += summed[j]


@kernel
def _joint_jacobian(features, summed, T, omega, local, parents, revolute, jac):
    """The momentum's derivatives ``jac (m, 3, 2 n_joints + 3)`` by ``[q, qd, w0]`` from the per-body sums
    ``features (n_bodies, 45, m)`` of :func:`spaceid.dynamics._momentum_jacobian._chunk_jacobian` and their sums
    over each joint's subtree ``summed (n_joints, 45, m)`` (entries ``3 x + y`` of ``S V^T``, ``S Z^T``, ``U Z^T``
    and ``I``, then ``I w``, ``V_0`` and ``Z_0``), the frame table's block ``T (3, 2, n_bodies, 4, m)`` (pose rows
    ``S``, rate rows ``U``), the bodies' angular velocities ``omega (3, n_bodies, m)``, the joint axes in their
    parents' axes ``local (n_joints, 3)``, the parents and the revolute flags: the formulas of that module's
    docstring, samples innermost (the inputs hold them last: read in order)."""
    nj, m, nb = summed.shape[0], summed.shape[2], features.shape[0]
    for x in range(3):  # the base rate's columns: the trace of sum S Z^T, less sum S Z^T, plus sum I
        for y in range(3):
            for n in range(m):
                jac[n, x, 2 * nj + y] = 0.0
            for b in range(nb):
                for n in range(m):
                    jac[n, x, 2 * nj + y] += features[b, 27 + 3 * x + y, n] - features[b, 9 + 3 * x + y, n]
                    if x == y:
                        jac[n, x, 2 * nj + y] += features[b, 9, n] + features[b, 13, n] + features[b, 17, n]
    for j in range(nj):
        p, f, l0, l1, l2 = parents[j], summed[j], local[j, 0], local[j, 1], local[j, 2]
        for n in range(m):
            a0 = l0 * T[0, 0, p, 1, n] + l1 * T[0, 0, p, 2, n] + l2 * T[0, 0, p, 3, n]
            a1 = l0 * T[1, 0, p, 1, n] + l1 * T[1, 0, p, 2, n] + l2 * T[1, 0, p, 3, n]
            a2 = l0 * T[2, 0, p, 1, n] + l1 * T[2, 0, p, 2, n] + l2 * T[2, 0, p, 3, n]
            w0, w1, w2 = omega[0, p, n], omega[1, p, n], omega[2, p, n]
            r0, r1, r2 = w1 * a2 - w2 * a1, w2 * a0 - w0 * a2, w0 * a1 - w1 * a0  # D a = w_parent x a
            v0, v1, v2, z0, z1, z2 = f[39, n], f[40, n], f[41, n], f[42, n], f[43, n], f[44, n]
            if not revolute[j]:  # a prismatic joint translates its subtree along a: a x V0 + Z0 x Da, Z0 x a
                jac[n, 0, j] = a1 * v2 - a2 * v1 + z1 * r2 - z2 * r1
                jac[n, 1, j] = a2 * v0 - a0 * v2 + z2 * r0 - z0 * r2
                jac[n, 2, j] = a0 * v1 - a1 * v0 + z0 * r1 - z1 * r0
                jac[n, 0, nj + j], jac[n, 1, nj + j], jac[n, 2, nj + j] = z1 * a2 - z2 * a1, z2 * a0 - z0 * a2, \
                    z0 * a1 - z1 * a0
                continue
            # the child's origin, its rate
            o0, o1, o2 = T[0, 0, j + 1, 0, n], T[1, 0, j + 1, 0, n], T[2, 0, j + 1, 0, n]
            u0, u1, u2 = T[0, 1, j + 1, 0, n], T[1, 1, j + 1, 0, n], T[2, 1, j + 1, 0, n]
            zs = f[9, n] + f[13, n] + f[17, n] - (o0 * z0 + o1 * z1 + o2 * z2)
            zt = f[18, n] + f[22, n] + f[26, n] - (u0 * z0 + u1 * z1 + u2 * z2)
            vs = f[0, n] + f[4, n] + f[8, n] - (o0 * v0 + o1 * v1 + o2 * v2)
            v0a, z0a, z0r = v0 * a0 + v1 * a1 + v2 * a2, z0 * a0 + z1 * a1 + z2 * a2, z0 * r0 + z1 * r1 + z2 * r2
            iw0, iw1, iw2 = f[36, n], f[37, n], f[38, n]
            for x in range(3):
                a_x = a0 if x == 0 else a1 if x == 1 else a2
                r_x = r0 if x == 0 else r1 if x == 1 else r2
                o_x = o0 if x == 0 else o1 if x == 1 else o2
                u_x = u0 if x == 0 else u1 if x == 1 else u2
                k = 3 * x
                sv = f[k, n] * a0 + f[k + 1, n] * a1 + f[k + 2, n] * a2
                sz_r = f[9 + k, n] * r0 + f[10 + k, n] * r1 + f[11 + k, n] * r2 - o_x * z0r
                sz_a = f[9 + k, n] * a0 + f[10 + k, n] * a1 + f[11 + k, n] * a2 - o_x * z0a
                uz = f[18 + k, n] * a0 + f[19 + k, n] * a1 + f[20 + k, n] * a2
                i_r = f[27 + k, n] * r0 + f[28 + k, n] * r1 + f[29 + k, n] * r2
                i_a = f[27 + k, n] * a0 + f[28 + k, n] * a1 + f[29 + k, n] * a2
                spin = a1 * iw2 - a2 * iw1 if x == 0 else a2 * iw0 - a0 * iw2 if x == 1 else a0 * iw1 - a1 * iw0
                jac[n, x, j] = (sv - o_x * v0a - a_x * vs + r_x * zs - sz_r + a_x * zt - uz + u_x * z0a + spin
                                + i_r)  # fmt: skip
                jac[n, x, nj + j] = a_x * zs - sz_a + i_a
