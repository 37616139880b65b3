"""SuperEx deployment package: SPAD LiDAR simulation, NLOS processing, ONNX Runtime inference and exploration.

This package never imports torch; the training side lives in :mod:`superex_train`.
"""

from superex_deploy import _moved

__version__ = "0.2.0"

_moved.install()
