"""The economy of decoded Gaussians (reconstruct / generate): static cells of one model-image pixel. What it keeps on
the shipped decoder is measured in test_models_weights.py (test_decoded_cells_keep_the_decoders_detail)."""

import math

import pytest

from worldsplat.gaussians.aggregate import DECODED_CELL_MODEL_PX, Economy


def test_for_decoded_scales_with_the_model_pixel_and_rejects_a_bad_one():
    assert Economy.for_decoded(1.0).cell_factor == pytest.approx(DECODED_CELL_MODEL_PX)
    assert Economy.for_decoded(1.75).cell_factor == pytest.approx(1.75 * DECODED_CELL_MODEL_PX)
    for bad in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(ValueError, match="model_px"):
            Economy.for_decoded(bad)


def test_the_cell_follows_the_model_image_on_the_served_image():
    from worldsplat.pipeline.inference import decoded_economy

    # the models' 112-pixel-wide image: one model pixel is 1 pixel of a 112-wide render, 200/112 of the playground's
    assert decoded_economy(112, 112, "decoder").cell_factor == pytest.approx(DECODED_CELL_MODEL_PX)
    assert decoded_economy(112, 200, "decoder").cell_factor == pytest.approx(200 / 112 * DECODED_CELL_MODEL_PX)
    # Gaussians lifted per pixel of the served image are the oracle's kind: the oracle's economy
    assert decoded_economy(112, 200, "pixels") == Economy()
