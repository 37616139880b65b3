"""The exported ONNX models and their manifest, installed as the package ``superex_deploy.models``.

``superex export`` writes here and the repository keeps the models here; the wheel carries this folder as
``superex_deploy/models`` (see ``pyproject.toml``), and :data:`superex_deploy.onboard.prediction.inference.DEFAULT_MODEL_DIR`
finds it with :mod:`importlib.resources`, wherever the package is installed.
"""
