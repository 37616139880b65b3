"""SuperEx training package (torch): datasets from the simulator, Pix2Pix and LaMa-ensemble training, ONNX export.

Requires the ``train`` extra (``pip install -e '.[train]'``, which pins ``torch==2.13.0``).
"""
