"""The Rerun entity schema: every path necviz logs, in one place.

What every lane of a source shares is logged once, at the root; each camera/controller lane
``NAME`` (``nec``, ``navid``, …; ``camera`` for ``live`` and ``replay``) owns a subtree:

================================  =============================  ================================
path                              archetype                      meaning
================================  =============================  ================================
``events``                        EncodedImage (paletted PNG,    events of the last window, ON blue,
                                  lossless)                      OFF red (shared by all lanes)
``events/points``                 Points2D (optional, capped)    raw events of the window
``event_rate``                    Scalars                        events/s over the event window
``NAME/frame``                    EncodedImage (JPEG, grey)      the APS frame, at exposure start
``NAME/irradiance/predicted``     Scalars                        P-TEDI ln P(t), every few ms
``NAME/irradiance/frame``         Scalars                        frame-measured ln Pbar, per frame
``NAME/exposure/commanded``       Scalars                        commanded exposure, µs (from the
                                                                 setting the run started with)
``NAME/exposure/applied``         Scalars                        exposure of each frame, µs
``NAME/gain/commanded``           Scalars                        commanded gain (linear)
``NAME/gain/applied``             Scalars                        gain of each frame (linear)
``NAME/over_exposed_rate``        Scalars                        fraction of pixels >= 250 DN
``NAME/under_exposed_rate``       Scalars                        fraction of pixels <= 9 DN
``NAME/saturated``                Scalars (points)               marker at each frame > 50 %
                                                                 saturated (value: that fraction)
``NAME/latency_us``               Scalars                        processing latency of each
                                                                 command (packet in -> command out)
``NAME/prediction_error``         Scalars                        predicted − measured ln Pbar
``NAME/prediction_error/          Scalars                        "same as the last frame" −
persistence``                                                    measured ln Pbar (frames only)
``NAME/prediction_skill``         Scalars                        P-TEDI's skill score against
                                                                 persistence so far:
                                                                 1 − MSE_ptedi / MSE_persistence
``NAME/truth/valid_fraction``     Scalars                        simulated frames only: fraction of
                                                                 pixels whose true irradiance was
                                                                 recorded inside 10..249 DN
``NAME/truth/rank_correlation``   Scalars                        simulated frames only: Spearman's ρ
                                                                 of the digits against the true
                                                                 irradiance on valid pixels
``NAME/log``                      TextLog                        saturated frames (with the diagnosed
                                                                 cause), controller switches
``tuning``                        TextLog                        every live parameter change
================================  =============================  ================================

Timelines: ``t`` (sensor time, seconds, as a duration) and ``frame`` (the lane's newest frame
number at that moment; for the shared events, the first lane's) on everything, so every view
shows data on either timeline. Run settings (scenario or file, controllers, camera profile) are
recording properties (``rr.send_property``).
"""

from __future__ import annotations

#: Sensor-time timeline (duration, seconds) and frame-number timeline (sequence).
TIME = "t"
FRAME = "frame"

# shared by every lane (root entities)
EVENTS = "events"
EVENT_POINTS = "events/points"
EVENT_RATE = "event_rate"
TUNING = "tuning"
#: the camera's DVS settings after each bias change (``dvs/c_on``, ``dvs/c_off``, ``dvs/refractory_us``,
#: ``dvs/bandwidth_hz``; the bias model's values, :mod:`necviz.dvs_controls`)
DVS = "dvs"
DVS_SERIES = ("c_on", "c_off", "refractory_us", "bandwidth_hz")

# per lane (under NAME/)
FRAME_IMAGE = "frame"
IRRADIANCE_PREDICTED = "irradiance/predicted"
IRRADIANCE_FRAME = "irradiance/frame"
EXPOSURE_COMMANDED = "exposure/commanded"
EXPOSURE_APPLIED = "exposure/applied"
GAIN_COMMANDED = "gain/commanded"
GAIN_APPLIED = "gain/applied"
OVER_EXPOSED = "over_exposed_rate"
UNDER_EXPOSED = "under_exposed_rate"
SATURATED = "saturated"
LATENCY = "latency_us"
PREDICTION_ERROR = "prediction_error"
PERSISTENCE_ERROR = "prediction_error/persistence"
PREDICTION_SKILL = "prediction_skill"
LOG = "log"
#: the thresholds P-TEDI uses, from the packet where a DVS bias change took effect (``LANE/ptedi/c_on``, ...)
PTEDI_C_ON = "ptedi/c_on"
PTEDI_C_OFF = "ptedi/c_off"
# ground truth of simulated frames (see necviz.core.metrics); absent for cameras and recordings
TRUE_VALID = "truth/valid_fraction"
RANK_CORRELATION = "truth/rank_correlation"

#: Root entities of every recording that has seen an event window.
SHARED_ENTITIES = (EVENTS, EVENT_RATE)
#: Entities every lane has once it has seen a frame (tests check them).
#: ``latency_us`` exists once the controller has issued a command in response to a packet.
LANE_ENTITIES = (
    FRAME_IMAGE,
    IRRADIANCE_PREDICTED,
    IRRADIANCE_FRAME,
    EXPOSURE_COMMANDED,
    EXPOSURE_APPLIED,
    GAIN_COMMANDED,
    GAIN_APPLIED,
    OVER_EXPOSED,
    UNDER_EXPOSED,
)


def path(lane: str, leaf: str) -> str:
    """The entity path of ``leaf`` in lane ``lane`` (e.g. ``path("nec", EXPOSURE_COMMANDED)``)."""
    return f"{lane}/{leaf}"
