"""`CodaKvmPolicy`: loss and gradients, frozen old skills, save/load, skill forcing, action queue, input checks."""

import pytest
import torch
from safetensors.torch import load_file, save_file

from lerobot_kvm.policy import CodaKvmPolicy
from lerobot_kvm.policy.coda_prompt import Skill

IMAGE_KEY = "observation.images.front"


def train_steps(policy: CodaKvmPolicy, optimizer: torch.optim.Optimizer, batch: dict, n: int) -> None:
    policy.train()
    for _ in range(n):
        loss, _ = policy.forward(batch)
        loss.backward()
        optimizer.step()
        optimizer.zero_grad()


def test_forward_gives_finite_loss_and_grads_reach_only_the_current_skill(make_policy, make_batch) -> None:
    policy = make_policy()
    policy.begin_new_skill("firm_grasp", "grip hard")
    loss, info = policy.forward(make_batch(policy.config))
    assert loss.ndim == 0 and torch.isfinite(loss)
    assert "l1_loss" in info and all(isinstance(v, float) for v in info.values())
    assert all(k == "l1_loss" or k.startswith("kvm_") for k in info)  # the KVM's offline learning metrics
    loss.backward()
    for name, p in policy.backbone.named_parameters():
        assert p.grad is not None and p.grad.abs().sum() > 0, name
    for t, task in enumerate(policy.pool.tasks):
        for name, p in task.named_parameters():
            if t == 1:
                assert p.grad is not None and p.grad.abs().sum() > 0, f"task {t} {name}"
            else:
                assert p.grad is None, f"task {t} {name} must not receive gradients"


def test_per_sample_loss_and_ortho_penalty(make_policy, make_batch) -> None:
    policy = make_policy(ortho_weight=0.1)
    per_sample, info = policy.forward(make_batch(policy.config), reduction="none")
    assert per_sample.shape == (3,) and torch.isfinite(per_sample).all()
    assert "ortho_loss" in info


def test_forward_trains_the_new_skill_under_its_own_prompt_alone(make_policy, make_batch) -> None:
    policy = make_policy()
    policy.train()
    batch = make_batch(policy.config)
    policy.forward(batch)
    assert int(policy.pool.prototype_counts[0].sum()) == 3  # skill 0 keeps its training queries
    policy.begin_new_skill("next")
    policy.eval()  # no dropout: the two losses below must be equal
    own = policy.pool.own_weights(1, 3)
    assert policy.forward(batch)[0].item() == policy.forward(batch, skill_weights=own)[0].item()
    policy.train()
    loss, _ = policy.forward(batch)
    loss.backward()
    assert policy.pool.tasks[1].prompts.grad is not None and policy.pool.tasks[0].prompts.grad is None
    assert int(policy.pool.prototype_counts[1].sum()) == 3 and int(policy.pool.prototype_counts[0].sum()) == 3


def test_frozen_backbone_trains_only_the_current_skill(make_policy, make_batch) -> None:
    policy = make_policy(train_backbone=False)
    groups = policy.get_optim_params()
    kvm = {id(p) for p in policy.kvm.learnable_parameters()}
    params = [p for g in groups for p in g["params"] if id(p) not in kvm]
    assert {id(p) for p in params} == {id(p) for p in policy.pool.tasks[0].parameters()}
    assert all(g.get("weight_decay") == 0.0 for g in groups)
    policy.forward(make_batch(policy.config))[0].backward()
    assert all(p.grad is None for p in policy.backbone.parameters())


def test_weight_decay_only_on_backbone(make_policy) -> None:
    policy = make_policy()
    backbone, prompts, kvm = policy.get_optim_params()
    assert {id(p) for p in kvm["params"]} == {id(p) for p in policy.kvm.learnable_parameters()}
    assert "weight_decay" not in backbone and prompts["weight_decay"] == 0.0
    assert {id(p) for p in backbone["params"]} == {id(p) for p in policy.backbone.parameters()}
    assert {id(p) for p in prompts["params"]} == {id(p) for p in policy.pool.tasks[0].parameters()}


def test_earlier_skill_bit_identical_after_training_a_new_one(make_policy, make_batch) -> None:
    policy = make_policy()
    batch = make_batch(policy.config)
    # Worst case: one optimizer over *all* parameters with weight decay and momentum from skill 0.
    optimizer = torch.optim.AdamW(policy.parameters(), lr=1e-2, weight_decay=0.5)
    train_steps(policy, optimizer, batch, 3)
    before = {k: v.clone() for k, v in policy.pool.tasks[0].state_dict().items()}
    policy.begin_new_skill("skill_1")
    new_before = {k: v.clone() for k, v in policy.pool.tasks[1].state_dict().items()}
    train_steps(policy, optimizer, batch, 3)
    fresh = torch.optim.AdamW(policy.get_optim_params(), lr=1e-2, weight_decay=0.5)
    train_steps(policy, fresh, batch, 3)
    for k, v in policy.pool.tasks[0].state_dict().items():
        assert torch.equal(v, before[k]), f"old skill tensor {k} changed"
    assert any(not torch.equal(v, new_before[k]) for k, v in policy.pool.tasks[1].state_dict().items())


def test_save_load_round_trip_is_bit_identical(make_policy, make_batch, tmp_path) -> None:
    policy = make_policy()
    batch = make_batch(policy.config)
    optimizer = torch.optim.AdamW(policy.get_optim_params(), lr=1e-2)
    train_steps(policy, optimizer, batch, 2)
    policy.begin_new_skill("gentle_grasp", "grip softly for fragile objects")
    train_steps(policy, torch.optim.AdamW(policy.get_optim_params(), lr=1e-2), batch, 2)
    policy.save_pretrained(tmp_path)
    loaded = CodaKvmPolicy.from_pretrained(tmp_path)
    assert loaded.n_skills == 2
    assert loaded.skills == [Skill(0, "skill_0", ""), Skill(1, "gentle_grasp", "grip softly for fragile objects")]
    original, restored = policy.state_dict(), loaded.state_dict()
    assert original.keys() == restored.keys()
    for k, v in original.items():
        assert torch.equal(v, restored[k]), k
    assert [p.requires_grad for p in loaded.parameters()] == [p.requires_grad for p in policy.parameters()]
    batch = make_batch(policy.config, with_action=False)
    assert torch.equal(policy.predict_action_chunk(batch), loaded.predict_action_chunk(batch))


def test_loading_with_a_new_skill_name_begins_the_next_task(make_policy, make_batch, tmp_path) -> None:
    """`lerobot-train --policy.path=<previous> --policy.skill_name=<next>`: the checkpoint's skills are loaded
    bit-identically and the next task begins in new components; the saved result round-trips as it is."""
    policy = make_policy()
    batch = make_batch(policy.config)
    train_steps(policy, torch.optim.AdamW(policy.get_optim_params(), lr=1e-2), batch, 2)
    policy.save_pretrained(tmp_path / "stage0")
    config = CodaKvmPolicy.config_class.from_pretrained(tmp_path / "stage0")
    config.skill_name = "gentle_grasp"
    grown = CodaKvmPolicy.from_pretrained(tmp_path / "stage0", config=config)
    assert [s.name for s in grown.skills] == [policy.skills[0].name, "gentle_grasp"]
    assert int(grown.pool.task_count) == 2
    for k, v in policy.pool.tasks[0].state_dict().items():
        assert torch.equal(v, grown.pool.tasks[0].state_dict()[k]), k
    assert torch.equal(policy.query_fingerprint, grown.query_fingerprint)
    trainable = {n for n, p in grown.pool.named_parameters() if p.requires_grad}
    assert trainable and all(n.startswith("tasks.1.") for n in trainable)
    grown.save_pretrained(tmp_path / "stage1")
    again = CodaKvmPolicy.from_pretrained(tmp_path / "stage1")
    assert again.skills == grown.skills
    for k, v in grown.state_dict().items():
        assert torch.equal(v, again.state_dict()[k]), k


def test_incompatible_checkpoint_is_a_clear_error(make_policy, make_config, tmp_path) -> None:
    make_policy().save_pretrained(tmp_path)
    with pytest.raises(ValueError, match="incompatible.*shape"):
        CodaKvmPolicy.from_pretrained(tmp_path, config=make_config(prompt_length=6))
    state = load_file(tmp_path / "model.safetensors")
    del state["kvm.metabolism.streak"]  # state added later: older checkpoints load, it starts fresh
    save_file(state, tmp_path / "model.safetensors")
    assert int(CodaKvmPolicy.from_pretrained(tmp_path).kvm.metabolism.streak.sum()) == 0
    del state["pool.task_count"]
    save_file(state, tmp_path / "model.safetensors")
    with pytest.raises(ValueError, match="pool.task_count"):
        CodaKvmPolicy.from_pretrained(tmp_path)


def test_changed_query_encoder_is_refused(make_policy, make_batch) -> None:
    policy = make_policy()
    batch = make_batch(policy.config)
    policy.forward(batch)
    policy.load_state_dict({**policy.state_dict(), "query_fingerprint": torch.ones(policy.config.query_dim)})
    with pytest.raises(ValueError, match="embeds differently"):
        policy.forward(batch)


def test_forcing_one_skill_changes_the_actions(make_policy, make_batch) -> None:
    policy = make_policy()
    policy.config.kvm.enabled = False  # the plain CODA-Prompt core (the KVM's own fusion is tested in tests/kvm)
    policy.begin_new_skill("skill_1")
    policy.eval()
    batch = make_batch(policy.config, with_action=False)
    coda = policy.predict_action_chunk(batch)
    assert torch.equal(policy.predict_action_chunk(batch, skill_weights=torch.ones(3, 2)), coda)
    only_0 = policy.predict_action_chunk(batch, skill_weights=torch.tensor([[1.0, 0.0]] * 3))
    only_1 = policy.predict_action_chunk(batch, skill_weights=torch.tensor([[0.0, 1.0]] * 3))
    assert (only_0 - only_1).abs().max() > 1e-4
    assert (only_0 - coda).abs().max() > 1e-5


def test_skill_relevance_and_prompts_for_task_strings(make_policy) -> None:
    policy = make_policy()
    policy.begin_new_skill("skill_1")
    tasks = ["pick up the stone", "gently pick up the egg"]
    relevance = policy.skill_relevance(tasks)
    prompts = policy.skill_prompts(tasks)
    assert relevance.shape == (2, 2) and torch.equal(relevance, torch.ones(2, 2))  # no skill has seen a query yet
    assert prompts.shape == (2, 2, 2, 4, 32)
    query = policy.encode_query(tasks)
    for skill in range(2):
        assert torch.equal(policy.pool(query, policy.pool.own_weights(skill, 2)), prompts[:, :, skill])


def test_select_action_uses_a_chunk_queue(make_policy, make_batch) -> None:
    policy = make_policy()
    batch = make_batch(policy.config, batch_size=2, with_action=False)
    chunk = policy.predict_action_chunk(batch)
    actions = [policy.select_action(batch) for _ in range(3)]
    assert actions[0].shape == (2, 5)
    assert torch.equal(actions[0], chunk[:, 0]) and torch.equal(actions[1], chunk[:, 1])
    assert torch.equal(actions[2], chunk[:, 0])  # n_action_steps=2: the third call predicts a new chunk
    policy.reset()
    assert len(policy._action_queue) == 0


@pytest.mark.parametrize("infer", ["select_action", "predict_action_chunk"])
def test_inference_switches_a_policy_left_in_training_mode_to_eval(make_policy, make_batch, infer) -> None:
    policy = make_policy(dropout=0.5)
    batch = make_batch(policy.config, batch_size=2, with_action=False)
    policy.eval()
    expected = policy.predict_action_chunk(batch)
    policy.train()
    out = getattr(policy, infer)(batch)
    assert not any(m.training for m in policy.modules())
    torch.testing.assert_close(out, expected[:, 0] if infer == "select_action" else expected)  # no dropout


@pytest.mark.parametrize(
    ("mutate", "key"),
    [
        (lambda b: b.pop("observation.context"), "observation.context"),
        (lambda b: b.pop(IMAGE_KEY), IMAGE_KEY),
        (lambda b: b.__setitem__("observation.state", torch.zeros(3, 7)), "observation.state"),
        (lambda b: b.__setitem__("observation.context", torch.zeros(2, 23)), "observation.context"),
        (lambda b: b.__setitem__(IMAGE_KEY, torch.zeros(3, 3, 16, 16)), IMAGE_KEY),
        (lambda b: b["observation.context"].__setitem__((1, 4), float("nan")), "observation.context"),
        (lambda b: b["observation.state"].__setitem__((0, 0), float("inf")), "observation.state"),
        (lambda b: b.__setitem__("task", ["only one"]), "task"),
        (lambda b: b.pop("task"), "task"),
        (lambda b: b.__setitem__("action", torch.zeros(3, 2, 5)), "action"),
        (lambda b: b["action"].__setitem__((0, 0, 0), float("nan")), "action"),
    ],
)
def test_bad_inputs_raise_value_error_naming_the_key(make_policy, make_batch, mutate, key) -> None:
    policy = make_policy()
    batch = make_batch(policy.config)
    mutate(batch)
    with pytest.raises(ValueError, match=key.replace(".", r"\.")):
        policy.forward(batch)


def test_bad_select_action_input_raises(make_policy, make_batch) -> None:
    policy = make_policy()
    batch = make_batch(policy.config, batch_size=1, with_action=False)
    batch["observation.state"] = torch.zeros(6)
    with pytest.raises(ValueError, match=r"observation\.state.*\[1, 6\]"):
        policy.select_action(batch)


def test_forcing_a_skill_of_a_trained_pool_gives_exactly_its_stage_trained_actions(make_policy, make_batch) -> None:
    """Two stages, each a different task with its own targets (the second with the backbone frozen, as the
    sequences train it): afterwards each skill, forced alone, acts exactly as right after its own stage (tolerance
    0), the two act differently, and the KVM-off fusion routes each task to the skill that learned it alone."""
    policy = make_policy()
    stages = []
    for stage, task in enumerate(("pick up the stone", "open the drawer")):
        if stage:
            policy.begin_new_skill("drawer")
            policy.backbone.requires_grad_(False)
        batch = make_batch(policy.config, batch_size=4)
        batch["task"] = [task] * 4
        batch["action"] = torch.full_like(batch["action"], 1.0 - 2.0 * stage)  # +1 for the stone, -1 for the drawer
        optimizer = torch.optim.Adam([p for p in policy.parameters() if p.requires_grad], lr=3e-3 if stage else 1e-3)
        policy.train()
        for _ in range(100 if stage else 30):
            loss, _ = policy.forward(batch)
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
        policy.eval()
        query = {k: v for k, v in batch.items() if k not in ("action", "action_is_pad")}
        stages.append((query, policy.predict_action_chunk(query, skill_weights=policy.pool.own_weights(stage, 4))))
    forced = []
    for skill, (query, trained) in enumerate(stages):
        forced.append(policy.predict_action_chunk(query, skill_weights=policy.pool.own_weights(skill, 4)))
        assert torch.equal(forced[-1], trained)
        policy.config.kvm.enabled = False
        assert torch.equal(policy.predict_action_chunk(query), forced[-1])  # the other task's skill: no candidate
        policy.config.kvm.enabled = True
    # the second skill, a prompt on a frozen backbone, moved its task's actions towards its own target
    assert forced[0].mean() - forced[1].mean() > 0.05
