"""The only rclpy users: the ``loss_estimator`` node (a shell over the one estimator), its
diagnostics and input thread, the bag player and the watcher.
"""

from ..base.face import lazy_face

#: the wing's API (the names other wings use) and the module that defines each
_FACE = {
    "contract_line": "nodehelp",
    "GRAPH_WAIT_S": "player",
    "MIN_MATCHED_WAIT_S": "player",
    "SUBSCRIBER_SETTLE_S": "player",
    "PlayOptions": "player",
    "init_for_command_line": "player",
    "play": "player",
}

__all__, __getattr__, __dir__ = lazy_face(__name__, _FACE)
