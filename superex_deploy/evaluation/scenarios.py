"""The scenario sets the benchmarks run on: where an episode starts, on which floor.

* :func:`eval_scenarios`: the 40 eval scenarios (every bundled eval floor's start poses), for reporting only;
* :func:`train_scenarios` / :func:`heldout_scenarios`: seeded starts on the larger train floors (tuning studies
  run here; :data:`HELDOUT_BUILDINGS` are the buildings the learned models never trained on);
* :func:`altered_scenarios`: the eval scenarios with the seed of their altered floor
  (:mod:`superex_deploy.sim.altered_floors`).
"""

from __future__ import annotations

import zlib
from typing import Literal, NamedTuple, Optional, Sequence

import numpy as np

from superex_deploy.maps import list_maps, load_map, map_building, random_start, start_poses
from superex_deploy.sim.altered_floors import alteration_seed

__all__ = ["Scenario", "HELDOUT_BUILDINGS", "eval_scenarios", "train_scenarios", "heldout_scenarios",
           "altered_scenarios"]

HELDOUT_BUILDINGS = (10, 20, 21, 28, 30)
"""``superex_train.generate.heldout_buildings()``, spelled out because the deploy side does not import the training
package (tests/test_evaluation.py checks that the two agree)."""


class Scenario(NamedTuple):
    """One start on one floor (a tuple: it unpacks as ``map_name, start_index, start_rc`` and pickles to workers).

    Attributes:
        map_name: bundled map name.
        start_index: index of the start among the map's start poses (0 for a seeded start on a train floor).
        start_rc: the start cell ``(row, col)``, Python ints.
    """

    map_name: str
    start_index: int
    start_rc: tuple[int, int]


def eval_scenarios(order: Literal["map", "start"] = "map", starts: int = 0,
                   maps: Optional[Sequence[str]] = None) -> list[Scenario]:
    """The eval scenarios: every start pose of every eval floor (40: 10 floors x 4 starts).

    Args:
        order: ``"map"``: map by map, each map's starts in order; ``"start"``: start 0 of every map, then start 1,
            ... (the first ``k`` then spread over the floors).
        starts: keep only each map's first ``starts`` start poses (0: all).
        maps: these eval maps, in this order, instead of all of them.
    """
    names = list(list_maps("eval") if maps is None else maps)
    poses = {name: start_poses(name) for name in names}
    if starts:
        poses = {name: p[:starts] for name, p in poses.items()}
    if order == "map":
        pairs = [(name, k) for name in names for k in range(len(poses[name]))]
    elif order == "start":
        pairs = [(name, k) for k in range(max((len(p) for p in poses.values()), default=0)) for name in names
                 if k < len(poses[name])]
    else:
        raise ValueError(f"order must be 'map' or 'start', got {order!r}")
    return [Scenario(name, k, (int(poses[name][k][0]), int(poses[name][k][1]))) for name, k in pairs]


def train_scenarios(n_maps: int, starts: int = 1, min_area: int = 40000, heldout: bool = False
                    ) -> list[tuple[str, tuple[int, int]]]:
    """``(map, start cell)`` pairs on the train floors: the floors of at least ``min_area`` valid cells (the eval
    floors have 85k-450k), every k-th of them to take ``n_maps``, and ``starts`` start cells on each, drawn by
    :func:`superex_deploy.maps.random_start` (0.5 m clearance) from a generator seeded with the map's name (crc32),
    so a set is the same on every machine.

    Args:
        heldout: only the floors of :data:`HELDOUT_BUILDINGS` (where the learned predictors can be tuned on
            without having seen the floor in training).
    """
    names = [n for n in list_maps("train") if int(load_map(n).valid.sum()) >= min_area]
    if heldout:
        names = [n for n in names if map_building(n) in HELDOUT_BUILDINGS]
    names = names[::max(1, len(names) // n_maps)][:n_maps]
    out = []
    for name in names:
        grid = load_map(name)
        rng = np.random.default_rng(zlib.crc32(name.encode()))
        out += [(name, random_start(grid, rng, 0.5)) for _ in range(starts)]
    return out


def heldout_scenarios(n_maps: int = 12, starts: int = 1) -> list[Scenario]:
    """The held-out tuning set: ``starts`` seeded starts on each of ``n_maps`` held-out train floors of at least
    40,000 valid cells (:func:`train_scenarios` with ``heldout=True``), as :class:`Scenario` (start index ``k``: the
    floor's k-th draw, so a floor's first ``s`` starts are the same for every ``starts >= s``), floor by floor.

    Raises:
        ValueError: ``starts < 1``.
    """
    if starts < 1:
        raise ValueError(f"starts must be >= 1, got {starts}")
    pairs = train_scenarios(n_maps, starts, 40000, heldout=True)
    return [Scenario(name, i % starts, (int(start[0]), int(start[1]))) for i, (name, start) in enumerate(pairs)]


def altered_scenarios(order: Literal["map", "start"] = "map") -> list[tuple[Scenario, int]]:
    """The eval scenarios, each with the seed of its altered floor
    (:func:`~superex_deploy.sim.altered_floors.alteration_seed`), as ``superex benchmark --suite altered`` runs
    them."""
    return [(s, alteration_seed(s.map_name, s.start_rc)) for s in eval_scenarios(order)]
