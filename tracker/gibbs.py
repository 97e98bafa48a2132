# TEMPORARY re-export (issue 12 wave 1): removed at merge
from tracker.bnp.gibbs import CLUTTER, NEW, GibbsProblem, log_joint, run_gibbs  # noqa: F401
