"""Fixtures shared by several test files: hand-built grids, hand-built benchmark logs and small message builders.

Each fixture is a session-scoped factory (it returns a plain function), so a test builds the object with its own
sizes, and Hypothesis tests, which refuse function-scoped fixtures, can use them too. The slow twins of the numba
kernels are a plain module, ``tests/naive.py``.

Tests marked ``slow`` (a long property test, a subprocess, a model or an episode of hundreds of steps) are left out
by ``pytest -m "not slow"``; the default run, the one CI runs, keeps them."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from superex_deploy.maps import OccupancyGrid
from superex_deploy.messages import Command, LaserScan, MapFrame, Observation, Pose2D
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN

# The fields of a benchmark's episode that the same scenarios reproduce exactly, whatever the backend or an
# interruption (timings and worker names differ).
DETERMINISTIC = ("map", "start_index", "planner", "coverage", "coverage_with_carving", "path_length_m", "goals", "iou",
                 "steps", "finished")


def _box_walls(rows: int, cols: int, walls=()) -> np.ndarray:
    """The wall cells (bool, ``rows`` x ``cols``) of a box walled on its border, with each of ``walls`` (an index into
    a 2-D array: a cell or slices) walled too."""
    occupied = np.zeros((rows, cols), bool)
    occupied[0, :] = occupied[-1, :] = occupied[:, 0] = occupied[:, -1] = True
    for cell in walls:
        occupied[cell] = True
    return occupied


def _walled_box(rows: int = 20, cols: int = 20, walls=(), name: str = "box") -> OccupancyGrid:
    """A ``rows`` x ``cols`` grid at 0.1 m a cell, walled on its border and at ``walls`` (see :func:`_box_walls`);
    every other cell is free. The grid's arrays are read-only: build on ``.occupied.copy()``."""
    occupied = _box_walls(rows, cols, walls)
    return OccupancyGrid(occupied, ~occupied, 0.1, name)


@pytest.fixture(scope="session")
def walled_box():
    """``walled_box(rows=20, cols=20, walls=(), name="box")``: a walled box, see :func:`_walled_box`."""
    return _walled_box


@pytest.fixture(scope="session")
def two_rooms():
    """``two_rooms()``: a 30 x 40 box split by a wall (column 20) with a 0.6 m door (rows 12-17): most of the right
    room is hidden from cell (5, 5)."""
    def build() -> OccupancyGrid:
        occupied = _box_walls(30, 40, walls=[(slice(None), 20)])
        occupied[12:18, 20] = False
        return OccupancyGrid(occupied, ~occupied, 0.1, "two rooms")
    return build


@pytest.fixture(scope="session")
def wall_room():
    """``wall_room()``: a 40 x 40 box with an interior wall (rows 5-34 of column 25, its face on a cell boundary)
    facing a robot on its left."""
    return lambda: _walled_box(40, 40, walls=[(slice(5, 35), 25)], name="wall room")


@pytest.fixture(scope="session")
def l_corner():
    """``l_corner()``: the robot's corridor (rows 45-55, ending at a wall at column 40) and a side corridor (columns
    30-39) north to a hidden wall at row 9, at 0.1 m a cell; the side corridor beyond row 44 is hidden from a robot
    at (50, 10)."""
    def build() -> OccupancyGrid:
        walls = np.ones((70, 60), bool)
        walls[45:56, 1:40] = False
        walls[10:45, 30:40] = False
        return OccupancyGrid(walls, ~walls, 0.1, "l-corner")
    return build


@pytest.fixture(scope="session")
def corridor_rooms():
    """``corridor_rooms()``: six rooms on both sides of an east-west corridor (rows 36-43), a door each, 80 x 160
    cells: enough frontiers and goal choices for an explorer starting at (40, 6) in 150 steps."""
    def build() -> OccupancyGrid:
        walls = np.ones((80, 160), bool)
        walls[36:44, 2:158] = False  # corridor
        for left in (10, 60, 110):
            walls[4:34, left:left + 40] = False
            walls[46:76, left:left + 40] = False
            walls[34:36, left + 18:left + 22] = False  # doors
            walls[44:46, left + 18:left + 22] = False
        return OccupancyGrid(walls, ~walls, 0.1, "rooms")
    return build


@pytest.fixture(scope="session")
def observed_from_text():
    """``observed_from_text(rows)``: an observed map (int8) from strings, ``.`` free, ``#`` occupied, ``?``
    unknown."""
    codes = {".": FREE, "#": OCCUPIED, "?": UNKNOWN}
    return lambda rows: np.array([[codes[ch] for ch in row] for row in rows], np.int8)


@pytest.fixture(scope="session")
def laser_scan():
    """``laser_scan(ranges, angle_increment=2 pi / len(ranges), range_min=0.1, range_max=5.0, dtype=float64)``: a
    scan whose first ray points east (angle 0), ranges in metres."""
    def build(ranges, angle_increment=None, range_min=0.1, range_max=5.0, dtype=np.float64) -> LaserScan:
        ranges = np.asarray(ranges, dtype)
        increment = 2 * math.pi / len(ranges) if angle_increment is None else angle_increment
        return LaserScan(0.0, increment, range_min, range_max, ranges)
    return build


@pytest.fixture(scope="session")
def episode_log():
    """``episode_log(coverage, carved=None, iou=((0, 0.0, 0.0),), start=0, name="m", dead_ends=None)``: a
    benchmark's episode entry as ``results.json`` holds it; ``iou`` as (step, IoU, coverage) triples, ``dead_ends``
    as (entries, metres in, metres inside, reached end)."""
    def build(coverage, carved=None, iou=((0, 0.0, 0.0),), start=0, name="m", dead_ends=None) -> dict:
        steps, values, covs = zip(*iou)
        episode = {"map": name, "start_index": start, "coverage": list(coverage),
                   "coverage_with_carving": list(carved if carved is not None else coverage),
                   "iou": {"steps": list(steps), "iou": list(values), "coverage": list(covs)}}
        if dead_ends is not None:
            episode["dead_ends"] = {"entries": dead_ends[0], "metres_in": dead_ends[1], "metres_inside": dead_ends[2],
                                    "deepest_m": 0.0, "reached_end": dead_ends[3]}
        return episode
    return build


@pytest.fixture(scope="session")
def deterministic_episodes():
    """``deterministic_episodes(out)``: the episodes of ``out/results.json``, each cut to its :data:`DETERMINISTIC`
    fields, in the file's order."""
    def read(out: Path) -> list:
        return [{k: e[k] for k in DETERMINISTIC} for e in json.loads((out / "results.json").read_text())["episodes"]]
    return read


def nearest_metadata(**changes) -> dict:
    """The metadata of a recording of the nearest-frontier planner on the observed map, no SPAD, the full profile and
    the default explorer (:func:`superex_deploy.recording.metadata.recording_metadata`), with ``changes``."""
    from superex_deploy.onboard import ExplorerConfig
    from superex_deploy.onboard.planning.planners import make_planner
    from superex_deploy.recording.metadata import recording_metadata

    metadata = recording_metadata(map_name="", planner_name="nearest", planner=make_planner("nearest"),
                                  planner_options={}, predictor="observed", seed=0, sensor=None, nlos_cfg=None,
                                  explorer_cfg=ExplorerConfig(), profile="full")
    return {**metadata, **changes}


@pytest.fixture(scope="session")
def write_recording():
    """``write_recording(path, metadata=<a nearest-frontier run>, steps=1, yaw=0.0, chunk_bytes=256 KiB)``: a
    recording of ``steps`` steps on a 20 x 20 frame at 0.1 m, each a 72-ray scan of 1 m ranges from (1 m, 1 m,
    ``yaw``), an empty command and an unknown map; returns ``path``."""
    def write(path, metadata=None, steps=1, yaw=0.0, chunk_bytes=256 * 1024):
        from superex_deploy.recording import EpisodeRecorder

        frame = MapFrame((20, 20), 0.1)
        if metadata is None:
            metadata = nearest_metadata()
        scan = LaserScan(0.0, 2 * math.pi / 72, 0.1, 5.0, np.full(72, 1.0))
        with EpisodeRecorder(path, frame, metadata, chunk_bytes=chunk_bytes) as recorder:
            for step in range(steps):
                recorder.write(Observation(float(step), Pose2D(1.0, 1.0, yaw), scan),
                               Command(float(step), None, None, np.zeros((0, 2)), np.zeros((0, 2), np.int64), False,
                                       False, step=step), np.zeros(frame.shape, np.int8))
        return path
    return write


@pytest.fixture(scope="session")
def record_episode():
    """``record_episode(path, world, explorer, metadata, steps=15)``: drive ``explorer`` in ``world`` for ``steps``
    steps, recording every observation and command to ``path``; returns the new goals' cells, in order (what a
    replay of the recording must choose again)."""
    def record(path, world, explorer, metadata, steps=15):
        from superex_deploy.recording import EpisodeRecorder

        goals = []
        with EpisodeRecorder(path, world.frame, metadata) as recorder, explorer:
            for _ in range(steps):
                observation = world.observe()
                command = explorer.step(observation)
                recorder.write(observation, command, explorer.observed)
                if command.new_goal:
                    goals.append(list(command.goal_rc))
                world.apply(command)
        return goals
    return record


OLD_SUPEREX = {"gain": "path", "transmittance": "independent"}
"""SuperexConfig's defaults before 0.2, of the fields whose default changed since (an old recording's planner ran
them; its metadata does not name them)."""


@pytest.fixture(scope="session")
def old_recording(record_episode):
    """``old_recording(path, start_index, planner_options={}, scan_matching_extra={})``: a short recording of the
    superex planner on map 50052750 from that start in recording format "1", its metadata as a version before 0.2
    wrote it (the options given, no ``planner_config``; the explorer's fields by ``asdict``, the scan matcher's plus
    ``scan_matching_extra``); the planner ran the defaults of then (:data:`OLD_SUPEREX` under the options), which
    the metadata does not name. Returns ``(path, goals)``: the goals the run chose."""
    def record(path, start_index, planner_options=None, scan_matching_extra=None):
        from dataclasses import asdict

        from superex_deploy.maps import load_map, start_poses
        from superex_deploy.onboard.planning.planners import make_planner
        from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
        from superex_deploy.pipeline import PROFILES
        from superex_deploy.evaluation.episodes import make_world_and_explorer

        name = "50052750"
        cfg = PROFILES["full"].episode_config(iou_every=0)
        explorer_cfg = asdict(cfg.explorer)
        explorer_cfg["scan_matching"].update(scan_matching_extra or {})
        metadata = {"format_version": "1", "map": name, "planner": "superex",
                    "planner_options": dict(planner_options or {}), "predictor": "observed", "seed": 0,
                    "spad": False, "models": None, "sensor": None, "nlos": None, "explorer": explorer_cfg,
                    "profile": "full", "profile_settings": PROFILES["full"].to_json()}
        world, explorer = make_world_and_explorer(load_map(name), start_poses(name)[start_index],
                                                  # transmittance: read by the expected gain only
                                                  make_planner("superex", gain=OLD_SUPEREX["gain"]),
                                                  ObservedAsPrediction(), 0, cfg)
        return path, record_episode(path, world, explorer, metadata)
    return record
