"""APS frames of a colour DAVIS: the Bayer mosaic demosaiced to the grey image necviz works with.

A colour DAVIS346 delivers one 10-bit sample per pixel through a colour filter; libcaer (github.com/
inivation/libcaer, ``src/davis_common.h``, the frame-end case of ``davisCommonEventTranslator``) demosaics
it, in its grey frame mode with ``DEMOSAIC_OPENCV_TO_GRAY`` (``src/frame_utils_opencv.cpp``,
``caerFrameUtilsOpenCVDemosaic``): the filter's layout, shifted to the colour of the ROI's first pixel
(``caerFrameUtilsPixelColor``, ``src/frame_utils.c``), picks OpenCV's Bayer-to-grey conversion, run on the
16-bit samples (``Z10 << 6``). necviz does the same with OpenCV (its demosaicing is what libcaer calls) and
keeps the 8 most significant bits, as it does for a grey sensor (``Z8 = Z10 >> 2``).

Colour filter codes (APS register ``COLOR_FILTER``, libcaer's ``enum caer_frame_event_color_filter``):
0 mono, 1 RGBG, 2 GRGB, 3 GBGR, 4 BGRG (Bayer), 5..8 RGBW, GRWB, WBGR, BWRG (white instead of the second
green). libcaer's OpenCV path does not handle the RGBW variants; necviz leaves their mosaic as it is.
"""

from __future__ import annotations

import cv2
import numpy as np

#: colour filter code -> its name (libcaer's enum caer_frame_event_color_filter)
COLOR_FILTERS = {0: "mono", 1: "RGBG", 2: "GRGB", 3: "GBGR", 4: "BGRG", 5: "RGBW", 6: "GRWB", 7: "WBGR", 8: "BWRG"}

#: colour of the pixel at (x, y) for each filter, indexed ``(x & 1) << 1 | (y & 1)`` (libcaer's colorKeys);
#: R, G1, G2, B as "R", "G", "g", "B", white as "W"
PIXEL_COLORS = {
    1: ("R", "g", "G", "B"),
    2: ("G", "B", "R", "g"),
    3: ("g", "R", "B", "G"),
    4: ("B", "G", "g", "R"),
    5: ("R", "W", "G", "B"),
    6: ("G", "B", "R", "W"),
    7: ("W", "R", "B", "G"),
    8: ("B", "G", "W", "R"),
}

#: colour of a Bayer frame's first pixel -> OpenCV's Bayer-to-grey code (libcaer's DEMOSAIC_OPENCV_TO_GRAY table:
#: a first pixel R is its RGBG, G1 its GRGB, G2 its GBGR, B its BGRG)
_TO_GRAY = {
    "R": cv2.COLOR_BayerBG2GRAY,
    "G": cv2.COLOR_BayerGB2GRAY,
    "g": cv2.COLOR_BayerGR2GRAY,
    "B": cv2.COLOR_BayerRG2GRAY,
}


def pixel_color(color_filter: int, x: int, y: int) -> str:
    """Colour of pixel ``(x, y)`` (sensor coordinates) under ``color_filter``."""
    return PIXEL_COLORS[color_filter][(x & 1) << 1 | (y & 1)]


def is_bayer(color_filter: int) -> bool:
    """Whether frames of this filter are demosaiced (the four Bayer layouts)."""
    return color_filter in (1, 2, 3, 4)


def demosaic_to_gray8(z10: np.ndarray, color_filter: int, x0: int = 0, y0: int = 0) -> np.ndarray:
    """The 8-bit grey image of a Bayer mosaic of 10-bit values whose first pixel is at ``(x0, y0)``.

    ``z10`` (H x W, any integer type, values 0..1023) is demosaiced as libcaer does: scaled to 16 bits
    (``<< 6``), converted with OpenCV's Bayer-to-grey code of the first pixel's colour, then ``>> 8``.
    A mosaic smaller than 2 x 2 or a non-Bayer filter is returned as ``z10 >> 2``.
    """
    z = np.asarray(z10)
    if not is_bayer(color_filter) or min(z.shape) < 2:
        return (z >> 2).astype(np.uint8)
    code = _TO_GRAY[pixel_color(color_filter, x0, y0)]
    gray16 = cv2.cvtColor(np.ascontiguousarray(z.astype(np.uint16) << 6), code)
    return (gray16 >> 8).astype(np.uint8)


__all__ = ["COLOR_FILTERS", "PIXEL_COLORS", "demosaic_to_gray8", "is_bayer", "pixel_color"]
