"""What a Rerun recording of a run looks like: its entity paths, annotation classes, colours and
sizes (:mod:`sinks.rerun_sink` writes them; the tests read them back).  Does not import rerun.

Entity tree (``world`` is drawn with +y up; positions in metres, world frame)::

    world                      AnnotationContext (class 0 clutter, 1 unassigned, 2.. labels)
    world/sensors/<name>       each sensor at its pose: dot, name, field-of-view wedge (a ring
                               for range-only kinds); logged again when its pose changes
    world/grid                 metric grid (static); world/grid/axes x and y axes, world/grid/ticks
                               tick labels in metres
    world/legend/<what>        legend symbols with their meaning (static, top corners)
    world/measurements         Points2D, coloured by the label they were assigned to
    world/measurements/rings   range-only sensors: one arc per measurement
    world/assignments          LineStrips2D measurement -> assigned track estimate
    world/tracks/<label>       Points2D (position, short name T1, T2, ... in order of
                               confirmation) + LineStrips2D (trail, 2-sigma
                               ellipse); cleared (rr.Clear) when the label ends.  Colour per
                               frame: the track's motion cluster's when it has one, else its label's
    world/clusters             motion clusters with two or more reported members: Points2D at the
                               members' centroid + LineStrips2D centroid -> member
    world/clusters/labels      Points2D "C<id> (n)" above each such cluster's highest member
    world/truth                LineStrips2D grey crosses (when the source has truth)
    world/truth/trails         LineStrips2D thin grey trails of the true objects
    metrics/cardinality        Scalars [estimated, true]
    metrics/ospa               Scalars [total, localisation, cardinality]
    metrics/ospa2              Scalars [total]
    metrics/structure/clusters     Scalars ["motion clusters": distinct motion clusters of the
                                   reported tracks] (from the first frame with a cluster on)
    metrics/structure/cardinality  Scalars [mean, MAP] of the frame's cardinality_pmf
    diagnostics/<key>          Scalars, one per tracker diagnostic (alpha, d, n_clusters: the
                               "hypothesised objects" of the state, reported or not, ...)
    health/<key>               Scalars, pipeline health counters when given
    events                     TextLog: track and truth births and ends
    metadata                   TextDocument: scenario, parameters, tracker, seed, versions
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Iterable, Sequence

__all__ = ["label_color", "cluster_color", "pack_rgba", "unpack_rgba", "PALETTE", "MIN_COLOR_DISTANCE", "SERIES", "DIAG_NAMES"]

# --------------------------------------------------------------------------- entity paths

WORLD = "world"
SENSORS = "world/sensors"
MEASUREMENTS = "world/measurements"
RINGS = "world/measurements/rings"
ASSIGNMENTS = "world/assignments"
TRACKS = "world/tracks"
TRUTH = "world/truth"
TRUTH_TRAILS = "world/truth/trails"
CARDINALITY = "metrics/cardinality"
OSPA = "metrics/ospa"
OSPA2 = "metrics/ospa2"
STRUCTURE = "metrics/structure"
CLUSTER_COUNT = "metrics/structure/clusters"
CARD_POSTERIOR = "metrics/structure/cardinality"
CLUSTERS = "world/clusters"
CLUSTER_LABELS = "world/clusters/labels"
DIAGNOSTICS = "diagnostics"
HEALTH = "health"
EVENTS = "events"
METADATA = "metadata"
GRID = "world/grid"
GRID_TICKS = "world/grid/ticks"
AXES = "world/grid/axes"
LEGEND = "world/legend"

#: Class ids of the annotation context on ``world`` (labels get ids from FIRST_LABEL_CLASS on).
CLUTTER_CLASS = 0
UNASSIGNED_CLASS = 1
FIRST_LABEL_CLASS = 2
MAX_CLASS = 65535  # class ids are uint16

# Colours (RGBA) and sizes; negative radii are screen points (zoom independent).
GREY_CLUTTER = (150, 150, 150, 255)
WHITE_UNASSIGNED = (225, 225, 225, 255)
GREY_TRUTH = (175, 175, 175, 255)
GREY_TRUTH_TRAIL = (175, 175, 175, 110)
SENSOR_COLOR = (240, 200, 80, 255)
R_TRACK = -5.0
R_TRAIL = -1.25
R_ELLIPSE = -1.0
R_MEAS_CLUTTER = -2.0
R_MEAS_ASSIGNED = -3.0
R_ASSIGN_LINE = -0.6
R_TRUTH_CROSS = -1.0
R_TRUTH_TRAIL = -0.6
R_RING = -0.6
R_CLUSTER_CENTRE = -2.5
R_CLUSTER_LINK = -0.9
R_CLUSTER_LABEL = -1.0
#: A cluster's name sits this many truth-cross half-widths (0.0075 of the scene's span each)
#: above its highest member: clear of the members' own names, drawn under them.
CLUSTER_LABEL_LIFT = 4.0
ELLIPSE_SIGMA = 2.0
ELLIPSE_POINTS = 36

#: Series styles: entity -> (names, colours).
SERIES: dict[str, tuple[list[str], list[tuple[int, int, int]]]] = {
    CARDINALITY: (["estimated", "true"], [(80, 170, 255), (190, 190, 190)]),
    OSPA: (["total", "localisation", "cardinality"], [(255, 120, 80), (120, 200, 120), (200, 140, 255)]),
    OSPA2: (["OSPA(2)"], [(255, 200, 60)]),
    CLUSTER_COUNT: (["motion clusters"], [(240, 50, 230)]),
    CARD_POSTERIOR: (["posterior mean", "posterior MAP"], [(80, 170, 255), (120, 220, 60)]),
}
DIAG_NAMES = {
    "alpha": "alpha (concentration)",
    "d": "d (discount)",
    "n_clusters": "hypothesised objects (n_clusters)",
    "n_tracks": "reported tracks",
    "log_joint": "Gibbs log joint",
    "ms": "tracker ms / frame",
}


# --------------------------------------------------------------------------- colours


#: Distinct track colours (RGB, bright on the viewer's dark background): a label takes one at
#: birth and keeps it until it ends.  None is near the colours of the sensor, the truth, clutter
#: or unassigned measurements (RGB distance >= :data:`MIN_COLOR_DISTANCE`: no yellow, cream,
#: pale pink or lavender track that could be read as the sensor or the truth).
PALETTE: tuple[tuple[int, int, int], ...] = (
    (230, 25, 75), (60, 180, 75), (90, 130, 255), (245, 130, 49), (170, 80, 230),
    (66, 212, 244), (240, 50, 230), (70, 200, 180), (255, 120, 120), (120, 220, 60),
    (0, 110, 255),
)
#: Smallest RGB distance between a track colour and the reserved colours (tests check it).
MIN_COLOR_DISTANCE = 75.0


def label_color(label: str, taken: Iterable[tuple[int, ...]] = ()) -> tuple[int, int, int, int]:
    """Colour of a track label: the palette entry picked by the CRC32 of the label, or, when
    that one is ``taken`` by a live label, the next free entry (the least used one if none is).

    Without ``taken`` the result depends on the label alone, in every run and process (no
    ``hash()`` salt); :class:`sinks.rerun_sink.RerunSink` passes the colours of the live labels at birth, so that
    labels alive together differ, and keeps the colour for the label's whole life.
    """
    n = len(PALETTE)
    start = zlib.crc32(label.encode("utf-8")) % n
    used: dict[tuple[int, int, int], int] = {}
    for rgba in taken:
        key = tuple(rgba[:3])
        used[key] = used.get(key, 0) + 1  # type: ignore[index]
    best = min(range(n), key=lambda i: (used.get(PALETTE[(start + i) % n], 0), i))
    return (*PALETTE[(start + best) % n], 255)


def cluster_color(cluster: int, taken: Iterable[tuple[int, ...]] = ()) -> tuple[int, int, int, int]:
    """Colour of motion cluster ``cluster``: the :data:`PALETTE` entry (never a reserved colour)
    farthest in RGB from the nearest of the ``taken`` colours, so that clusters alive together
    contrast (two greens side by side read as one group); ties go to the palette order
    starting at ``cluster mod len(PALETTE)`` (without ``taken``: that entry)."""
    n = len(PALETTE)
    order = [PALETTE[(int(cluster) + i) % n] for i in range(n)]
    used = [tuple(c[:3]) for c in taken]

    def spread(i: int) -> tuple[float, int]:
        return min((math.dist(order[i], u) for u in used), default=math.inf), -i

    return (*order[max(range(n), key=spread)], 255)


def pack_rgba(rgba: Sequence[int]) -> int:
    r, g, b, a = (list(rgba) + [255])[:4]
    return (int(r) << 24) | (int(g) << 16) | (int(b) << 8) | int(a)


def unpack_rgba(packed: int) -> tuple[int, int, int, int]:
    return (packed >> 24) & 255, (packed >> 16) & 255, (packed >> 8) & 255, packed & 255

