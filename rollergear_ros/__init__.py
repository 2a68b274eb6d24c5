"""rollergear_ros: friction losses and efficiency of a roller gearing gearbox, online and offline.

The package is laid out in wings by concern; data flows one way, from the bottom of
:data:`WINGS` to its top, and a module imports only from its own wing and the wings below it
(``test/test_imports.py`` holds the package to it).
"""

#: the wings, bottom to top
WINGS: tuple[str, ...] = ("base", "core", "recordings", "sources", "outputs", "replay", "calibration", "fleet", "ros",
                          "cli")

__all__ = ["WINGS", "predict"]


def __getattr__(name: str):
    """``from rollergear_ros import predict`` (:func:`replay.predict.predict`), imported when asked for."""
    if name == "predict":
        from .replay.predict import predict

        return predict
    raise AttributeError(f"module 'rollergear_ros' has no attribute {name!r}")
