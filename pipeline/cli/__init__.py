"""The ``bnptrack`` command line (``bnptrack = "pipeline.cli:main"``; also ``python -m pipeline``).

Subcommands are thin: they parse options, call the library and print a summary.

\b
- :mod:`pipeline.cli.common`: error handling (one line, exit code 2), summary rows, shared
  option texts and registry-derived choices;
- :mod:`pipeline.cli.offline_commands`: ``simulate``, ``track``;
- :mod:`pipeline.cli.tools`: ``info``, ``export``, ``view``, ``experiment``, ``schema``;
- :mod:`pipeline.cli.pipeline_commands`: ``launch``, ``replay``, ``stage``, ``router``;
- :mod:`pipeline.cli.monitor`: ``monitor``.
"""

from __future__ import annotations

import click

from pipeline.cli.common import EXIT_ERROR, EXIT_INCOMPLETE, CliError, IncompleteError
from pipeline.cli.monitor import monitor
from pipeline.cli.offline_commands import simulate, track
from pipeline.cli.pipeline_commands import launch, replay, router, stage
from pipeline.cli.tools import experiment, export, info, schema, view

__all__ = ["main", "CliError", "IncompleteError", "EXIT_ERROR", "EXIT_INCOMPLETE"]


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(package_name="bnptrack", prog_name="bnptrack")
def main() -> None:
    """bnptrack: streaming multi-object tracking with Bayesian nonparametric priors.

    Simulate the paper's scenarios into MCAP logs and run the DDP-EMM (ddp) or DPY-STP
    (dpyp) tracker over a log offline. Logs hold /measurements, /truth and /tracks as
    JSON messages (see docs/formats.md and `bnptrack schema`).

    \b
    Example:
      bnptrack simulate --scenario vo2017 --params vo2017 --seed 1 --out recordings/vo2017-s1.mcap
      bnptrack track recordings/vo2017-s1.mcap --tracker ddp --out recordings/vo2017-s1-ddp.mcap
      bnptrack schema /tracks

    Errors are reported on one line with exit code 2 (BNPTRACK_DEBUG=1 shows the traceback).
    """


for _command in (simulate, track, info, export, view, experiment, schema, launch, replay, stage, router,
                 monitor):
    main.add_command(_command)


if __name__ == "__main__":  # pragma: no cover
    main()
