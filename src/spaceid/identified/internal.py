"""Internal interface of :mod:`spaceid.identified` for the later stages (:mod:`spaceid.studies`):
stable within the package, not public API.

``tests/test_layout.py`` enforces that other subpackages import only through
``spaceid.identified`` (its ``__all__``) or this module (its ``__all__``).

``draw_payload``
    The figure of a payload estimate (``PayloadEstimate.plot``), which :mod:`spaceid.studies`
    saves (``plot_payload``).
"""

from ._plots import draw_payload

__all__ = ["draw_payload"]
