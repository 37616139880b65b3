"""``superex offline``'s options and what it reports (:mod:`superex_deploy.commands.offline`): the usable range and
the range sigma of the LiDAR, the profile, the exploration bounds, a recording that replays, the accepted scan
matches, a SLAM map after the last scan, the resolution as printed and the progress bar's total."""

import csv
import json
import math

import numpy as np
import pytest

pytest.importorskip("rosbags")

from superex_deploy.cli import main  # noqa: E402
from superex_deploy.messages import LaserScan, OccupancyGridMessage  # noqa: E402
from superex_deploy.recording.bags import read_bag  # noqa: E402
from tests.test_bags import (T0, _drive, _grid_message, _laser_mount, _pose_message, _scan_message, _tf,  # noqa: E402
                             _write, _write_items)

NO_ECHO = 81.83  # a SICK LMS's reading without an echo (range_max 80 m)


def _standing_bag(path, ranges, range_max=80.0, scans=2):
    """A robot standing at the map's origin, its laser scanning 360 rays of ``ranges``."""
    scan = LaserScan(0.0, 2 * math.pi / 360, 0.05, range_max, np.asarray(ranges, np.float32))
    items = [_laser_mount()]
    for k in range(scans):
        t = T0 + 0.1 * k
        items += [("/tf", t, _tf(t, ("map", "base_link", 0.0, 0.0, 0.0))), ("/scan", t, _scan_message(t, scan))]
    return _write_items(path, items)


def test_the_usable_range_bounds_the_free_space_a_reading_without_an_echo_clears(tmp_path, capsys):
    # Every reading but four is the no-echo code: each cleared 80 m of free space (range_max), and the option
    # did not exist.
    ranges = np.full(360, NO_ECHO)
    ranges[::90] = 30.0  # four returns beyond the usable range: no walls either
    bag = _standing_bag(tmp_path / "open", ranges)
    for usable in (5.0, 10.0):
        out = tmp_path / f"out{usable:g}"
        assert main(["offline", str(bag), "--out", str(out), "--usable-range", f"{usable:g}"]) == 0
        assert f"usable range {usable:g} m" in capsys.readouterr().out
        observed = np.load(out / "map.npz")["observed"]
        assert np.count_nonzero(observed == 0) * 0.01 == pytest.approx(math.pi * usable ** 2, rel=0.08)
        assert np.count_nonzero(observed == 1) == 0
        assert json.loads((out / "summary.json").read_text())["usable_range_m"] == usable
    assert main(["offline", str(bag), "--out", str(tmp_path / "default"), "--deskew"]) == 0
    assert json.loads((tmp_path / "default" / "summary.json").read_text())["usable_range_m"] == 20.0
    assert "--deskew: no scan carries a time_increment" in capsys.readouterr().err  # these scans have none
    assert main(["offline", str(bag), "--out", str(tmp_path / "bad"), "--usable-range", "0"]) == 2
    assert "--usable-range must be a positive number of metres, got 0.0" in capsys.readouterr().err


def test_the_range_sigma_places_each_return_two_sigmas_farther(tmp_path):
    bag = _standing_bag(tmp_path / "round", np.full(360, 3.0), range_max=20.0)
    radius = {}
    for sigma in ("0", "0.05"):
        out = tmp_path / f"out{sigma}"
        assert main(["offline", str(bag), "--out", str(out), "--range-sigma", sigma]) == 0
        saved = np.load(out / "map.npz")
        rows, cols = np.nonzero(saved["observed"] == 1)
        x = saved["origin_xy"][0] + (cols + 0.5) * 0.1
        y = saved["origin_xy"][1] + (saved["observed"].shape[0] - rows - 0.5) * 0.1
        radius[sigma] = float(np.mean(np.hypot(x - 0.1, y)))  # from the laser, 10 cm ahead of base_link
        assert json.loads((out / "summary.json").read_text())["range_sigma_m"] == float(sigma)
    assert radius["0.05"] - radius["0"] == pytest.approx(0.1, abs=0.03)


def test_offline_runs_a_profile_inside_bounds_counts_the_scan_matches_and_records_a_replayable_mcap(tmp_path, capsys):
    # superex explore had --profile, --bounds and --record; superex offline had none of them, nor the matches.
    _, drive = _drive(12)
    items = [_laser_mount()]
    for k, (t, _, base, scan) in enumerate(drive):
        x, y, yaw = base
        x += 0.07 if k >= 3 else 0.0  # the localisation jumps 7 cm: the scan matcher corrects it
        items += [("/amcl_pose", t, _pose_message(t, x, y, yaw, sigma=0.05)), ("/scan", t, _scan_message(t, scan))]
    bag = _write_items(tmp_path / "jump", items)
    out, record = tmp_path / "out", tmp_path / "out" / "run.mcap"
    assert main(["offline", str(bag), "--out", str(out), "--profile", "full", "--record", str(record),
                 "--bounds", "0.1,0.1 5.5,0.1 5.5,3.9 0.1,3.9"]) == 0
    assert "profile full" in capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    assert summary["profile"] == "full" and summary["bounds"][1] == [5.5, 0.1] and summary["record"] == str(record)
    assert summary["scan_match"]["attempted"] == 12 and summary["scan_match"]["accepted"] >= 3
    # The count is the explorer's own: the same observations stepped here accept as many matches.
    from superex_deploy.commands.offline import frame_for
    from superex_deploy.pipeline import build_explorer

    reading, observations = read_bag(bag)
    explorer = build_explorer(frame_for(reading.extent_xy, 0.1, 2.0), "nearest", "observed", profile="full")
    accepted = 0
    for observation in observations:
        explorer.step(observation)
        accepted += int(explorer.scan_match.accepted)
    assert summary["scan_match"]["accepted"] == accepted
    with open(out / "commands.csv") as table:
        goals = [float(row["goal_x_m"]) for row in csv.DictReader(table) if row["goal_x_m"]]
    assert goals and max(goals) <= 5.5
    assert main(["replay", str(record), "--out", str(tmp_path / "replay")]) == 0
    replayed = json.loads((tmp_path / "replay" / "metrics.json").read_text())
    assert replayed["steps"] == 12 and replayed["goals_match"]
    # Bounds that leave out the first scan's position are refused before anything is created.
    assert main(["offline", str(bag), "--out", str(tmp_path / "outside"), "--bounds", "5,0.1 6.9,0.1 6.9,3.9"]) == 2
    assert "must contain the robot's start pose" in capsys.readouterr().err
    assert not (tmp_path / "outside").exists()


def test_a_slam_map_after_the_last_scan_is_applied_in_one_more_step(tmp_path, capsys):
    # SLAM publishes its map after the bag's last scan (a map_saver at the end of the run): it was dropped.
    _, drive = _drive(4)
    known = np.full((40, 70), -1, np.int8)
    known[1:39, 1:69] = 0
    known[:, 50] = 100  # a wall only SLAM knows of, at x = 5.0 .. 5.1 m
    slam = OccupancyGridMessage(float(np.float32(0.1)), 70, 40, (0.0, 0.0), np.ascontiguousarray(known[::-1]).ravel())
    items = [_laser_mount()]
    for t, _, base, scan in drive:
        items += [("/tf", t, _tf(t, ("map", "base_link", *base))), ("/scan", t, _scan_message(t, scan))]
    items.append(("/map", T0 + 1.5, _grid_message(T0 + 1.5, slam)))
    bag = _write_items(tmp_path / "late-map", items)
    reading, observations = read_bag(bag)
    observations = list(observations)
    last = observations[-1]
    assert len(observations) == 5 and reading.late_maps == 1 and last.scan is None
    assert last.occupancy_grid.stamp_s == pytest.approx(T0 + 1.5) and last.stamp_s == pytest.approx(1.5)
    assert (last.pose.x, last.pose.y) == (observations[-2].pose.x, observations[-2].pose.y)
    assert main(["offline", str(bag), "--out", str(tmp_path / "out")]) == 0
    assert "5/5 [" in capsys.readouterr().err  # the progress bar counts that step too
    saved = np.load(tmp_path / "out" / "map.npz")
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["steps"] == 5 and summary["late_maps"] == 1
    col = int(round((5.05 - saved["origin_xy"][0]) / 0.1 - 0.5))
    assert np.count_nonzero(saved["observed"][:, col] == 1) >= 30


def test_offline_prints_the_resolution_rounded_and_a_progress_bar_with_a_total(tmp_path, capsys):
    # 0.05000000074505806 m (the SLAM map's float32 resolution), and a bar of "12scan" without a total.
    _, drive = _drive(12)
    slam = OccupancyGridMessage(float(np.float32(0.05)), 140, 80, (0.0, 0.0), np.zeros(140 * 80, np.int8))
    bag = _write(tmp_path / "slam", 2, drive, slam=slam)
    assert main(["offline", str(bag), "--out", str(tmp_path / "out")]) == 0
    captured = capsys.readouterr()
    assert " at 0.05 m," in captured.out and "0.0500000" not in captured.out
    assert "12/12 [" in captured.err


def test_offline_documents_its_options(capsys):
    assert main(["offline", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    for option in ("--usable-range METRES", "--range-sigma METRES", "--max-extrapolation SECONDS", "--deskew",
                   "--stamps {header,arrival}", "--profile", "--bounds", "--record FILE", "--max-pose-age SECONDS"):
        assert option in text, option
    assert "81.83 m" in text and "(default: 20)" in text
