"""Camera images as the detectors want them: grey uint8 (H, W), from a sensor_msgs/Image (a ROS 2 topic's message
or one read from a bag) or a compressed image.

One decoder for every camera: colour turns grey with OpenCV's weights (0.299 R + 0.587 G + 0.114 B), a 16-bit
image is scaled from its full range to 8 bits, rows may be padded (`step`), and YUV 4:2:2 gives its luma. A
message is anything with sensor_msgs/Image's fields (height, width, encoding, is_bigendian, step, data): rclpy's
messages and rosbags' alike.
"""

from __future__ import annotations

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


def grey_compressed(data: Any) -> np.ndarray | None:
    """The grey uint8 image of a compressed image's bytes (JPEG, PNG: sensor_msgs/CompressedImage's data), turned
    grey as a raw image is; None when they do not decode."""
    buffer = _bytes(data)
    image = cv2.imdecode(buffer, cv2.IMREAD_UNCHANGED) if buffer.size else None
    if image is None:
        return None
    if image.dtype == np.uint16:
        image = (image.astype(np.uint32) // 257).astype(np.uint8)
    if image.ndim == 2:
        return image
    return cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY)


def _bytes(data: Any) -> np.ndarray:
    """A message's byte array (numpy from rosbags; bytes or array.array from rclpy) as uint8, without a copy."""
    if isinstance(data, np.ndarray):
        return data.astype(np.uint8, copy=False).ravel()
    return np.frombuffer(data, np.uint8)
