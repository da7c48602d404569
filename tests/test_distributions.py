"""spaceid's distribution functions return scipy.stats' values bit for bit, on and off the support."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from spaceid._distributions import chi2_cdf, chi2_isf, chi2_ppf, chi2_sf, f_sf, norm_sf
from conftest import examples

EDGES = [0.0, -0.0, -1.0, np.inf, -np.inf, np.nan, 1e-300, 1e300]
points = st.one_of(st.sampled_from(EDGES), st.floats(-10, 1e4, allow_nan=False))
dofs = st.one_of(st.integers(1, 5000), st.floats(0.05, 500.0))
probabilities = st.floats(1e-12, 1 - 1e-12)


def _same(a, b):
    """Equal bit for bit, NaN where NaN, of the same kind (a float for a scalar argument)."""
    assert np.ndim(a) == np.ndim(b)
    np.testing.assert_array_equal(a, b, strict=False)
    assert np.array_equal(np.signbit(a), np.signbit(b)) or np.all(np.isnan(a))


@settings(max_examples=examples(300, 40), deadline=None)
@given(x=points, df=dofs)
def test_chi_square_cdf_and_sf(x, df):
    _same(chi2_cdf(x, df), stats.chi2.cdf(x, df))
    _same(chi2_sf(x, df), stats.chi2.sf(x, df))


@settings(max_examples=examples(300, 40), deadline=None)
@given(p=probabilities, df=dofs)
def test_chi_square_quantiles(p, df):
    _same(chi2_ppf(p, df), stats.chi2.ppf(p, df))
    _same(chi2_isf(p, df), stats.chi2.isf(p, df))


@settings(max_examples=examples(300, 40), deadline=None)
@given(x=points, dfn=dofs, dfd=dofs)
def test_f_sf(x, dfn, dfd):
    _same(f_sf(x, dfn, dfd), stats.f.sf(x, dfn, dfd))


@settings(max_examples=examples(200, 40), deadline=None)
@given(x=points)
def test_normal_sf(x):
    _same(norm_sf(x), stats.norm.sf(x))


def test_arrays_as_the_monitor_passes_them():
    """An array of points (the monitor's CUSUM passes one, clipped at zero) and the median."""
    x = np.array([0.0, 0.5, 3.0, np.inf, 1e-310])
    _same(chi2_cdf(x, 3), stats.chi2.cdf(x, 3))
    _same(chi2_sf(x, 7), stats.chi2.sf(x, 7))
    _same(chi2_ppf(0.5, 3), stats.chi2.median(3))
    assert isinstance(chi2_sf(2.0, 3), float) and isinstance(norm_sf(0.3), float)
