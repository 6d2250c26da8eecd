"""``--help`` of every ``hyprog`` command, found by walking the typer app: plain text (no reST
double backticks leaking into the terminal, no ``<bool>`` after a flag, no "[run]" eaten by
rich's markup: every bracketed word of the source's help strings is printed), a usage line
naming the arguments as click does (``MODEL_DIR``, ``[DATA]``, never ``{features}``), exit 0,
an example in every command that runs something (the groups list their commands), choices
listed where an option takes one, and shell completion installable from the root."""

import re

import pytest
import typer
from typer.testing import CliRunner

from cli.main import app


def _paths(command, path=()):
    yield path, command
    for name, sub in sorted((getattr(command, "commands", None) or {}).items()):
        yield from _paths(sub, (*path, name))


COMMANDS = list(_paths(typer.main.get_command(app)))


def test_the_walk_finds_every_command():
    names = {" ".join(p) for p, _ in COMMANDS}
    assert {"pipeline", "train", "calibrate run", "data import-cmapss", "model point",
            "experiment paper", "discover", "effects", "simulate"} <= names


@pytest.mark.parametrize("path", [p for p, _ in COMMANDS], ids=lambda p: " ".join(p) or "root")
def test_help_is_plain_text_with_an_example(path):
    command = dict(COMMANDS)[path]
    res = CliRunner().invoke(app, [*path, "--help"], terminal_width=100)
    assert res.exit_code == 0, res.stdout
    text = res.stdout
    assert "``" not in text, text
    # rich reads "[...]" in a help string as markup and drops it: "window [60]." -> "window ."
    assert not re.search(r"\w \.(\s|$)", text), text
    assert "Usage:" in text
    assert "<bool>" not in text, text
    usage = text.split("Usage:", 1)[1].splitlines()[0]
    assert "{" not in usage and "}" not in usage, usage
    for param in command.params:
        if param.param_type_name == "argument":
            name = param.name.upper()
            assert (name if param.required else f"[{name}]") in usage, usage
    flat = " ".join(text.split())
    for param in command.params:  # "overrides [run] jobs" keeps its "[run]"
        for word in re.findall(r"\[[a-z_]+\]", " ".join((param.help or "").split())):
            assert word in flat, (param.name, word, text)
    if not hasattr(command, "commands"):  # a leaf: it does something, show how
        assert re.search(r"Examples?:\n +hyprog " + re.escape(path[0]), text), text


def test_choices_are_listed_and_refused_otherwise():
    text = CliRunner().invoke(app, ["train", "--help"], terminal_width=100).stdout
    assert "--model <fnn|cnn|dcnn|tcn|trend|similarity>" in text, text
    assert "<auto|cpu|cuda>" in text, text
    res = CliRunner().invoke(app, ["train", "features", "--out", "m", "--model", "lstm"])
    assert res.exit_code == 2
    assert "'lstm' is not one of 'fnn', 'cnn', 'dcnn', 'tcn', 'trend', 'similarity'" in res.stderr
    assert "Value error" not in res.stderr  # the validation layer's wording stays out


def test_completion_is_installable_and_completes():
    """``hyprog --install-completion`` is offered, and the completion it installs answers:
    a command's name from its first letters, an option's choices."""
    import os
    import subprocess
    import sys

    text = CliRunner().invoke(app, ["--help"]).stdout
    assert "--install-completion" in text and "--show-completion" in text

    def complete(words: str, cword: int) -> list[str]:
        env = {**os.environ, "COMP_WORDS": words, "COMP_CWORD": str(cword),
               "_HYPROG_COMPLETE": "complete_bash"}
        r = subprocess.run([sys.executable, "-c",
                            "from cli.main import app; app(prog_name='hyprog')"],
                           env=env, capture_output=True, text=True, check=True)
        return r.stdout.split()

    assert complete("hyprog tr", 1) == ["train"]
    assert complete("hyprog train f --model ", 4) == ["fnn", "cnn", "dcnn", "tcn", "trend",
                                                     "similarity"]


@pytest.mark.parametrize("group", ["data", "experiment", "model", "calibrate"])
def test_a_group_without_its_command_says_so(group):
    res = CliRunner().invoke(app, [group])
    assert res.exit_code == 2
    assert f"error: hyprog {group}: missing a command" in res.stderr, res.stderr
