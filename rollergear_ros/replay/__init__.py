"""Offline replay through the one estimator, in rooms: ``inputs`` (plan, decode, batches),
``window`` (a time slice), ``output`` (where the estimates go), ``summary`` (sums and summary),
``plot`` (the summary picture); ``run`` takes them in order (:func:`~.run.replay`).
"""

from ..base.face import lazy_face

#: the wing's API (the names other wings use) and the module that defines each
_FACE = {
    "imported_table": "run",
    "replay": "run",
}

__all__, __getattr__, __dir__ = lazy_face(__name__, _FACE)
