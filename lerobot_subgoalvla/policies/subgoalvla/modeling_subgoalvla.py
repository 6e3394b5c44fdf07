"""SubgoalVLAPolicy: LeRobot's policy interface over :class:`SubgoalVLAModel` (paper section 4).

The policy is thin: the computation lives in ``model.py``; this module does the LeRobot plumbing.

- Training: ``forward`` picks the stage (section 4.3) from the config and the number of optimizer steps done
  so far. LeRobot calls ``update()`` after every optimizer step; the count lives in a saved buffer, so a
  resumed run or a reloaded checkpoint continues in the right stage, and one ``lerobot-train`` run can switch
  from stage I to stage II at ``stage2_start_step``.
- Optimizer groups (appendix C, table 8): heads 1e-4, projector 1e-5, LLM 2e-5; the frozen vision tower is in
  no group. LeRobot only uses these groups through the policy's optimizer preset. The heads
  come first because LeRobot logs ``param_groups[0]``'s learning rate, which is then the scheduler's peak.
- Inference (``select_action``): the state history the model needs is built online from the normalised states
  with :class:`StateHistoryBuffer` (the same window and clamping as the dataset's
  ``observation.state_history``). The
  backbone and both samplers run once per chunk; ``n_action_steps`` actions are queued. CALVIN resets the
  model at every subtask, but ``lerobot-eval`` calls ``reset()`` once per rollout, so a change of
  ``batch["task"]`` (the env switches the instruction at each subtask) flushes the queue and restarts the
  history of the envs whose instruction changed.
- Visualisation: the trace planned with the latest chunk is kept in ``last_subgoal_trace`` (B, M, p),
  normalised (None without a planner or before the first chunk; cleared by ``reset()``), so a rollout can draw
  it as ghost robots (paper figure 7, ``subgoalvla-render-traces``) without a second model pass.
- Hub: loading or pushing a Hub id while ``HF_HUB_OFFLINE=1`` fails with one line naming the local
  alternative.
- LeRobot versions: the same code runs on LeRobot 0.6.1 and on main (``lerobot_compat.py``): both
  ``_save_pretrained`` signatures, ``drop_queued_actions`` (main's hook for a new instruction mid-episode),
  ``_fsdp_wrap_modules`` (main's FSDP2 wrap units) and a stop when ``dtype`` asks for mixed precision that the
  training step does not get.

Dimension legend (the package's, ``__init__.py``): ``B`` batch / parallel envs, ``N`` chunk size, ``A`` action
dim, ``h`` history steps, ``p`` proprio dim.
"""

from __future__ import annotations

import contextlib
import logging
from collections import deque
from pathlib import Path
from typing import Any, ClassVar

import torch
from huggingface_hub import is_offline_mode
from lerobot.configs import FeatureType
from lerobot.policies import PreTrainedPolicy
from torch import Tensor

from lerobot_subgoalvla.config_error import DatasetContractError
from lerobot_subgoalvla.contract.keys import STATE_HISTORY_KEY, STATE_KEY, TASK_KEY, TRACE_COLUMNS
from lerobot_subgoalvla.policies.subgoalvla.configuration_subgoalvla import SubgoalVLAConfig
from lerobot_subgoalvla.policies.subgoalvla.dataset_features import ADD_TRACES_COMMAND, dataset_instructions
from lerobot_subgoalvla.policies.subgoalvla.lerobot_compat import (
    BASE_SAVE_TAKES_STATE_DICT,
    model_card,
    require_autocast,
    write_state_dict,
)
from lerobot_subgoalvla.policies.subgoalvla.model import SubgoalVLAModel
from lerobot_subgoalvla.policies.subgoalvla.state_history import StateHistoryBuffer
from lerobot_subgoalvla.policies.subgoalvla.tokenizer import vocabulary_words
from lerobot_subgoalvla.policies.subgoalvla.training_steps import log_loaded_step, seeded_rng

logger = logging.getLogger(__name__)


def _require_online(action: str, alternative: str) -> None:
    """Raise one clear line when ``action`` needs the Hugging Face Hub but offline mode is on."""
    if is_offline_mode():
        raise OSError(f"{action} needs the Hugging Face Hub but HF_HUB_OFFLINE=1 is set; {alternative}")


class SubgoalVLAPolicy(PreTrainedPolicy):
    """SubgoalVLA as a LeRobot policy (``--policy.type=subgoalvla``).

    Args:
        config: the policy config; ``validate_features`` is checked here (LeRobot does not call it).
        dataset_meta: the training dataset's metadata when LeRobot builds the policy from a dataset: its
            features are checked against the data contract (trace and history are needed for training only),
            a tiny backbone takes its vocabulary from its tasks, and a run that would end by pushing to the
            Hub fails now when the Hub is offline. The auxiliary environment head (if on) takes the
            statistics of its target from it.
        **kwargs: the rest of LeRobot's factory arguments (``dataset_stats``): normalisation is the
            processor's job, so the policy does not use them.
    """

    config_class = SubgoalVLAConfig
    name = "subgoalvla"
    #: FSDP2 wrap units for ``lerobot-train --parallelism.dp_shard`` (LeRobot main reads them from the class):
    #: the DiT blocks, the proprioceptive cross-attention blocks, and the layers of the LLaVA-1.5-layout
    #: backbones (LLaMA + CLIP: the tiny, laptop and paper presets). The small preset's backbone (Qwen2 +
    #: SigLIP) needs --accelerator.fsdp.wrap_modules naming Qwen2DecoderLayer and SiglipEncoderLayer instead
    #: (docs/lerobot_versions.md).
    _fsdp_wrap_modules: ClassVar[list[str]] = [
        "DiTBlock",
        "ProprioCrossAttentionBlock",
        "LlamaDecoderLayer",
        "CLIPEncoderLayer",
    ]

    def __init__(self, config: SubgoalVLAConfig, dataset_meta: Any | None = None, **kwargs: Any) -> None:
        super().__init__(config)
        config.validate_features()
        if dataset_meta is not None:
            config.set_dataset_feature_metadata(dataset_meta.features)
            if config.backbone.name_or_path is None and config.backbone.vocabulary is None:
                config.backbone.vocabulary = list(vocabulary_words(dataset_instructions(dataset_meta)))
            if config.push_to_hub and config.repo_id:  # fail before training, not after it
                _require_online(
                    f"--policy.push_to_hub=true (to {config.repo_id!r})",
                    "train with --policy.push_to_hub=false and push the checkpoint later",
                )
        self.config: SubgoalVLAConfig = config
        self.model = SubgoalVLAModel(config)
        if self.model.environment_head is not None and dataset_meta is not None:
            self.model.environment_head.set_statistics(dataset_meta.stats)
        # Optimizer steps done so far; saved with the weights so resume/reload keeps the training stage.
        self.register_buffer("optimizer_steps", torch.zeros((), dtype=torch.long))
        # Base seed of the training draws (noise, timesteps, label dropout, dropout), drawn from the seeded
        # global RNG and saved with the weights: each step's draws then depend on (seed, step) alone, so a
        # `--resume=true` run equals an uninterrupted one (see `_step_rng`).
        self.register_buffer("training_seed", torch.randint(0, 2**31, (), dtype=torch.long))
        self._history = StateHistoryBuffer(config.state_history_len, config.state_stride or 1)
        self._queue: deque[Tensor] = deque(maxlen=config.n_action_steps)
        self._image_sizes_checked = False
        self._start_step_logged = False
        self.reset()

    # Training -----------------------------------------------------------------------------------------------
    @property
    def stage(self) -> str:
        """The training stage in force now ("stage1" or "stage2")."""
        return self.config.stage_at(int(self.optimizer_steps))

    def update(self) -> None:
        """Called by LeRobot after every optimizer step: count it (and log the stage I -> II switch)."""
        before = self.stage
        self.optimizer_steps += 1
        if self.stage != before:
            logger.info(
                "SubgoalVLA: switching to %s after %d optimizer steps", self.stage, int(self.optimizer_steps)
            )

    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict[str, float]]:
        """Training loss of the current stage (eq. 1 = planner eq. 3 + generator eq. 4).

        Args:
            batch: preprocessed batch: cameras (B, 3, H, W) in [0, 1], language tokens/mask (B, L), normalised
                ``observation.state_history`` (B, h, p) and ``observation.subgoal_trace`` (B, M', p),
                ``action`` (B, N, A) and ``action_is_pad`` (B, N).

        Returns:
            The loss and numbers to log: ``planner_loss``, ``generator_loss``, ``stage`` (1 or 2), and
            ``environment_state_loss`` where the auxiliary head is on.
        """
        missing = [key for key in TRACE_COLUMNS if key not in batch]
        if missing:
            raise DatasetContractError(
                f"SubgoalVLA trains on {missing}, which the batch lacks; add them with `{ADD_TRACES_COMMAND}`"
            )
        if self.training:
            require_autocast(self.config.dtype, self.optimizer_steps.device.type)
            if not self._start_step_logged:  # once per run
                self._start_step_logged = True
                log_loaded_step(
                    int(self.optimizer_steps), self.stage, self.config.stage, self.config.stage2_start_step
                )
        stage = self.stage
        with self._step_rng():
            losses = self.model.compute_losses(batch, stage)
        if self.training and not torch.isfinite(losses["loss"]):
            # Stop before the optimizer step: a non-finite loss would poison every weight, and LeRobot would
            # go on logging NaN and save a broken checkpoint.
            step = int(self.optimizer_steps)
            raise FloatingPointError(
                f"SubgoalVLA: training loss is {losses['loss'].item()} at optimizer step {step} (planner "
                f"{losses['planner_loss'].item()}, generator {losses['generator_loss'].item()}); "
                "likely cause: NaN/inf in the dataset (reconvert it: the converter refuses them) or a "
                "learning rate too high for this preset"
            )
        logs = {name: value.item() for name, value in losses.items() if name != "loss"}
        return losses["loss"], {**logs, "stage": 1 if stage == "stage1" else 2}

    def _step_rng(self) -> contextlib.AbstractContextManager:
        """In training, the global RNG seeded from (training_seed, step, rank) for one forward, then restored.

        Why: LeRobot 0.6.1 restores the RNG states on ``--resume`` before it builds a new DataLoader iterator,
        whose base seed is one more draw from the global generator, so every later draw of a resumed run would
        be shifted by one against the uninterrupted run. Keyed draws make a resumed run identical (tested in
        ``test_lerobot_integration.py``); the rank keeps processes of a multi-GPU run from sharing noise.
        The outer RNG stream is left as it was, so LeRobot's own draws are unchanged.
        """
        if not self.training:
            return contextlib.nullcontext()
        device = self.optimizer_steps.device  # the policy's device: the batch is moved there first
        rank = torch.distributed.get_rank() if torch.distributed.is_initialized() else 0
        seed = (int(self.training_seed) * 1_000_003 + int(self.optimizer_steps)) * 1009 + rank
        return seeded_rng(seed % 2**63, device)

    def get_optim_params(self) -> list[dict[str, Any]]:
        """Parameter groups with the paper's learning rates (table 8); frozen parameters are left out.

        Raises:
            RuntimeError: when a trainable parameter belongs to no group (a new module must be assigned one).
        """
        backbone = self.model.backbone
        cfg = self.config
        # An unfrozen vision tower (--policy.backbone.freeze_vision_tower=false)
        # joins the most conservative group.
        projector = backbone.projector_parameters()
        if not cfg.backbone.freeze_vision_tower:
            projector = backbone.vision_parameters() + projector
        groups = [
            {"params": self.model.head_parameters(), "lr": cfg.optimizer_lr_heads},
            {"params": projector, "lr": cfg.optimizer_lr_projector},
            {"params": backbone.language_model_parameters(), "lr": cfg.optimizer_lr_llm},
        ]
        for group in groups:
            group["params"] = [p for p in group["params"] if p.requires_grad]
        grouped = {id(p) for group in groups for p in group["params"]}
        orphans = [n for n, p in self.named_parameters() if p.requires_grad and id(p) not in grouped]
        if orphans:
            raise RuntimeError(f"SubgoalVLA parameters in no optimizer group: {orphans[:5]}")
        return [group for group in groups if group["params"]]

    # Inference ----------------------------------------------------------------------------------------------
    def reset(self) -> None:
        """Forget the action queue, the state history, the last instruction and trace (start of a rollout)."""
        self._queue.clear()
        self._history.reset()
        self._last_tasks: list[str] | None = None
        self._num_envs: int | None = None
        #: The subgoal trace (B, M, p) planned with the latest chunk, normalised; None without a planner.
        self.last_subgoal_trace: Tensor | None = None

    def _on_new_step(self, batch: dict[str, Any], num_envs: int) -> None:
        """Flush the queue and restart the history of envs whose ``batch["task"]`` changed (new subtask).

        A different number of envs than at the previous step starts everything afresh.
        """
        tasks = batch.get(TASK_KEY)
        tasks = [tasks] if isinstance(tasks, str) else (None if tasks is None else list(tasks))
        if self._num_envs is not None and num_envs != self._num_envs:
            self.reset()
        elif tasks is not None and self._last_tasks is not None and tasks != self._last_tasks:
            changed = torch.tensor([new != old for new, old in zip(tasks, self._last_tasks, strict=True)])
            self.drop_queued_actions()
            self._history.reset(changed)
        self._num_envs = num_envs
        self._last_tasks = tasks

    def drop_queued_actions(self) -> None:
        """Forget the queued actions, so that the next ``select_action`` predicts a new chunk.

        LeRobot main calls it when the instruction changes mid-episode (its rollout's task switch); the policy
        calls it itself when ``batch["task"]`` changes. The state history stays (``reset()`` clears it).
        """
        self._queue.clear()

    @torch.no_grad()
    def predict_action_chunk(self, batch: dict[str, Tensor], **kwargs: Any) -> Tensor:
        """A normalised action chunk (B, N, A) for the current observation.

        Uses ``batch["observation.state_history"]`` when present (dataset batches, ``select_action``);
        otherwise pushes ``observation.state`` into the policy's history buffer and uses that. The planned
        trace is kept in ``last_subgoal_trace`` (module docstring).
        """
        if STATE_HISTORY_KEY not in batch:
            batch = {**batch, STATE_HISTORY_KEY: self._history.push(batch[STATE_KEY])}
        actions, trace = self.model.sample_actions(batch)
        self.last_subgoal_trace = trace  # (B, M, p) normalised, or None without a planner
        return actions

    @torch.no_grad()
    def select_action(self, batch: dict[str, Tensor], **kwargs: Any) -> Tensor:
        """The next action (B, A): pops the queue, predicting a new chunk (one backbone pass) when it is
        empty."""
        state = batch[STATE_KEY]  # (B, p), normalised by the preprocessor
        if not self._image_sizes_checked:
            self._image_sizes_checked = True
            self._warn_on_other_image_sizes(batch)
        self._on_new_step(batch, state.shape[0])
        history = self._history.push(state)  # (B, h, p), every step, so the history has no gaps
        if not self._queue:
            chunk = self.predict_action_chunk({**batch, STATE_HISTORY_KEY: history})  # (B, N, A)
            self._queue.extend(chunk[:, : self.config.n_action_steps].transpose(0, 1))  # n x (B, A)
        return self._queue.popleft()

    def _warn_on_other_image_sizes(self, batch: dict[str, Tensor]) -> None:
        """Say it once when the cameras differ in size from the training data: the model resizes them to its
        vision tower anyway, but objects then appear at another scale than in training."""
        for key, feature in self.config.input_features.items():
            if key in batch and feature.type is FeatureType.VISUAL and batch[key].ndim == 4:
                trained, seen = tuple(feature.shape[-2:]), tuple(batch[key].shape[-2:])  # (H, W)
                if trained != seen:
                    logger.warning(
                        "%s is %dx%d but the policy was trained on %dx%d images; evaluate with the training "
                        "sizes (the env's image-size flags)",
                        key, *seen, *trained,
                    )  # fmt: skip

    # Hub ----------------------------------------------------------------------------------------------------
    @classmethod
    def from_pretrained(
        cls, pretrained_name_or_path: str | Path, *, strict: bool = True, **kwargs: Any
    ) -> SubgoalVLAPolicy:
        """LeRobot's ``from_pretrained``, strict by default; a Hub id fails fast and clearly when offline.

        LeRobot loads with ``strict=False`` and only logs the weights a checkpoint lacks, which then keep
        their random initialisation: a policy that acts differently with every ``--seed``. A checkpoint that
        does not match this model raises instead; ``strict=False`` restores LeRobot's behaviour.

        Raises:
            DatasetContractError: If ``strict`` and the checkpoint's weights do not match the model of its
                config (a ``ValueError``; LeRobot's CLIs print it as one line).
        """
        if not Path(pretrained_name_or_path).is_dir():
            _require_online(
                f"loading {str(pretrained_name_or_path)!r} (not a local directory)",
                "pass a local checkpoint directory such as "
                "outputs/train/<run>/checkpoints/last/pretrained_model",
            )
        try:
            return super().from_pretrained(pretrained_name_or_path, strict=strict, **kwargs)
        except RuntimeError as err:
            if "Error(s) in loading state_dict" not in str(err):
                raise
            detail = " ".join(str(err).split())
            detail = detail if len(detail) <= 300 else detail[:300] + " ..."
            raise DatasetContractError(
                f"{pretrained_name_or_path}: the checkpoint's weights do not match this SubgoalVLA "
                f"({detail}); load it with the lerobot-subgoalvla version that saved it, or pass "
                "strict=False to keep the unmatched weights random"
            ) from err

    def _load_from_state_dict(self, state_dict: dict[str, Tensor], prefix: str, *args: Any) -> None:
        key = f"{prefix}training_seed"
        if key not in state_dict:  # checkpoints saved before the buffer existed
            logger.warning(
                "the checkpoint has no training_seed (saved before it existed): training on from it draws "
                "its randomness from a new seed, %d",
                int(self.training_seed),
            )
            state_dict[key] = self.training_seed.clone()
        super()._load_from_state_dict(state_dict, prefix, *args)

    def save_pretrained(
        self,
        save_directory: str | Path,
        *,
        state_dict: dict[str, Tensor] | None = None,
        card_kwargs: dict[str, Any] | None = None,
        push_to_hub: bool = False,
        repo_id: str | None = None,
        **kwargs: Any,
    ) -> str | None:
        """Save config + weights; with ``card_kwargs`` (e.g. ``{"dataset_repo_id": ...}``) also a model card.

        ``state_dict``: a full state dict the caller gathered (LeRobot 0.6.1's FSDP checkpointing passes one);
        None saves the policy's own. LeRobot's model card is validated with the Hub, so the card needs a
        connection; it is always written when pushing (``push_to_hub`` saves through this method).

        ``push_to_hub=True`` then uploads the directory (``repo_id`` defaults to its name).
        """
        save_directory = Path(save_directory)
        save_directory.mkdir(parents=True, exist_ok=True)
        self._save_pretrained(save_directory, state_dict=state_dict)
        if card_kwargs is not None:
            card = model_card(self, card_kwargs.get("dataset_repo_id", "unknown"))
            card.save(str(save_directory / "README.md"))
        if push_to_hub:
            return self.push_to_hub(repo_id or Path(save_directory).name, card_kwargs=card_kwargs, **kwargs)
        return None

    def _save_pretrained(self, save_directory: Path, state_dict: dict[str, Tensor] | None = None) -> None:
        """Config + weights into ``save_directory``, under either LeRobot's signature of this hook.

        LeRobot 0.6.1 calls it with a pre-gathered ``state_dict`` (or None), main with the directory alone
        (its base gathers a sharded policy itself). A given ``state_dict`` is written on both.
        """
        if state_dict is None:
            super()._save_pretrained(save_directory)
        elif BASE_SAVE_TAKES_STATE_DICT:
            super()._save_pretrained(save_directory, state_dict=state_dict)
        else:
            write_state_dict(self.config, state_dict, save_directory)

    def push_to_hub(self, repo_id: str, *, card_kwargs: dict[str, Any] | None = None, **kwargs: Any) -> str:
        """Upload config, weights and a model card to ``repo_id``; fails with one line when offline."""
        _require_online(
            f"push_to_hub({repo_id!r})", "save locally with policy.save_pretrained(<dir>) instead"
        )
        return super().push_to_hub(repo_id, card_kwargs=card_kwargs or {}, **kwargs)


__all__ = ["SubgoalVLAPolicy"]
