"""The lattice the LaMa members draw far from known space: the filter that removes it
(superex_deploy.onboard.prediction.inference.lattice) on hand-made fields, and the committed ensembles through
ONNX Runtime on a map whose unknown region is large and featureless.

The committed members draw faint lines every 8 cells (their ``size_multiple``: three stride-2 transposed
convolutions) across large unknown regions; docs/benchmarks/models.md, "The grid of lines far out", has the
measurements. The threshold below, at most :data:`MAX_LATTICE_SHARE` of the far field's variance in the
period-8 phase means of any member, sits between what the filter leaves (0.019 at most, LaMa-LOS member 1) and
the weakest raw member (0.099, LaMa-BP member 1) on this map; a member with no lattice scores about
``64 / cells`` = 0.002 (noise) here.
"""

from pathlib import Path

import numpy as np
import pytest

from superex_deploy.evaluation.known_distance import distance_to_known, lattice_strength
from superex_deploy.onboard.prediction.inference import LamaEnsemble, ModelKind, remove_lattice
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN

MAX_LATTICE_SHARE = 0.05
PERIOD = 8
COMMITTED_MODELS = Path(__file__).resolve().parents[1] / "exported"
"""This checkout's models (not ``$SUPEREX_MODELS`` or another install's)."""


def _template(seed: int, amplitude: float) -> np.ndarray:
    """A zero-mean 8 x 8 lattice tile, values within +-amplitude."""
    tile = np.random.default_rng(seed).uniform(-amplitude, amplitude, (PERIOD, PERIOD))
    return tile - tile.mean()


def _walls(shape=(128, 128)) -> np.ndarray:
    """A 0.1 background with a 2-cell wall at 0.7 and its 0.3 shoulder (rows 60-63), and a 1-cell wall at 0.6
    (column 90): what a predicted map holds besides a lattice."""
    field = np.full(shape, 0.1, np.float32)
    field[60:62, 10:120] = 0.7
    field[62:64, 10:120] = 0.3
    field[20:110, 90] = 0.6
    return field


# --- the filter on hand-made fields ---


def test_a_lattice_on_a_flat_field_is_removed():
    field = 0.3 + np.tile(_template(0, 0.08), (12, 16))
    out = remove_lattice(field.astype(np.float32), PERIOD)
    assert out.dtype == np.float32 and out.shape == field.shape
    # Within 1e-3 (1 % of the lattice's +-0.08) everywhere: the smoothing reflects the lattice at the borders, which
    # the window carries a few blocks in.
    np.testing.assert_allclose(out, 0.3, atol=1e-3)


def test_smooth_fields_and_walls_without_a_lattice_are_left_alone():
    ramp = (0.2 + 0.002 * np.arange(96)[:, None] + 0.001 * np.arange(128)[None, :]).astype(np.float32)
    # A ramp is not a lattice: the smoothing reproduces it, so nothing of it is subtracted (up to the borders).
    np.testing.assert_allclose(remove_lattice(ramp, PERIOD), ramp, atol=2e-3)
    walls = _walls()
    np.testing.assert_allclose(remove_lattice(walls, PERIOD), walls, atol=1e-6)


def test_a_lattice_over_walls_is_removed_and_the_walls_kept():
    walls = _walls()
    lattice = np.tile(_template(1, 0.08), (16, 16))
    out = remove_lattice((walls + lattice).astype(np.float32), PERIOD)
    error = out - walls
    assert np.abs(error[:40]).max() < 2e-3  # open field above the walls: lattice gone
    assert abs(error[60:62, 20:80].mean()) < 2e-3 and abs(error[30:100, 90].mean()) < 2e-3  # walls not lowered
    assert lattice_strength(out, np.ones(out.shape, bool), PERIOD).share < 0.2 * lattice_strength(
        walls + lattice, np.ones(out.shape, bool), PERIOD).share


def test_block_means_are_kept():
    rng = np.random.default_rng(2)
    field = np.clip(0.2 + np.tile(_template(3, 0.05), (8, 8)) + rng.normal(0, 0.02, (64, 64)), 0, 1)
    field[30:32, 5:60] = 0.9
    out = remove_lattice(field.astype(np.float32), PERIOD)
    means = lambda a: a.reshape(8, PERIOD, 8, PERIOD).mean(axis=(1, 3))  # noqa: E731
    np.testing.assert_allclose(means(out), means(field), atol=1e-5)


def test_bad_arguments():
    with pytest.raises(ValueError, match="multiples of 8"):
        remove_lattice(np.zeros((20, 24), np.float32), 8)
    with pytest.raises(ValueError, match="period"):
        remove_lattice(np.zeros((8, 8), np.float32), 1)
    with pytest.raises(ValueError, match="odd"):
        remove_lattice(np.zeros((16, 16), np.float32), 8, window_blocks=4)
    with pytest.raises(ValueError, match="positive"):
        remove_lattice(np.zeros((16, 16), np.float32), 8, outlier=0.0)


# --- the committed ensembles ---


def _featureless_map(size: int = 256, room: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """A walled 4 m x 4 m room with two doors, seen, in the corner of a 25.6 m square unknown map; and the cells
    where a lattice is measured: more than 10 m from the room and off its rows and columns (the room's walls are
    continued along those by the members: structure, not lattice)."""
    observed = np.full((size, size), UNKNOWN, np.int8)
    observed[:room, :room] = OCCUPIED
    observed[1:room - 1, 1:room - 1] = FREE
    observed[room // 2 - 5:room // 2 + 5, room - 1] = FREE
    observed[room - 1, room // 2 - 5:room // 2 + 5] = FREE
    far = distance_to_known(observed == UNKNOWN, 0.1) > 10.0
    far[:64] = False
    far[:, :64] = False
    return observed, far


@pytest.fixture(scope="module")
def members():
    """``{(kind, filtered): [3, H, W] member outputs}`` on :func:`_featureless_map`, and its far region."""
    observed, far = _featureless_map()
    out = {}
    for kind in (ModelKind.LAMA_LOS, ModelKind.LAMA_BP):
        filtered = LamaEnsemble.from_manifest(kind, COMMITTED_MODELS)
        assert filtered.size_multiple == PERIOD and filtered.lattice_filter  # on unless turned off
        raw = filtered.with_lattice_filter(False)
        assert not raw.lattice_filter and filtered.lattice_filter and raw.kind is kind
        evidence = np.zeros(observed.shape, np.float32) if kind is ModelKind.LAMA_BP else None
        out[kind, False] = raw.predict_members(observed, evidence)
        out[kind, True] = filtered.predict_members(observed, evidence)
    return out, far


def _shares(outputs: np.ndarray, far: np.ndarray) -> list[float]:
    return [lattice_strength(member, far, PERIOD).share for member in outputs]


@pytest.mark.slow
@pytest.mark.xfail(strict=True, raises=AssertionError, reason="the committed members draw a lattice every 8 cells far from known space "
                   "(their stride-2 transposed convolutions' response to a featureless region; shares 0.10-0.83 here): "
                   "only retraining with an up-sampling that treats every output cell alike removes the cause; "
                   "LamaEnsemble's lattice_filter, on by default, removes the lines (test below). Drop this mark for "
                   "models that "
                   "pass.")
def test_committed_members_draw_no_lattice_far_from_known_space(members):
    outputs, far = members
    for kind in (ModelKind.LAMA_LOS, ModelKind.LAMA_BP):
        assert max(_shares(outputs[kind, False], far)) <= MAX_LATTICE_SHARE, kind


@pytest.mark.slow
def test_the_lattice_filter_removes_the_committed_members_lattice(members):
    outputs, far = members
    observed, _ = _featureless_map()
    distance = distance_to_known(observed == UNKNOWN, 0.1)
    near = (distance > 0.0) & (distance <= 2.0)
    for kind in (ModelKind.LAMA_LOS, ModelKind.LAMA_BP):
        raw, filtered = outputs[kind, False], outputs[kind, True]
        assert max(_shares(raw, far)) > MAX_LATTICE_SHARE, kind  # a member draws a lattice to remove
        assert max(_shares(filtered, far)) <= MAX_LATTICE_SHARE, kind
        # What the filter takes out is the lattice only: the far field's mean is kept (calibration far out).
        assert abs(float(filtered[:, far].mean() - raw[:, far].mean())) < 1e-3, kind
        # The walls the members continue from the room (within 2 m of it, called at 0.5) are not lowered.
        near_walls = (raw >= 0.5) & (near[None] & ~far[None])
        assert near_walls.sum() > 100, kind
        assert abs(float((filtered - raw)[near_walls].mean())) < 0.01, kind
