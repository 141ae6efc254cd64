"""Camera images as the detectors want them: grey uint8 (H, W), from a sensor_msgs/Image (a ROS 2 topic's message
or one read from a bag), a NAOqi camera image (ALVideoDevice.getImageRemote) or a compressed image.

One decoder for every camera: colour turns grey with OpenCV's weights (0.299 R + 0.587 G + 0.114 B), a 16-bit
image is scaled from its full range to 8 bits, rows may be padded (`step`), and YUV 4:2:2 gives its luma. A
message is anything with sensor_msgs/Image's fields (height, width, encoding, is_bigendian, step, data): rclpy's
messages and rosbags' alike. A NAOqi image is the list getImageRemote answers, its colour space named as ROS
names it (NAOQI_COLOR_SPACES) and decoded by the same code; its bytes arrive as `bytes` or, through libqi's
Python bindings, as a `str` of one character per byte.
"""

from __future__ import annotations

from collections.abc import Sequence
from types import SimpleNamespace
from typing import Any

import cv2
import numpy as np

# sensor_msgs/Image encodings read: (channels, dtype); NAOqi's kYUV422 images are yuv422_yuy2.
ENCODINGS: dict[str, tuple[int, str]] = {
    "mono8": (1, "u1"),
    "8UC1": (1, "u1"),
    "mono16": (1, "u2"),
    "16UC1": (1, "u2"),
    "bgr8": (3, "u1"),
    "rgb8": (3, "u1"),
    "8UC3": (3, "u1"),
    "bgra8": (4, "u1"),
    "rgba8": (4, "u1"),
    "8UC4": (4, "u1"),
    "yuv422": (2, "u1"),  # UYVY
    "yuv422_yuy2": (2, "u1"),  # YUYV
}
_TO_GREY = {
    "bgr8": cv2.COLOR_BGR2GRAY,
    "8UC3": cv2.COLOR_BGR2GRAY,
    "rgb8": cv2.COLOR_RGB2GRAY,
    "bgra8": cv2.COLOR_BGRA2GRAY,
    "8UC4": cv2.COLOR_BGRA2GRAY,
    "rgba8": cv2.COLOR_RGBA2GRAY,
    "yuv422": cv2.COLOR_YUV2GRAY_UYVY,
    "yuv422_yuy2": cv2.COLOR_YUV2GRAY_YUY2,
}


def grey_image(msg: Any) -> np.ndarray:
    """The grey uint8 image of a sensor_msgs/Image; ValueError, a sentence, for an encoding not read here or
    data shorter than the size and row step say."""
    encoding = str(msg.encoding)
    if encoding not in ENCODINGS:
        raise ValueError(f"image encoding '{encoding}' is not supported (use one of {', '.join(ENCODINGS)})")
    channels, kind = ENCODINGS[encoding]
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    dtype = np.dtype(kind).newbyteorder(">" if msg.is_bigendian else "<")
    data = _bytes(msg.data)
    row = width * channels * dtype.itemsize
    if step < row or data.size < height * step:
        raise ValueError(
            f"an image of {width} x {height} px ({encoding}, row step {step}) holds only {data.size} bytes"
        )
    rows = data[: height * step].reshape(height, step)[:, :row]
    pixels = np.ascontiguousarray(rows).view(dtype).reshape(height, width, channels)
    if dtype.itemsize == 2:
        pixels = (pixels.astype(np.uint32) // 257).astype(np.uint8)  # full 16-bit scale -> 8 bits
    if channels == 1:
        return np.ascontiguousarray(pixels[:, :, 0])
    return cv2.cvtColor(np.ascontiguousarray(pixels), _TO_GREY[encoding])


# ALVideoDevice's colour spaces read: kYuv (the luma alone), kYUV422 (Y U Y V), kRGB, kBGR.
NAOQI_COLOR_SPACES = {0: "mono8", 9: "yuv422_yuy2", 11: "rgb8", 13: "bgr8"}


def naoqi_image(image: Sequence[Any]) -> tuple[np.ndarray, float]:
    """The grey uint8 image of ALVideoDevice.getImageRemote's answer `[width, height, layers, colorSpace,
    seconds, microseconds, data, ...]` and its time stamp (s, the robot's clock); ValueError, a sentence, for a
    colour space not read here or data that do not fit."""
    if image is None or len(image) < 7:
        raise ValueError("ALVideoDevice gave no image (is the camera subscribed and running?)")
    width, height, layers, space, seconds, micro, data = image[:7]
    if space not in NAOQI_COLOR_SPACES:
        spaces = ", ".join(f"{k} ({v})" for k, v in NAOQI_COLOR_SPACES.items())
        raise ValueError(f"NAOqi colour space {space} is not supported (use one of {spaces})")
    msg = SimpleNamespace(
        height=height, width=width, encoding=NAOQI_COLOR_SPACES[space], is_bigendian=0, step=width * layers, data=data
    )
    return grey_image(msg), float(seconds) + float(micro) * 1e-6


def grey_compressed(data: Any) -> np.ndarray | None:
    """The grey uint8 image of a compressed image's bytes (JPEG, PNG: sensor_msgs/CompressedImage's data), turned
    grey as a raw image is; None when they do not decode."""
    buffer = _bytes(data)
    try:
        image = cv2.imdecode(buffer, cv2.IMREAD_UNCHANGED) if buffer.size else None
    except cv2.error:  # a header that claims more pixels than OpenCV reads (damaged bytes)
        return None
    if image is None:
        return None
    if image.dtype == np.uint16:
        image = (image.astype(np.uint32) // 257).astype(np.uint8)
    if image.ndim == 2:
        return image
    return cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY)


def _bytes(data: Any) -> np.ndarray:
    """A message's byte array (numpy from rosbags; bytes or array.array from rclpy; a str of one character per
    byte from libqi's Python bindings) as uint8, without a copy but for a str."""
    if isinstance(data, str):
        try:
            return np.frombuffer(data.encode("latin-1"), np.uint8)
        except UnicodeEncodeError:
            raise ValueError("the image data are text, not one character per byte") from None
    if isinstance(data, np.ndarray):
        return data.astype(np.uint8, copy=False).ravel()
    return np.frombuffer(data, np.uint8)
