"""Where the grid of faint lines in the LaMa members' predictions far from known space comes from.

Part 1, the network, on a hand-made map: a walled 4 m room with two doors, seen, in the corner of an unknown
square (:func:`featureless_map`); measured on the far region (unknown cells > 10 m from the room, off its rows and
columns, which the members continue as walls). For each member of both ensembles:

* the period: the strongest non-zero peak of the 2-D power spectrum of the far block (rows and columns from 64 on,
  the room's distance mask filled with the far mean), as (rows, columns) cells per cycle, at map sides 256, 264,
  320, 400 and 256 x 400 (a period tied to the Fourier units would follow the side, one tied to the network's
  strides would not);
* the lattice (:func:`~superex_deploy.evaluation.known_distance.lattice_strength`, period ``size_multiple``):
  share of the far field's variance in the 64 phase means and their peak-to-peak range;
* what it is locked to: the same map shifted by 2, 4 and 6 cells down and right (unknown rows and columns in
  front): the correlation of the 8 x 8 phase template with the unshifted one in the network's grid (cell
  ``(r, c)`` of the input) and in the map's (cell ``(r - s, c - s)``).

With ``--checkpoints`` (torch checkpoints of the ensembles, ``exported/checkpoints``): the decoder alone, fed a
spatially constant body (the FFC blocks' output at the centre of an all-unknown map), reproduces the lattice of
the whole network on that map (correlation of the 8 x 8 templates), and after each stride-2 transposed
convolution the share of every channel's variance that repeats every 2, 4, 8 cells.

Part 2, held-out train buildings: a SuperEx-sensing episode (nearest frontier, observed map as the predictor)
on each held-out map of at least ``--min-side`` cells a side until the line-of-sight coverage reaches
``--coverage``; both ensembles predict. On the far region (unknown, in the evaluation area, > 10 m from known
space, more than :data:`BORDER` cells from the map's edge) of each member: the strongest spectral peak's period, the lattice share, and whether the lines are room
structure. A member's own lattice is its 8 x 8 phase template on an all-unknown map (nothing else is there);
its crest phases are the 16 of 64 highest, its trough phases the 16 lowest. On each map: the member's mean wall
probability and the true wall share on the far cells of its crest phases against its trough phases, the
correlation of its lattice with the true walls' phase template there, and with its own phase template there (how
much of the far field's phase structure is the lattice). ``--figure`` draws the first map's LaMa-LOS
member 0 and ensemble mean, as predicted and through the lattice filter, on 160 x 240 cells around the unknown
cell farthest from known space.

Prints markdown tables and writes JSON (``--out``, default ``benchmarks/lattice/lattice.json``) and the figure
(``--figure``, default ``docs/img/lattice.png``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from superex_deploy.evaluation import markdown_table, run_benchmark_episode, save_figure, write_json
from superex_deploy.evaluation.reports import pyplot
from superex_deploy.evaluation.known_distance import (LATTICE_MIN_CELLS, distance_to_known, lattice_strength,
                                                      phase_means)
from superex_deploy.maps import list_maps, load_map, map_building
from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
from superex_deploy.onboard.prediction.inference import (DEFAULT_MODEL_DIR, LamaEnsemble, ModelKind, Pix2PixFilter,
                                                         SessionConfig)
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN
from superex_deploy.pipeline import PROFILES
from superex_deploy.evaluation.metrics import evaluation_area
from superex_deploy.sim.sensing import SpadSensing
from superex_train.generate import heldout_buildings, random_start

ROOT = Path(__file__).resolve().parent.parent
KINDS = (ModelKind.LAMA_LOS, ModelKind.LAMA_BP)
SIDES = ((256, 256), (264, 264), (320, 320), (400, 400), (256, 400))
SHIFTS = (2, 4, 6)
FAR_M = 10.0
BORDER = 8
"""Part 2 leaves out the cells this close to the map's edge (cells)."""


def featureless_map(shape=(256, 256), room: int = 40, shift: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """int8 observed map and bool far region (see the module docstring); ``shift`` unknown rows and columns in
    front of the room."""
    observed = np.full(shape, UNKNOWN, np.int8)
    r = slice(shift, shift + room)
    observed[r, r] = OCCUPIED
    observed[shift + 1:shift + room - 1, shift + 1:shift + room - 1] = FREE
    observed[shift + room // 2 - 5:shift + room // 2 + 5, shift + room - 1] = FREE
    observed[shift + room - 1, shift + room // 2 - 5:shift + room // 2 + 5] = FREE
    far = distance_to_known(observed == UNKNOWN, 0.1) > FAR_M
    far[:shift + 64] = False
    far[:, :shift + 64] = False
    return observed, far


def peak_period(field: np.ndarray, region: np.ndarray) -> list:
    """(rows, columns) cells per cycle of the strongest non-zero peak of the power spectrum of ``region``'s
    bounding box (cells outside the region set to its mean); None for an axis with no cycle."""
    rows, cols = np.nonzero(region)
    box = (slice(rows.min(), rows.max() + 1), slice(cols.min(), cols.max() + 1))
    values = np.where(region[box], field[box], field[region].mean()) - field[region].mean()
    power = np.abs(np.fft.fft2(values)) ** 2
    power[0, 0] = 0.0
    kr, kc = np.unravel_index(int(np.argmax(power)), power.shape)
    freq = [np.fft.fftfreq(n)[k] for n, k in zip(values.shape, (kr, kc))]
    return [None if f == 0 else round(1.0 / abs(float(f)), 2) for f in freq]


def phase_template(field: np.ndarray, region: np.ndarray, period: int, offset: int = 0) -> np.ndarray:
    """``[period * period]`` mean of ``field`` over ``region`` per phase of cell ``(r - offset, c - offset)``
    (:func:`~superex_deploy.evaluation.known_distance.phase_means`)."""
    return phase_means(field, region, period, offset)[0]


def network_part(model_dir: Path, checkpoints: Path | None) -> dict:
    """Part 1 (see the module docstring)."""
    session = SessionConfig(intra_op_threads=1)
    out: dict = {"sides": {}, "shifts": {}}
    for kind in KINDS:
        ensemble = LamaEnsemble.from_manifest(kind, model_dir, session, lattice_filter=False)
        period = ensemble.size_multiple

        def members(observed):
            extra = np.zeros(observed.shape, np.float32) if kind is ModelKind.LAMA_BP else None
            return ensemble.predict_members(observed, extra)

        for shape in SIDES:
            observed, far = featureless_map(shape)
            for i, member in enumerate(members(observed)):
                strength = lattice_strength(member, far, period)
                out["sides"][f"{kind.value}_{i} {shape[0]}x{shape[1]}"] = {
                    "period": peak_period(member, far), "share": strength.share, "amplitude": strength.amplitude}
        observed, far = featureless_map(SIDES[0])
        base = members(observed)
        for s in SHIFTS:
            shifted_obs, shifted_far = featureless_map(SIDES[0], shift=s)
            region = far & shifted_far
            for i, (a, b) in enumerate(zip(base, members(shifted_obs))):
                grid = np.corrcoef(phase_template(a, region, period), phase_template(b, region, period))[0, 1]
                moved = np.corrcoef(phase_template(a, region, period),
                                    phase_template(b, region, period, offset=s))[0, 1]
                out["shifts"][f"{kind.value}_{i} shift {s}"] = {"grid": float(grid), "map": float(moved)}
    if checkpoints is not None:
        out["decoder"] = decoder_part(checkpoints)
    return out


def decoder_part(checkpoints: Path) -> dict:
    """The decoder on a constant body (see the module docstring); torch is imported here only."""
    import torch

    from superex_train.models.lama import dft_basis
    from superex_train.training import build_generator, load_checkpoint
    torch.set_num_threads(1)
    out = {}
    for path in sorted(checkpoints.glob("lama_*.pt")):
        checkpoint = load_checkpoint(path)
        net = build_generator(checkpoint["kind"], checkpoint["model_config"])
        net.load_state_dict(checkpoint["state"]["generator"])
        net.eval()
        x = torch.zeros(1, net.cfg.in_channels, 256, 256)
        x[:, -1] = 1.0  # the unknown channel is the last of both kinds
        with torch.no_grad():
            h = net.down(net.stem(x))
            local, global_ = h[:, :net.local_channels], h[:, net.local_channels:]
            basis = dft_basis(h.shape[-2], h.shape[-1], h)
            for block in net.blocks:
                local, global_ = block(local, global_, basis)
            body = torch.cat([local, global_], dim=1)
            centre = body.shape[-1] // 2
            constant = body[:, :, centre:centre + 1, centre:centre + 1].expand_as(body).contiguous()
            whole = torch.sigmoid(net(x))[0, 0].numpy()
            z, shares = constant, []
            for stage, up in enumerate(net.up):
                z = up(z)
                p = 2 ** (stage + 1)
                edge = z.shape[-1] // 4  # away from the borders' padding
                a = z[0].numpy()[:, edge:-edge, edge:-edge]
                k = a.shape[-1] // p
                a = a[:, :k * p, :k * p]
                t = a.reshape(a.shape[0], k, p, k, p).mean(axis=(1, 3))
                var = a.var(axis=(1, 2))
                resid = (a - np.tile(t, (1, k, k))).var(axis=(1, 2))
                shares.append(float(np.median(1.0 - resid[var > 1e-10] / var[var > 1e-10])))
            decoded = torch.sigmoid(net.head(z))[0, 0].numpy()
        centre_region = np.zeros(whole.shape, bool)
        centre_region[64:192, 64:192] = True
        period = 2 ** net.cfg.n_downsample
        corr = np.corrcoef(phase_template(whole, centre_region, period),
                           phase_template(decoded, centre_region, period))[0, 1]
        out[path.stem] = {"template_correlation": float(corr), "periodic_share_by_stage": shares,
                          "whole_share": lattice_strength(whole, centre_region, period).share}
    return out


def _observation(name: str, index: int, model_dir: Path, coverage: float) -> dict:
    """A SuperEx-sensing episode on ``name`` until the coverage reaches ``coverage``: its maps and evidence."""
    session = SessionConfig(intra_op_threads=1)
    sensing = SpadSensing(bp_filter=Pix2PixFilter.from_manifest(model_dir, session).filter_map)
    grid = load_map(name)
    start = random_start(grid, np.random.default_rng([777, index]), 0.4)
    kept: dict = {}

    class _Done(Exception):
        pass

    def on_step(state) -> None:
        if state.coverage >= coverage:
            kept.update(observed=state.observed.copy(), los=state.mapper.observed(include_carved=False).copy(),
                        evidence=sensing.evidence.copy(), coverage=state.coverage, step=state.step)
            raise _Done

    try:
        run_benchmark_episode(grid, start, "nearest", ObservedAsPrediction(), steps=600, seed=index,
                              sensing=sensing, on_step=on_step, profile=PROFILES["full"])
    except _Done:
        pass
    return kept


def draw(path: Path, name: str, observed: np.ndarray, members: np.ndarray, filtered: np.ndarray) -> None:
    """The figure of ``--figure``: member 0 and the mean, as predicted and filtered, unknown cells only."""
    plt = pyplot()
    # A 160 x 240 cell window around the unknown cell farthest from known space.
    distance = distance_to_known(observed == UNKNOWN, 0.1)
    r, c = np.unravel_index(int(np.argmax(np.where(np.isinf(distance), -1.0, distance))), distance.shape)
    r0 = int(np.clip(r - 80, 0, max(observed.shape[0] - 160, 0)))
    c0 = int(np.clip(c - 120, 0, max(observed.shape[1] - 240, 0)))
    window = (slice(r0, r0 + 160), slice(c0, c0 + 240))
    observed, members, filtered = observed[window], members[:, window[0], window[1]], filtered[:, window[0], window[1]]
    fig, axes = plt.subplots(2, 2, figsize=(8, 5.8))
    known = observed != UNKNOWN
    for row, (label, arrays) in enumerate((("as predicted", members), ("lattice filter", filtered))):
        for col, (what, image) in enumerate((("member 0", arrays[0]), ("mean of 3", arrays.mean(axis=0)))):
            shown = np.ma.masked_where(known, image)
            axes[row, col].imshow(shown, cmap="viridis", vmin=0.0, vmax=0.25, interpolation="nearest")
            axes[row, col].set_title(f"LaMa-LOS {what}, {label}", fontsize=9)
            axes[row, col].axis("off")
    fig.suptitle(f"{name}, rows {r0}-{r0 + 159}, columns {c0}-{c0 + 239}: wall probability 0-0.25", fontsize=10)
    fig.tight_layout()
    save_figure(fig, path, dpi=64)
    from PIL import Image  # matplotlib's own dependency: 64 colours keep the file under 100 kB

    Image.open(path).convert("RGB").quantize(64).save(path, optimize=True)


def heldout_part(model_dir: Path, min_side: int, coverage: float, figure: Path | None = None) -> dict:
    """Part 2 (see the module docstring)."""
    held = set(heldout_buildings())
    names = [n for n in list_maps("train") if map_building(n) in held and min(load_map(n).shape) >= min_side]
    session = SessionConfig(intra_op_threads=1)
    ensembles = {kind: LamaEnsemble.from_manifest(kind, model_dir, session, lattice_filter=False) for kind in KINDS}
    # Each member's own lattice: its phase template on an all-unknown map (nothing but the lattice there).
    blank = np.full((256, 256), UNKNOWN, np.int8)
    centre = np.zeros(blank.shape, bool)
    centre[64:192, 64:192] = True
    lattices = {kind: [phase_template(m, centre, e.size_multiple) for m in e.predict_members(
        blank, np.zeros(blank.shape, np.float32) if kind is ModelKind.LAMA_BP else None)]
        for kind, e in ensembles.items()}
    out = {}
    for index, name in enumerate(names):
        seen = _observation(name, index, model_dir, coverage)
        if not seen:
            continue
        grid = load_map(name)
        area = evaluation_area(grid)
        for kind, ensemble in ensembles.items():
            observed = seen["observed"] if kind is ModelKind.LAMA_BP else seen["los"]
            far = (observed == UNKNOWN) & area & (distance_to_known(observed == UNKNOWN, grid.resolution_m) > FAR_M)
            # Off the map's frame: many floors' first and last rows and columns are walls, which puts 1.4x the
            # walls on row phase 0 (away from the frame, every phase holds 0.92-1.14x): a property of the files.
            far[:BORDER], far[-BORDER:], far[:, :BORDER], far[:, -BORDER:] = False, False, False, False
            if np.count_nonzero(far) < LATTICE_MIN_CELLS:
                continue
            members = ensemble.predict_members(observed, seen["evidence"] if kind is ModelKind.LAMA_BP else None)
            if figure is not None and kind is ModelKind.LAMA_LOS:
                draw(figure, name, observed, members, ensemble.with_lattice_filter(True).predict_members(observed))
                figure = None
            period = ensemble.size_multiple
            rows, cols = np.nonzero(far)
            phase = (rows % period) * period + cols % period
            truth = grid.occupied[rows, cols]
            walls_by_phase = phase_template(grid.occupied.astype(np.float64), far, period)
            for i, member in enumerate(members):
                lattice = lattices[kind][i]
                crest = np.argsort(lattice)[-16:]
                trough = np.argsort(lattice)[:16]
                on_crest, on_trough = np.isin(phase, crest), np.isin(phase, trough)
                out[f"{name} {kind.value}_{i}"] = {
                    "kind": kind.value, "coverage": seen["coverage"], "far_cells": int(rows.size),
                    "period": peak_period(member, far), "share": lattice_strength(member, far, period).share,
                    "p_crest": float(member[rows, cols][on_crest].mean()),
                    "p_trough": float(member[rows, cols][on_trough].mean()),
                    "walls_crest": float(truth[on_crest].mean()), "walls_trough": float(truth[on_trough].mean()),
                    "walls_far": float(truth.mean()), "crest_cells": int(on_crest.sum()),
                    "trough_cells": int(on_trough.sum()), "crest_walls": int(truth[on_crest].sum()),
                    "trough_walls": int(truth[on_trough].sum()),
                    "lattice_truth_correlation": float(np.corrcoef(lattice, walls_by_phase)[0, 1]),
                    "lattice_member_correlation": float(np.corrcoef(lattice, phase_template(member, far, period))[0, 1])}
    return out


def heldout_summary(entries: dict) -> dict:
    """Per kind over all maps and members: mean crest / trough probability, the true wall share on crest and
    trough cells pooled cell by cell, and the correlation of the member's phase template with the true walls'
    (mean, min, max)."""
    out = {}
    for kind in KINDS:
        rows = [e for e in entries.values() if e["kind"] == kind.value]
        if not rows:
            continue
        corr = [e["lattice_truth_correlation"] for e in rows]
        out[kind.value] = {"members": len(rows), "p_crest": float(np.mean([e["p_crest"] for e in rows])),
                           "p_trough": float(np.mean([e["p_trough"] for e in rows])),
                           "walls_crest": sum(e["crest_walls"] for e in rows) / sum(e["crest_cells"] for e in rows),
                           "walls_trough": sum(e["trough_walls"] for e in rows) / sum(e["trough_cells"] for e in rows),
                           "correlation_mean": float(np.mean(corr)), "correlation_min": float(np.min(corr)),
                           "correlation_max": float(np.max(corr)),
                           "member_correlation_mean": float(np.mean([e["lattice_member_correlation"] for e in rows])),
                           "period_8": sum(8 in [round(v) for v in e["period"] if v] for e in rows)}
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", type=Path, default=DEFAULT_MODEL_DIR)
    parser.add_argument("--checkpoints", type=Path, default=None,
                        help="torch checkpoints of the LaMa members (e.g. exported/checkpoints): decoder part")
    parser.add_argument("--min-side", type=int, default=250, help="part 2: held-out maps at least this many cells "
                        "a side")
    parser.add_argument("--coverage", type=float, default=0.05, help="part 2: predict when coverage reaches this")
    parser.add_argument("--skip-heldout", action="store_true")
    parser.add_argument("--figure", type=Path, default=ROOT / "docs" / "img" / "lattice.png")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "lattice" / "lattice.json")
    args = parser.parse_args(argv)
    clock = time.perf_counter()
    result = {"models": str(args.models), "network": network_part(args.models, args.checkpoints)}
    net = result["network"]
    print("\n## Period and lattice strength on the hand-made map (far region)\n")
    print("\n".join(markdown_table(["member, side", "strongest peak (rows, cols cells)", "lattice share",
                                    "amplitude"],
                                   [[k, v["period"], f"{v['share']:.3f}", f"{v['amplitude']:.4f}"]
                                    for k, v in net["sides"].items()], ["-", "-", "---:", "---:"])))
    print("\n## Locked to the network's grid or to the map? Template correlation after shifting the map\n")
    print("\n".join(markdown_table(["member, shift", "in the network's grid", "in the map"],
                                   [[k, f"{v['grid']:.3f}", f"{v['map']:.3f}"] for k, v in net["shifts"].items()],
                                   ["-", "---:", "---:"])))
    if "decoder" in net:
        print("\n## The decoder alone on a constant body (all-unknown 256 x 256 map)\n")
        print("\n".join(markdown_table(
            ["member", "template correlation with the whole network", "periodic share after up 1 / 2 / 3",
             "whole network's lattice share"],
            [[k, f"{v['template_correlation']:.3f}", " / ".join(f"{s:.3f}" for s in v["periodic_share_by_stage"]),
              f"{v['whole_share']:.3f}"] for k, v in net["decoder"].items()], ["-", "---:", "---:", "---:"])))
    if not args.skip_heldout:
        result["heldout"] = heldout_part(args.models, args.min_side, args.coverage, args.figure)
        print(f"\n## Held-out maps (at least {args.min_side} cells a side, coverage {args.coverage:.0%}): far region "
              f"(> {FAR_M:g} m)\n")
        print("\n".join(markdown_table(
            ["map, member", "far cells", "strongest peak", "lattice share", "p crest / trough",
             "true walls crest / trough / all far"],
            [[k, v["far_cells"], v["period"], f"{v['share']:.3f}", f"{v['p_crest']:.3f} / {v['p_trough']:.3f}",
              f"{v['walls_crest']:.3f} / {v['walls_trough']:.3f} / {v['walls_far']:.3f}"]
             for k, v in result["heldout"].items()], ["-", "---:", "-", "---:", "---:", "---:"])))
        result["heldout_summary"] = heldout_summary(result["heldout"])
        print("\nPooled over the maps: mean wall probability on the lattice's crest / trough phases, the true wall "
              "share on them (cell by cell), the correlation of each member's lattice with the true walls' phase "
              "template (mean, min-max) and with the member's own phase template far out (mean), members whose "
              "strongest peak is at 8 cells\n")
        print("\n".join(markdown_table(
            ["ensemble", "members x maps", "p crest / trough", "true walls crest / trough", "lattice vs walls",
             "lattice vs member far out", "peak at 8 cells"],
            [[k, v["members"], f"{v['p_crest']:.3f} / {v['p_trough']:.3f}",
              f"{v['walls_crest']:.4f} / {v['walls_trough']:.4f}",
              f"{v['correlation_mean']:+.2f} ({v['correlation_min']:+.2f} to {v['correlation_max']:+.2f})",
              f"{v['member_correlation_mean']:+.2f}", v["period_8"]]
             for k, v in result["heldout_summary"].items()], ["-"] + ["---:"] * 6)))
    result["seconds"] = time.perf_counter() - clock
    write_json(args.out, result)
    print(f"\nwrote {args.out} ({result['seconds']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
