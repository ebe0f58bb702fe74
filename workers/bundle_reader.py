"""Open a mission bundle safely and run its concatenated policy ``(pi_0..pi_K)(pi_K+1..)^omega``.

``read_bundle`` validates the zip before anything is loaded: it must be a zip, hold a
``manifest.json`` of this format and version (pydantic schema, unknown keys rejected), every
member name must be a plain relative path (no ``..``, no absolute path, no backslash), every
model file the manifest names must exist and hold only the members stable-baselines3 writes.
Models are then rebuilt without unpickling anything: stable-baselines3's own ``load`` would
unpickle the ``:serialized:`` entries of a model's ``data`` (cloudpickle), so instead the
policy network is constructed from the manifest (algorithm, ``policy_kwargs``) and the mission's
spaces, and its weights are read with ``torch.load(..., weights_only=True)``. The model files
stay ordinary stable-baselines3 archives (``SAC.load`` opens them, for files one trusts).

``ConcatenatedPolicy.load(path)`` needs only the bundle, stable-baselines3 and
``planner``/``envs``: ``make_env()`` gives the mission env (``envs.mission_env.MissionEnv``,
which hands the robot from sub-task env to sub-task env when a goal region is reached) and
``reset(obs)`` / ``act(obs)`` pick the sub-policy of the current stage, cycling the suffix.
"""

from __future__ import annotations

import dataclasses
import io
import json
import re
import warnings
import zipfile
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np
import torch
from pydantic import ValidationError
from stable_baselines3 import DDPG, PPO, SAC, TD3
from stable_baselines3.common.policies import BasePolicy

from envs.errors import EnvConfigError
from envs.factory import subtask_guides
from envs.mission_env import MissionEnv
from envs.options import EnvOptions
from planner.decompose import SubTask, subtask_at
from planner.plan import MissionPlan
from planner.serialize import plan_from_dict
from workers.evaluation import MissionEvaluation, rollout_mission
from workers.hyperparameters import ACTIVATIONS
from workers.manifest import (
    FORMAT,
    MANIFEST,
    READABLE_VERSIONS,
    BundleError,
    DrawnGuide,
    Manifest,
    SubtaskEntry,
)
from workers.mission import MissionError, MissionSpec, parse_mission
from workers.policy_act import deterministic_act

MODEL_NAME = re.compile(r"models/subtask_[0-9]{1,4}\.zip")
MODEL_MEMBERS = re.compile(r"data|_stable_baselines3_version|system_info\.txt|[A-Za-z0-9_.]+\.pth")
"""Members of a stable-baselines3 model archive."""
MAX_MEMBER_BYTES = 512 * 1024 * 1024
POLICY_CLASSES: dict[str, Any] = {"sac": SAC, "td3": TD3, "ddpg": DDPG, "ppo": PPO}


def _safe_name(name: str) -> bool:
    p = PurePosixPath(name)
    return (
        bool(name)
        and "\\" not in name
        and not p.is_absolute()
        and ".." not in p.parts
        and not name.startswith("/")
        and ":" not in p.parts[0]
    )


def read_bundle(path: str | Path) -> tuple[Manifest, dict[str, bytes]]:
    """The validated manifest and the model files' bytes of the bundle at ``path``."""
    path = Path(path)
    if not path.is_file():
        raise BundleError(f"{path}: no such bundle file")
    try:
        with zipfile.ZipFile(path) as archive:
            infos = archive.infolist()
            names = [i.filename for i in infos]
            bad = [n for n in names if not _safe_name(n)]
            if bad:
                raise BundleError(f"{path}: unsafe member name(s) {bad} (path traversal)")
            if MANIFEST not in names:
                raise BundleError(f"{path}: not an ltlnav bundle (no {MANIFEST})")
            if any(i.file_size > MAX_MEMBER_BYTES for i in infos):
                raise BundleError(f"{path}: a member is larger than {MAX_MEMBER_BYTES} bytes")
            manifest = _manifest(path, archive.read(MANIFEST))
            models: dict[str, bytes] = {}
            for entry in manifest.subtasks:
                if not MODEL_NAME.fullmatch(entry.model) or entry.model not in names:
                    raise BundleError(f"{path}: model file {entry.model!r} is missing or misnamed")
                models[entry.model] = archive.read(entry.model)
            missing = [f for f in manifest.files if f not in names or not _safe_name(f)]
            if missing:
                raise BundleError(f"{path}: files listed in the manifest are missing: {missing}")
    except zipfile.BadZipFile as err:
        raise BundleError(f"{path}: not a zip file or corrupted ({err})") from err
    for name, blob in models.items():
        _check_model_archive(path, name, blob)
    return manifest, models


def _manifest(path: Path, raw: bytes) -> Manifest:
    try:
        doc = json.loads(raw)
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise BundleError(f"{path}: {MANIFEST} is not valid JSON ({err})") from err
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise BundleError(f"{path}: not an ltlnav bundle (manifest format is not {FORMAT!r})")
    if doc.get("format_version") not in READABLE_VERSIONS:
        readable = ", ".join(str(v) for v in sorted(READABLE_VERSIONS))
        raise BundleError(
            f"{path}: bundle format version {doc.get('format_version')!r} is not supported "
            f"(this ltlnav reads versions {readable})"
        )
    try:
        manifest = Manifest.model_validate(doc)
    except ValidationError as err:
        first = err.errors()[0]
        where = ".".join(str(p) for p in first["loc"])
        raise BundleError(f"{path}: invalid {MANIFEST}: {where}: {first['msg']}") from err
    indices = [s.index for s in manifest.subtasks]
    if indices != list(range(len(indices))) or not indices:
        raise BundleError(f"{path}: sub-tasks must be numbered 0..n-1 in order, got {indices}")
    return manifest


def _check_model_archive(path: Path, name: str, blob: bytes) -> None:
    try:
        with zipfile.ZipFile(io.BytesIO(blob)) as inner:
            members = inner.namelist()
    except zipfile.BadZipFile as err:
        raise BundleError(f"{path}: {name} is not a stable-baselines3 model archive") from err
    odd = [m for m in members if not MODEL_MEMBERS.fullmatch(m)]
    if odd or "policy.pth" not in members:
        raise BundleError(f"{path}: {name} has unexpected members {odd or members}")


def build_policy(entry: SubtaskEntry, blob: bytes, env: MissionEnv) -> BasePolicy:
    """The sub-task's policy network rebuilt from the manifest, weights loaded without
    unpickling (``weights_only``)."""
    cls = POLICY_CLASSES[entry.algorithm]
    kwargs = dict(entry.policy_kwargs)
    act = kwargs.get("activation_fn", "relu")
    if act not in ACTIVATIONS:
        raise BundleError(f"sub-task {entry.index}: unknown activation {act!r}")
    kwargs["activation_fn"] = getattr(torch.nn, _TORCH_NAMES[act])
    sub_env = env.envs[entry.index]
    policy_cls = cls.policy_aliases["MlpPolicy"]
    policy: BasePolicy = policy_cls(
        sub_env.observation_space, sub_env.action_space, lambda _: 0.0, **kwargs
    )
    try:
        with zipfile.ZipFile(io.BytesIO(blob)) as inner:
            state = torch.load(
                io.BytesIO(inner.read("policy.pth")), map_location="cpu", weights_only=True
            )
        policy.load_state_dict(state)
    except (RuntimeError, KeyError, ValueError, zipfile.BadZipFile) as err:
        raise BundleError(
            f"sub-task {entry.index}: the weights in {entry.model} do not fit its policy ({err})"
        ) from err
    policy.set_training_mode(False)
    return policy


_TORCH_NAMES = {
    "relu": "ReLU",
    "tanh": "Tanh",
    "elu": "ELU",
    "leaky_relu": "LeakyReLU",
    "gelu": "GELU",
    "silu": "SiLU",
}


def with_drawn_guides(
    path: Path | str, plan: MissionPlan, entries: list[SubtaskEntry]
) -> MissionPlan:
    """``plan`` fixed to the drawn paths the manifest records (a car's, version 3 on), so its
    rollouts drive the guides its policies were trained on whatever today's redraw does."""
    records = [entry.drawn for entry in entries]
    if all(record is None for record in records):
        return plan
    if any(record is None for record in records):
        raise BundleError(f"{path}: some sub-tasks record their drawn guide and others do not")
    dim = plan.start.shape[0]
    drawn = [
        _drawn_subtask(path, sub, record, dim)
        for sub, record in zip(plan.subtasks, records, strict=True)
        if record is not None
    ]
    return dataclasses.replace(plan, drawn=drawn)


def _drawn_subtask(path: Path | str, sub: SubTask, record: DrawnGuide, dim: int) -> SubTask:
    where = f"{path}: sub-task {sub.index}'s drawn guide"
    try:
        start = np.asarray(record.start, dtype=float)
        points = np.asarray(record.path, dtype=float)
    except ValueError as err:
        raise BundleError(f"{where} is malformed ({err})") from err
    if start.shape != (dim,) or points.ndim != 2 or points.shape[1] != dim or not len(points):
        raise BundleError(f"{where} is not a {dim}D path")
    if not 0 <= record.reverse < len(points):
        raise BundleError(f"{where} backs up past its end")
    return dataclasses.replace(sub, start=start, path=points, reverse=record.reverse)


class ConcatenatedPolicy:
    """The mission's policy: one sub-policy per sub-task, run in lasso order, suffix repeated.

    ``act(obs)`` takes a ``MissionEnv`` observation (the current sub-task env's observation
    followed by the stage number) and returns the action of the stage's sub-policy; stages past
    the prefix map onto the suffix cyclically, so the policy runs for any number of cycles.
    """

    def __init__(
        self,
        manifest: Manifest,
        mission: MissionSpec,
        plan: MissionPlan,
        models: dict[str, bytes],
    ) -> None:
        self.manifest, self.mission, self.plan = manifest, mission, plan
        self.cycles = manifest.cycles
        self._probe = self.make_env(cycles=1)
        self.policies = [build_policy(e, models[e.model], self._probe) for e in manifest.subtasks]
        self._acts = [deterministic_act(policy) for policy in self.policies]
        self.stage = 0

    @classmethod
    def load(cls, path: str | Path) -> ConcatenatedPolicy:
        """Validate the bundle at ``path`` and rebuild its policies (``BundleError`` if bad)."""
        manifest, models = read_bundle(path)
        try:
            mission = parse_mission(manifest.mission)
            plan = plan_from_dict(manifest.plan)
        except MissionError as err:
            raise BundleError(f"{path}: the bundled mission is invalid: {err}") from err
        except (KeyError, TypeError, ValueError) as err:
            raise BundleError(f"{path}: the bundled plan is malformed ({err!r})") from err
        if len(plan.subtasks) != len(manifest.subtasks):
            raise BundleError(f"{path}: the plan and the manifest list different sub-tasks")
        plan = with_drawn_guides(path, plan, manifest.subtasks)
        if manifest.eval_env is not None:
            try:
                EnvOptions(**manifest.eval_env)
            except (EnvConfigError, TypeError) as err:
                raise BundleError(f"{path}: invalid eval_env in the manifest: {err}") from err
        policy = cls(manifest, mission, plan, models)
        redrawn = policy.redrawn_subtasks()
        if redrawn:
            warnings.warn(
                f"{path}: this ltlnav draws the guides of sub-tasks {redrawn} differently from "
                "those they were trained on (the bundle was written before bundles recorded "
                "their guides and before a change to how they are drawn); its rollouts follow "
                "today's guides",
                stacklevel=2,
            )
        return policy

    def options(self) -> EnvOptions:
        """The evaluation env's options: the recorded ones (bundles written before they were
        recorded: the mission's defaults of this ltlnav). A bundle that does not record its
        rays' range predates ranges in the robot's terms: its policies saw an eighth of the
        world's diagonal."""
        recorded = self.manifest.eval_env
        if recorded is not None:
            options = EnvOptions(**recorded)
        else:
            options = self.mission.training.eval_env_options(self.mission.robot.model)
        if options.rays and options.ray_range is None:
            world_scaled = self.mission.build_world().diagonal / 8.0
            options = dataclasses.replace(options, ray_range=world_scaled)
        return options

    def redrawn_subtasks(self) -> list[int]:
        """Sub-tasks whose guide this ltlnav draws otherwise than the manifest's (the one their
        policy was trained on)."""
        guides = subtask_guides(self.mission, self.plan, self.options(), self.mission.build_world())
        return [
            entry.index
            for entry, guide in zip(self.manifest.subtasks, guides, strict=True)
            if np.shape(entry.guide_centers) != guide.centers.shape
            or not np.allclose(entry.guide_centers, guide.centers, rtol=0.0, atol=1e-9)
        ]

    def make_env(self, cycles: int | None = None) -> MissionEnv:
        """The mission env this policy acts in (``cycles`` suffix cycles, default the bundle's)."""
        return MissionEnv(self.mission, self.plan, self.options(), cycles or self.cycles)

    def subtask_of(self, stage: int) -> int:
        """The sub-task that acts at ``stage`` (the suffix repeats forever)."""
        return subtask_at(self.plan.subtasks, stage)

    def reset(self, obs: np.ndarray) -> None:
        """Start a new rollout at ``obs`` (stage 0)."""
        self.stage = round(float(obs[-1]))

    def act(self, obs: np.ndarray) -> np.ndarray:
        """The deterministic action of the current stage's sub-policy."""
        self.stage = round(float(obs[-1]))
        act = self._acts[self.subtask_of(self.stage)]
        return np.asarray(act(np.asarray(obs[:-1], dtype=np.float32)), dtype=np.float32)

    def evaluate(
        self, episodes: int, seed: int = 0, cycles: int | None = None
    ) -> MissionEvaluation:
        """Whole-mission rollouts judged by the automaton (see ``rollout_mission``)."""
        env = self.make_env(cycles)
        try:
            return rollout_mission(self.act, env, episodes, seed=seed, reset=self.reset)
        finally:
            env.close()

    def close(self) -> None:
        self._probe.close()
