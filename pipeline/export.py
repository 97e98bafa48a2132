"""``bnptrack export``: a run's tracks (and per-frame metrics) as CSV or Parquet tables.

One row per track per frame: ``frame, stamp_ns, label, name, px, vx, py, vy, omega`` (the state;
``name`` the track's display name, :func:`tracker.types.display_name`, as the viewer shows it),
``var_px .. var_omega`` (the covariance diagonal), ``existence`` and ``cluster`` (the motion
cluster of a two-level tracker's object, the viewer's track colour; empty for other trackers).  When the run has truth
(``/truth``), a second table holds one row per frame: ``frame, stamp_ns, n_true, n_tracks,
n_measurements, ospa, ospa_localisation, ospa_cardinality, cardinality_error`` (OSPA c = 100 m,
p = 1 on position, as ``bnptrack track`` prints).
"""

from __future__ import annotations

import csv
import os
from dataclasses import dataclass
from pathlib import Path

from bnptrack.sources.mcap_log import read_log
from bnptrack.tracker.config import ConfigError
from bnptrack.tracker.types import display_name

STATE_NAMES = ("px", "vx", "py", "vy", "omega")
TRACK_COLUMNS = ("frame", "stamp_ns", "label", "name", *STATE_NAMES, *(f"var_{n}" for n in STATE_NAMES), "existence",
                 "cluster")
METRIC_COLUMNS = ("frame", "stamp_ns", "n_true", "n_tracks", "n_measurements", "ospa", "ospa_localisation",
                  "ospa_cardinality", "cardinality_error")


@dataclass(frozen=True)
class ExportResult:
    track_rows: int
    metric_rows: int
    tracks_path: str
    metrics_path: str | None


def run_tables(run: str | os.PathLike) -> tuple[list[tuple], list[tuple]]:
    """``(track rows, metric rows)`` of a run file (``/tracks``; metrics need ``/truth``)."""
    from bnptrack.pipeline.offline import frame_metrics

    log = read_log(run)
    if not log.tracks:
        raise ValueError(f"{os.fspath(run)} has no /tracks: export reads the output of `bnptrack track` or a run")
    frames = {f.frame: f for f in log.frames}
    tracks, metrics = [], []
    for est in log.tracks:
        for t in est.tracks:
            tracks.append((est.frame, est.stamp_ns, t.label, display_name(t.label), *map(float, t.state),
                           *map(float, t.covariance.diagonal()), float(t.existence),
                           None if t.cluster is None else int(t.cluster)))
        f = frames.get(est.frame)
        if f is not None and f.truth is not None:
            m = frame_metrics(f, est)
            metrics.append((est.frame, est.stamp_ns, m.n_true, m.n_tracks, m.n_measurements, m.ospa,
                            m.ospa_localisation, m.ospa_cardinality, m.cardinality_error))
    return tracks, metrics


def metrics_path(out: Path) -> Path:
    """``OUT.metrics.EXT`` beside ``OUT.EXT``."""
    return out.with_name(f"{out.stem}.metrics{out.suffix}")


def check_export_outputs(run: str | os.PathLike, outputs: dict[str, Path]) -> None:
    """Refuse tables (option -> file) that would replace the run, one another or a table's
    metrics file, a name that is itself a metrics file's (``OUT.metrics.EXT``), and a name
    whose suffix is the other format's (``--csv out.parquet``)."""
    seen: dict[Path, str] = {}
    run_path = Path(run).resolve()
    for option, out in outputs.items():
        for path, what in ((out, "the table"), (metrics_path(out), f"its metrics table {metrics_path(out)}")):
            if path.resolve() == run_path:
                raise ConfigError(f"{option} {out}: {what} would overwrite the run {os.fspath(run)}")
        if out.stem.endswith(".metrics"):
            table = out.with_name(out.stem.removesuffix(".metrics") + out.suffix)
            raise ConfigError(f"{option} {out}: that is the name of the metrics table beside a track table; "
                              f"give the track table's name ({table} writes {table} and {out})")
        for path in (out, metrics_path(out)):
            other = seen.setdefault(path.resolve(), option)
            if other != option:
                raise ConfigError(f"{option} {out}: the same file as {other}'s table")
    for option, out in outputs.items():  # after the checks across tables: their clash is the mistake
        _check_suffix(option, out)


#: Each table option: the suffix of the other format and the option that writes it.
_OTHER_FORMAT = {"--csv": (".parquet", "--parquet", "Parquet"), "--parquet": (".csv", "--csv", "CSV")}


def _check_suffix(option: str, out: Path) -> None:
    """Refuse ``--csv X.parquet`` and ``--parquet X.csv`` (a table in the other format than its
    name says); any other suffix is the user's choice."""
    suffix, other, name = _OTHER_FORMAT.get(option, ("", "", ""))
    if suffix and out.suffix.lower() == suffix:
        raise ConfigError(f"{option} {out}: a {name} file's name; give {other} {out} to write {name}, or a "
                          f"name that does not end in {suffix}")


def export(run: str | os.PathLike, out: str | os.PathLike, fmt: str = "csv") -> ExportResult:
    """Write the run's track table to ``out`` (and its metrics beside it) as CSV or Parquet."""
    tracks, metrics = run_tables(run)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write = _write_csv if fmt == "csv" else _write_parquet
    write(out, TRACK_COLUMNS, tracks)
    mpath = None
    if metrics:
        mpath = metrics_path(out)
        write(mpath, METRIC_COLUMNS, metrics)
    return ExportResult(len(tracks), len(metrics), str(out), None if mpath is None else str(mpath))


def _write_csv(path: Path, columns: tuple[str, ...], rows: list[tuple]) -> None:
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(columns)
        w.writerows(rows)


def _write_parquet(path: Path, columns: tuple[str, ...], rows: list[tuple]) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    cols = list(zip(*rows)) if rows else [[] for _ in columns]
    pq.write_table(pa.table({name: list(c) for name, c in zip(columns, cols)}), path)
