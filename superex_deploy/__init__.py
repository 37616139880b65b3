"""SuperEx deployment package: SPAD LiDAR simulation, NLOS processing, ONNX Runtime inference and exploration.

This package never imports torch; the training side lives in :mod:`superex_train`.
"""

__version__ = "0.2.0"
