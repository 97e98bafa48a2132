# TEMPORARY re-export (issue 12 wave 1): removed at merge
"""The old names of ``tracker.messages`` that pipeline/cli.py and pipeline/stages.py still import."""

from tracker.messages import (  # noqa: F401
    MSG_TYPES,
    TOPIC_MEASUREMENTS,
    TOPIC_TRACKS,
    TOPIC_TRUTH,
    CodecError,
    json_schema,
)
from tracker.messages import decode as decode_msg  # noqa: F401
from tracker.messages import encode as encode_measurements  # noqa: F401  (encode(frame, run))
from tracker.messages import encode as encode_tracks  # noqa: F401  (encode(est, run))
from tracker.messages import from_truth as _from_truth
from tracker.messages import encode as _encode
from tracker.messages import to_estimate as estimate_from_msg  # noqa: F401
from tracker.messages import to_frame as frame_from_msg  # noqa: F401
from tracker.messages import to_truth as truth_from_msg  # noqa: F401


def encode_truth(frame_index, stamp_ns, truth, run=""):  # encode(from_truth(...))
    return _encode(_from_truth(frame_index, stamp_ns, truth, run))
