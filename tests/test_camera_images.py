"""The one camera image decoder (calib_core.io.camera_images) that the ROS 2 driver and the bag importer share:
every encoding it reads gives OpenCV's grey of the same picture (not the channels' mean), padded rows, either
byte order, the message's data as numpy (rosbags), bytes or array.array (rclpy); an unknown encoding and short
data are a sentence."""

from __future__ import annotations

import array
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from calib_core.io.camera_images import ENCODINGS, grey_compressed, grey_image

H, W = 24, 32


def _bgr() -> np.ndarray:
    """A colour picture whose channels differ, so that the grey weights matter."""
    y, x = np.mgrid[0:H, 0:W]
    return np.dstack([(7 * x) % 256, (11 * y + 3 * x) % 256, (5 * x + 13 * y) % 256]).astype(np.uint8)


def _yuv422(bgr: np.ndarray, order: str) -> np.ndarray:
    """Packed 4:2:2 (2 bytes a pixel) whose luma is OpenCV's grey of the picture, chroma varying."""
    luma = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    chroma = np.empty_like(luma)
    chroma[:, 0::2] = bgr[:, 0::2, 0]  # U: anything but the luma
    chroma[:, 1::2] = bgr[:, 1::2, 2]  # V
    pair = [chroma, luma] if order == "uyvy" else [luma, chroma]
    return np.dstack(pair)


def _pixels(encoding: str, bgr: np.ndarray) -> np.ndarray:
    rgb = bgr[:, :, ::-1]
    alpha = np.full((H, W, 1), 200, np.uint8)
    grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    return {
        "mono8": grey,
        "8UC1": grey,
        "mono16": grey.astype(np.uint16) * 257,
        "16UC1": grey.astype(np.uint16) * 257,
        "bgr8": bgr,
        "8UC3": bgr,
        "rgb8": rgb,
        "bgra8": np.concatenate([bgr, alpha], axis=2),
        "8UC4": np.concatenate([bgr, alpha], axis=2),
        "rgba8": np.concatenate([rgb, alpha], axis=2),
        "yuv422": _yuv422(bgr, "uyvy"),
        "yuv422_yuy2": _yuv422(bgr, "yuyv"),
    }[encoding]


def _message(encoding: str, pixels: np.ndarray, *, big_endian: bool = False, pad: int = 6, data_as=np.asarray):
    wide = pixels.astype(pixels.dtype.newbyteorder(">" if big_endian else "<"))
    raw = np.ascontiguousarray(wide).view(np.uint8).reshape(H, -1)
    step = raw.shape[1] + pad  # rows padded, as some drivers do
    data = np.zeros((H, step), np.uint8)
    data[:, : raw.shape[1]] = raw
    return SimpleNamespace(
        height=H, width=W, encoding=encoding, is_bigendian=int(big_endian), step=step, data=data_as(data.ravel())
    )


@pytest.mark.parametrize("encoding", list(ENCODINGS))
def test_every_encoding_gives_opencvs_grey_of_the_picture(encoding: str) -> None:
    bgr = _bgr()
    expected = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    image = grey_image(_message(encoding, _pixels(encoding, bgr)))
    assert image.dtype == np.uint8 and image.shape == (H, W)
    assert np.array_equal(image, expected), np.abs(image.astype(int) - expected).max()
    if ENCODINGS[encoding][0] >= 3:  # the channels' plain mean (what the ROS 2 driver used to take) differs
        assert np.abs(bgr.mean(axis=2).astype(np.uint8).astype(int) - expected).max() > 10


@pytest.mark.parametrize("data_as", [bytes, lambda a: array.array("B", a.tobytes())], ids=["bytes", "array"])
def test_rclpy_data_and_either_byte_order_decode_alike(data_as) -> None:
    bgr = _bgr()
    expected = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    assert np.array_equal(grey_image(_message("rgb8", _pixels("rgb8", bgr), data_as=data_as)), expected)
    for big in (False, True):
        assert np.array_equal(grey_image(_message("mono16", _pixels("mono16", bgr), big_endian=big)), expected)


def test_an_unknown_encoding_or_short_data_is_a_sentence() -> None:
    msg = _message("mono8", _pixels("mono8", _bgr()))
    msg.encoding = "bayer_rggb8"
    with pytest.raises(ValueError, match=r"^image encoding 'bayer_rggb8' is not supported \(use one of mono8, "):
        grey_image(msg)
    msg = _message("rgb8", _pixels("rgb8", _bgr()))
    msg.data = msg.data[: msg.step * (H - 1)]
    with pytest.raises(ValueError, match=rf"^an image of {W} x {H} px \(rgb8, row step 102\) holds only 2346 bytes$"):
        grey_image(msg)


def test_compressed_images_decode_grey_and_junk_is_none() -> None:
    grey = cv2.cvtColor(_bgr(), cv2.COLOR_BGR2GRAY)
    ok, png = cv2.imencode(".png", _bgr())
    assert ok
    assert np.array_equal(grey_compressed(png.ravel()), grey)
    assert np.array_equal(grey_compressed(png.tobytes()), grey)
    assert grey_compressed(b"not an image") is None and grey_compressed(b"") is None
