# TEMPORARY re-export (issue 12 wave 1): removed at merge
from tracker.bnp.assignment import best_permutation, best_permutation_pairs  # noqa: F401
from tracker.bnp.clusters import _Clusters, _near_pairs, merge_duplicates  # noqa: F401
from tracker.bnp.config import TRACKER_PRESETS, BnpConfig  # noqa: F401
from tracker.bnp.filter import (BnpState, BnpTracker, _capped_warned, _moment_match, _Prediction,  # noqa: F401
                                make_tracker)
