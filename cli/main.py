"""The ``hyprog`` console script: the root typer app and its sub-apps."""

from __future__ import annotations

import typer

from cli import calibrate, data, effects, evaluate, experiment, model, predict, simulate, train

app = typer.Typer(
    name="hyprog",
    help="Hybrid physics + deep-learning prognostics for turbofan engine fleets.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
app.add_typer(model.app, name="model")
app.add_typer(data.app, name="data")
app.add_typer(calibrate.app, name="calibrate")
app.command("simulate")(simulate.simulate)
app.command("effects")(effects.effects)
app.command("train")(train.train)
app.command("evaluate")(evaluate.evaluate)
app.command("predict")(predict.predict)
app.add_typer(experiment.app, name="experiment")


def _version(value: bool):
    if value:
        from importlib.metadata import PackageNotFoundError, version

        try:
            typer.echo(f"hyprog {version('hyprog')}")
        except PackageNotFoundError:
            typer.echo("hyprog (not installed)")
        raise typer.Exit()


@app.callback()
def main(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True,
                                 help="Print the version and exit."),
):
    """Hybrid physics + deep-learning prognostics for turbofan engine fleets."""


if __name__ == "__main__":  # pragma: no cover
    app()
