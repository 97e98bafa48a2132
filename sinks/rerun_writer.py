# TEMPORARY re-export (issue 12 wave 1): removed at merge
from sinks.rerun_process import CHILD_FLUSH_INTERVAL, RecordingError, RecordingProcess  # noqa: F401
