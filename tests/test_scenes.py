"""Built-in scenes: calibrated in the cd/m2 they document."""

import numpy as np
import pytest

from jaxadapt import scenes
from jaxadapt.color import photopic_luminance


@pytest.mark.parametrize("size", [(480, 320), (120, 80)])
def test_interior_with_window_is_calibrated_in_cd_m2(size):
    rgb, labels = scenes.interior_with_window(*size)
    assert rgb.shape == (size[1], size[0], 3) and rgb.dtype == np.float32
    assert labels.shape == rgb.shape[:2]
    L = np.asarray(photopic_luminance(rgb))
    fy = np.broadcast_to((np.arange(size[1]) / size[1])[:, None], labels.shape)
    fx = np.broadcast_to(np.arange(size[0]) / size[0], labels.shape)
    room, outside = L[labels == scenes.ROOM], L[labels == scenes.OUTSIDE]
    assert room.min() >= 1.6 and room.max() <= 53.0
    np.testing.assert_allclose(L[labels == scenes.FRAME], 15.0, rtol=1e-5)
    sky = (labels == scenes.OUTSIDE) & (fy < 0.3)
    assert L[sky].min() >= 4800.0 and L[sky].max() <= 5520.0
    shaded = (labels == scenes.OUTSIDE) & ~sky & (fx < 0.6)
    sunlit = (labels == scenes.OUTSIDE) & ~sky & (fx >= 0.6)
    np.testing.assert_allclose([L[shaded].min(), L[shaded].max()], [1200.0, 1500.0], rtol=1e-5)
    np.testing.assert_allclose([L[sunlit].min(), L[sunlit].max()], [1.6e4, 2e4], rtol=1e-5)
    assert outside.max() == pytest.approx(2e4, rel=1e-5)
