"""Noise-free logs at random states and attitudes, shared by the tests of the identified model."""

import numpy as np

from spaceid.data import Log, quat_to_matrix
from spaceid.dynamics import base_rate


def random_log(param, h, n, rng):
    """Noise-free samples at random states and attitudes, the base rate from momentum ``h``."""
    model = param.model
    q = rng.uniform(-np.pi, np.pi, (n, model.n_joints))
    qd = rng.standard_normal((n, model.n_joints))
    quat = rng.standard_normal((n, 4))
    if model.planar:
        quat[:, 1:3] = 0.0
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    h_base = np.einsum("nji,j->ni", quat_to_matrix(quat), h)
    w0 = base_rate(param, param.true_values, q, qd, h_base)
    return Log(np.arange(n) * 0.01, model.joints, q, qd, quat, w0, model.planar)
