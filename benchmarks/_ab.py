"""Shared by the A/B benchmarks that time this checkout against another one (``--base``)."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess


def last_json_line(cmd: list[str], root: str) -> dict:
    """Run ``cmd`` in the checkout ``root`` (its code first on ``PYTHONPATH``) and return the JSON
    object its last line of standard output holds."""
    out = subprocess.run(cmd, cwd=root, env={**os.environ, "PYTHONPATH": root}, check=True,
                         capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


#: The per-frame series of an experiment run that a fingerprint covers (everything but the timings).
SERIES = ("ospa", "ospa_loc", "ospa_card", "ospa2", "gospa", "n_est")


def fingerprint(results) -> str:
    """SHA-256 (first 16 hex digits) of every run's per-frame series except the timings
    (``RunResult.n_true`` and, per tracker label in order, :data:`SERIES` as float64 bytes)."""
    import numpy as np

    h = hashlib.sha256()
    for r in results:
        h.update(r.n_true.tobytes())
        for label, tr in sorted(r.trackers.items()):
            h.update(label.encode())
            for name in SERIES:
                h.update(np.ascontiguousarray(getattr(tr, name), dtype=float).tobytes())
    return h.hexdigest()[:16]
