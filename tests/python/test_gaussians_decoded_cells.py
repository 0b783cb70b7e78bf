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
    # Gaussians lifted per pixel of the served image: the oracle's economy with the decoded depths' tolerance
    assert decoded_economy(112, 200, "pixels") == Economy.for_lifted_decoding()
    assert decoded_economy(112, 200, "pixels").cell_factor == Economy().cell_factor


def test_each_mode_serves_its_source_and_economy():
    """Both modes lift the VAE's decoding per pixel (finest rule, decoded tolerance, carving); the latent decoder's
    grid refined 2x merges in cells of half a model pixel (the coarse grid's, of one); an explicit source overrides
    the mode's."""
    from worldsplat.gaussians.aggregate import FINEST_DEPTH_TOL, LIFTED_DECODED_DEPTH_TOL
    from worldsplat.pipeline.inference import decoded_economy, gaussian_source

    assert gaussian_source(None, "reconstruct") == "pixels"
    assert gaussian_source(None, "generate") == "pixels"
    assert gaussian_source("decoder", "reconstruct") == "decoder"
    rec, gen = decoded_economy(112, 200, mode="reconstruct"), decoded_economy(112, 200, mode="generate")
    assert rec.static_rule == "finest" and rec.carve and rec.finest_depth_tol == LIFTED_DECODED_DEPTH_TOL
    assert LIFTED_DECODED_DEPTH_TOL > FINEST_DEPTH_TOL and not Economy().carve
    assert gen == rec
    grid2x = decoded_economy(112, 200, "decoder2x", mode="generate")
    assert grid2x.static_rule == "merge"
    assert decoded_economy(112, 200, "decoder").cell_factor == pytest.approx(2 * grid2x.cell_factor)
    with pytest.raises(ValueError, match="gaussians"):
        gaussian_source("grid", "generate")
