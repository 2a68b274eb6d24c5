"""Offline replay through the one estimator, in rooms: ``inputs`` (plan, decode, batches),
``window`` (a time slice), ``output`` (where the estimates go), ``summary`` (sums and summary),
``plot`` (the summary picture); ``run`` takes them in order (:func:`~.run.replay`).
"""
