"""One training stage of `worldsplat train-stack`, made stable, resumable and measured around the one loop
(`loop.train_loop`): a learning rate chosen by a short sweep, warm-up and clipping (the loop's), a held-out figure
every `eval_every` steps that stops a diverging stage and rolls it back to its best checkpoint, and the throughput.

    sweep     each candidate lr (the stage's lr x `SWEEP_FACTORS`) trains a copy of the initial weights for a few
              steps; the lowest finite held-out figure wins (its figures are kept in the stage's state)
    guard     `DivergenceGuard`: held-out figure non-finite or above k x the best so far -> diverged
    rollback  the best checkpoint replaces the current one and the stage continues from it at a quarter of the lr
              (at most `retries` times); a stage ends on its best checkpoint
    resume    RUN/<stage>.state.json (lr, best, retries, done) beside the loop's checkpoint (weights, optimizer,
              step; every step's randomness is seeded by (seed, step)), so a restart continues where it stopped
    measure   images or clips per second, and the wall time's shares: the step, assembling batches, held-out figures
"""

from __future__ import annotations

import copy
import json
import math
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import torch

from worldsplat.core.io import write_json_atomic
from worldsplat.training.loop import train_loop, unwrap
from worldsplat_models.configs import TrainConfig

SWEEP_FACTORS = (0.3, 1.0, 3.0)
# Shares of a budgeted run's wall time, in training order (the enhancer's includes its pair renders; the last
# share is the snapshot's and the cards').
SHARES = {
    "vae": 0.13,
    "vae_decoder": 0.05,
    "decoder": 0.16,
    "prior": 0.1,
    "dit": 0.2,
    "enhancer": 0.2,
    "mix": 0.06,
    "snapshot": 0.1,
}


class StageStopped(Exception):
    """A planned interruption (`Run.stop_at`): the run stopped at a checkpoint; running it again continues."""


@dataclass
class DivergenceGuard:
    """Lower-is-better held-out figure; `update` -> "best", "ok" or "diverged" (non-finite, or above k x best)."""

    k: float = 3.0
    best: float = math.inf
    best_step: int = -1

    def update(self, step: int, value: float) -> str:
        if not math.isfinite(value) or (math.isfinite(self.best) and value > self.k * self.best):
            return "diverged"
        if value < self.best:
            self.best, self.best_step = value, step
            return "best"
        return "ok"


@dataclass
class Stage:
    """What a stage trains: `batch(step, gen)` assembles a batch on the device (timed as data), `loss(fwd, batch,
    step)` -> (loss, logs) runs the model (`fwd`: the model, compiled where that helps), `heldout(model)` -> the
    lower-is-better figure the guard watches. `items`: images or clips a step (`unit`)."""

    name: str
    model: torch.nn.Module
    batch: Callable
    loss: Callable
    heldout: Callable
    steps: int
    lr: float
    items: int
    unit: str = "images"
    eval_every: int = 50
    warmup: int = 100
    compile: bool = False
    channels_last: bool = False


@dataclass
class Run:
    """Where and how every stage runs. `lr_override` {stage: lr} skips that stage's sweep (a forced lr);
    `stop_at` (stage, step) stops the run at that checkpoint (a planned interruption)."""

    dir: Path
    device: torch.device
    seed: int = 0
    sweep_steps: int = 20
    k: float = 3.0
    retries: int = 1
    threads: int = 1
    lr_override: dict = field(default_factory=dict)
    stop_at: tuple[str, int] | None = None
    workers: int = 1  # processes for the CPU-side data of a stage (the enhancer's pair renders)
    deadline: float | None = None  # time.time() by which every stage must be done
    shares: dict = field(default_factory=lambda: dict(SHARES))

    def minutes_for(self, name: str) -> float | None:
        """The stage's share of the time left, among the stages not done yet (None: no budget)."""
        if self.deadline is None:
            return None
        later = list(self.shares)[list(self.shares).index(name) :]
        left = self.deadline - time.time()
        return max(0.05, left * self.shares[name] / sum(self.shares[k] for k in later) / 60)

    @property
    def bf16(self) -> bool:
        return self.device.type == "cuda"


def prepare(stage: Stage, run: Run) -> Callable:
    """The stage's model on the device (channels_last on CUDA for conv nets) and the forward the step calls
    (torch.compile on CUDA where the stage asks; the loop keeps the plain module, so checkpoints stay plain)."""
    stage.model.to(run.device)
    if run.device.type == "cuda" and stage.channels_last:
        stage.model.to(memory_format=torch.channels_last)
    if run.device.type == "cuda" and stage.compile and hasattr(torch, "compile"):
        return torch.compile(stage.model)
    return stage.model


def fit_batch(build: Callable[[int], Stage], n: int, run: Run, memory_share: float = 0.5, most: int = 8) -> Stage:
    """The stage at a batch sized to the device: on CUDA one forward and backward at batch n measures the peak
    memory, and the batch grows by the whole factor that keeps it under `memory_share` of the device (at most
    `most` x); elsewhere the stage as built (the CPU's batch is the size's)."""
    stage = build(n)
    if run.device.type != "cuda":
        return stage
    fwd = prepare(stage, run)
    torch.cuda.reset_peak_memory_stats(run.device)
    with torch.autocast("cuda", dtype=torch.bfloat16):
        loss, _ = stage.loss(fwd, stage.batch(0, torch.Generator().manual_seed(run.seed)), 0)
    loss.backward()
    stage.model.zero_grad(set_to_none=True)
    peak = torch.cuda.max_memory_allocated(run.device)
    total = torch.cuda.get_device_properties(run.device).total_memory
    factor = max(1, min(most, int(memory_share * total / max(peak, 1))))
    return build(n * factor) if factor > 1 else stage


def timed_step(stage: Stage, fwd, timers: dict) -> Callable:
    def step(model, i, gen):
        t = time.perf_counter()
        b = stage.batch(i, gen)
        timers["data_s"] += time.perf_counter() - t
        return stage.loss(fwd, b, i)

    return step


def tcfg(stage: Stage, run: Run, steps: int, lr: float, warmup: int, every: int) -> TrainConfig:
    return TrainConfig(
        steps=steps, lr=lr, warmup=warmup, ckpt_every=every, log_every=every, threads=run.threads, bf16=run.bf16,
        seed=run.seed,
    )  # fmt: skip


def sweep(stage: Stage, run: Run, fwd_of: Callable) -> dict:
    """Each candidate lr trains a copy of the initial weights for `run.sweep_steps` (resumable: its own checkpoint
    under RUN/sweep); -> {"lr": the lowest finite held-out figure's, "figures": {lr: figure}}."""
    figures = {}
    for i, f in enumerate(SWEEP_FACTORS):
        lr = stage.lr * f
        m = copy.deepcopy(stage.model)
        timers = {"data_s": 0.0}
        n = run.sweep_steps
        cfg = tcfg(stage, run, n, lr, max(1, n // 3), n)
        train_loop(f"{stage.name}_sweep{i}", m, timed_step(stage, fwd_of(m), timers), cfg, run.dir / "sweep",
                   progress=False, device=run.device)  # fmt: skip
        figures[f"{lr:.3g}"] = float(stage.heldout(unwrap(m)))
    finite = {k: v for k, v in figures.items() if math.isfinite(v)}
    best = min(finite, key=finite.get) if finite else f"{stage.lr * SWEEP_FACTORS[0]:.3g}"
    return {"lr": float(best), "figures": figures}


def _state_path(stage: Stage, run: Run) -> Path:
    return run.dir / f"{stage.name}.state.json"


def _save_initial(stage: Stage, run: Run, best: Path, state: dict) -> None:
    """Step 0 as the first best checkpoint (the loop's format): a stage that diverges at once rolls back to it."""
    opt = torch.optim.AdamW([p for p in stage.model.parameters() if p.requires_grad], lr=state["lr"])
    torch.save({"model": stage.model.state_dict(), "opt": opt.state_dict(), "step": 0, "extra": {}}, best)
    value = float(stage.heldout(stage.model))
    state["heldout"] = [{"step": 0, "value": value}]
    state["best"], state["best_step"] = value, 0


def run_stage(stage: Stage, run: Run) -> dict:
    """Sweep (once), then train under the guard, rolling back on divergence; ends on the best checkpoint. Resumes
    from RUN/<stage>.*; a finished stage only loads its best weights. -> the stage's record (its state)."""
    run.dir.mkdir(parents=True, exist_ok=True)
    sp, ckpt, best = _state_path(stage, run), run.dir / f"{stage.name}.ckpt.pt", run.dir / f"{stage.name}.best.pt"
    state = json.loads(sp.read_text()) if sp.exists() else {"retries": 0, "diverged_at": [], "wall_s": 0.0}
    fwd = prepare(stage, run)
    if not state.get("done"):
        if "lr" not in state:
            if stage.name in run.lr_override:
                state.update(lr=float(run.lr_override[stage.name]), sweep={"forced": run.lr_override[stage.name]})
            else:
                state.update(sweep(stage, run, lambda m: m if fwd is stage.model else torch.compile(m)))
                state["sweep"] = state.pop("figures")
            write_json_atomic(sp, state)
        if not best.exists():
            _save_initial(stage, run, best, state)
            write_json_atomic(sp, state)
        train_guarded(stage, run, fwd, state, sp, ckpt, best)
    stage.model.load_state_dict(torch.load(best, map_location=run.device, weights_only=False)["model"])
    return state


def train_guarded(stage: Stage, run: Run, fwd, state: dict, sp: Path, ckpt: Path, best: Path) -> None:
    guard = DivergenceGuard(run.k, state["best"], state["best_step"])
    while True:
        timers, verdict = {"data_s": 0.0, "eval_s": 0.0}, {}

        def on_ckpt(model, done):
            t = time.perf_counter()
            value = float(stage.heldout(unwrap(model)))
            timers["eval_s"] += time.perf_counter() - t
            status = guard.update(done, value)
            state["heldout"].append({"step": done, "value": value, "status": status})
            if status == "best":
                shutil.copyfile(ckpt, best)
                state["best"], state["best_step"] = guard.best, guard.best_step
            write_json_atomic(sp, state)
            verdict["status"] = status
            if status == "diverged" or run.stop_at == (stage.name, done):
                return True
            return None

        lr = state["lr"] * 0.25 ** state["retries"]
        cfg = tcfg(stage, run, stage.steps, lr, min(stage.warmup, max(1, stage.steps // 10)), stage.eval_every)
        t0 = time.perf_counter()
        hist = train_loop(stage.name, stage.model, timed_step(stage, fwd, timers), cfg, run.dir, progress=False,
                          device=run.device, on_checkpoint=on_ckpt, minutes=run.minutes_for(stage.name))  # fmt: skip
        record_throughput(stage, state, hist, time.perf_counter() - t0, timers)
        if verdict.get("status") == "diverged":
            state["diverged_at"].append(hist[-1]["step"])
            shutil.copyfile(best, ckpt)  # roll back: the next try resumes from the best checkpoint
            if state["retries"] < run.retries:
                state["retries"] += 1
                write_json_atomic(sp, state)
                continue
        elif run.stop_at is not None and run.stop_at[0] == stage.name and hist and hist[-1]["step"] == run.stop_at[1]:
            write_json_atomic(sp, state)
            raise StageStopped(f"stopped at {stage.name} step {run.stop_at[1]}")
        state["done"] = True
        write_json_atomic(sp, state)
        return


def record_throughput(stage: Stage, state: dict, hist: list[dict], wall: float, timers: dict) -> None:
    """Adds this call's steps and times to the state: items per second over the whole wall time (held-out figures
    included), and the shares of the wall in the step, in assembling batches and in held-out figures."""
    t = state.setdefault("time", {"steps": 0, "wall_s": 0.0, "data_s": 0.0, "eval_s": 0.0})
    t["steps"] += len(hist)
    t["wall_s"] += wall
    t["data_s"] += timers["data_s"]
    t["eval_s"] += timers["eval_s"]
    w = max(t["wall_s"], 1e-9)
    state["throughput"] = {
        f"{stage.unit}_per_s": round(t["steps"] * stage.items / w, 2),
        "step_share": round(max(0.0, 1 - (t["data_s"] + t["eval_s"]) / w), 3),
        "data_share": round(t["data_s"] / w, 3),
        "heldout_share": round(t["eval_s"] / w, 3),
    }
