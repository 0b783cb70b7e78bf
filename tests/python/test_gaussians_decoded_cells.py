"""The economy of decoded Gaussians (reconstruct / generate): cells of half a decoder-grid pitch. What it keeps on the
shipped decoder is measured in test_models_weights.py (test_decoded_cells_keep_the_decoders_detail)."""

import math

import pytest

from worldsplat.gaussians.aggregate import DECODED_CELL_PITCH, Economy


def test_for_decoded_scales_with_the_grid_pitch_and_rejects_a_bad_one():
    assert Economy.for_decoded(2.0).cell_factor == pytest.approx(2.0 * DECODED_CELL_PITCH)
    assert Economy.for_decoded(3.5).cell_factor == pytest.approx(3.5 * DECODED_CELL_PITCH)
    for bad in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(ValueError, match="pitch_px"):
            Economy.for_decoded(bad)


def test_the_pitch_comes_from_the_decoders_grid_on_the_served_image():
    from worldsplat.pipeline.inference import decoded_economy

    # 32x56 Gaussians per view: 2 px at the 112x64 model image, ~3.54 px on the playground's 200x112
    assert decoded_economy(32 * 56, 112, 64).cell_factor == pytest.approx(2.0 * DECODED_CELL_PITCH)
    assert decoded_economy(32 * 56, 200, 112).cell_factor == pytest.approx(
        math.sqrt(200 * 112 / 1792) * DECODED_CELL_PITCH
    )
