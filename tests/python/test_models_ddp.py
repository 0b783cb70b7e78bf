"""Scale-out smoke test: the torchrun/DDP path of train.train_loop with 2 gloo processes on CPU.

A few DiT steps on per-rank synthetic latents: the loss on a fixed probe batch falls and both ranks hold
bit-identical weights after every step (DDP averaged the gradients and applied the same update)."""

import json
import os
import socket

import torch
import torch.multiprocessing as mp


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _worker(rank: int, world: int, port: int, out_dir: str) -> None:
    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port), RANK=str(rank), WORLD_SIZE=str(world))
    import torch.distributed as dist

    from worldsplat.training.loop import dit_batch, dit_step_fn, train_loop
    from worldsplat_models import rflow
    from worldsplat_models.configs import TrainConfig, get_config
    from worldsplat_models.dit import DiT4D

    torch.set_num_threads(1)
    cfg = get_config("tiny")
    torch.manual_seed(100 + rank)  # different initial weights per rank: DDP must broadcast rank 0's
    dit = DiT4D(cfg.dit)
    g = torch.Generator().manual_seed(rank)
    d = cfg.data
    h, w = d.height // 8, d.width // 8
    pattern = torch.linspace(-2, 2, cfg.dit.in_channels).view(1, 1, -1, 1, 1)  # learnable: a fixed latent
    samples = [
        {
            "L": pattern.expand(d.frames, d.views, -1, h, w) + 0.1 * torch.randn(h, w, generator=g),
            "control": torch.randn(d.frames, d.views, cfg.dit.control_channels, h, w, generator=g),
            "caption_emb": torch.randn(384, generator=g),
            "box_corners": torch.randn(d.frames, d.max_boxes, 8, 3, generator=g).numpy(),
            "box_cls": torch.randint(0, 17, (d.frames, d.max_boxes), generator=g).numpy(),
            "box_moving": (torch.rand(d.frames, d.max_boxes, generator=g) > 0.5).numpy(),
            "box_mask": (torch.rand(d.frames, d.max_boxes, generator=g) > 0.5).numpy(),
            "traj": torch.eye(4).expand(d.frames, 4, 4).numpy(),
        }
        for _ in range(2)
    ]
    probe_x, probe_c = dit_batch(samples)
    pg = torch.Generator().manual_seed(7)
    eps = torch.randn(probe_x.shape, generator=pg)
    s = torch.full((probe_x.shape[0],), 0.5)

    def probe(model):
        with torch.no_grad():
            return float(rflow.training_loss(model, probe_x, probe_c, eps=eps, s=s))

    tcfg = TrainConfig(steps=8, lr=1e-2, warmup=1, seed=0, threads=1, ckpt_every=1000, log_every=1000)
    # probe with rank 0's initial weights on every rank
    dist.init_process_group("gloo")
    for p in dit.state_dict().values():
        dist.broadcast(p, 0)
    before = probe(dit)
    train_loop("dit", dit, dit_step_fn(samples), tcfg, out_dir, progress=False)
    after = probe(dit)
    flat = torch.cat([p.detach().reshape(-1) for p in dit.parameters()])
    gathered = [torch.zeros_like(flat) for _ in range(world)]
    dist.all_gather(gathered, flat)
    diff = float((gathered[0] - gathered[1]).abs().max())
    with open(os.path.join(out_dir, f"rank{rank}.json"), "w") as f:
        json.dump({"before": before, "after": after, "diff": diff}, f)
    dist.destroy_process_group()


def test_ddp_two_process_gloo(tmp_path):
    # fork: the children inherit the imported torch (spawn would pay the import twice more)
    mp.start_processes(_worker, args=(2, _free_port(), str(tmp_path)), nprocs=2, join=True, start_method="fork")
    r = [json.loads((tmp_path / f"rank{i}.json").read_text()) for i in range(2)]
    assert r[0]["diff"] == 0.0 and r[1]["diff"] == 0.0  # identical weights on both ranks
    for x in r:
        assert x["after"] < x["before"] * 0.9, x  # the loss falls on each rank's probe batch
