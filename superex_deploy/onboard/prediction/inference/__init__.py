"""ONNX Runtime inference of the learned models: the Pix2Pix back-projection filter and the LaMa ensembles.

Models are exported by :mod:`superex_train.export` into a folder (``exported/`` in the repository, installed as
``superex_deploy.models``) with a ``manifest.json`` that lists every file with its kind, ensemble member index and
sha256. Every ``.onnx`` file carries its own description in ``metadata_props`` (keys in :data:`METADATA_KEYS`):
model kind, input channels and their order, normalisation, resolution, window size or size multiple, ensemble
member, training-data hash, package version. Loading checks the file's sha256 against the manifest (or a hash the
caller gives), then the metadata against what the caller asked for, and raises ``ValueError`` naming the file and
the mismatch for a missing, corrupt or mismatched model. Input and output tensor names are read from the model,
not assumed.

One module per concept (this package re-exports their public names, so
``from superex_deploy.onboard.prediction.inference import LamaEnsemble`` works):

* :mod:`~superex_deploy.onboard.prediction.inference.manifest`: model kinds and their channels, the metadata format, the
  default model folder (``$SUPEREX_MODELS`` or the installed ``superex_deploy.models``), the manifest and sha256.
* :mod:`~superex_deploy.onboard.prediction.inference.encoding`: how inputs are encoded (back-projection windows, observed
  maps; shared with :mod:`superex_train`, which imports them from here) and the resolution models are trained at.
* :mod:`~superex_deploy.onboard.prediction.inference.sessions`: the one ONNX Runtime session factory and the loading of one
  model file with its checks.
* :mod:`~superex_deploy.onboard.prediction.inference.pix2pix`: :class:`Pix2PixFilter`, the learned back-projection filter.
* :mod:`~superex_deploy.onboard.prediction.inference.lama`: :class:`LamaEnsemble`, the LaMa map predictors.
* :mod:`~superex_deploy.onboard.prediction.inference.lattice`: :func:`remove_lattice`, the filter that takes the
  LaMa members' lines every ``size_multiple`` cells out of their outputs.

This package never imports torch; ``onnxruntime`` is imported when the first session is made.
"""

from __future__ import annotations

from superex_deploy.onboard.prediction.inference.manifest import (DEFAULT_MODEL_DIR, FORMAT_VERSION, MANIFEST_NAME, METADATA_KEYS,
                                                       MODEL_CHANNELS, ManifestEntry, ModelKind, PathLike,
                                                       manifest_resolution, read_manifest, sha256_file)
from superex_deploy.onboard.prediction.inference.encoding import (NORMALISATION, RESOLUTION_M, BpEncoding, crop_window,
                                                       encode_bp_windows, encode_map)
from superex_deploy.onboard.prediction.inference.sessions import (GraphOptimization, SessionConfig, ThreadBudget, available_cores,
                                                      make_session)
from superex_deploy.onboard.prediction.inference.pix2pix import Pix2PixFilter
from superex_deploy.onboard.prediction.inference.lama import LamaEnsemble, check_member_options
from superex_deploy.onboard.prediction.inference.lattice import remove_lattice

__all__ = ["ModelKind", "BpEncoding", "MODEL_CHANNELS", "METADATA_KEYS", "FORMAT_VERSION", "MANIFEST_NAME",
           "DEFAULT_MODEL_DIR", "GraphOptimization", "SessionConfig", "ThreadBudget", "available_cores", "make_session",
           "sha256_file", "ManifestEntry", "manifest_resolution",
           "read_manifest", "encode_bp_windows", "encode_map", "crop_window", "Pix2PixFilter", "LamaEnsemble",
           "check_member_options", "remove_lattice", "NORMALISATION", "RESOLUTION_M", "PathLike"]
