"""A recording of an earlier format rewritten into this one: ``superex convert-recording OLD.mcap NEW.mcap``.

Recording format ``"1"`` (the versions up to 0.2) held each configuration in the form of the version that wrote it;
:func:`convert_metadata` brings it to this version's, by the tables below (this module is the one place that knows
them: the configurations themselves read only their own fields, :mod:`superex_deploy.configs`):

- settings that counted cells and now take metres (:data:`RENAMED`), and the NLOS lengths of the first recordings
  (``*_cells``): the old value times the recording's cell size (squared for an area), so that a setting gives back
  its recorded cell count;
- options retired since (:data:`RETIRED`): left out at their old default (the run behaved as this version does
  without them), refused by name at another value (a run this version cannot reproduce);
- a recording made before the planner's whole configuration was recorded holds the options its user gave: the other
  fields at the defaults of its version, which are this version's but for :data:`PREVIOUS_DEFAULTS`;
- explorer fields added since (:data:`ADDED_EXPLORER_FIELDS`), at the values that behave as the explorer did before;
- the prediction schedule as ``asynchronous`` (before its modes); no profile (``full``), no profile settings (this
  version's), profile settings without the fields added since (their defaults).

Each configuration is then built by its class's strict ``from_json`` and written by its ``to_json``: what this
version cannot build is refused here, naming the field, not when the recording is replayed. The steps' messages
are copied as they are (the reader reads every schema written since the first recording); a file cut short keeps
what was readable, and the converter says where it stopped.
"""

from __future__ import annotations

import json
import math
import numbers
from pathlib import Path
from typing import Optional, Union

from superex_deploy.recording.schemas import FORMAT_VERSION, METADATA_NAME, METADATA_TYPES, check_metadata

__all__ = ["OLD_FORMATS", "RENAMED", "RETIRED", "PREVIOUS_DEFAULTS", "ADDED_EXPLORER_FIELDS", "in_metres",
           "schedule_in_modes", "convert_metadata", "convert_recording"]

OLD_FORMATS = ("1",)
"""The format versions this module converts to :data:`~superex_deploy.recording.schemas.FORMAT_VERSION`."""

RENAMED: dict = {
    "explorer": {"frontier_min_cells": ("frontier_min_m", 1)},
    "motion": {"step_cells": ("step_m", 1)},
    "reuse": {"min_changed_cells": ("min_changed_m2", 2)},
    "scan_matching": {"field_sigma_cells": ("field_sigma_m", 1), "coarse_sigma_cells": ("coarse_sigma_m", 1),
                      "min_map_walls": ("min_map_wall_m", 1)},
    "upen": {"expand_cells": ("expand_m", 1)},
    "mapex": {"min_distance_cells": ("min_distance_m", 1)},
}
"""Per configuration (the explorer's, its parts', a planner's by name): each old name that counted cells, with its
new name and the power of the cell size that converts it (1: metres, 2: square metres)."""

RETIRED: dict = {
    "superex": ("docs/benchmarks/better-map.md", {"choice": "greedy", "candidates": 5, "rollout_goals": 4,
                                                  "horizon_m": 60.0, "rollout_cell_m": 0.3,
                                                  "rollout_frontier_cells": 3, "tour_frontiers": 18,
                                                  "wall_support": None, "transmittance": "correlated"}),
    "mapex": ("docs/benchmarks/better-map.md", {"wall_support": None, "transmittance": "independent"}),
    "scan_matching": ("docs/on-a-robot.md", {"match_sigma_cells": 0.0, "match_sigma_deg": 0.0,
                                             "start_after_scans": 0}),
    "profile": ("docs/benchmarks/realtime.md", {"agreement_stop": None}),
    "nlos_skips": ("docs/benchmarks/realtime.md", {"without_unknown": False, "when_still": False,
                                                  "filter_without_votes": False, "rays_without_unknown": False,
                                                  "filter_same_input": False}),
}
"""Per configuration: the page that measured the retired options, and each option's old default."""

PREVIOUS_DEFAULTS: dict = {"superex": {"gain": "path", "transmittance": "independent"}}
# transmittance "independent" was retired since (RETIRED): a run of superex made before 0.2 cannot be reproduced.
"""Per planner: the defaults before 0.2 of the fields whose default changed since, which a recording made before
``planner_config`` (the options given only) ran."""

ADDED_EXPLORER_FIELDS: dict = {"finish_frontier_m": 0.0, "goal_policy": {"drop_resolved_m": None,
                                                                         "confirm_visit_m": None}}
"""Fields of the explorer's configuration (and of its ``goal_policy``) added after 0.2.0, at the values that behave
as the explorer did before them (``finish_after_s`` counted goals of any size; a goal was kept until reached)."""


def in_metres(section: str, values: dict, resolution_m: float) -> dict:
    """``values`` (a recorded configuration's fields) with the old names of ``section`` (:data:`RENAMED`) converted
    on a grid of ``resolution_m`` metres per cell; the converted value gives back the recorded cell count
    (:func:`~superex_deploy.onboard.checks.cells_at_least`, :func:`~superex_deploy.onboard.checks.cells_within`).

    Raises:
        ValueError: an old name beside its new one, or an old value that is not a number >= 0, named.
    """
    converted = dict(values)
    for old, (new, power) in RENAMED.get(section, {}).items():
        if old not in converted:
            continue
        if new in converted:
            raise ValueError(f"{section}: both {old!r} and its new name {new!r} are given")
        count = converted.pop(old)
        if isinstance(count, bool) or not isinstance(count, numbers.Real) or not (math.isfinite(count)
                                                                                    and count >= 0):
            raise ValueError(f"{section}: {old} must be a finite number >= 0, got {count!r}")
        converted[new] = round(float(count) * float(resolution_m) ** power, 12)
    return converted


def _without_retired(section: str, values: dict) -> dict:
    """``values`` without the options ``section`` retired (:data:`RETIRED`), each of which must hold its old default."""
    where, retired = RETIRED.get(section, ("", {}))
    changed = sorted(name for name in values if name in retired and values[name] != retired[name])
    if changed:
        many = len(changed) > 1
        raise ValueError(f"{section}: the option{'s' if many else ''} {', '.join(repr(n) for n in changed)} "
                         f"{'were' if many else 'was'} retired (measured, with a negative result: {where}); this "
                         f"version cannot reproduce a run that used {'them' if many else 'it'}")
    return {name: value for name, value in values.items() if name not in retired}


def schedule_in_modes(fields) -> dict:
    """A prediction schedule written before its modes (``asynchronous``: False is ``inline``; True with
    ``every_steps`` 0 is ``free``, with ``every_steps >= 1`` the retired thread mode, whose predictions landed where
    ``simulated``'s do) in this version's form; others as given."""
    if not isinstance(fields, dict) or "asynchronous" not in fields:
        return fields
    fields = dict(fields)
    if "mode" in fields:
        raise ValueError("a schedule gives either mode or the older asynchronous, not both")
    asynchronous = fields.pop("asynchronous")
    if not isinstance(asynchronous, bool):
        raise ValueError(f"asynchronous must be True or False, got {asynchronous!r}")
    fields["mode"] = ("simulated" if fields.get("every_steps", 10) else "free") if asynchronous else "inline"
    return fields


def _explorer(fields: dict, resolution_m: float) -> dict:
    """The explorer's recorded configuration in this version's form, built and written by ``ExplorerConfig``."""
    from superex_deploy.onboard import ExplorerConfig

    fields = in_metres("explorer", fields, resolution_m)
    for name, value in ADDED_EXPLORER_FIELDS.items():
        if isinstance(value, dict) and isinstance(fields.get(name), dict):
            fields[name] = {**value, **fields[name]}
        else:
            fields.setdefault(name, value)
    for part in ("motion", "reuse", "scan_matching"):
        if isinstance(fields.get(part), dict):
            fields[part] = _without_retired(part, in_metres(part, fields[part], resolution_m))
    if "prediction" in fields:
        fields["prediction"] = schedule_in_modes(fields["prediction"])
    return ExplorerConfig.from_json(fields).to_json()


def _planner(old: dict, resolution_m: float) -> dict:
    """The planner's whole configuration in this version's form (``{}`` for a planner without one)."""
    from superex_deploy.onboard.planning.planners import planner_config

    name = old["planner"]
    if "planner_config" in old:
        fields = old["planner_config"]
    else:
        fields = {**PREVIOUS_DEFAULTS.get(name, {}), **(old.get("planner_options") or {})}
    if name in ("superex", "mapex") and fields.get("gain") != "expected":
        fields = {key: value for key, value in fields.items() if key != "transmittance"}  # read by that gain only
    config_class = planner_config(name)
    if config_class is None:
        if fields:
            raise ValueError(f"planner {name!r} takes no configuration, got {sorted(fields)}")
        return {}
    return config_class.from_json(_without_retired(name, in_metres(name, fields, resolution_m))).to_json()


def _nlos(fields: dict, resolution_m: float) -> dict:
    """The NLOS processing's recorded configuration: lengths of the first recordings in cells (``wall_strip_cells``
    ...) as that many cells of the grid, names this version does not have left out (as the replay of format 1
    read them)."""
    from superex_deploy.onboard.nlos import NlosConfig

    known = set(NlosConfig.__dataclass_fields__)
    kept = {name: value for name, value in fields.items() if name in known}
    for name, value in fields.items():
        metric = name.removesuffix("_cells") + "_m"
        if name.endswith("_cells") and metric in known and metric not in kept:
            kept[metric] = float(value) * float(resolution_m)
    return NlosConfig.from_json(kept).to_json()


def _profile_settings(settings, profile: str, resolution_m: float):
    """The recorded profile settings in this version's form: this version's where none were recorded, the fields
    added since at their defaults, schedules and reuse converted; a replay compares them with the profile's now."""
    from superex_deploy.pipeline import PROFILES, RealtimeProfile

    if settings is None:
        return PROFILES[profile].to_json() if profile in PROFILES else {}  # a replay names the unknown profile
    settings = {**RealtimeProfile().to_json(), **_without_retired("profile", settings)}
    if isinstance(settings.get("nlos_skips"), dict):
        settings["nlos_skips"] = _without_retired("nlos_skips", settings["nlos_skips"])
    for key in ("schedule", "simulated_schedule"):
        settings[key] = schedule_in_modes(settings[key])
    if isinstance(settings["reuse"], dict):
        settings["reuse"] = in_metres("reuse", settings["reuse"], resolution_m)
    return settings


def convert_metadata(old: dict) -> dict:
    """The metadata of this format (:mod:`superex_deploy.recording.metadata`) that rebuilds the run whose metadata
    of format ``"1"`` is ``old`` (see the module docstring); keys a replay does not read (``bag``, the simulator's
    noise) are kept as they are.

    Raises:
        ValueError: a configuration this version cannot build (a retired option in use, a field it does not have,
            a bad value), said in one line naming it.
    """
    missing = [key for key in ("frame", "planner", "predictor", "seed", "explorer") if key not in old]
    if missing:
        raise ValueError(f"the recording's metadata lacks {', '.join(repr(key) for key in missing)}")
    try:
        resolution_m = float(old["frame"]["resolution_m"])
    except (KeyError, TypeError, ValueError):
        raise ValueError(f"the recording's map frame gives no cell size: {old['frame']!r:.80}") from None
    spad = bool(old.get("spad"))
    profile = old.get("profile") or "full"
    try:
        explorer = _explorer(dict(old["explorer"]), resolution_m)
        planner = _planner(old, resolution_m)
        sensing = {"sensor": None, "nlos": None}
        if spad:
            from superex_deploy.spad_types import SpadConfig

            sensing = {"sensor": SpadConfig.from_json(old["sensor"]).to_json(),
                       "nlos": _nlos(old["nlos"], resolution_m)}
    except (KeyError, TypeError, ValueError) as error:
        raise ValueError(f"the recording's configuration cannot be converted: {error}") from None
    extra = {key: value for key, value in old.items() if key not in METADATA_TYPES}  # e.g. "bag", the noise
    return {**extra, "format_version": FORMAT_VERSION, "frame": old["frame"], "map": old.get("map", ""),
            "planner": old["planner"], "planner_options": old.get("planner_options") or {},
            "planner_config": planner, "predictor": old["predictor"], "seed": old["seed"], "spad": spad,
            "models": old.get("models"), **sensing, "explorer": explorer, "profile": profile,
            "profile_settings": _profile_settings(old.get("profile_settings"), profile, resolution_m)}


def convert_recording(source: Union[str, Path], target: Union[str, Path],
                      chunk_bytes: int = 256 * 1024) -> tuple[int, Optional[str]]:
    """Write ``target``: the recording ``source`` of an older format (:data:`OLD_FORMATS`) with its metadata
    converted (:func:`convert_metadata`) and every message, schema and channel copied as they are (atomically:
    ``target`` is complete or absent).

    Returns:
        ``(messages, error)``: the messages copied, and None or what stopped the reading of a file cut short (the
        messages before it are copied).

    Raises:
        ValueError: a source that is missing, not a SuperEx recording, already of this format or of one this
            module does not read; a target that is the source or a folder; metadata it cannot convert.
    """
    from superex_deploy.files import write_atomically
    from superex_deploy.recording.reader import read_metadata

    source, target = Path(source), Path(target)
    metadata = read_metadata(source)
    version = metadata.get("format_version")
    if version == FORMAT_VERSION:
        raise ValueError(f"{source} is already of recording format {FORMAT_VERSION!r}: nothing to convert (replay it "
                         f"as it is)")
    if version not in OLD_FORMATS:
        raise ValueError(f"{source} has recording format {version!r}: this version converts "
                         f"{', '.join(repr(v) for v in OLD_FORMATS)} to {FORMAT_VERSION!r}")
    if target.exists() and target.resolve() == source.resolve():
        raise ValueError(f"the converted recording must go to another file than {source}")
    if target.is_dir():
        raise ValueError(f"{target} is a folder, not a file")
    if not target.parent.is_dir():
        raise ValueError(f"{target}: the folder {target.parent} does not exist")
    try:
        converted = check_metadata(convert_metadata(metadata), str(source))
    except ValueError as error:
        raise ValueError(f"{source}: {error}") from None
    copied: list = [0, None]

    def write(part: Path) -> None:
        with open(source, "rb") as original, open(part, "wb") as file:
            copied[:] = _copy(original, file, {key: json.dumps(value) for key, value in converted.items()},
                              chunk_bytes)

    write_atomically(target, write)
    return copied[0], copied[1]


def _copy(original, file, metadata: dict, chunk_bytes: int) -> tuple[int, Optional[str]]:
    """Copy the MCAP records of ``original`` to ``file``, the ``superex.episode`` metadata replaced by
    ``metadata`` (written first, as the recorder does): ``(messages copied, None or why the reading stopped)``."""
    from mcap.records import Attachment, Channel, DataEnd, Header, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader
    from mcap.writer import Writer

    records = StreamReader(original, validate_crcs=True).records
    writer, schemas, channels, messages, error = None, {0: 0}, {}, 0, None
    try:
        for record in records:
            if isinstance(record, Header):
                writer = Writer(file, chunk_size=int(chunk_bytes))
                writer.start(profile=record.profile, library=record.library)
                writer.add_metadata(METADATA_NAME, metadata)
            elif writer is None:
                raise ValueError("no MCAP header")
            elif isinstance(record, Schema) and record.id not in schemas:
                schemas[record.id] = writer.register_schema(record.name, record.encoding, record.data)
            elif isinstance(record, Channel) and record.id not in channels:
                channels[record.id] = writer.register_channel(record.topic, record.message_encoding,
                                                              schemas[record.schema_id], dict(record.metadata))
            elif isinstance(record, Message):
                writer.add_message(channels[record.channel_id], record.log_time, record.data, record.publish_time,
                                   record.sequence)
                messages += 1
            elif isinstance(record, Metadata) and record.name != METADATA_NAME:
                writer.add_metadata(record.name, dict(record.metadata))
            elif isinstance(record, Attachment):
                writer.add_attachment(record.create_time, record.log_time, record.name, record.media_type,
                                      record.data)
            elif isinstance(record, DataEnd):
                break
    except Exception as failure:  # noqa: BLE001 - a file cut short: what was read is copied
        if writer is None:
            raise ValueError(f"not an MCAP file ({type(failure).__name__}: {failure})") from None
        error = f"the file is cut short or broken after {messages} messages ({type(failure).__name__}: {failure})"
    writer.finish()
    return messages, error
