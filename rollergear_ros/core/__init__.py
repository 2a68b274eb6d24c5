"""The core, without I/O or rclpy: the paper's equations, the parameter set (validated in one
place), the model, the effect registry and the model-parameter table, online adaptation, input
pairing, the one estimator, and the model at operating points.  Imports only ``base``.
"""
