"""SubgoalVLAPolicy: training losses and stages, optimizer groups, ablations, inference queue/history,
save/load."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from helpers.policy_batches import inference_observation

from lerobot_subgoalvla.policies.subgoalvla.modeling_subgoalvla import SubgoalVLAPolicy

HISTORY = "observation.state_history"


def _train_step(policy: SubgoalVLAPolicy, batch: dict, steps: int = 1) -> list[float]:
    """``steps`` optimizer steps the way lerobot-train does them (preset optimizer, update() hook)."""
    optimizer = policy.config.get_optimizer_preset().build(policy.get_optim_params())
    policy.train()
    losses = []
    for _ in range(steps):
        loss, _ = policy.forward(batch)
        loss.backward()
        optimizer.step()
        optimizer.zero_grad()
        policy.update()
        losses.append(loss.item())
    return losses


def test_forward_gives_finite_losses_and_gradients_reach_every_group(
    make_config, make_policy_and_processors, raw_batch
):
    policy, pre, _ = make_policy_and_processors(make_config())
    batch = pre(dict(raw_batch))
    _train_step(policy, batch, steps=2)  # adaLN-zero DiTs: nothing upstream gets gradient for the first steps
    loss, logs = policy.forward(batch)
    assert torch.isfinite(loss) and loss.item() > 0
    assert set(logs) == {"planner_loss", "generator_loss", "stage"} and logs["stage"] == 1
    assert loss.item() == pytest.approx(logs["planner_loss"] + logs["generator_loss"], rel=1e-5)
    loss.backward()
    for group in policy.get_optim_params():  # heads, projector, LLM: all receive gradient in stage I
        assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in group["params"])
    assert all(p.grad is None for p in policy.model.backbone.vision_parameters())  # frozen


def test_training_draws_depend_on_the_step_alone_and_leave_the_global_rng_as_it_was(
    make_config, make_policy_and_processors, raw_batch
) -> None:
    """Why: LeRobot's --resume shifts the global RNG by one draw; the loss must not depend on that stream."""
    policy, pre, _ = make_policy_and_processors(make_config())
    batch = pre(dict(raw_batch))
    policy.train()
    torch.manual_seed(0)
    first, _ = policy.forward(batch)
    state = torch.get_rng_state()
    torch.rand(3)  # e.g. a new DataLoader iterator drawing its base seed
    again, _ = policy.forward(batch)
    assert torch.equal(first, again)  # same step, same draws, whatever the global stream did
    torch.set_rng_state(state)
    policy.forward(batch)
    assert torch.equal(torch.get_rng_state(), state)  # the forward consumed nothing of the outer stream
    policy.optimizer_steps += 1
    assert not torch.equal(policy.forward(batch)[0], first)  # the next step draws anew
    policy.eval()
    assert "training_seed" in policy.state_dict()  # saved, so a reload keeps the stream


def test_a_non_finite_loss_stops_training_with_the_step_and_the_cause(
    make_config, make_policy_and_processors, raw_batch
) -> None:
    policy, pre, _ = make_policy_and_processors(make_config())
    batch = pre(dict(raw_batch))
    batch["action"] = batch["action"].clone()
    batch["action"][0, 0, 0] = float("nan")  # what a NaN in one dataset frame becomes
    policy.train()
    with pytest.raises(
        FloatingPointError, match=r"training loss is nan at optimizer step 0 .* NaN/inf in the data"
    ):
        policy.forward(batch)


def test_optimizer_groups_have_the_configured_learning_rates(make_config, make_policy_and_processors) -> None:
    rates = {"optimizer_lr_heads": 1e-4, "optimizer_lr_projector": 1e-5, "optimizer_lr_llm": 2e-5}
    policy, _, _ = make_policy_and_processors(make_config(**rates))
    groups = policy.get_optim_params()
    assert [g["lr"] for g in groups] == [1e-4, 1e-5, 2e-5]  # heads first: LeRobot logs param_groups[0]
    grouped = {id(p) for g in groups for p in g["params"]}
    vision = {id(p) for p in policy.model.backbone.vision_parameters()}
    assert not grouped & vision
    assert grouped == {id(p) for p in policy.parameters() if p.requires_grad}


def test_stage_two_freezes_the_backbone(make_config, make_policy_and_processors, raw_batch) -> None:
    policy, pre, _ = make_policy_and_processors(make_config(stage="stage2"))
    batch = pre(dict(raw_batch))
    _train_step(policy, batch, steps=2)
    loss, logs = policy.forward(batch)
    loss.backward()
    assert logs["stage"] == 2
    assert all(p.grad is None for p in policy.model.backbone.parameters())
    for head in (policy.model.planner, policy.model.generator, policy.model.generator_aggregator):
        assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in head.parameters())


def test_one_run_switches_stage_at_the_configured_step_and_keeps_it_on_reload(
    make_config, make_policy_and_processors, raw_batch, tmp_path: Path
) -> None:
    policy, pre, _ = make_policy_and_processors(make_config(stage2_start_step=2))
    batch = pre(dict(raw_batch))
    stages = []
    for _ in range(3):
        stages.append(policy.forward(batch)[1]["stage"])
        policy.update()
    assert stages == [1, 1, 2]
    policy.save_pretrained(tmp_path)
    reloaded = SubgoalVLAPolicy.from_pretrained(tmp_path)
    assert int(reloaded.optimizer_steps) == 3 and reloaded.stage == "stage2"  # resume continues in stage II


def test_a_loaded_policy_past_its_switch_says_at_the_first_training_step_that_it_trains_stage_two_only(
    make_config, make_policy_and_processors, raw_batch, caplog
) -> None:
    """Why: a policy fine-tuned with --policy.path keeps its step count while the schedule restarts."""
    policy, pre, _ = make_policy_and_processors(make_config(stage2_start_step=2))
    batch = pre(dict(raw_batch))
    policy.optimizer_steps += 5  # what from_pretrained restores from a finished run's weights
    policy.train()
    with caplog.at_level("INFO", logger="lerobot_subgoalvla"):
        policy.forward(batch)
        policy.forward(batch)
    warnings = [r for r in caplog.records if "trains stage II only" in r.getMessage()]
    assert len(warnings) == 1 and warnings[0].levelname == "WARNING"  # once per run, not per step
    assert "--policy.stage2_start_step=2" in warnings[0].getMessage()


@pytest.mark.parametrize(
    "overrides",
    [
        {"feature_aggregation": "mean"},
        {"feature_aggregation": "max"},
        {"feature_aggregation": "attn"},
        {"use_planner": False},
        {"subgoal_trace_len": 1},
    ],
    ids=["mean", "max", "attn", "wo_SP", "wo_ST"],
)
def test_every_ablation_trains_a_step(make_config, make_policy_and_processors, raw_batch, overrides) -> None:
    policy, pre, _ = make_policy_and_processors(make_config(aggregation_top_k=8, **overrides))
    before = {n: p.detach().clone() for n, p in policy.named_parameters() if p.requires_grad}
    (loss,) = _train_step(policy, pre(dict(raw_batch)))
    assert torch.isfinite(torch.tensor(loss))
    changed = [n for n, p in policy.named_parameters() if p.requires_grad and not torch.equal(p, before[n])]
    assert any(n.startswith("model.generator.") for n in changed)
    assert (policy.model.planner is None) == (overrides == {"use_planner": False})


def test_forward_without_a_trace_names_the_command_that_adds_it(
    make_config, make_policy_and_processors, raw_batch
) -> None:
    policy, pre, _ = make_policy_and_processors(make_config())
    batch = pre(dict(raw_batch))
    batch.pop("observation.subgoal_trace")
    with pytest.raises(ValueError, match="observation.subgoal_trace.*subgoalvla-add-traces"):
        policy.forward(batch)


def _count_chunk_predictions(policy: SubgoalVLAPolicy) -> list[torch.Tensor]:
    """Wrap the model's sampler; returns the list of state histories it was called with."""
    histories: list[torch.Tensor] = []
    sample = policy.model.sample_actions

    def recording(batch, generator=None):
        histories.append(batch[HISTORY].clone())
        return sample(batch, generator)

    policy.model.sample_actions = recording
    return histories


def test_queue_runs_the_model_once_per_chunk_and_replans_on_a_new_instruction(
    make_config, make_policy_and_processors, raw_batch
) -> None:
    policy, pre, _ = make_policy_and_processors(make_config(n_action_steps=3))
    policy.eval()
    obs = inference_observation(pre(dict(raw_batch)))
    state = obs["observation.state"]

    def at_step(step: int, tasks: list[str]) -> dict:
        return {**obs, "observation.state": state + 0.1 * step, "task": tasks}  # the robot moves every step

    calls = _count_chunk_predictions(policy)
    actions = [policy.select_action(at_step(i, obs["task"])) for i in range(6)]
    assert len(calls) == 2 and all(a.shape == (4, 7) for a in actions)
    new_tasks = ["open the drawer", *obs["task"][1:]]  # env 0 moves on to its next subtask
    policy.select_action(at_step(6, new_tasks))
    assert len(calls) == 3  # the queue was flushed: a new chunk for the new instruction
    fresh = calls[-1]  # (B, h, p)
    newest = state + 0.6
    assert torch.equal(fresh[0], newest[0].expand_as(fresh[0]))  # env 0's history restarted at its new state
    torch.testing.assert_close(
        fresh[1, -7:], torch.stack([state[1] + 0.1 * i for i in range(7)])
    )  # env 1 kept its
    assert torch.equal(fresh[1, 0], state[1])  # history: first state repeated before the rollout start
    policy.reset()
    policy.select_action(obs)
    assert len(calls) == 4


def test_inference_history_equals_the_normalised_dataset_history(
    make_config, make_policy_and_processors, tiny_dataset
):
    """Step through episode 1 frame by frame as lerobot-eval would (raw state + cameras + task only)."""
    policy, pre, _ = make_policy_and_processors(make_config(n_action_steps=1))
    policy.eval()
    histories = _count_chunk_predictions(policy)
    episode = tiny_dataset.meta.episodes[1]
    start, end = episode["dataset_from_index"], episode["dataset_to_index"]
    expected = []
    for index in range(start, end):
        frame = tiny_dataset[index]
        observation = {
            k: frame[k]
            for k in ("observation.state", "observation.images.static", "observation.images.gripper")
        }
        policy.select_action(pre({**observation, "task": frame["task"]}))  # unbatched -> batch of 1
        expected.append(pre({**frame})[HISTORY])  # the dataset's precomputed history, normalised
    torch.testing.assert_close(torch.cat(histories), torch.cat(expected), rtol=1e-6, atol=1e-6)


def test_save_load_is_exact_and_actions_match(
    make_config, make_policy_and_processors, raw_batch, tmp_path: Path
):
    cfg = make_config()
    policy, pre, _ = make_policy_and_processors(cfg)
    _train_step(policy, pre(dict(raw_batch)))  # move away from the initialisation (zero-init DiT outputs)
    policy.eval()
    policy.save_pretrained(tmp_path)
    reloaded = SubgoalVLAPolicy.from_pretrained(tmp_path)
    state, state2 = policy.state_dict(), reloaded.state_dict()
    assert state.keys() == state2.keys()
    for key in state:
        torch.testing.assert_close(state2[key], state[key], atol=0, rtol=0)
    obs = inference_observation(pre(dict(raw_batch)))
    torch.manual_seed(123)
    expected = policy.predict_action_chunk(obs)
    torch.manual_seed(123)
    actual = reloaded.predict_action_chunk(obs)
    assert torch.equal(expected, actual)
    assert not torch.equal(expected[0], expected[1])  # actions depend on the observation


def test_cameras_of_another_size_than_in_training_are_reported_once(
    make_config, make_policy_and_processors, raw_batch, caplog
) -> None:
    import logging

    import torch.nn.functional as F  # noqa: N812

    policy, pre, _ = make_policy_and_processors(make_config())
    policy.eval()
    obs = inference_observation(pre(dict(raw_batch)))
    obs = {**obs, "observation.images.static": F.interpolate(obs["observation.images.static"], size=(40, 40))}
    with caplog.at_level(logging.WARNING):
        policy.select_action(obs)
        policy.select_action(obs)
    warnings = [r.getMessage() for r in caplog.records if "trained on" in r.getMessage()]
    assert len(warnings) == 1 and "observation.images.static is 40x40" in warnings[0]
