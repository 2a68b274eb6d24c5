"""The node's live loss map: published on the map channel and written to ``node.map_file``.

The map (:mod:`outputs.livemap`) is the model with the accepted effects at their adapted
coefficients on the ``map.*`` grid.  :class:`LiveMapPublisher` makes one at start, after a
parameter change, whenever an adapted coefficient has left its 95 % interval since the last one
and, for a model that follows the oil, when the oil has moved ``node.map_oil_step_c`` from the map's.
"""

from __future__ import annotations

from pathlib import Path

from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from ..base.errors import RollergearError
from ..core.estimator import Estimator
from ..core.params import Config
from ..outputs.livemap import coefficients_moved, live_map, oil_moved, to_multiarray
from ..outputs.lossmap import map_comments, write_vtlm

__all__ = ["LiveMapPublisher"]


class LiveMapPublisher:
    """Publishes the loss map (``publishers``: the map channels') and rewrites the map file when
    the adapted coefficients have moved; ``source`` names the node in the file's comments."""

    def __init__(self, publishers: tuple, source: str, logger) -> None:
        self.publishers = publishers
        self.source = source
        self.logger = logger
        self.published = 0  #: maps made so far
        self.last_message: Float64MultiArray | None = None  #: the last map published (the node records it)
        self.oil_temperature_c: float | None = None  #: the last finite oil temperature the node received
        self.path: Path | None = None  #: the VECTO file rewritten with each map (the node's ``node.map_file``)
        self._coefficients: dict[str, float] | None = None  # of the map last published
        self._temperature_c: float | None = None  # the oil temperature the last map was evaluated at

    def renew(self) -> None:
        """Make the next :meth:`update` publish a map (the parameters changed)."""
        self._coefficients = None

    def update(self, config: Config, estimator: Estimator) -> None:
        """Publish the map (and rewrite ``node.map_file``) if there is none yet, an adapted
        coefficient has left its 95 % interval since the last one or the oil has moved far enough."""
        current = estimator.coefficients()
        if self._coefficients is not None and not coefficients_moved(
                self._coefficients, current, estimator.coefficient_intervals()) \
                and not oil_moved(config, self._temperature_c, self.oil_temperature_c):
            return
        self._coefficients = current
        try:
            adapted, loss_map = live_map(config, current, self.oil_temperature_c)
        except RollergearError as exc:  # e.g. a map.* grid outside the estimator's plausible range
            self.logger.warn(f"no loss map: {exc}")
            return
        self._temperature_c = loss_map.temperature_c
        if self.publishers:
            arr = to_multiarray(loss_map)
            msg = Float64MultiArray()
            msg.layout.dim = [MultiArrayDimension(label=label, size=size, stride=stride)
                              for label, size, stride in zip(arr.labels, arr.sizes, arr.strides)]
            msg.layout.data_offset = arr.data_offset
            msg.data = arr.data.tolist()
            self.last_message = msg
            for publisher in self.publishers:
                publisher.publish(msg)
        map_file = self.path
        if map_file:
            try:  # the folder may have gone since start-up: a warning, the node and the topic go on
                write_vtlm(loss_map, map_file,
                           map_comments(adapted, f"{self.source} (live; adapted coefficients)",
                                        loss_map.temperature_c, reverse=False))
            except OSError as exc:
                self.logger.warn(f"node.map_file: could not rewrite {map_file}: {exc}")
        self.published += 1
