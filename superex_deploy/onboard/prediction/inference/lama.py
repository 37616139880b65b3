"""The LaMa map predictors: an ensemble of ONNX Runtime sessions whose mean and variance over the members is the
prediction (:class:`LamaEnsemble`), and the validation of its member options (:func:`check_member_options`).

Its input encoding is :func:`superex_deploy.onboard.prediction.inference.encoding.encode_map`; its files are opened and
checked by :func:`superex_deploy.onboard.prediction.inference.sessions.load_model`.
"""

from __future__ import annotations

import copy
from typing import Optional, Sequence

import numpy as np

from superex_deploy.onboard.prediction.inference.encoding import encode_map
from superex_deploy.onboard.prediction.inference.lattice import remove_lattice
from superex_deploy.onboard.prediction.inference.manifest import (DEFAULT_MODEL_DIR, MODEL_CHANNELS, ModelKind, PathLike,
                                                       manifest_entries, manifest_resolution)
from superex_deploy.onboard.prediction.inference.sessions import SessionConfig, load_model
from superex_deploy.onboard.types import OCCUPIED, UNKNOWN, Prediction

__all__ = ["LamaEnsemble", "check_member_options"]


def check_member_options(max_members: Optional[int], members: Optional[int] = None) -> None:
    """Validate :meth:`LamaEnsemble.with_members`'s option (``members``: the ensemble's size, None: not known yet).

    Raises:
        ValueError: ``max_members`` not an integer in 1..members (or >= 1).
    """
    if max_members is not None and (not isinstance(max_members, (int, np.integer)) or isinstance(max_members, bool)
                                    or max_members < 1 or (members is not None and max_members > members)):
        allowed = f"in 1..{members}" if members is not None else ">= 1"
        raise ValueError(f"max_members must be an integer {allowed} or None, got {max_members!r}")


class LamaEnsemble:
    """An ensemble of LaMa map predictors: a :class:`~superex_deploy.onboard.types.MapPredictor`.

    ``predict`` encodes the observed map (and the evidence, for LAMA_BP), pads it at the bottom and right with
    unknown cells to a size the network takes (multiples of ``size_multiple``, at least ``min_size``), runs every
    member, crops back and returns the members' mean and (population) variance. With ``keep_observed`` the
    observed cells keep their observed value with zero variance (observations agree with the ground truth in
    simulation); only unknown cells carry the networks' predictions. The members are separate files (each with
    its own member index), so they run one after the other, each on all ``intra_op_threads``.

    ``max_members`` trades members for time (:meth:`with_members`): only the first members run, and the variance is
    theirs (one member: zero). (An ``agreement_stop``, which stopped after the first two members when they agreed,
    was measured in docs/benchmarks/realtime.md and retired.)

    The committed members draw a faint grid of lines every ``size_multiple`` cells across large unknown regions
    (their stride-2 transposed convolutions; docs/benchmarks/models.md, "The grid of lines far out"). With
    ``lattice_filter`` (the default) each member's output goes through
    :func:`~superex_deploy.onboard.prediction.inference.lattice.remove_lattice` on the padded grid before it is
    cropped: the lines go, each ``size_multiple``-block's mean stays (map IoU and calibration unchanged to 0.001,
    docs/benchmarks/models.md). It costs a few per cent of a prediction (``scripts/bench_lattice_cost.py``,
    ``benchmarks/lattice/``); ``with_lattice_filter(False)`` gives the members' raw outputs.

    Args:
        paths: the members' ``.onnx`` files (all of one kind).
        expected_sha256: one hex sha256 per file, or None (not checked; :meth:`from_manifest` passes them).
        session: ONNX Runtime settings.
        keep_observed: see above.
        expected_resolution_m: the training resolution the manifest gives the members (None: not checked).
        lattice_filter: see above.

    Attributes:
        kind: LAMA_BP or LAMA_LOS.
        resolution_m: metres per cell of the maps the members were trained on (from their metadata; all
            members share it): :meth:`predict` takes maps at this scale,
            :func:`superex_deploy.onboard.prediction.scale.at_resolution` serves other grids.
        name: ``"lama_bp"`` or ``"lama_los"`` (the predictor's name in episode logs).
        size_multiple, min_size: padding targets (cells).
        max_members: members run per prediction (None: all).
        lattice_filter: whether members' outputs go through the lattice filter (see above).
        members_run: how many members the latest prediction ran.
    """

    accepts_crops = True  # a fully convolutional network: any sub-map is a valid input

    def __init__(self, paths: Sequence[PathLike], expected_sha256: Optional[Sequence[str]] = None,
                 session: SessionConfig = SessionConfig(), keep_observed: bool = True,
                 expected_resolution_m: Optional[float] = None, lattice_filter: bool = True):
        paths = list(paths)
        if not paths:
            raise ValueError("a LamaEnsemble needs at least one member file")
        if expected_sha256 is not None and len(expected_sha256) != len(paths):
            raise ValueError(f"got {len(expected_sha256)} hashes for {len(paths)} member files")
        hashes = list(expected_sha256) if expected_sha256 is not None else [None] * len(paths)
        self._members = [load_model(p, (ModelKind.LAMA_BP, ModelKind.LAMA_LOS), h, session, expected_resolution_m)
                         for p, h in zip(paths, hashes)]
        first = self._members[0]
        self.kind = first.kind
        self.resolution_m = first.resolution_m
        self.name = self.kind.value
        self.size_multiple = int(first.metadata.get("size_multiple", 0))
        self.min_size = int(first.metadata.get("min_size", 0))
        if self.size_multiple < 1 or self.min_size < 1:
            raise ValueError(f"model file {first.path} lacks a valid size_multiple / min_size in its metadata")
        for member in self._members[1:]:
            if member.kind is not self.kind:
                raise ValueError(f"ensemble members differ in kind: {first.path} is {self.kind.value}, "
                                 f"{member.path} is {member.kind.value}")
            if (int(member.metadata.get("size_multiple", 0)), int(member.metadata.get("min_size", 0))) != (
                    self.size_multiple, self.min_size):
                raise ValueError(f"ensemble members {first.path} and {member.path} need different input sizes")
            if member.resolution_m != self.resolution_m:
                raise ValueError(f"ensemble members {first.path} and {member.path} were trained at different "
                                 f"resolutions ({self.resolution_m} and {member.resolution_m} m/cell)")
        self.keep_observed = bool(keep_observed)
        self.lattice_filter = bool(lattice_filter)
        self.max_members: Optional[int] = None
        self.members_run = 0

    def with_members(self, max_members: Optional[int] = None) -> "LamaEnsemble":
        """This ensemble (sharing its sessions) running at most ``max_members`` members (None: all).

        Raises:
            ValueError: ``max_members`` outside 1..members.
        """
        check_member_options(max_members, len(self._members))
        view = copy.copy(self)
        view.max_members = None if max_members is None else int(max_members)
        view.members_run = 0
        return view

    def with_lattice_filter(self, enabled: bool = True) -> "LamaEnsemble":
        """This ensemble (sharing its sessions) with the lattice filter on or off (see the class docstring)."""
        view = copy.copy(self)
        view.lattice_filter = bool(enabled)
        return view

    @classmethod
    def from_manifest(cls, kind: ModelKind, directory: PathLike = DEFAULT_MODEL_DIR,
                      session: SessionConfig = SessionConfig(), keep_observed: bool = True,
                      lattice_filter: bool = True) -> "LamaEnsemble":
        """Every ``kind`` member listed in ``directory/manifest.json``, in member order, sha256 checked."""
        if kind not in (ModelKind.LAMA_BP, ModelKind.LAMA_LOS):
            raise ValueError(f"a LamaEnsemble is made of lama_bp or lama_los models, got {kind}")
        entries = manifest_entries(directory, kind)
        return cls([e.path for e in entries], [e.sha256 for e in entries], session, keep_observed,
                   manifest_resolution(entries), lattice_filter)

    @property
    def members(self) -> int:
        """Number of ensemble members."""
        return len(self._members)

    def padded_shape(self, shape: tuple[int, int]) -> tuple[int, int]:
        """The ``(rows, cols)`` a map of ``shape`` is padded to."""
        m = self.size_multiple
        return tuple(max(-(-int(n) // m) * m, self.min_size) for n in shape)  # type: ignore[return-value]

    def predict_members(self, observed: np.ndarray, extra: Optional[np.ndarray] = None) -> np.ndarray:
        """Each member's wall probability: float32 ``[M, H, W]`` in [0, 1] (before ``keep_observed``, after the
        lattice filter when it is on); ``M`` is the members run (see ``max_members``)."""
        encoded = encode_map(observed, extra, self.kind)
        height, width = observed.shape
        rows, cols = self.padded_shape((height, width))
        padded = np.zeros((1, encoded.shape[1], rows, cols), np.float32)
        padded[:, MODEL_CHANNELS[self.kind].index("unknown")] = 1.0  # the padding is unknown space
        padded[:, :, :height, :width] = encoded
        members = self._members if self.max_members is None else self._members[:self.max_members]
        out = np.empty((len(members), height, width), np.float32)
        for i, member in enumerate(members):
            result = member.session.run([member.output_name], {member.input_name: padded})[0][0, 0]
            if self.lattice_filter:
                result = remove_lattice(np.clip(result, 0.0, 1.0), self.size_multiple)
            out[i] = np.clip(result[:height, :width], 0.0, 1.0)
        self.members_run = len(out)
        return out

    def predict(self, observed: np.ndarray, extra: Optional[np.ndarray] = None) -> Prediction:
        """Mean and variance over the members (see the class docstring). ``observed`` int8 ``[H, W]``;
        ``extra`` float32 ``[H, W]`` filtered back-projection (LAMA_BP: required; LAMA_LOS: ignored)."""
        return self.combine(self.predict_members(observed, extra), observed)

    def combine(self, members: np.ndarray, observed: np.ndarray) -> Prediction:
        """The prediction of the members' outputs ``members`` (float32 ``[M, H, W]``, :meth:`predict_members`) on
        ``observed`` (int8 ``[H, W]``): their mean and variance, the known cells kept where ``keep_observed``."""
        mean = members.mean(axis=0)
        variance = members.var(axis=0)
        if self.keep_observed:
            known = observed != UNKNOWN
            mean[known] = (observed[known] == OCCUPIED)
            variance[known] = 0.0
        return Prediction(mean=mean.astype(np.float32), variance=variance.astype(np.float32))
