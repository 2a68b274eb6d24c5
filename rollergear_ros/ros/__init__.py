"""The only rclpy users: the ``loss_estimator`` node (a shell over the one estimator), its
diagnostics and input thread, the bag player and the watcher.
"""
