"""Observe's 2-D view: the latest settled look's image with what the finder found in it (vision, red) and where
the active calibration predicts the target (blue), as the Review's split view draws a frame. The image travels
in the answer (a JPEG data URL) so that it and its marks are always of the same look."""

from __future__ import annotations

import base64
from typing import TypedDict

import numpy as np

from calib_core import Profile
from calib_core.vision import predicted_points

from ..drivers import Look
from .review import image_pixels

JPEG_QUALITY = 85


class LookView(TypedDict):
    """The data sensor's sighting of a look as the 2-D view draws it (the API's LiveLook): `image` a JPEG data URL
    (None: the sensor takes no image), `measured` and `predicted` [u, v] px per point (None where a point has no
    pixel; predicted None without the camera's pose), `look` its count since Observe began."""

    look: int
    sensor: str
    target: str
    status: str
    reason: str
    width: int | None
    height: int | None
    image: str | None
    measured: list[list[float] | None] | None
    predicted: list[list[float] | None] | None


def look_view(profile: Profile, look: Look, p: np.ndarray | None, number: int) -> LookView:
    """The data sensor's sighting of `look` (number `number`) in 2-D; its prediction with parameters `p` (None:
    while the camera's pose is not known yet)."""
    sighting = look.sightings[0]
    sensor = profile.sensors[sighting.sensor]
    image = next((look.images[r] for r in sensor.image_roles if r in look.images), None)
    predicted = None
    if p is not None:
        predicted = sensor.project(p, predicted_points(profile, p, look.readings_rad, sighting.target, sighting.sensor))
    measured = (
        None
        if sighting.measured is None
        else sensor.measured_pixels(profile.nominal() if p is None else p, sighting.measured)
    )
    height, width = image.shape[:2] if image is not None else (None, None)
    return LookView(
        look=number,
        sensor=sensor.name,
        target=profile.targets[sighting.target].name,
        status=str(sighting.status),
        reason=sighting.reason,
        width=width,
        height=height,
        image=None if image is None else _jpeg(image),
        measured=None if measured is None else image_pixels(measured),
        predicted=None if predicted is None else image_pixels(predicted),
    )


def _jpeg(image: np.ndarray) -> str:
    import cv2  # only when a look is asked for: the desk starts without OpenCV

    ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise ValueError("the look's image could not be encoded")
    return "data:image/jpeg;base64," + base64.b64encode(data.tobytes()).decode("ascii")
