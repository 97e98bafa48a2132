"""A resumable experiment: one JSON line per finished run in ``OUT/runs.jsonl``.

The first line is a header naming the experiment's setup (experiment, seed, parameter set,
trackers, variants) and a fingerprint of the code that decides its numbers; every further
line is one run's :class:`~pipeline.experiment_summary.RunScores`, appended and flushed to disk
as the run finishes.  ``bnptrack experiment`` started again with the same ``--out`` reads the
journal, skips the runs it holds and runs the rest, so an experiment of 10,000 runs survives
being stopped at any moment; ``--runs`` may grow between invocations.

A line cut short by a crash (the last one, without its newline) is dropped and rewritten.  A
journal of another setup, or of other tracker code, is refused: runs of two versions of the
trackers are not pooled into one table.  After a change that should not move any number (a
faster kernel, a refactor), :func:`adopt` carries a journal over once some of its runs, redone
by the new code, gave the same scores (``bnptrack experiment --revalidate K``).
"""

from __future__ import annotations

import ast
import hashlib
import json
import os
from pathlib import Path

from bnptrack.pipeline.experiment_summary import RunScores, TrackerScores
from bnptrack.tracker.config import ConfigError

JOURNAL_NAME = "runs.jsonl"
_FORMAT = "bnptrack-experiment-journal/1"

#: What decides an experiment's numbers: the trackers, models and parameter sets, the
#: simulator, the scores and the experiments' definitions (paths relative to the checkout).
_CODE = ("tracker", "sources", "sinks/metrics.py", "sinks/crossings.py", "sinks/range_scores.py",
         "sinks/metric_checks.py", "pipeline/experiments.py", "pipeline/resolve.py")


def _strip_docstrings(tree: ast.AST) -> ast.AST:
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if isinstance(body, list) and body and isinstance(body[0], ast.Expr) \
                and isinstance(body[0].value, ast.Constant) and isinstance(body[0].value.value, str):
            node.body = body[1:] or [ast.Pass()]
    return tree


def code_fingerprint(root: Path | None = None) -> str:
    """A hash of the syntax trees (comments and docstrings left out) of the modules that decide
    an experiment's numbers, and of the built-in parameter files: equal for two checkouts whose
    trackers compute the same thing, whatever their prose."""
    root = root or Path(__file__).resolve().parent.parent
    h = hashlib.sha256()
    for rel in _CODE:
        p = root / rel
        files = sorted(p.rglob("*.py")) + sorted(p.rglob("*.toml")) if p.is_dir() else [p]
        for f in files:
            h.update(str(f.relative_to(root)).encode())
            text = f.read_text()
            h.update((ast.dump(_strip_docstrings(ast.parse(text))) if f.suffix == ".py" else text).encode())
    return h.hexdigest()[:16]


def _encode(s: RunScores) -> str:
    return json.dumps({"variant": s.variant, "run": s.run, "trackers": {
        t: {"values": list(v.values), "crossings_kept": [bool(k) for k in v.crossings_kept],
            "extra": {k: list(x) for k, x in v.extra.items()}} for t, v in s.trackers.items()}},
        separators=(",", ":"), allow_nan=True)


def _decode(d: dict) -> RunScores:
    return RunScores(d["variant"], int(d["run"]), {
        t: TrackerScores(tuple(v["values"]), tuple(v["crossings_kept"]), {k: tuple(x) for k, x in v["extra"].items()})
        for t, v in d["trackers"].items()})


class RunJournal:
    """The journal of one experiment's output folder: open it with :meth:`open`, which returns
    the runs it already holds; :meth:`append` each finished run; :meth:`close` at the end."""

    def __init__(self, path: Path, fh) -> None:
        self.path = path
        self._fh = fh

    @classmethod
    def open(cls, out: Path, setup: dict) -> tuple[RunJournal, list[RunScores]]:
        """Open (or start) ``out/runs.jsonl`` for ``setup`` (a JSON-able dict: experiment, seed,
        params, trackers, variants, code); the runs already recorded, in file order."""
        path = Path(out) / JOURNAL_NAME
        header = {"format": _FORMAT, **setup}
        done: list[RunScores] = []
        if path.exists() and b"\n" in path.read_bytes():  # a header cut short holds no run
            done, good_bytes = _read(path, header)
            fh = path.open("r+b")
            fh.truncate(good_bytes)  # drops a last line cut short by a crash
            fh.seek(good_bytes)
        else:
            fh = path.open("wb")
            fh.write((json.dumps(header) + "\n").encode())
            fh.flush()
        return cls(path, fh), done

    def append(self, scores: RunScores) -> None:
        self._fh.write((_encode(scores) + "\n").encode())
        self._fh.flush()
        os.fsync(self._fh.fileno())

    def close(self) -> None:
        self._fh.close()


def journal_runs(out: Path) -> tuple[dict, list[RunScores]]:
    """The header and the runs of ``out/runs.jsonl`` as they are (no setup check)."""
    path = Path(out) / JOURNAL_NAME
    header = json.loads(path.read_text().splitlines()[0])
    return header, _read(path, header)[0]


def same_scores(a: RunScores, b: RunScores, timing: int) -> bool:
    """Equal scores of every tracker, except the clock reading at index ``timing``."""
    if a.trackers.keys() != b.trackers.keys():
        return False
    for t, x in a.trackers.items():
        y = b.trackers[t]
        keep = [i for i in range(len(x.values)) if i != timing]
        if [x.values[i] for i in keep] != [y.values[i] for i in keep] or x.crossings_kept != y.crossings_kept \
                or x.extra != y.extra:
            return False
    return True


def adopt(out: Path, code: str) -> None:
    """Rewrite the journal's header with ``code`` (the runs kept as they are): called once
    redone runs matched the journal's."""
    path = Path(out) / JOURNAL_NAME
    lines = path.read_bytes().split(b"\n", 1)
    header = json.loads(lines[0])
    header["code"] = code
    tmp = path.with_suffix(".tmp")
    tmp.write_bytes((json.dumps(header) + "\n").encode() + lines[1])
    os.replace(tmp, path)


def _read(path: Path, header: dict) -> tuple[list[RunScores], int]:
    """The runs of the journal at ``path`` and the byte length of its complete lines; refuses a
    journal whose header differs from ``header``."""
    data = path.read_bytes()
    lines = data.split(b"\n")
    try:
        found = json.loads(lines[0])
    except ValueError:
        raise ConfigError(f"{path}: line 1 is not an experiment journal's header; move the file away "
                          "or choose another --out") from None
    for key, want in header.items():
        if found.get(key) != want:
            what = ("other tracker code (the runs cannot be pooled with this code's)" if key == "code"
                    else f"{key} {found.get(key)!r}, not {want!r}")
            raise ConfigError(f"{path} holds runs of {what}; use --fresh to start over, or another --out")
    done, good = [], len(lines[0]) + 1
    complete = lines[1:-1]  # the part after the last newline is empty or cut short
    for i, line in enumerate(complete, start=2):
        try:
            done.append(_decode(json.loads(line)))
        except (ValueError, KeyError, TypeError) as exc:
            raise ConfigError(f"{path}, line {i}: not a run record ({exc})") from None
        good += len(line) + 1
    return done, good
