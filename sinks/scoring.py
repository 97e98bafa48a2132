# TEMPORARY re-export (issue 12 wave 1): removed at merge
from sinks.metrics import OSPA2_WINDOW, OSPA_C, OSPA_P, RunScorer, ScoreTally  # noqa: F401
