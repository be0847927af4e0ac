"""The KVM inside `coda_kvm`: ablation switches, identity with the CODA core, fail-safe, telemetry, offline
learning inside forward() (labels, leakage rule), config on the command line, overhead measurement."""

import json

import draccus
import pytest
import torch

from lerobot_kvm.evaluation.overhead import measure_overhead, paired_ratio
from lerobot_kvm.kvm.attribution import PERSISTENCE
from lerobot_kvm.kvm.configuration import KvmConfig
from lerobot_kvm.kvm.energy import GAMMA, L0
from lerobot_kvm.kvm.fusion import candidates, decision_weights
from lerobot_kvm.kvm.losses import ENERGY_MARGIN
from lerobot_kvm.kvm.metabolism import METABOLISM_WINDOW, PRUNE_THRESHOLD
from lerobot_kvm.kvm.telemetry import TAU_V, KvmStepTelemetry
from lerobot_kvm.policy import CodaKvmConfig

CONTEXT = "observation.context"
STONE, EGG = "pick up the stone", "pick up the egg"


def core_chunk(policy, batch, skill_weights=None):
    """The CODA-Prompt core's chunk under the given skill weights (None: eq. 3 with every v = 1, the KVM left
    out)."""
    query = policy.encode_query(batch["task"])
    if skill_weights is None:
        relevance = policy.pool.skill_relevance(query)
        everyone = torch.ones(policy.n_skills, dtype=torch.bool)
        skill_weights = decision_weights(torch.ones_like(relevance), relevance, candidates(relevance, everyone))
    return policy.decode(batch, policy.pool.component_alphas(query), skill_weights)


def two_skill_policy(make_policy, **overrides):
    policy = make_policy(**overrides)
    policy.begin_new_skill("gentle_grasp")
    policy.eval()
    return policy


def test_kvm_disabled_gives_exactly_the_coda_core_actions(make_policy, make_batch) -> None:
    policy = two_skill_policy(make_policy)
    batch = make_batch(policy.config, with_action=False)
    core = core_chunk(policy, batch)  # plain CODA-Prompt
    policy.config.kvm.enabled = False
    assert torch.equal(policy.predict_action_chunk(batch), core)
    assert policy.kvm_telemetry is None
    policy.reset()
    assert torch.equal(policy.select_action(batch), core[:, 0])


def test_every_v_forced_to_one_gives_exactly_the_coda_core_actions(make_policy, make_batch, make_kvm_config) -> None:
    policy = two_skill_policy(make_policy, kvm=make_kvm_config(force_validity=1.0, smart_gate=False))
    batch = make_batch(policy.config, with_action=False)
    core = core_chunk(policy, batch)
    assert torch.equal(policy.predict_action_chunk(batch), core)
    tele = policy.kvm_telemetry
    assert tele.gate.all() and torch.equal(tele.validity, torch.ones(4, 2))
    assert torch.equal(tele.skill_weight, torch.ones(4, 2))


def test_closed_gate_gives_exactly_the_coda_core_actions(make_policy, make_batch) -> None:
    policy = two_skill_policy(make_policy)
    batch = make_batch(policy.config, with_action=False)
    core = core_chunk(policy, batch)
    policy.kvm.set_gate_override("closed")
    assert torch.equal(policy.predict_action_chunk(batch), core)
    assert not policy.kvm_telemetry.gate.any() and torch.isnan(policy.kvm_telemetry.energy).all()
    policy.kvm.set_gate_override("open")
    open_chunk = policy.predict_action_chunk(batch)
    tele = policy.kvm_telemetry
    assert tele.gate.all() and torch.isfinite(tele.energy).all() and (tele.validity < 1).all()
    assert not torch.equal(open_chunk, core)  # v < 1 re-weights the skills


def test_every_candidate_suppressed_abstains_and_holds(make_policy, make_batch, make_kvm_config) -> None:
    policy = two_skill_policy(make_policy, kvm=make_kvm_config(force_validity=1.0))
    policy.rest_action[-1] = -2.0  # the last dimension is the grip: it rests at -2 (normalized)
    policy.release_mask[-1] = True
    batch = make_batch(policy.config, batch_size=1, with_action=False)
    last = policy.select_action(batch)  # acting normally: the command the abstention will hold
    policy.config.kvm.force_validity = 0.0  # every skill invalid now
    policy._action_queue.clear()
    first = policy.select_action(batch)
    tele = policy.kvm_telemetry
    assert torch.equal(tele.skill_weight, torch.zeros(1, 2)) and tele.abstained.all()  # no prompt is trusted
    assert tele.row(0)["abstained"] is True
    second = policy.select_action(batch)
    # the arm holds its last command; the grip goes halfway to rest per step
    assert torch.equal(first[:, :-1], last[:, :-1]) and torch.equal(second[:, :-1], last[:, :-1])
    torch.testing.assert_close(first[:, -1], (last[:, -1] - 2.0) / 2)
    torch.testing.assert_close(second[:, -1], (last[:, -1] - 2.0 * 3) / 4)
    assert policy.kvm_trace().summary()["abstention_steps"] == 2


def test_a_correction_is_out_of_force_with_the_gate_closed_and_takes_over_where_its_skill_is_suppressed(
    make_policy, make_batch
) -> None:
    policy = make_policy()
    policy.begin_new_skill("kvm_fix", corrects=0)
    policy.eval()
    batch = make_batch(policy.config, with_action=False)
    without_fix = torch.tensor([[1.0, 0.0]]).expand(4, 2)
    policy.kvm.set_gate_override("closed")
    closed = policy.predict_action_chunk(batch)
    tele = policy.kvm_telemetry
    assert torch.equal(tele.skill_weight, without_fix) and torch.equal(tele.validity, torch.ones(4, 2))
    assert not tele.intervention.any()  # leaving an unassessed correction out is no suppression
    assert torch.equal(closed, core_chunk(policy, batch, without_fix))
    assert not torch.equal(closed, core_chunk(policy, batch))
    policy.kvm.set_gate_override("open")
    policy.predict_action_chunk(batch)
    tele = policy.kvm_telemetry
    raw = policy.kvm_validity(batch)
    assert torch.equal(tele.validity[:, 0], raw[:, 0])
    relied_on = tele.alpha[:, 0] >= 0.8 * tele.alpha[:, 0]  # skill 0 is the only skill that corrects nothing
    assert relied_on.all()
    assert torch.equal(tele.validity[:, 1], 1 - raw[:, 0])  # as valid as the skill it corrects is not
    assert not tele.intervention[:, 1].any()  # held out where skill 0 holds: a mirror, not a suppression
    # the weights are eq. 3's v * alpha over the candidates not suppressed (v >= tau_v = 0.1)
    torch.testing.assert_close(tele.skill_weight, tele.validity.masked_fill(tele.validity < 0.1, 0.0))


def test_non_finite_context_or_energy_is_invalid_never_valid(make_policy, make_batch) -> None:
    policy = two_skill_policy(make_policy)
    batch = make_batch(policy.config)
    context = batch[CONTEXT].clone()
    context[1, 2] = float("nan")
    context[2, 0] = float("inf")
    query = policy.encode_query(batch["task"])
    alphas = policy.skill_relevance(batch["task"])
    weights, tele = policy.kvm.assess(context, query, alphas, policy.kvm_active_skills())
    assert tele.invalid[1].all() and tele.invalid[2].all() and not tele.invalid[0].any()
    assert (tele.validity[1:3] == 0).all() and (weights[1:3] == 0).all()
    assert tele.gate[1] and tele.gate[2]
    policy.kvm.set_gate_override("closed")  # forced shut, yet a non-finite context still opens it and is invalid
    weights, tele = policy.kvm.assess(context, query, alphas, policy.kvm_active_skills())
    assert tele.gate.tolist() == [False, True, True, False]
    assert tele.invalid[1:3].all() and not tele.invalid[[0, 3]].any() and (weights[1:3] == 0).all()
    policy.kvm.set_gate_override(None)

    def nan_energy(h):
        return torch.full(h.shape[:-1], float("nan"))

    policy.kvm.energy.forward = nan_energy
    policy.kvm.set_gate_override("open")
    weights, tele = policy.kvm.assess(batch[CONTEXT], query, alphas, policy.kvm_active_skills())
    assert tele.invalid.all() and (tele.validity == 0).all() and (weights == 0).all()
    # the policy's own input check still rejects NaN observations with a clear error
    batch[CONTEXT] = context
    with pytest.raises(ValueError, match=r"observation\.context"):
        policy.select_action(batch)


def test_telemetry_and_trace_per_step(make_policy, attempt) -> None:
    policy = two_skill_policy(make_policy)
    trace = attempt(policy, "pick up the egg", steps=5)
    assert len(trace) == 5 and trace.batch_size == 1
    assert all(t is not None for t in trace.telemetry)
    tele = policy.kvm_telemetry
    row = tele.row(0)
    assert set(row) >= {"sigma2", "tau", "gate", "alpha", "energy", "validity", "skill_weight", "intervention"}
    assert len(row["validity"]) == 2
    json.dumps(row)
    summary = trace.summary()
    assert summary["steps"] == 5 and 0 <= summary["gate_open_steps"] <= 5
    assert trace.observations and CONTEXT in trace.observations[0]
    policy.reset()
    assert len(policy.kvm_trace()) == 0


def test_risk_model_and_smart_gate_switch_on_the_same_weights(make_policy, make_batch) -> None:
    policy = two_skill_policy(make_policy)
    batch = make_batch(policy.config, with_action=False)
    v_energy = policy.kvm_validity(batch)
    policy.config.kvm.risk_model = "bce"
    v_bce = policy.kvm_validity(batch)
    assert v_energy.shape == v_bce.shape == (4, 2) and not torch.equal(v_energy, v_bce)
    policy.config.kvm.smart_gate = False
    policy.kvm.gate.push(torch.zeros(64, policy.kvm.encoder.raw_dim))  # statistics exist now
    policy.predict_action_chunk(batch)
    assert policy.kvm_telemetry.gate.all()


def test_an_instruction_without_safe_experience_opens_the_gate_on_its_rows(make_policy, make_batch) -> None:
    policy = two_skill_policy(make_policy)
    kvm = policy.kvm
    kvm.gate.k = 1e6  # tau far above any sigma^2: only the instruction can open the gate
    stone = policy.encode_query([STONE]).expand(64, -1)
    kvm.gate.push(kvm.raw_context(torch.rand(64, policy.config.input_features[CONTEXT].shape[0]), stone))
    policy.predict_action_chunk(make_batch(policy.config, task=STONE, with_action=False))
    assert not policy.kvm_telemetry.gate.any()
    policy.predict_action_chunk(make_batch(policy.config, task=[STONE, EGG, EGG, STONE], with_action=False))
    tele = policy.kvm_telemetry
    assert tele.gate.tolist() == [False, True, True, False] and torch.isfinite(tele.energy[1:3]).all()


def test_with_the_gate_open_a_suppression_replans_within_one_step(make_policy, make_batch, make_kvm_config) -> None:
    policy = two_skill_policy(make_policy, kvm=make_kvm_config(force_validity=1.0))
    batch = make_batch(policy.config, batch_size=1, with_action=False)
    policy.kvm.set_gate_override("closed")
    policy.select_action(batch)
    policy.config.kvm.force_validity = 0.0  # every candidate now suppressed, but the gate was closed
    policy.select_action(batch)
    assert not policy.kvm_telemetry.intervention.any()  # the chunk's assessment holds: no call to the KVM
    policy.kvm.set_gate_override("open")
    policy.select_action(batch)  # a new chunk, assessed with the gate open
    assert len(policy._action_queue) == 1 and policy.kvm_telemetry.intervention.any()
    policy.reset()  # a new attempt
    policy.config.kvm.force_validity = 1.0
    policy.select_action(batch)
    policy.config.kvm.force_validity = 0.0  # suppressed from the next step: it replans at once
    policy.select_action(batch)
    assert len(policy._action_queue) == 1 and policy.kvm_telemetry.intervention.any()


def test_only_a_suppression_of_the_skill_the_task_relies_on_is_held() -> None:
    alpha = torch.tensor([[1.0, 0.5, 1e-4]])  # every skill a candidate; only skill 0 above tau_high's share
    held = [
        KvmStepTelemetry(
            sigma2=torch.ones(1),
            tau=torch.tensor(0.0),
            gate=torch.ones(1, dtype=torch.bool),
            alpha=alpha,
            active=torch.ones(3, dtype=torch.bool),
            validity=torch.tensor([v]),
        ).held(0.8)
        for v in ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.05, 1.0, 1.0])
    ]
    assert [h.tolist() for h in held] == [[[True, False, False]], [[False, False, False]], [[True, False, False]]]


def test_a_suppression_of_the_skill_the_task_relies_on_holds_to_the_end_of_the_attempt(
    make_policy, make_batch, make_kvm_config
) -> None:
    policy = two_skill_policy(make_policy, kvm=make_kvm_config(force_validity=1.0))
    batch = make_batch(policy.config, batch_size=1, with_action=False)
    policy.kvm.set_gate_override("open")
    policy.select_action(batch)
    relied = policy.kvm_telemetry.relevance > policy.config.kvm.tau_high
    assert relied.any()
    policy.config.kvm.force_validity = 0.0
    policy.select_action(batch)
    policy.config.kvm.force_validity = 1.0  # judged valid again from now on
    for gate in ("open", "closed"):
        policy.kvm.set_gate_override(gate)
        policy._action_queue.clear()  # a new chunk: assessed under either gate state
        policy.select_action(batch)
        tele = policy.kvm_telemetry
        assert torch.equal(tele.intervention, relied) and torch.equal(tele.validity == 0, relied)
        assert torch.equal(tele.skill_weight > 0, ~relied)
    policy.reset()  # the next attempt judges afresh
    policy.select_action(batch)
    assert not policy.kvm_telemetry.intervention.any()


def test_one_rows_replan_leaves_the_other_rows_chunks(make_policy, make_batch, make_kvm_config) -> None:
    """In a batch of environments (`lerobot-eval`), a change in one row's suppressions replans that row only: the
    other rows go on with their own chunk, acting as they would alone."""
    policy = two_skill_policy(make_policy, n_action_steps=4, kvm=make_kvm_config(force_validity=1.0))
    policy.kvm.set_gate_override("open")
    both = make_batch(policy.config, batch_size=2, with_action=False)
    first = {k: v[:1] for k, v in both.items()}
    policy.reset()
    alone = [policy.select_action(first)[0] for _ in range(4)]
    policy.reset()
    together = [policy.select_action(both)]
    new_chunk = policy.predict_action_chunk(both)
    policy._queued_interventions[1] = ~policy._queued_interventions[1]  # row 1 was planned under other suppressions
    together += [policy.select_action(both) for _ in range(3)]
    for step in range(4):
        torch.testing.assert_close(together[step][0], alone[step])
    for step in range(1, 4):  # row 1 replanned at once, then follows its new chunk
        torch.testing.assert_close(together[step][1], new_chunk[1, step - 1])
    assert not policy._action_queue


def test_forward_learns_the_kvm_offline_and_reports_metrics(make_policy, make_batch) -> None:
    policy = two_skill_policy(make_policy)
    policy.train()
    batch = make_batch(policy.config)
    loss, info = policy.forward(batch)
    for key in ("kvm_loss", "kvm_recon", "kvm_energy_loss", "kvm_contrast", "kvm_tau", "kvm_gate_rate", "kvm_v_fail"):
        assert isinstance(info[key], float), key
    loss.backward()
    assert all(p.grad is not None for p in policy.kvm.energy.parameters())
    assert len(policy.kvm.gate.window) == 4 and len(policy.kvm.safe_offline) == 4
    per_sample, _ = policy.forward(batch, reduction="none")
    assert per_sample.shape == (4,)
    policy.eval()
    _, info = policy.forward(batch)
    assert not any(k.startswith("kvm_") for k in info)  # evaluation loss: no learning, no buffer updates
    assert len(policy.kvm.gate.window) == 8


@pytest.mark.parametrize("gate", ["closed", "open"])
def test_telemetry_can_be_read_after_the_step(make_policy, make_batch, gate) -> None:
    """A caller may read the step's telemetry after its inference mode has ended, or after a new skill has begun."""
    policy = two_skill_policy(make_policy)
    policy.kvm.set_gate_override(gate)
    batch = make_batch(policy.config, with_action=False)
    with torch.inference_mode():
        policy.select_action(batch)
    tele = policy.kvm_telemetry
    expected = policy.skill_relevance(batch["task"])
    policy.begin_new_skill("third")
    torch.testing.assert_close(tele.alpha, expected)
    assert tele.intervention.shape == (4, 2)


def test_safe_frames_still_judged_invalid_are_kept_and_replayed(make_policy, make_batch, make_kvm_config) -> None:
    policy = two_skill_policy(make_policy, kvm=make_kvm_config(hard_safe_replay=4))
    kvm = policy.kvm
    c = torch.randn(6, kvm.encoder.raw_dim)
    energy = torch.tensor([-10.0, 4.9, 5.1, 20.0, -3.0, 6.0])  # v = sigmoid(-E - l0') < 0.5 iff E > 5
    assert kvm.keep_hard_safe(c, torch.tensor([0, 1, 1, 0, 1, 0]), energy) == 3
    stored = kvm.safe_hard.filled()
    torch.testing.assert_close(kvm.safe_hard.data[stored], c[[2, 3, 5]])
    assert kvm.safe_hard.skill[stored].tolist() == [1, 0, 0]
    seen: dict[str, torch.Tensor] = {}
    loss_terms = kvm.loss_terms

    def spy(safe_c, safe_s, routine, fail_c, fail_s):
        seen.update(safe=safe_c, routine=routine)
        return loss_terms(safe_c, safe_s, routine, fail_c, fail_s)

    kvm.loss_terms = spy
    policy.train()
    policy.forward(make_batch(policy.config))
    replayed = seen["safe"][-4:]
    assert (torch.cdist(replayed, c[[2, 3, 5]]).min(1).values < 1e-6).all()  # every step replays hard safe rows
    assert seen["routine"][-4:].all()


@pytest.mark.parametrize("judged_invalid", [True, False])
def test_a_feedback_update_keeps_the_safe_samples_it_judges_invalid(make_policy, judged_invalid: bool) -> None:
    """The few negatives of one failure must not suppress the culprit in its own safe experience: the recorded safe
    frames an online update replays and judges invalid join the hard safe memory, replayed at every later step
    (what was met online stays out of it: the hard memory's frames count as recorded, for cross-skill pairs)."""
    policy = two_skill_policy(make_policy)
    kvm = policy.kvm
    safe = torch.randn(8, kvm.encoder.raw_dim)
    kvm.safe_offline.add(safe, skill=torch.tensor([0, 1] * 4), tag=torch.arange(8))
    kvm.add_safe(torch.randn(4, kvm.encoder.raw_dim) + 50.0, torch.zeros(4).long(), routine=True)
    seen: list[torch.Tensor] = []
    loss_terms = kvm.loss_terms

    def energies_of(safe_c, safe_s, routine, fail_c, fail_s, **kwargs):
        loss, metrics, energy = loss_terms(safe_c, safe_s, routine, fail_c, fail_s, **kwargs)
        seen.append(safe_c.detach().clone())
        return loss, metrics, energy.new_full(energy.shape, 20.0 if judged_invalid else -20.0)

    kvm.loss_terms = energies_of
    fail = torch.randn(3, kvm.encoder.raw_dim)
    update = (policy.kvm_negative_partners(), (safe[:0], torch.zeros(0).long()), (fail, torch.zeros(3).long()))
    kvm.train_online(1, *update)
    stored = kvm.safe_hard.data[kvm.safe_hard.filled()]
    if judged_invalid:
        recorded = seen[0][seen[0].abs().amax(1) < 25]
        assert len(stored) == len(recorded) > 0 and torch.equal(stored, recorded)
        assert len(recorded) < len(seen[0])  # the online rows were replayed too
        kvm.train_online(1, *update)
        n_hard = kvm.config.feedback_hard_safe_replay  # a later step replays that many hard rows, last
        assert len(seen[1]) == len(seen[0]) + n_hard
        assert (torch.cdist(seen[1][-n_hard:], stored).min(1).values < 1e-6).all()
    else:
        assert not len(stored)


class _Meta:
    def __init__(self, root):
        self.root = root


def test_dataset_labels_map_skills_by_name_and_never_use_shifted_frames(make_config, make_batch, tmp_path) -> None:
    from lerobot_kvm.policy import CodaKvmPolicy

    labels = {
        "episodes": [
            {"episode_index": 0, "skill": "firm_grasp", "outcome": "success", "variant": "prior"},
            {"episode_index": 1, "skill": "gentle_grasp", "outcome": "success", "variant": "prior"},
            {"episode_index": 2, "skill": "firm_grasp", "outcome": "catastrophe", "variant": "control"},
            {"episode_index": 3, "skill": "firm_grasp", "outcome": "catastrophe", "variant": "shifted"},
            {"episode_index": 4, "skill": "weird_skill", "outcome": "success", "variant": "prior"},
        ]
    }
    (tmp_path / "meta").mkdir()
    (tmp_path / "meta" / "kvm_labels.json").write_text(json.dumps(labels))
    torch.manual_seed(0)
    policy = CodaKvmPolicy(make_config(), dataset_meta=_Meta(tmp_path))
    policy.begin_new_skill("gentle_grasp")
    names = [s.name for s in policy.skills]
    skill, outcome, usable = policy.kvm.labels.lookup(torch.tensor([0, 1, 2, 3, 4, 40]), 6, names, 1)
    assert skill.tolist() == [0, 1, 0, 0, 1, 1]  # unknown skill and unlabelled episode -> the skill being trained
    assert outcome.tolist() == [0, 0, 2, 2, 0, 0]
    assert usable.tolist() == [True, True, True, False, True, True]  # the shifted episode is never used
    policy.train()
    batch = make_batch(policy.config, batch_size=4)
    batch["episode_index"] = torch.tensor([0, 2, 3, 3])
    policy.forward(batch)
    assert len(policy.kvm.safe_offline) == 1 and len(policy.kvm.fail_offline) == 1  # shifted frames dropped


def test_kvm_config_on_the_command_line_and_validation() -> None:
    cfg = draccus.parse(
        CodaKvmConfig, args=["--kvm.enabled=false", "--kvm.risk_model=bce", "--kvm.smart_gate=false", "--kvm.gate_k=2"]
    )
    assert cfg.kvm.enabled is False and cfg.kvm.risk_model == "bce" and cfg.kvm.smart_gate is False
    assert cfg.kvm.gate_k == 2.0
    defaults = KvmConfig()
    assert (defaults.gate_window, GAMMA, L0) == (1000, 1.0, -5.0)  # App. E
    assert defaults.gate_k == 1.5  # eq. 1's k, measured (App. E has 3)
    assert (ENERGY_MARGIN, PERSISTENCE, defaults.tau_high, TAU_V) == (10.0, 3, 0.8, 0.1)
    assert (METABOLISM_WINDOW, PRUNE_THRESHOLD) == (5, 0.8)
    assert defaults.encoder_hidden == [128, 128] and defaults.energy_hidden == [256, 256, 256]
    for bad, name in [
        ({"risk_model": "svm"}, "risk_model"),
        ({"tau_high": 1.5}, "tau_high"),
        ({"gate_window": 0}, "gate_window"),
        ({"encoder_hidden": []}, "encoder_hidden"),
        ({"departure_radius": 0.0}, "departure_radius"),
        ({"feedback_hard_safe_replay": -1}, "feedback_hard_safe_replay"),
    ]:
        with pytest.raises(ValueError, match=name):
            KvmConfig(**bad)


def test_overhead_measures_three_modes_on_the_same_inputs(make_policy, make_batch) -> None:
    policy = two_skill_policy(make_policy)
    batch = make_batch(policy.config, batch_size=1, with_action=False)
    result = measure_overhead(policy, batch, steps=4, warmup=1, block=2)
    assert set(result["model_call_ms"]) == {"off", "closed", "open"}
    assert result["gate_open_check"] == {"off": False, "closed": False, "open": True}
    assert result["ratio_gate_closed"] > 0 and result["ratio_gate_open"] > 0
    assert result["paired_ratio_gate_closed"] > 0 and result["paired_ratio_gate_open"] > 0
    assert result["paired_control_step_ratio_gate_closed"] > 0 and result["paired_control_step_ratio_gate_open"] > 0
    assert policy.config.kvm.enabled and policy.kvm.gate_override is None  # settings restored


def test_paired_ratio_cancels_a_drift_between_rotations() -> None:
    off = [1.0, 2.0, 4.0]  # the machine slows down rotation by rotation
    closed = [1.1, 2.4, 4.4]  # 1.1x, 1.2x, 1.1x of the same rotation's off block
    assert paired_ratio(closed, off) == pytest.approx(1.1)
    with pytest.raises(ValueError):
        paired_ratio(closed, off[:2])


def test_a_huge_finite_context_is_refused_by_name(make_policy, make_batch):
    policy = make_policy()
    policy.eval()
    batch = make_batch(policy.config, batch_size=2, with_action=False)
    policy.reset()
    assert torch.isfinite(policy.select_action(batch)).all()  # (and a chunk queued for the next steps)
    batch[CONTEXT][0, 0] = 1e30
    policy.reset()
    with pytest.raises(ValueError, match=r"observation 'observation.context' has a value of magnitude 1e\+30"):
        policy.select_action(batch)


def test_the_novelty_detector_suppresses_every_skill_where_the_gate_opens(make_policy, make_batch, make_kvm_config):
    policy = two_skill_policy(make_policy, kvm=make_kvm_config(risk_model="novelty"))
    batch = make_batch(policy.config, with_action=False)
    policy.kvm.set_gate_override("open")
    policy.predict_action_chunk(batch)
    tele = policy.kvm_telemetry
    assert (tele.validity < TAU_V).all() and tele.abstained.all()  # novel: nothing is trusted, the policy holds
    policy.reset()  # another attempt (within one, the suppression holds)
    policy.kvm.set_gate_override("closed")
    chunk = policy.predict_action_chunk(batch)
    assert not policy.kvm_telemetry.abstained.any() and torch.equal(chunk, core_chunk(policy, batch))
