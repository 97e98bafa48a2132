"""First-compile CPU of the two-level model's object -> cluster Gibbs kernels, this checkout against
another one (``--base DIR``), alternately.

Each run is a fresh process with an empty kernel cache (``NUMBA_CACHE_DIR`` a new temporary
folder) that calls ``sample_partition`` once (``--kernel``, default the gated one) on seed-pinned
inputs (30 objects, 8 transitioned clusters, both theta blocks) and records every numba
compilation's thread CPU time minus the compilations nested in it (numba's ``numba:compile``
events), as ``compile_times.py`` does for a whole run.  ``compile_times.py`` does not see these
kernels: on a first ``bnptrack track`` the second compiling process compiles them.  Prints per
round the CPU seconds of the ``group_*`` kernels on each side and their ratio, then each kernel's
mean over the rounds, and whether both sides drew the same sample::

    python3 benchmarks/group_compile_ab.py --base /tmp/base --rounds 4
"""

from __future__ import annotations

import argparse
import collections
import os
import sys
import tempfile
import time
from pathlib import Path

HERE = str(Path(__file__).resolve().parents[1])
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _ab import last_json_line  # noqa: E402
from compile_times import listen_to_compilations  # noqa: E402


def child(kernel: str) -> dict:
    """One ``sample_partition`` call with the compilation listener; the compilations and the sample."""
    import numpy as np

    from bnptrack.tracker.numerics import import_numba

    import_numba()
    compiled = listen_to_compilations()
    from bnptrack.tracker.bnp.group_sample import Block, sample_partition

    rng = np.random.default_rng(1)
    L, G = 30, 8

    def spd(n: int, s: float) -> np.ndarray:
        a = rng.normal(0, 1, (n, 2, 2))
        return s * (np.einsum("nij,nkj->nik", a, a) + np.eye(2))

    blocks = [Block(rng.normal(0, 5, (L, 2)), spd(L, 2.0), rng.normal(0, 5, (G, 2)), spd(G, 3.0), np.zeros(2),
                    100 * np.eye(2)),
              Block(rng.normal(0, 50, (L, 2)), spd(L, 20.0), rng.normal(0, 50, (G, 2)), spd(G, 30.0), np.zeros(2),
                    1e4 * np.eye(2))]
    z, shares = sample_partition(rng, blocks, np.ones(G), 1.0, 0.2, -np.ones(L, dtype=np.int64), 5, kernel=kernel)
    return {"rows": [(r["name"], r["self"]) for r in compiled], "sample": [z.tolist(), shares.w.tolist()]}


def _run(root: str, kernel: str) -> dict:
    with tempfile.TemporaryDirectory() as cache:
        os.environ["NUMBA_CACHE_DIR"] = cache  # inherited by the child (last_json_line copies os.environ)
        try:
            return last_json_line([sys.executable, os.path.join(HERE, "benchmarks", Path(__file__).name), "--child",
                                   "--kernel", kernel], root)
        finally:
            del os.environ["NUMBA_CACHE_DIR"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", required=False, help="the other checkout")
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--kernel", default="gated", choices=("scan", "urn", "gated"))
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        import json

        print(json.dumps(child(args.kernel)))
        return
    if not args.base:
        ap.error("--base DIR is required")
    base = os.path.abspath(args.base)
    per = {base: collections.defaultdict(float), HERE: collections.defaultdict(float)}
    print("| round | base group_* CPU s | this tree group_* CPU s | ratio | same sample |")
    print("|---|---|---|---|---|")
    for r in range(1, args.rounds + 1):
        order = (base, HERE) if r % 2 else (HERE, base)
        res = {root: _run(root, args.kernel) for root in order}
        tot = {}
        for root, out in res.items():
            tot[root] = sum(s for name, s in out["rows"] if ".group_" in name)
            for name, s in out["rows"]:
                if ".group_" in name:
                    per[root][name] += s / args.rounds
        same = "yes" if res[base]["sample"] == res[HERE]["sample"] else "NO"
        print(f"| {r} | {tot[base]:.2f} | {tot[HERE]:.2f} | {tot[HERE] / tot[base]:.3f} | {same} |", flush=True)
    print("\nmean CPU s per kernel (base, this tree):")
    for name in sorted(set(per[base]) | set(per[HERE]), key=lambda n: -per[base].get(n, 0.0) - per[HERE].get(n, 0.0)):
        print(f"  {per[base].get(name, 0.0):6.2f} {per[HERE].get(name, 0.0):6.2f}  {name}")


if __name__ == "__main__":
    main()
