"""Shared by the A/B benchmarks that time this checkout against another one (``--base``)."""

from __future__ import annotations

import json
import os
import subprocess


def last_json_line(cmd: list[str], root: str) -> dict:
    """Run ``cmd`` in the checkout ``root`` (its code first on ``PYTHONPATH``) and return the JSON
    object its last line of standard output holds."""
    out = subprocess.run(cmd, cwd=root, env={**os.environ, "PYTHONPATH": root}, check=True,
                         capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])
