"""Types of the ``bnptrack`` options that name something: a file or folder (:class:`PathName`), a
preset or a stage (:data:`NAME`), a viewer URL (:data:`URL`), a run id (:data:`RUN`).  Each
refuses an empty value (``--out ""``, an unset shell variable) with one line naming the option,
before it can mean a default or the current folder."""

from __future__ import annotations

import os
from typing import Any

import click

__all__ = ["NAME", "RUN", "URL", "PathName", "RunId", "TextName", "UrlText"]


class _NotEmpty(click.ParamType):
    """A value that names something (a file, a preset, a run): an empty one (``--out ""``, an
    unset shell variable) is a usage error naming the option, before it can mean a default or
    the current folder."""

    #: What the error asks for (``empty --connect: give a URL``).
    what = "name"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        if isinstance(value, str) and value == "":
            name = _option_name(param)
            rest = "" if param is None or param.required else ", or leave the option out"
            raise click.UsageError(f"empty {name}: give a {self.what}{rest}", ctx)
        return super().convert(value, param, ctx)


def _option_name(param: click.Parameter | None) -> str:
    """The option as a user types it (its longest name: ``--out``)."""
    return max(param.opts, key=len) if param is not None and param.opts else "value"


class PathName(_NotEmpty, click.Path):
    """:class:`click.Path` that refuses an empty value (``empty --out``) and, for a file
    (``dir_okay=False``), a name that ends in a path separator (``--csv newdir/``: a folder's
    name, which would otherwise be written as the file ``newdir``)."""

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        seps = tuple(s for s in (os.sep, os.altsep) if s)
        if not self.dir_okay and isinstance(value, str) and value.endswith(seps):
            raise click.UsageError(f"{_option_name(param)} {value}: names a folder; give a file name", ctx)
        return super().convert(value, param, ctx)


class TextName(_NotEmpty, click.types.StringParamType):
    """A text option (a preset or file name, a run id) that refuses an empty value."""

    name = "text"


#: A non-empty text option (``--params``, ``--config``, ``--name``).
NAME = TextName()


class UrlText(TextName):
    """A viewer URL option (``--connect URL``) that refuses an empty value."""

    what = "URL"


#: ``--connect URL`` of ``track`` and ``replay``.
URL = UrlText()


class RunId(TextName):
    """``--run``: a run id (:data:`pipeline.config.RUN_RE`), else a usage error naming the
    option as typed."""

    name = "run"
    what = "run id"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        from bnptrack.pipeline.config import RUN_RE, run_id_problem

        run = super().convert(value, param, ctx)
        if not RUN_RE.match(run):
            raise click.UsageError(run_id_problem(run, "--run"), ctx)
        return run


#: ``--run`` of ``launch``, ``replay``, ``stage``, ``monitor``.
RUN = RunId()
