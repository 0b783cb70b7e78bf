"""`python -m worldsplat.evaluation.models --parts cells` (the command behind gaussians.md's decoded-cells table):
at the served cell it scores exactly the scene the reconstruct evaluation scores (the served `to_scene4d`), coarser
cells keep fewer Gaussians, and a missing shifted ground truth is an error that names it."""

import pytest

from worldsplat.pipeline import inference as inf

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif("reconstruct" not in inf.available_modes(), reason="no shipped weights in models/weights"),
]


@pytest.fixture(scope="module")
def one_clip(tmp_path_factory):
    from worldsplat.training.data import ShardDataset
    from worldsplat.world.dataset import write_dataset

    root = tmp_path_factory.mktemp("data")
    write_dataset(root, "test", 1, shifts=(2.0,), progress=False)
    models = inf.load_models()
    return models, ShardDataset(root, "test", models.data.max_boxes)


def test_cells_at_the_served_cell_score_the_served_scene(one_clip):
    from worldsplat.evaluation.models import eval_cells, eval_reconstruct

    models, ds = one_clip
    # the cells of the latent decoder's Gaussians (lifted pixels take the oracle's economy, `decoded_economy`)
    rows = eval_cells(models, ds, 1, factors=(0.0, 1.0, 3.0), frames=(1,), gaussians="decoder")
    served = eval_reconstruct(models, ds, 1, frames=(1,), shifts=(0.0, 2.0), oracle=True, gaussians="decoder")
    by_cell = {r["cell"]: r for r in rows}
    # one model pixel at the models' own image size is the decoder's economy (`decoded_economy`)
    assert by_cell[1.0]["psnr_0"] == pytest.approx(served["0.0"]["model_psnr"], abs=1e-9)
    assert by_cell[1.0]["psnr_2"] == pytest.approx(served["2.0"]["model_psnr"], abs=1e-9)
    # the served oracle keeps each place's finest observation (no cells): above the cells of 3 it merged before
    assert served["0.0"]["oracle_psnr"] > by_cell[3.0]["oracle_psnr_0"]
    assert by_cell[0.0]["static"] > by_cell[1.0]["static"] > by_cell[3.0]["static"] > 0
    assert by_cell[0.0]["oracle_static"] > by_cell[1.0]["oracle_static"] > by_cell[3.0]["oracle_static"] > 0
    with pytest.raises(ValueError, match=r"no ground truth at shift\(s\) \[4.0\]"):
        eval_cells(models, ds, 1, factors=(1.0,), frames=(1,), shifts=(0.0, 4.0))


def test_joint_fit_raises_the_rig_over_the_served_scene(one_clip):
    from worldsplat.evaluation.models import eval_reconstruct

    models, ds = one_clip
    r = eval_reconstruct(models, ds, 1, frames=(1,), shifts=(0.0,), oracle=True, joint=True)["0.0"]
    # the static colours fitted to every frame's images at once: the rig's images are the fit's targets
    assert r["oracle_joint_psnr"] > r["oracle_psnr"] + 1.0
    assert r["model_joint_psnr"] > r["model_psnr"]


def test_observed_clips_make_the_scenes_scored_at_the_data_image(one_clip, tmp_path):
    """`--observed`: the scenes are made from the same clip at the playground's 200x112 image and scored at --data's
    cameras and images (the oracle lifted from either scores within a dB or two there: the same world, aligned); a
    dataset of other clips is refused by name."""
    from worldsplat.evaluation.models import eval_reconstruct
    from worldsplat.training.data import ShardDataset
    from worldsplat.world.dataset import write_dataset

    models, ds = one_clip
    write_dataset(tmp_path / "served", "test", 1, width=200, height=112, progress=False)
    observed = ShardDataset(tmp_path / "served", "test", models.data.max_boxes)
    kw = dict(frames=(1,), shifts=(0.0, 2.0), model=False, oracle=True)
    at_data = eval_reconstruct(models, ds, 1, **kw)
    at_served = eval_reconstruct(models, ds, 1, observed=observed, **kw)
    for sh in ("0.0", "2.0"):
        a, b = at_data[sh]["oracle_psnr"], at_served[sh]["oracle_psnr"]
        assert a != b and abs(a - b) < 2.0, (sh, a, b)
    write_dataset(tmp_path / "other", "val", 1, width=200, height=112, progress=False)
    with pytest.raises(ValueError, match="observed clip 0 is not --data's clip 0"):
        eval_reconstruct(models, ds, 1, observed=ShardDataset(tmp_path / "other", "val", models.data.max_boxes), **kw)
