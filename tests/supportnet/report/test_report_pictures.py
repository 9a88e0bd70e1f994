"""Picture helpers: colour bars under maps, colour names captions can rely on."""

from __future__ import annotations

import numpy as np
import pytest

from supportnet.report.pictures import (
    colour_bar,
    colour_bar_height,
    colour_name,
    colourise,
    depth_bar,
    map_picture,
    named_colours,
    tag,
)


@pytest.mark.parametrize(
    ("rgb", "name"),
    [
        (colourise(np.array([0.0]))[0], "purple"),  # viridis' low end (68, 1, 84)
        (colourise(np.array([1.0]))[0], "yellow"),  # viridis' high end
        (colourise(np.array([1.0]), "turbo")[0], "red"),
        (colourise(np.array([0.1]), "turbo")[0], "blue"),
        ((214, 39, 40), "red"),  # matplotlib tab:red
        ((153, 153, 153), "grey"),  # matplotlib "0.6"
        ((31, 119, 180), "blue"),  # matplotlib C0
        ((255, 127, 14), "orange"),  # matplotlib C1
        ((0, 0, 0), "black"),
        ((255, 255, 255), "white"),
    ],
)
def test_colour_names(rgb, name):
    assert colour_name(rgb) == name


def test_a_map_picture_carries_its_colour_bar():
    values = np.linspace(0, 1, 40 * 300).reshape(40, 300)
    picture = map_picture(values, "support")
    bar = colour_bar_height(300)
    assert picture.shape == (40 + bar, 300, 3)
    np.testing.assert_array_equal(picture[:40], colourise(values))
    strip = picture[40:]
    assert {"purple", "yellow", "black", "white"} <= named_colours(strip, min_pixels=3)
    # the ramp runs from the map's low end (left) to its high end (right)
    row = strip[bar // 4]
    ramp = row[(row != 255).any(axis=1) & (row != 0).any(axis=1)]
    assert colour_name(ramp[1]) == "purple" and colour_name(ramp[-2]) == "yellow"


def test_bars_and_tags_keep_the_width():
    assert colour_bar(
        200, "viridis", "0", "1", "a title far too long to fit in a strip this narrow"
    ).shape == (
        colour_bar_height(200),
        200,
        3,
    )
    assert depth_bar(1242).shape == (colour_bar_height(1242), 1242, 3)
    image = np.full((50, 120, 3), 128, np.uint8)
    tagged = tag(image, "before")
    assert tagged.shape == image.shape and (tagged[:3, :3] == 0).all() and (image == 128).all()
