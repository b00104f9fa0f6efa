"""Image files as training reads them: EXIF orientation honoured (a phone's JPEG shown turned)."""

import numpy as np
import pytest

from va_plugin.data.dataparsers import image_shape
from va_plugin.data.images import read_image


def test_a_jpeg_is_turned_as_its_exif_orientation_says(tmp_path):
    image_module = pytest.importorskip("PIL.Image", reason="Pillow writes the EXIF block of the test file")
    pixels = np.zeros((20, 40, 3), np.uint8)
    pixels[:, :10] = 255  # a white band on the left of a wide picture
    picture = image_module.fromarray(pixels)
    exif = picture.getexif()
    exif[0x0112] = 6  # "turn 90 degrees clockwise to show": the band comes on top
    picture.save(tmp_path / "turned.jpg", exif=exif.tobytes())
    picture.save(tmp_path / "plain.jpg")
    turned, plain = read_image(tmp_path / "turned.jpg"), read_image(tmp_path / "plain.jpg")
    assert plain.shape == (20, 40, 3) and plain[:, :5].mean() > 0.9
    assert turned.shape == (40, 20, 3) and turned[:5].mean() > 0.9 and turned[-5:].mean() < 0.1
    assert image_shape(tmp_path / "turned.jpg") == (40, 20)
