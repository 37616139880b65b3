"""The learned back-projection filter: a Pix2Pix generator run by ONNX Runtime on a window around the robot.

Its input encoding is :mod:`superex_deploy.onboard.prediction.inference.encoding`'s (:func:`crop_window`,
:func:`encode_bp_windows`); its file is opened and checked by
:func:`superex_deploy.onboard.prediction.inference.sessions.load_model`.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from superex_deploy.onboard.prediction.inference.encoding import BpEncoding, crop_window, encode_bp_windows, paste_window
from superex_deploy.onboard.prediction.inference.manifest import (DEFAULT_MODEL_DIR, ModelKind, PathLike,
                                                                  manifest_entries, manifest_resolution)
from superex_deploy.onboard.prediction.inference.sessions import SessionConfig, load_model

__all__ = ["Pix2PixFilter"]


class Pix2PixFilter:
    """The learned back-projection filter (numpy in, numpy out).

    Args:
        path: the ``.onnx`` file.
        expected_sha256: hex sha256 the file must have (None: not checked; :meth:`from_manifest` passes the
            manifest's).
        session: ONNX Runtime settings.
        expected_resolution_m: the training resolution the manifest gives (None: not checked).

    Attributes:
        window_cells: side ``S`` of the window the model reads (cells; from the metadata).
        resolution_m: metres per cell of the back-projections it was trained on (from the metadata);
            :meth:`filter_map` takes maps at this scale, :func:`superex_deploy.onboard.prediction.scale.at_resolution`
            serves other grids.
        encoding: the :class:`BpEncoding` the model reads (from the metadata's ``normalisation``).
        metadata: the model's ``metadata_props``.
    """

    def __init__(self, path: PathLike, expected_sha256: Optional[str] = None, session: SessionConfig = SessionConfig(),
                 expected_resolution_m: Optional[float] = None):
        self._model = load_model(path, (ModelKind.PIX2PIX,), expected_sha256, session, expected_resolution_m)
        self.metadata = self._model.metadata
        self.resolution_m = self._model.resolution_m
        self.window_cells = int(self.metadata.get("window_cells", -1))
        self.encoding = BpEncoding.from_description(self.metadata["normalisation"])
        if self._model.input_shape[2:] != (self.window_cells, self.window_cells):
            raise ValueError(f"model file {path} takes windows of {list(self._model.input_shape[2:])} cells but its "
                             f"metadata says window_cells = {self.window_cells}")

    @classmethod
    def from_manifest(cls, directory: PathLike = DEFAULT_MODEL_DIR,
                      session: SessionConfig = SessionConfig()) -> "Pix2PixFilter":
        """The Pix2Pix model listed in ``directory/manifest.json``, its sha256 checked."""
        entries = manifest_entries(directory, ModelKind.PIX2PIX)
        if len(entries) != 1:
            raise ValueError(f"the manifest in {directory} lists {len(entries)} pix2pix models, expected one")
        return cls(entries[0].path, entries[0].sha256, session, manifest_resolution(entries))

    def filter_windows(self, windows: np.ndarray) -> np.ndarray:
        """Wall probability of back-projection windows.

        Args:
            windows: float32 ``[S, S]`` or ``[N, S, S]`` raw back-projection in [0, 1], robot at ``(S//2, S//2)``.

        Returns:
            float32 of the same shape, in [0, 1].
        """
        windows = np.asarray(windows)
        single = windows.ndim == 2
        batch = windows[None] if single else windows
        if batch.ndim != 3 or batch.shape[1:] != (self.window_cells, self.window_cells):
            raise ValueError(f"windows must be [{self.window_cells}, {self.window_cells}] or [N, "
                             f"{self.window_cells}, {self.window_cells}], got shape {windows.shape}")
        out = self._model.session.run([self._model.output_name],
                                      {self._model.input_name: encode_bp_windows(batch, self.encoding)})[0][:, 0]
        out = np.clip(out, 0.0, 1.0).astype(np.float32)
        return out[0] if single else out

    def filter_map(self, bp: np.ndarray, pose_rc) -> np.ndarray:
        """Filter the window of a map-frame back-projection around the robot.

        Args:
            bp: float32 ``[H, W]`` raw back-projection in [0, 1] (``superex_deploy.onboard.nlos.back_project``).
            pose_rc: the robot cell (row, col) the scan was taken from.

        Returns:
            float32 ``[H, W]`` wall probability inside the window (zero outside it).
        """
        bp = np.asarray(bp)
        if bp.ndim != 2 or bp.dtype != np.float32:
            raise ValueError(f"bp must be a float32 [H, W] map, got {bp.dtype} with shape {bp.shape}")
        window = crop_window(bp, pose_rc, self.window_cells)
        return paste_window(self.filter_windows(window), pose_rc, bp.shape)
