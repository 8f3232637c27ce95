"""Help texts: every option of every command of both CLIs says what it does, and the defaults the
help names are the ones the commands use."""

import argparse

import pytest

import nbvdata.cli
import nbvtrain.cli
from nbvtrain.planners.released import released_checkpoint, released_ranker


def _commands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    (sub,) = [action for action in parser._actions if isinstance(action, argparse._SubParsersAction)]
    return dict(sub.choices)


def _options(parser: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    """Each argument of a command by its first flag (or its name), the --help flag left out."""
    return {(action.option_strings or [action.dest])[0]: action for action in parser._actions
            if not isinstance(action, argparse._HelpAction)}


@pytest.mark.parametrize("cli", [nbvdata.cli, nbvtrain.cli], ids=["nbvdata", "nbvtrain"])
def test_every_option_of_every_command_has_help(cli):
    commands = _commands(cli.build_parser())
    assert commands
    missing = [f"{command} {flag}" for command, parser in commands.items()
               for flag, action in _options(parser).items()
               if not (action.help or "").strip() or action.help == argparse.SUPPRESS]
    assert not missing, f"options without help: {missing}"


def test_the_checkpoint_defaults_named_are_the_ones_used():
    commands = {name: _options(parser) for name, parser in _commands(nbvtrain.cli.build_parser()).items()}
    scores, regression = released_checkpoint("scores").stem, released_checkpoint("regression").stem
    ranker = released_ranker().stem
    for command, flag, model in (("predict", "--checkpoint", ranker), ("plan", "--checkpoint", ranker),
                                 ("evaluate", "--score-checkpoint", scores),
                                 ("evaluate", "--checkpoint", regression)):
        text = commands[command][flag].help
        assert "default: the released" in text and model in text, (command, flag, text)
    assert "nbvscore-3" not in commands["evaluate"]["--score-checkpoint"].help  # a model never released
    # plan takes any of the three kinds a planner is made of, the score network first (its default)
    assert "candidate-score, regression or classification" in commands["plan"]["--checkpoint"].help
    # smoke.yaml is offered as a quick scene, not named as the default
    assert "default: the default scene" in commands["evaluate"]["--config"].help
