# TEMPORARY re-export (issue 12 wave 1): removed at merge
"""The old names of ``tracker.messages`` (pipeline/cli.py and pipeline/stages.py still import
some; the others keep branches of this wave importable until the merge rewrites them)."""

from tracker._message_checks import check_measurements, check_tracks, check_truth
from tracker.messages import (  # noqa: F401
    MAX_DIAGNOSTICS,
    MAX_MEASUREMENTS,
    MAX_OBJECTS,
    MAX_TRACKS,
    MEASUREMENTS_SCHEMA_VERSION,
    MSG_TYPES,
    SCHEMA_VERSION,
    TOPIC_MEASUREMENTS,
    TOPIC_TRACKS,
    TOPIC_TRUTH,
    TRACKS_SCHEMA_VERSION,
    CodecError,
    MeasurementsMsg,
    TrackMsg,
    TracksMsg,
    TruthMsg,
    TruthObject,
    decode,
    encode,
    from_truth,
    json_schema,
    to_estimate,
    to_frame,
    to_truth,
)
from tracker.messages import decode as decode_msg  # noqa: F401
from tracker.messages import encode as encode_measurements  # noqa: F401  (encode(frame, run))
from tracker.messages import encode as encode_msg  # noqa: F401
from tracker.messages import encode as encode_tracks  # noqa: F401  (encode(est, run))
from tracker.messages import from_estimate as tracks_msg  # noqa: F401
from tracker.messages import from_frame as measurements_msg  # noqa: F401
from tracker.messages import from_truth as truth_msg  # noqa: F401
from tracker.messages import to_estimate as estimate_from_msg  # noqa: F401
from tracker.messages import to_frame as frame_from_msg  # noqa: F401
from tracker.messages import to_truth as truth_from_msg  # noqa: F401


def encode_truth(frame_index, stamp_ns, truth, run=""):
    return encode(from_truth(frame_index, stamp_ns, truth, run))


def decode_measurements_msg(data):
    return decode(TOPIC_MEASUREMENTS, data)


def decode_truth_msg(data):
    return decode(TOPIC_TRUTH, data)


def decode_tracks_msg(data):
    return decode(TOPIC_TRACKS, data)


def decode_measurements(data):
    return to_frame(decode(TOPIC_MEASUREMENTS, data))


def decode_truth(data):
    msg = decode(TOPIC_TRUTH, data)
    return msg.frame, msg.stamp_ns, to_truth(msg)


def decode_tracks(data):
    return to_estimate(decode(TOPIC_TRACKS, data))


def validate_msg(msg):
    checks = {MeasurementsMsg: check_measurements, TruthMsg: check_truth, TracksMsg: check_tracks}
    if type(msg) not in checks:
        raise TypeError(f"not a bnptrack message: {type(msg).__name__}")
    checks[type(msg)](msg)
