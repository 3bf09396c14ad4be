"""Options are dataclass fields: a Literal type is the one list of a field's choices (the command line offers
them, the config rejects anything else), and a bool's help says what the field means when True."""

from __future__ import annotations

import argparse
import dataclasses
import typing
from dataclasses import dataclass
from typing import Literal

import pytest

from sparself.core.errors import ConfigError
from sparself.core.options import add_options, check_choices, literal_choices, option
from sparself.evaluation.config import EvalConfig
from sparself.model.decoders import DECODERS, DecoderName
from sparself.pipeline import DensifyConfig
from sparself.synthesis.plan import PlanConfig
from sparself.synthesis.train_config import TrainConfig

CONFIGS = (TrainConfig, PlanConfig, EvalConfig, DensifyConfig)


@dataclass
class _Toy:
    mode: Literal["fast", "slow"] = option("fast", "how to run")
    name: str = option("a", "any text")
    shade: bool = option(True, "colour the output")

    def __post_init__(self) -> None:
        check_choices(self)


def _parser(cls) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(exit_on_error=False)
    add_options(p, cls)
    return p


def test_a_literal_field_is_checked_by_the_config_and_offered_by_the_command_line():
    assert literal_choices(_Toy) == {"mode": ("fast", "slow")}
    with pytest.raises(ConfigError, match="mode must be one of fast, slow, got 'medium'"):
        _Toy(mode="medium")  # type: ignore[arg-type]
    p = _parser(_Toy)
    assert p.parse_args(["--mode", "slow", "--name", "anything"]).mode == "slow"
    with pytest.raises(argparse.ArgumentError, match="invalid choice"):
        p.parse_args(["--mode", "medium"])


def test_a_bool_that_defaults_to_true_becomes_a_no_flag_whose_help_keeps_the_fields_meaning():
    p = _parser(_Toy)
    assert p.parse_args([]).shade is True and p.parse_args(["--no-shade"]).shade is False
    help_text = p.format_help().replace("\n", " ")
    assert "colour the output (on by default; this flag turns it off)" in " ".join(help_text.split())


@pytest.mark.parametrize("cls", CONFIGS)
def test_every_choice_field_of_the_configs_is_a_literal_on_the_command_line(cls):
    choices = literal_choices(cls)
    actions = {a.dest: a for a in _parser(cls)._actions}
    for name, allowed in choices.items():
        if name in actions:
            assert tuple(actions[name].choices) == allowed, name
    # no option offers choices that its type does not name
    assert {a.dest for a in actions.values() if a.choices} <= set(choices)


def test_the_decoder_choices_are_the_registered_decoders():
    assert set(typing.get_args(DecoderName)) == set(DECODERS)
    with pytest.raises(ConfigError, match="decoder must be one of sweep, fc"):
        TrainConfig(decoder="mlp")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="order must be one of auto, capture, nearest"):
        PlanConfig(order="random").validate()  # type: ignore[arg-type]


@pytest.mark.parametrize("cls", CONFIGS)
def test_no_bool_option_describes_its_negation(cls):
    for f in dataclasses.fields(cls):
        if "help" in f.metadata and f.default is True:
            text = f.metadata["help"].lower()
            assert not text.startswith(("skip", "no ", "don't", "do not", "ablation: no")), (f.name, text)
