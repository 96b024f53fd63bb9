"""The `vslam` command line: thin Typer commands over the other packages (`commands` the app and its commands,
`eval`, `batch` and `external` the evaluation commands, `common` shared options and output, `entry` how the
process starts and ends)."""


def main() -> None:
    """The console script's entry point (`vslam`): imports the commands only when called."""
    from vslam.cli.commands import main as run

    run()
