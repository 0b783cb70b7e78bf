"""The VAE decoder's detail term (`training.loop.detail_loss`): zero on the target, paid for blur far more than for
a brightness error of the same L1, and each image weighted by its brightness gain (1 on a bright image, the cap on a
black one)."""

import pytest
import torch
import torch.nn.functional as F

from worldsplat.training.loop import DETAIL_MAX_GAIN, DETAIL_REF_BRIGHTNESS, detail_loss


def _image(seed: int, brightness: float, n: int = 2) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    x = torch.rand((n, 3, 32, 48), generator=g)
    x = (x - x.mean()) * 0.5 + brightness  # texture about a chosen mean brightness in [0, 1]
    return x.clamp(0, 1) * 2 - 1


def test_detail_loss_is_zero_on_the_target_and_paid_for_blur():
    x = _image(0, 0.5)
    assert float(detail_loss(x, x)[0]) < 1e-6
    blur = F.avg_pool2d(F.pad(x, (1, 1, 1, 1), mode="replicate"), 3, stride=1)
    shift = (x + (blur - x).abs().mean()).clamp(-1, 1)  # a brightness error of the blur's L1
    assert float(detail_loss(blur, x)[0]) > 5 * float(detail_loss(shift, x)[0])


def _gain(recon: torch.Tensor, target: torch.Tensor) -> float:
    loss, logs = detail_loss(recon, target)  # one image: loss = gain * (edge + 1 - luma SSIM)
    return float(loss) / (logs["edge"] + 1 - logs["luma_ssim"])


@pytest.mark.parametrize(
    ("brightness", "gain"),
    [(0.6, 1.0), (DETAIL_REF_BRIGHTNESS / 2, 2.0), (0.0, DETAIL_MAX_GAIN)],
)
def test_detail_loss_weights_dim_images_up_to_the_cap(brightness, gain):
    target = torch.full((1, 3, 32, 48), brightness * 2 - 1)
    err = 0.05 * torch.rand((1, 3, 32, 48), generator=torch.Generator().manual_seed(2))
    assert _gain(target + err, target) == pytest.approx(gain, rel=1e-4)
