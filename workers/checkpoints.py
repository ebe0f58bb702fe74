"""A job's checkpoint files: a model and its replay buffer per saved step, written whole or
not at all, newest first, the older ones pruned (replay buffers are large).

Layout (``CheckpointCallback``'s): ``model_<steps>_steps.zip`` and
``model_replay_buffer_<steps>_steps.pkl`` in the job's ``checkpoints/`` folder. The buffer is
written before its model, so a model file implies its buffer is complete.
"""

from __future__ import annotations

from pathlib import Path

from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

from workers.atomic import save_with


def save_checkpoint(model: BaseAlgorithm, folder: Path, steps: int) -> Path:
    """Save the replay buffer (off-policy) and then the model as the checkpoint of ``steps``,
    each atomically; the model's path."""
    folder.mkdir(parents=True, exist_ok=True)
    if isinstance(model, OffPolicyAlgorithm) and model.replay_buffer is not None:
        buffer = folder / f"model_replay_buffer_{steps}_steps.pkl"
        save_with(buffer, model.save_replay_buffer)
    path = folder / f"model_{steps}_steps.zip"
    save_with(path, model.save)
    return path


def checkpoint_steps(path: Path) -> int | None:
    """The step count in a checkpoint file name ``model_<steps>_steps.zip`` (None otherwise)."""
    parts = path.stem.split("_")
    if len(parts) == 3 and parts[0] == "model" and parts[2] == "steps" and parts[1].isdigit():
        return int(parts[1])
    return None


def checkpoints(folder: Path) -> list[tuple[Path, Path | None, int]]:
    """Every ``(model, replay buffer or None, steps)`` checkpoint in ``folder``, newest first."""
    found: list[tuple[int, Path]] = []
    for path in folder.glob("model_*_steps.zip") if folder.is_dir() else ():
        steps = checkpoint_steps(path)
        if steps is not None:
            found.append((steps, path))
    out: list[tuple[Path, Path | None, int]] = []
    for steps, model in sorted(found, reverse=True):
        buffer = folder / f"model_replay_buffer_{steps}_steps.pkl"
        out.append((model, buffer if buffer.is_file() else None, steps))
    return out


def prune_checkpoints(folder: Path, keep: int = 2) -> None:
    """Delete all but the newest ``keep`` checkpoints (replay buffers are large)."""
    found = sorted(
        (s, p) for p in folder.glob("model_*_steps.zip") if (s := checkpoint_steps(p)) is not None
    )
    for steps, path in found[:-keep]:
        path.unlink(missing_ok=True)
        (folder / f"model_replay_buffer_{steps}_steps.pkl").unlink(missing_ok=True)
