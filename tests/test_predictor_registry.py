"""The predictor registry (``onboard.prediction.registry.PREDICTORS``) is the one list of predictor names: each kind
declares what it needs, builds what it names, and every other list (the pipelines' checks, the CLI's choices and
help, ``superex warmup``) reads it."""

import argparse

import pytest

from superex_deploy.cli import build_parser
from superex_deploy.commands import offline
from superex_deploy.commands.options import add_profile_option, predictor_help
from superex_deploy.onboard.planning.planners import PLANNERS
from superex_deploy.onboard.prediction.baselines import EvidenceAsPrediction, ObservedAsPrediction
from superex_deploy.onboard.prediction.inference import ModelKind
from superex_deploy.onboard.prediction.registry import (ENSEMBLE_PREDICTORS, EVIDENCE_PREDICTORS, PREDICTORS,
                                                        TRUTH_PREDICTORS, PredictorKind, make_onboard_predictor,
                                                        predictor_kind)
from superex_deploy import pipeline


def test_the_names_and_what_each_kind_needs_are_those_of_before():
    assert tuple(PREDICTORS) == ("observed", "oracle", "lama_los", "lama_bp", "evidence")
    assert EVIDENCE_PREDICTORS == ("lama_bp", "evidence")
    assert ENSEMBLE_PREDICTORS == ("lama_los", "lama_bp")
    assert TRUTH_PREDICTORS == ("oracle",)
    assert {name: kind.models for name, kind in PREDICTORS.items() if kind.models} == {
        "lama_los": (ModelKind.LAMA_LOS,), "lama_bp": (ModelKind.LAMA_BP,)}
    assert pipeline.PREDICTORS is PREDICTORS and pipeline.EVIDENCE_PREDICTORS is EVIDENCE_PREDICTORS
    for name, kind in PREDICTORS.items():
        assert issubclass(kind, PredictorKind) and kind.name == name and kind.summary
        assert predictor_kind(name) is kind


def test_each_kind_builds_the_predictor_it_names():
    assert type(make_onboard_predictor("observed")) is ObservedAsPrediction
    assert type(make_onboard_predictor("evidence")) is EvidenceAsPrediction
    for name in ("observed", "evidence"):
        assert make_onboard_predictor(name).name == name
    with pytest.raises(ValueError, match="the oracle predictor reads the ground truth"):
        make_onboard_predictor("oracle")
    for bad in ("nope", None, ["observed"]):
        with pytest.raises(ValueError, match="unknown predictor .*; choose one of observed, oracle, lama_los, "
                                             "lama_bp, evidence"):
            make_onboard_predictor(bad)


def test_the_truth_reader_is_the_simulations_oracle():
    import numpy as np

    from superex_deploy.maps import OccupancyGrid

    walls = np.zeros((8, 8), bool)
    grid = OccupancyGrid(walls, ~walls, 0.1, "tiny")
    for name in TRUTH_PREDICTORS:
        assert pipeline.make_predictor(name, grid).name == name


def _subparser(command: str) -> argparse.ArgumentParser:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices[command]


def _option(parser: argparse.ArgumentParser, flag: str) -> argparse.Action:
    return next(a for a in parser._actions if flag in a.option_strings)


def test_the_commands_choices_and_help_read_the_registries():
    for command in ("explore", "benchmark"):
        predictor = _option(_subparser(command), "--predictor")
        assert tuple(predictor.choices) == tuple(PREDICTORS)
        assert all(f"{name}: {kind.summary}" in predictor.help for name, kind in PREDICTORS.items())
    assert offline.bag_predictors() == ("observed", "lama_los")
    assert tuple(_option(_subparser("offline"), "--predictor").choices) == offline.bag_predictors()
    assert _option(_subparser("benchmark"), "--planners").default == ",".join(PLANNERS)
    for command in ("explore", "offline"):
        assert " | ".join(PLANNERS) in _option(_subparser(command), "--planner").help
    assert predictor_help(("lama_bp",)) == f"lama_bp: {PREDICTORS['lama_bp'].summary} (needs --spad)"
    parser = argparse.ArgumentParser()
    add_profile_option(parser)
    assert "(upen, mapex)" in _option(parser, "--profile").help


def test_a_kind_registered_later_is_built_by_name_and_checked_by_what_it_needs(monkeypatch):
    from superex_deploy.messages import MapFrame

    class Walls(ObservedAsPrediction):
        name = "walls"

    class WallsKind(PredictorKind):
        name, summary = Walls.name, "the observed walls (reads the evidence, for the test)"
        reads_evidence = True

        @classmethod
        def build(cls, models=None, session=None, max_members=None):
            return Walls()

    monkeypatch.setitem(PREDICTORS, WallsKind.name, WallsKind)
    assert type(make_onboard_predictor("walls")) is Walls
    with pytest.raises(ValueError, match="the walls predictor reads the SPAD evidence"):
        pipeline.build_explorer(MapFrame((40, 40), 0.1), "nearest", "walls")
    with pytest.raises(ValueError, match="--predictor walls reads the SPAD evidence: add --spad"):
        pipeline.make_sensing("walls", False, 0)
    predictor = _option(_subparser("explore"), "--predictor")
    assert "walls" in predictor.choices and f"walls: {WallsKind.summary} (needs --spad)" in predictor.help
