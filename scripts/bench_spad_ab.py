"""Time the SPAD simulator and the NLOS processing against an earlier revision of this repository, in one process.

On a shared machine absolute times drift by tens of percent within a minute (other tenants, frequency changes),
so "this change made it N times faster" is measured here by alternation: the earlier revision's
``superex_deploy`` is extracted with ``git archive`` into a temporary folder (renamed, so both import side by
side), and for every one of the 40 eval scenarios the two revisions' cold scan (fan cache emptied first), cached
scan and ``process_scan`` run one after the other, with a plain 2500-ray LOS scan between them; each is the best
of ``--repeats``. Reported: medians over scenarios of the times and of the per-scenario ratios (new / base, and
each against the LOS scan), as a table and as JSON (``--out``). The known cells are those a 2500-ray LOS scan
from the pose sees, as in ``scripts/bench_spad.py`` part 1.

Needs git and the revision in the local history; the base revision must have ``simulate_scan``,
``prepare_scene`` and ``process_scan`` with today's signatures (every revision since the fan cache has).
"""

from __future__ import annotations

import argparse
import importlib
import io
import json
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np

from superex_deploy import nlos, spad
from superex_deploy.geometry import cast_rays, cell_centre, ray_angles
from superex_deploy.maps import list_maps, load_map, start_poses

from bench_spad import _hidden_mask  # scripts/ is on the path of a script run from it

ROOT = Path(__file__).resolve().parents[1]
BASE_PACKAGE = "superex_base"


def import_revision(revision: str, folder: Path):
    """``(spad, nlos, maps)`` modules of ``superex_deploy`` at ``revision``, imported as ``superex_base``."""
    archive = subprocess.run(["git", "archive", revision, "superex_deploy"], cwd=ROOT, check=True,
                             capture_output=True).stdout
    with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
        try:
            tar.extractall(folder, filter="data")
        except TypeError:  # Python releases before the extraction filters; the archive is our own history
            tar.extractall(folder)
    package = folder / BASE_PACKAGE
    (folder / "superex_deploy").rename(package)
    for source in package.rglob("*.py"):
        source.write_text(source.read_text().replace("superex_deploy", BASE_PACKAGE))
    sys.path.insert(0, str(folder))
    return tuple(importlib.import_module(f"{BASE_PACKAGE}.{name}") for name in ("spad", "nlos", "maps"))


def _stages(spad_module, nlos_module, grid, pose, known):
    """(cold scan, cached scan, processing) times of one revision, in seconds."""
    spad_module.prepare_scene(grid).clear_fan_caches()
    start = time.perf_counter()
    spad_module.simulate_scan(grid, pose)
    cold = time.perf_counter() - start
    start = time.perf_counter()
    scan = spad_module.simulate_scan(grid, pose)
    cached = time.perf_counter() - start
    start = time.perf_counter()
    nlos_module.process_scan(scan, nlos_module.NlosConfig(), known)
    return cold, cached, time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", required=True, help="the earlier revision (commit, tag, HEAD~3, ...)")
    parser.add_argument("--repeats", type=int, default=3, help="best of this many runs per scenario and stage")
    parser.add_argument("--out", type=Path, default=Path("bench_spad_ab.json"))
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        base_spad, base_nlos, base_maps = import_revision(args.base, Path(folder))
        rows = []
        for name in list_maps("eval"):
            for pose in start_poses(name):
                grid, base_grid = load_map(name), base_maps.load_map(name)  # separate scene caches
                known, _ = _hidden_mask(grid, pose)
                for module_spad, module_nlos, g in ((base_spad, base_nlos, base_grid), (spad, nlos, grid)):
                    _stages(module_spad, module_nlos, g, pose, known)  # compiled, caches warm
                best = np.full(7, np.inf)
                for _ in range(args.repeats):
                    start = time.perf_counter()
                    cast_rays(grid.occupied, cell_centre(pose), ray_angles(2500), 200.0)
                    los = time.perf_counter() - start
                    times = (los, *_stages(base_spad, base_nlos, base_grid, pose, known),
                             *_stages(spad, nlos, grid, pose, known))
                    best = np.minimum(best, np.array(times) * 1e3)
                rows.append(best)
    times = np.array(rows)  # [scenario, (los, base cold, base cached, base nlos, new cold, new cached, new nlos)]
    med = np.median(times, axis=0)
    stages = ("cold scan", "cached scan", "NLOS processing")
    print(f"\n{len(times)} eval scenarios, best of {args.repeats}, medians (base = {args.base})")
    print("| stage | base ms | new ms | new / base | base / LOS scan | new / LOS scan |")
    print("|---|---:|---:|---:|---:|---:|")
    result = {"base": args.base, "repeats": args.repeats, "scenarios": len(times),
              "median_los_scan_ms": float(med[0]), "stages": {}}
    for k, stage in enumerate(stages):
        base, new = times[:, 1 + k], times[:, 4 + k]
        entry = {"base_ms": float(np.median(base)), "new_ms": float(np.median(new)),
                 "new_over_base": float(np.median(new / base)), "base_over_los": float(np.median(base / times[:, 0])),
                 "new_over_los": float(np.median(new / times[:, 0]))}
        result["stages"][stage] = entry
        print(f"| {stage} | {entry['base_ms']:.3f} | {entry['new_ms']:.3f} | {entry['new_over_base']:.2f}x | "
              f"{entry['base_over_los']:.2f}x | {entry['new_over_los']:.2f}x |")
    processing_over_cold = {"base": float(np.median(times[:, 3] / times[:, 1])),
                            "new": float(np.median(times[:, 6] / times[:, 4]))}
    result["processing_over_cold_scan"] = processing_over_cold
    print(f"LOS scan {med[0]:.3f} ms; NLOS processing / cold scan: base {processing_over_cold['base']:.2f}x, "
          f"new {processing_over_cold['new']:.2f}x")
    args.out.write_text(json.dumps(result, indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
