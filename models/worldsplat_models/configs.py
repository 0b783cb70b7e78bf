"""Model configurations as dataclasses, three sizes per model.

- `tiny`: unit tests and stability sweeps (runs in milliseconds on one CPU thread).
- `small`: the weights trained and shipped here (2 CPU cores, minutes per model; 64x112 images, 6 views, 4 frames).
- `paper`: the scale of WorldSplat / OpenSora-STDiT3-XL for GPU clusters (documented; only constructed in tests).

Every size shares one data geometry (`DataConfig`): an image of HxW becomes a latent of (H/8)x(W/8).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field

SIZES = ("tiny", "small", "paper")


@dataclass
class DataConfig:
    height: int = 64
    width: int = 112
    views: int = 6
    frames: int = 4
    # Depth is normalised to [-1, 1] in log space over [depth_near, depth_far] metres; sky (inf) maps to far (+1).
    depth_near: float = 0.5
    depth_far: float = 80.0
    max_boxes: int = 32  # boxes per frame fed to the DiT (more are dropped, nearest kept)
    num_classes: int = 17  # box class ids = worldsplat.world.classes ids (0..16); larger ids are clamped


@dataclass
class VAEConfig:
    """Convolutional KL-VAE shared by the RGB, depth and mask modalities (3 input channels, 8x down-sampling)."""

    in_channels: int = 3
    latent_channels: int = 4  # per modality; L has 3x this
    channels: tuple[int, ...] = (16, 32, 64)  # one level per 2x down-sampling
    blocks: int = 1  # ResBlocks per level (encoder and decoder)
    unshuffle: int = 1  # space-to-depth factor before the first level (1 = none)
    kl_weight: float = 1e-6
    modalities: tuple[str, ...] = ("rgb", "depth", "mask")

    @property
    def downsample(self) -> int:
        return self.unshuffle * 2 ** len(self.channels)

    @property
    def joint_channels(self) -> int:
        return self.latent_channels * len(self.modalities)


@dataclass
class DiTConfig:
    """4D-aware DiT backbone (cross-view spatial + temporal + cross-attention blocks, adaLN-zero, ControlNet).

    `in_channels`/`control_channels` let a second model (the enhancement model) reuse the same backbone with other
    inputs: the generator uses L (3 modalities) in and the layout maps (or the sketch latent) as control; the
    enhancer uses the image latent in and render latent + sketch latent as control. Every field is stored in a
    weight file's metadata (weights.py) and read back by name, so the shipped files fix which control path a model
    uses: the generator (dit_small) the layout-map path (control_hint, control_at_input, refine_channels,
    hint_stem_stride, target "prior_residual"), the enhancer (enhancer_small) the ControlNet path on patchified
    latents."""

    in_channels: int = 12  # latent channels the flow runs on (input and, by default, output)
    control_channels: int = 4  # channels of the control input (a latent, or a layout map when control_hint > 0)
    out_channels: int = 12  # channels of the predicted velocity
    patch: int = 2  # latent pixels per token side
    dim: int = 128  # token width
    depth: int = 6  # main blocks
    heads: int = 4  # attention heads per block
    mlp_ratio: float = 4.0  # MLP hidden width / dim
    control_depth: int = 2  # ControlNet blocks (copies of the first main blocks), zero-initialised outputs; 0 = none
    cond_dim: int = 128  # width of condition tokens before the fusion MLP projects them to `dim`
    caption_dim: int = 384  # all-MiniLM-L6-v2 sentence embedding
    box_fourier: int = 4  # Fourier frequencies per box-corner coordinate
    max_views: int = 6  # size of the learned view embedding
    max_frames: int = 8  # size of the learned frame embedding
    cond_drop: float = 0.15  # probability of dropping all conditions in training (for CFG)
    sampler_shift: float = 2.0  # timestep shift of the Euler sampler (OpenSora/SD3 form)
    sampler_steps: int = 8  # Euler steps of the sampler
    cfg_scale: float = 1.0  # classifier-free guidance scale (1 = conditional prediction only)
    # Pixel-space layout control: when > 0 the control input is a per-camera layout map of `control_channels`
    # channels at `control_hint` times the token grid (pixels per token side), read by a small trainable conv
    # encoder (ControlNet's hint encoder, `HintEncoder`) instead of being patchified like a latent. 0: a latent.
    control_hint: int = 0
    # The layout tokens enter the main stream at its input (a plain Linear, not zero-initialised) instead of through
    # ControlNet's zero-initialised branch, which protects a pretrained base; trained from scratch the branch learned
    # the control too slowly (the layout ignored), so the generator conditions on the layout directly.
    control_at_input: bool = False
    # Width of a convolutional head at latent resolution (0 = off) that adds a residual to the unpatchified token
    # output from [token output, z_s, layout features at latent resolution]: a 4x4-latent token cannot draw a lane
    # marking, the head can (`LatentRefiner`; needs control_hint).
    refine_channels: int = 0
    hint_stem_stride: int = 1  # 2: the hint encoder's first conv already down-samples (about 4x fewer FLOPs)
    # What the flow generates. "latent": L itself; "prior_residual": (L - mu) / residual_scale, mu being the
    # LayoutPrior's regression of L from the layout (layout_prior.py), so generation = mu + residual_scale * sample.
    target: str = "latent"
    residual_scale: float = 1.0
    # The sampler's scale of a prior_residual DiT's sample (generation = mu + residual_scale * residual_temperature *
    # sample): above 1 a draw lies farther from the prior's smooth mean (a sampler default, stored with the weights
    # like cfg_scale; chosen for the shipped DiT in its card).
    residual_temperature: float = 1.0

    def __post_init__(self):
        if self.target not in ("latent", "prior_residual"):
            raise ValueError(f"DiTConfig.target must be 'latent' or 'prior_residual', got {self.target!r}")
        if not self.residual_scale > 0:
            raise ValueError(f"DiTConfig.residual_scale must be positive, got {self.residual_scale}")


@dataclass
class LayoutPriorConfig:
    """Layout map -> E[normalised L] regression U-Net (layout_prior.py), FiLM-conditioned on caption and camera."""

    in_channels: int = 7  # world.layout_maps.LAYOUT_CHANNELS
    out_channels: int = 24  # the VAE's joint latent channels
    downsample: int = 4  # the VAE's image -> latent factor
    widths: tuple[int, ...] = (32, 64, 128, 192)  # full res, each 2x down to the latent grid, one level below it
    blocks: int = 2  # FiLM ResBlocks at the lowest level and at the latent grid
    cond_dim: int = 128
    caption_dim: int = 384
    max_views: int = 6


@dataclass
class GSDecoderConfig:
    """Latent Gaussian decoder: L + Plucker rays -> pixel-aligned Gaussians at image/`gaussian_stride` resolution."""

    in_channels: int = 12
    dim: int = 128
    depth: int = 4
    heads: int = 4
    mlp_ratio: float = 4.0
    up_channels: tuple[int, ...] = (64, 32)  # one 2x up-sampling block each, from the latent grid
    max_views: int = 6
    max_frames: int = 8
    # Activation bounds (documented in web/docs/models.md).
    depth_near: float = 0.5
    depth_far: float = 80.0
    max_offset: float = 0.5  # metres, tanh-bounded
    scale_min: float = 1e-3  # metres
    scale_max: float = 3.0  # metres
    pixel_scale_range: tuple[float, float] = (0.25, 3.0)  # scale in pixel footprints before the metric clamp
    opacity_bias: float = 2.0  # start near-opaque: sigmoid(x + 2) ~ 0.88
    ray_scale: float = 20.0  # metres; Plucker origins are divided by this
    patch: int = 1  # latent pixels per token side (attention runs on the h/patch x w/patch grid)
    # Pixel guide: the VAE-decoded rgb + normalised depth + mask (5 channels; 0 = none) re-read by every up-sampling
    # block at its resolution, and the base that the colour, depth and dynamic heads add their residual to.
    guide_channels: int = 0
    reread_latent: bool = False  # every up-sampling block also re-reads L (nearest-resized) beside the rays

    @property
    def upsample(self) -> int:
        return 2 ** len(self.up_channels)


@dataclass
class TrainConfig:
    steps: int = 2000
    batch: int = 1
    lr: float = 3e-4
    weight_decay: float = 0.01
    warmup: int = 100
    grad_clip: float = 1.0
    seed: int = 0
    ckpt_every: int = 200
    log_every: int = 20
    threads: int = 2
    bf16: bool = False


@dataclass
class ModelSet:
    data: DataConfig = field(default_factory=DataConfig)
    vae: VAEConfig = field(default_factory=VAEConfig)
    dit: DiTConfig = field(default_factory=DiTConfig)
    decoder: GSDecoderConfig = field(default_factory=GSDecoderConfig)


def get_config(size: str = "small") -> ModelSet:
    """The three documented sizes."""
    if size == "small":
        return ModelSet()
    if size == "tiny":
        return ModelSet(
            data=DataConfig(height=32, width=48, views=2, frames=2, max_boxes=4),
            vae=VAEConfig(channels=(8, 8, 16), latent_channels=2),
            dit=DiTConfig(
                in_channels=6,
                control_channels=2,
                out_channels=6,
                dim=32,
                depth=2,
                heads=2,
                control_depth=1,
                cond_dim=32,
                max_views=2,
                max_frames=2,
            ),
            decoder=GSDecoderConfig(
                in_channels=6, dim=32, depth=1, heads=2, up_channels=(16, 8), max_views=2, max_frames=2
            ),
        )
    if size == "paper":
        # 424x800 (nuScenes), 6 views, 17 frames; STDiT3-XL/2 widths (hidden 1152, 28 blocks, 16 heads) and an
        # OpenSora-like VAE with 4 latent channels per modality. Trained on clusters, never here.
        return ModelSet(
            data=DataConfig(height=424, width=800, views=6, frames=17, max_boxes=64),
            vae=VAEConfig(channels=(128, 256, 512), latent_channels=4),
            dit=DiTConfig(dim=1152, depth=28, heads=16, control_depth=13, cond_dim=512, max_frames=32),
            decoder=GSDecoderConfig(dim=768, depth=12, heads=12, up_channels=(512, 256, 128), max_frames=32),
        )
    raise ValueError(f"unknown config size {size!r}; expected one of {', '.join(SIZES)}")


def to_json(cfg) -> str:
    return json.dumps(dataclasses.asdict(cfg), sort_keys=True)


def from_dict(cls, d: dict):
    """Rebuild a (possibly nested) config dataclass from `asdict` output; unknown keys are an error."""
    names = {f.name: f for f in dataclasses.fields(cls)}
    unknown = set(d) - set(names)
    if unknown:
        raise ValueError(f"{cls.__name__}: unknown field(s) {sorted(unknown)}")
    kwargs = {}
    for k, v in d.items():
        ftype = names[k].type
        sub = {
            "DataConfig": DataConfig,
            "VAEConfig": VAEConfig,
            "DiTConfig": DiTConfig,
            "GSDecoderConfig": GSDecoderConfig,
            "LayoutPriorConfig": LayoutPriorConfig,
        }.get(ftype if isinstance(ftype, str) else ftype.__name__)
        if sub is not None and isinstance(v, dict):
            v = from_dict(sub, v)
        elif isinstance(v, list):
            v = tuple(v)
        kwargs[k] = v
    return cls(**kwargs)
