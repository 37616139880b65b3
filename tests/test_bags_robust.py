"""Bags as robots write them, bad messages and all (``superex offline``, :mod:`superex_deploy.recording.bags`): a bad
pose, transform, map or scan mid-bag is skipped, counted and listed; a corrupt chunk is one error naming the bag and
how far it was read; the outputs are written as the run goes, so a run that stops keeps what it did."""

import json
import math
import re

import numpy as np
import pytest

pytest.importorskip("rosbags")

from superex_deploy.cli import main  # noqa: E402
from superex_deploy.messages import OccupancyGridMessage  # noqa: E402
from tests.test_bags import (T0, _drive, _grid_message, _laser_mount, _pose_message, _scan_message, _tf,  # noqa: E402
                             _write_items)

GARBLED = b"\x00\x01\x00\x00\x05\x00\x00\x00abc"  # a CDR header, then a sequence longer than the bytes left


def _summary(out):
    return json.loads((out / "summary.json").read_text())


def test_a_bad_pose_mid_bag_is_skipped_and_listed_not_the_end_of_the_run(tmp_path):
    # One pose with a negative variance stopped the run with exit 2 and an empty output folder.
    _, drive = _drive(10)
    items = [_laser_mount()]
    for k, (t, _, base, scan) in enumerate(drive):
        pose = _pose_message(t, *base, sigma=0.02)
        if k == 3:
            pose.pose.covariance[0] = -0.01
        if k == 6:
            pose.pose.pose.position.x = float("nan")
        items += [("/amcl_pose", t, pose), ("/scan", t, _scan_message(t, scan))]
    bag = _write_items(tmp_path / "bad-pose", items)
    assert main(["offline", str(bag), "--out", str(tmp_path / "out"), "--finish-after", "0"]) == 0
    summary = _summary(tmp_path / "out")
    # The scans of the bad poses take their neighbours' interpolation (0.1 s on either side).
    assert summary["steps"] == 10 and summary["scans_skipped"]["no_pose"] == 0
    assert summary["messages_skipped"] == {"/amcl_pose": 2}
    listed = summary["bad_messages"]
    assert [(entry["topic"], entry["stamp_s"]) for entry in listed] == [("/amcl_pose", pytest.approx(T0 + 0.3)),
                                                                        ("/amcl_pose", pytest.approx(T0 + 0.6))]
    assert "non-negative variances" in listed[0]["reason"] and "non-finite position" in listed[1]["reason"]


def test_a_garbled_transform_map_or_scan_is_skipped_and_listed(tmp_path):
    # rosbags' deserialisation error for one message stopped the reading with a traceback.
    _, drive = _drive(8)
    slam = OccupancyGridMessage(0.1, 70, 40, (0.0, 0.0), np.zeros(70 * 40, np.int8))
    bad_values = _grid_message(T0 + 0.45, slam)
    bad_values.data = np.full(70 * 40, 101, np.int8)
    bad_transform = _tf(T0 + 0.35, ("map", "base_link", float("nan"), 0.0, 0.0))
    items = [_laser_mount(), ("/map", T0, _grid_message(T0, slam))]
    for t, _, base, scan in drive:
        items += [("/tf", t, _tf(t, ("map", "base_link", *base))), ("/scan", t, _scan_message(t, scan))]
    items += [("/tf", T0 + 0.25, GARBLED), ("/tf", T0 + 0.35, bad_transform), ("/map", T0 + 0.45, bad_values),
              ("/map", T0 + 0.55, GARBLED), ("/scan", T0 + 0.65, GARBLED)]
    bag = _write_items(tmp_path / "garbled", sorted(items, key=lambda item: item[1]))
    assert main(["offline", str(bag), "--out", str(tmp_path / "out"), "--finish-after", "0"]) == 0
    summary = _summary(tmp_path / "out")
    assert summary["steps"] == 8 and summary["scans_skipped"]["invalid"] == 1
    assert summary["messages_skipped"] == {"/tf": 2, "/map": 2, "/scan": 1}
    listed = {(entry["topic"], round(entry["stamp_s"] - T0, 2)): entry["reason"] for entry in summary["bad_messages"]}
    assert set(listed) == {("/tf", 0.25), ("/tf", 0.35), ("/map", 0.45), ("/map", 0.55), ("/scan", 0.65)}
    assert "cannot be deserialised" in listed[("/tf", 0.25)] and "'map' -> 'base_link'" in listed[("/tf", 0.35)]
    assert "-1 (unknown) and 0..100" in listed[("/map", 0.45)]


def _corrupt_ros1_bag(path):
    """A ROS 1 bag of the drive in chunks of about 20 kB, one message header in its third chunk overwritten."""
    _, drive = _drive(12)
    items = [_laser_mount()]
    for t, _, base, scan in drive:
        items += [("/tf", t, _tf(t, ("map", "base_link", *base))), ("/scan", t, _scan_message(t, scan))]
    bag = _write_items(path, items, version=1, chunk_bytes=20000)
    data = bytearray(bag.read_bytes())
    chunks = [m.start() for m in re.finditer(b"op=\x05", data)]
    inside = [m.start() for m in re.finditer(b"op=\x02", data) if chunks[2] < m.start() < chunks[3]]
    data[inside[len(inside) // 2] - 4:inside[len(inside) // 2] + 4] = b"\xff" * 8
    bag.write_bytes(bytes(data))
    return bag


def test_a_corrupt_chunk_is_one_error_naming_the_bag_and_how_far_it_was_read(tmp_path, capsys):
    # rosbags raised its own ReaderError mid-iteration: a traceback.
    bag = _corrupt_ros1_bag(tmp_path / "corrupt.bag")
    assert main(["offline", str(bag), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert re.fullmatch(rf"superex offline: error: {re.escape(str(bag))} is corrupt: reading the poses stopped after "
                        r"\d+ messages, \d+\.\d{3} s into the bag's 1\.100 s \(ReaderError: .+\)", err[0]), err[0]


def test_outputs_are_written_as_the_run_goes(tmp_path, monkeypatch):
    # commands.csv, map.npz and summary.json were written once the whole bag had run: a run killed midway (a crash,
    # SIGKILL, a full disk) left nothing. Here the summary is due after every step, and step 6 crashes.
    from superex_deploy.commands import offline
    from superex_deploy.onboard import Explorer

    _, drive = _drive(12)
    bag = _write_items(tmp_path / "drive", [_laser_mount()] + [
        item for t, _, base, scan in drive
        for item in (("/tf", t, _tf(t, ("map", "base_link", *base))), ("/scan", t, _scan_message(t, scan)))])
    step = Explorer.step

    def crash_at_six(self, observation):
        if self.steps == 6:
            raise RuntimeError("the robot's computer lost power")
        return step(self, observation)

    monkeypatch.setattr(offline, "SUMMARY_EVERY_S", 0.0)
    monkeypatch.setattr(Explorer, "step", crash_at_six)
    with pytest.raises(RuntimeError, match="lost power"):
        main(["offline", str(bag), "--out", str(tmp_path / "out")])
    lines = (tmp_path / "out" / "commands.csv").read_text().splitlines()
    assert len(lines) == 7 and lines[6].startswith("0.500000,5,")
    summary = _summary(tmp_path / "out")
    assert summary["steps"] == 6 and not summary["complete"] and summary["expected_scans"] == 12
    assert np.load(tmp_path / "out" / "map.npz")["observed"].max() == 1


def test_a_bag_that_breaks_mid_run_keeps_the_steps_done_and_says_why(tmp_path, monkeypatch, capsys):
    # The storage breaking while the scans are run (a file still being copied): one error line, exit 2, and the
    # outputs of the steps done, marked with the error.
    from superex_deploy.recording import bags

    _, drive = _drive(10)
    bag = _write_items(tmp_path / "drive", [_laser_mount()] + [
        item for t, _, base, scan in drive
        for item in (("/tf", t, _tf(t, ("map", "base_link", *base))), ("/scan", t, _scan_message(t, scan)))])
    read = bags.read_bag

    def breaking(path, topics):
        reading, observations = read(path, topics)

        def cut():
            try:
                for k, observation in enumerate(observations):
                    if k == 4:
                        raise ValueError(f"{path} is corrupt: reading the scans stopped after 9 messages")
                    yield observation
            finally:
                observations.close()  # the bag

        return reading, cut()

    monkeypatch.setattr(bags, "read_bag", breaking)
    assert main(["offline", str(bag), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == (f"superex offline: error: {bag} is corrupt: reading the scans stopped after 9 messages (the 4 "
                       f"steps done are in {tmp_path / 'out'})")
    summary = _summary(tmp_path / "out")
    assert summary["steps"] == 4 and "is corrupt" in summary["error"] and not summary["complete"]
    assert len((tmp_path / "out" / "commands.csv").read_text().splitlines()) == 5
    assert (tmp_path / "out" / "map.png").stat().st_size > 0
    assert math.isfinite(summary["step_ms"]["p99"])
