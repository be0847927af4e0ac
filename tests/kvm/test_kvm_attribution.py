"""Verification-based attribution (App. D): hypotheses, persistence and necessity, confirmed negatives, knowledge
gap -> a new skill trained alone; metabolism -> pruning (recoverable)."""

import pytest
import torch
import torch.nn.functional as F  # noqa: N812

from lerobot_kvm.kvm.attribution import (
    CONFIRMED,
    OPEN,
    HypothesisTable,
    agreeing_skill,
    counterfactual_culprit,
    culprit_skill,
    knowledge_gap,
    normalised_relevance,
)
from lerobot_kvm.kvm.memory import PERMANENT
from lerobot_kvm.policy.feedback import FAIL_CONTEXT_STEPS, make_demonstration, relied_on

EGG = "pick up the egg"


def test_hypothesis_confirms_only_after_n_p_persistent_and_necessary_interventions() -> None:
    table = HypothesisTable(capacity=4, raw_dim=3, persistence=3, tau_high=0.8)
    h = table.open(skill=1, prototype=torch.ones(3))
    assert table.info(h)["state"] == "open" and table.info(h)["failures"] == 1
    for _ in range(3):  # counter 1..3: not yet above N_p = 3
        assert not table.record_intervention(h, necessary=True)
    assert not table.record_intervention(h, necessary=False)  # counter 4 > N_p but not necessary
    assert table.info(h)["state"] == "open"
    assert table.record_intervention(h, necessary=True)  # persistent and necessary: confirmed
    assert table.is_confirmed(h) and table.info(h)["counter"] == 5 and table.info(h)["necessary"] == 4
    assert not table.record_intervention(h, necessary=True)  # confirms once


def test_a_failure_despite_suppression_restarts_persistence() -> None:
    table = HypothesisTable(capacity=2, raw_dim=3, persistence=3, tau_high=0.8)
    h = table.open(skill=0, prototype=torch.zeros(3))
    for _ in range(3):
        table.record_intervention(h, necessary=True)
    table.record_failure(h, suppressed=False)  # failed while the skill ran: more evidence, counter kept
    assert table.info(h)["counter"] == 3 and table.info(h)["failures"] == 2
    table.record_failure(h, suppressed=True)  # failed although suppressed: the intervention did not help
    assert table.info(h)["counter"] == 0
    for _ in range(3):
        assert not table.record_intervention(h, necessary=True)
    assert table.record_intervention(h, necessary=True)


def test_hypothesis_table_evicts_the_oldest_open_row_when_full() -> None:
    table = HypothesisTable(capacity=2, raw_dim=1, persistence=0, tau_high=0.8)
    a = table.open(0, torch.zeros(1))
    table.record_intervention(a, necessary=True)  # confirmed (counter 1 > 0)
    b = table.open(1, torch.zeros(1))
    c = table.open(2, torch.zeros(1))  # evicts b (oldest open), keeps the confirmed a
    assert sorted(table.ids()) == [a, c] and table.ids(state=CONFIRMED) == [a] and table.ids(state=OPEN) == [c]
    with pytest.raises(KeyError):
        table.info(b)


def test_culprit_relevance_and_knowledge_gap() -> None:
    alphas = torch.tensor([[2.0, 1.0, 0.5], [1.0, 3.0, 0.5], [1.0, 3.0, 0.5]])
    assert culprit_skill(alphas, last_k=1) == 1
    # mean shares over the 3 steps: skill 0 (4/7 + 2/9 + 2/9) / 3 = 0.339 < skill 1 (1/7 + 2/3 + 2/3) / 3 = 0.492
    assert culprit_skill(alphas, last_k=3) == 1
    assert culprit_skill(alphas[:1], last_k=3) == 0
    active = torch.tensor([True, True, False])
    r = normalised_relevance(alphas, active)
    torch.testing.assert_close(r[0], torch.tensor([1.0, 0.5, 0.0]))
    torch.testing.assert_close(r[1], torch.tensor([1 / 3, 1.0, 0.0]))
    # pruning the dominant skill leaves the others' relevance where it was: they do not become candidates
    pruned_0 = normalised_relevance(alphas, torch.tensor([False, True, True]))
    torch.testing.assert_close(pruned_0[0], torch.tensor([0.0, 0.5, 0.25]))
    assert knowledge_gap(r[1:], culprit=1, active=active, gap_alpha=0.5)  # alternative 0 stays at 1/3
    assert not knowledge_gap(r[:1], culprit=1, active=active, gap_alpha=0.5)  # alternative 0 is strong there
    assert knowledge_gap(r, culprit=0, active=torch.tensor([True, False, False]), gap_alpha=0.5)  # no alternative


def test_the_culprit_is_a_skill_that_acted_not_the_most_relevant_one_suppressed_from_the_start() -> None:
    """Skill 0 is the most relevant but suppressed from step 0 (another scenario's skill); skill 1 carries the
    executed prompt, then is suppressed at step 2 and skill 2 takes over: skill 1 is blamed, never skill 0."""
    relevance = torch.tensor([[1.0, 0.5, 0.01]] * 4)
    nan = float("nan")
    weights = torch.tensor([[0.0, 0.5, 0.01], [0.0, 0.5, 0.01], [0.0, 0.0, 0.01], [0.0, 0.0, 0.01]])
    intervention = torch.tensor([[True, False, False]] * 2 + [[True, True, False]] * 2)
    rows = relied_on(weights, relevance, intervention)
    torch.testing.assert_close(rows[:, 0], torch.zeros(4))  # never acted: no share
    torch.testing.assert_close(rows[2:, 1], torch.full((2,), 0.5))  # suppressed after acting: keeps its relevance
    assert culprit_skill(rows, last_k=FAIL_CONTEXT_STEPS) == 1
    assert culprit_skill(relevance, last_k=FAIL_CONTEXT_STEPS) == 0  # what the relevance alone would blame
    # the KVM held from the first step (every weight 0): the relevance; steps without assessment (NaN): relevance
    torch.testing.assert_close(relied_on(torch.zeros(4, 3), relevance, intervention), relevance)
    torch.testing.assert_close(relied_on(torch.full((4, 3), nan), relevance, intervention), relevance)
    # steps at which the KVM held in the middle of an attempt are left out
    held = weights.clone()
    held[1] = 0.0
    assert len(relied_on(held, relevance, torch.zeros(4, 3, dtype=torch.bool))) == 3


def test_counterfactual_culprit_needs_a_margin_over_the_proposed_skills_removal() -> None:
    # error 1.0 with every skill in force; removing skill 0 -> 0.95, 1 -> 1.30, 2 -> 0.70, 3 (not proposed) -> 0.1
    without = torch.tensor([0.95, 1.30, 0.70, 0.10])
    candidates = torch.tensor([True, True, True, False])
    # gains 0.05, -0.30, 0.30: skill 2 beats the proposed skill 1 by 0.60 > 0.1 * 1.0
    assert counterfactual_culprit(1.0, without, candidates, proposed=1, margin=0.1) == 2
    # against proposed skill 0 the lead is 0.25: blamed at margin 0.2, not at margin 0.3
    assert counterfactual_culprit(1.0, without, candidates, proposed=0, margin=0.2) == 2
    assert counterfactual_culprit(1.0, without, candidates, proposed=0, margin=0.3) == 0
    assert counterfactual_culprit(1.0, without, candidates, proposed=2, margin=0.0) == 2
    # a removal that does not help by the margin blames nobody else, however much worse the proposed one's is
    hurting = torch.tensor([1.05, 9.0, 1.02, 0.1])
    assert counterfactual_culprit(1.0, hurting, candidates, proposed=1, margin=0.1) == 1
    # the skill that shows the correction: its removal hurts most (skill 1, +0.30); none when removals only help
    assert agreeing_skill(1.0, without, candidates, culprit=2) == 1
    assert agreeing_skill(1.0, without, candidates, culprit=1) is None


def test_a_demonstration_verifies_the_culprit_by_removing_each_proposed_skill(
    make_policy, make_kvm_config, make_batch, attempt
) -> None:
    """The demonstration is exactly what the policy does without one skill: that skill is blamed, whatever its
    share of the prompt, and the evidence is in the report."""
    settings = {"gap_on_failure": False}
    policy = make_policy(kvm=make_kvm_config(**settings), chunk_size=1, n_action_steps=1)
    policy.begin_new_skill("gentle_grasp")
    policy.begin_new_skill("slow_lift")
    trace = attempt(policy, EGG, steps=6)
    proposed = culprit_skill(policy.skill_relevance([EGG] * 6), last_k=FAIL_CONTEXT_STEPS)
    blamed = (proposed + 1) % 3
    weights = torch.ones(1, 3)
    weights[0, blamed] = 0.0
    steps = []
    for t in range(5):
        b = make_batch(policy.config, batch_size=1, task=EGG, seed=50 + t)
        b["action"] = policy.predict_action_chunk(b, skill_weights=weights)[:, 0]
        steps.append(b)
    demo = make_demonstration(steps)
    report = policy.kvm_feedback("catastrophe", trace, demonstration=demo, gradient_steps=0)
    evidence = report["attribution"]
    assert report["culprit"] == blamed and evidence["rule"] == "counterfactual"
    assert evidence["gain"][blamed] == pytest.approx(evidence["error"], abs=1e-6)  # its removal is the demo
    assert report["demo_skill"] == evidence["agrees"] != blamed
    assert report["hypothesis"]["skill"] == blamed


def _no_synthetic(c_raw, skills):
    """The KVM's synthetic negatives replaced by none, so that a test sees the cross-skill negatives alone."""
    return c_raw[:0], skills[:0]


def _force_suppression(trace, skill: int, value: float = 0.01) -> None:
    """Make the recorded assessments say the KVM suppressed `skill` at every step."""
    for tele in {id(t): t for t in trace.telemetry if t is not None}.values():
        tele.validity[:, skill] = value


def test_failure_feedback_forms_a_hypothesis_with_provisional_negatives(make_policy, attempt) -> None:
    policy = make_policy()
    trace = attempt(policy, EGG, steps=6, seed=0)
    report = policy.kvm_feedback("catastrophe", trace, gradient_steps=2)
    assert report["culprit"] == 0 and report["hypothesis"]["state"] == "open"
    h = report["hypothesis"]["id"]
    tagged = (policy.kvm.fail_online.tag == h) & (policy.kvm.fail_online.stamp >= 0)
    assert int(tagged.sum()) == report["negatives_added"] > 0
    # without a demonstration, every negative is a step of the attempt, and the report says which
    assert report["demo_negative_steps"] == [] and len(report["failure_context_steps"]) == report["negatives_added"]
    assert set(report["failure_context_steps"]) <= set(range(len(trace)))
    assert int((policy.kvm.fail_online.flags[tagged] & PERMANENT).sum()) == 0  # provisional
    assert (policy.kvm.fail_online.skill[tagged] == 0).all()
    # a second failure in the same context adds evidence to the same hypothesis
    report = policy.kvm_feedback("failure", attempt(policy, EGG, steps=6, seed=0), gradient_steps=0)
    assert report["hypothesis"]["id"] == h and report["hypothesis"]["failures"] == 2


def test_confirmed_gap_creates_a_new_skill_trained_alone(make_policy, attempt) -> None:
    policy = make_policy()
    policy.kvm_feedback("catastrophe", attempt(policy, EGG, steps=6, seed=0), gradient_steps=2)
    backbone = {k: v.clone() for k, v in policy.backbone.state_dict().items()}
    old_skill = {k: v.clone() for k, v in policy.pool.tasks[0].state_dict().items()}
    reports = []
    for budget in (0, 0, 0, 4):  # similar contexts, the culprit suppressed, success; the last one with a budget
        trace = attempt(policy, EGG, steps=6, seed=0)
        _force_suppression(trace, 0)
        reports.append(policy.kvm_feedback("success", trace, gradient_steps=budget))
    assert [len(r["interventions"]) for r in reports] == [1, 1, 1, 1]
    assert all(r["interventions"][0]["necessary"] for r in reports)  # the only skill: relevance 1 > tau_high
    assert [bool(r["confirmed"]) for r in reports] == [False, False, False, True]
    confirmed = reports[-1]["confirmed"][0]
    assert confirmed["gap"] and confirmed["permanent_negatives"] > 0
    assert policy.kvm.n_permanent() == confirmed["permanent_negatives"]
    new = reports[-1]["new_skill"]
    assert new["created"] and new["index"] == 1 and policy.n_skills == 2
    assert policy.skills[1].name == new["name"]
    info = policy.kvm.hypotheses.info(confirmed["hypothesis"])
    assert info["state"] == "confirmed" and info["gap"] and info["new_skill"] == 1
    # focused steps touched the new skill only
    for k, v in policy.backbone.state_dict().items():
        assert torch.equal(v, backbone[k]), k
    for k, v in policy.pool.tasks[0].state_dict().items():
        assert torch.equal(v, old_skill[k]), k
    assert "focused_l1" in new and new["seed_frames"] == 6
    # the budget counts everything trained: the KVM's steps and the new skill's together
    assert (reports[-1]["kvm_steps"], reports[-1]["skill_steps"]) == (2, 2)


def test_a_confirmation_without_a_gradient_budget_creates_no_untrained_skill(make_policy, attempt) -> None:
    policy = make_policy()
    policy.kvm_feedback("catastrophe", attempt(policy, EGG, steps=6, seed=0), gradient_steps=2)
    for _ in range(4):
        trace = attempt(policy, EGG, steps=6, seed=0)
        _force_suppression(trace, 0)
        report = policy.kvm_feedback("success", trace)
    assert report["confirmed"] and report["confirmed"][0]["gap"]
    assert report["new_skill"] == {"created": False, "reason": "no gradient steps to train it with"}
    assert policy.n_skills == 1 and (report["kvm_steps"], report["skill_steps"]) == (0, 0)


def _demonstration(policy, make_batch, steps: int = 5, skill: str | None = None) -> dict:
    per_step = []
    for t in range(steps):
        b = make_batch(policy.config, batch_size=1, task=EGG, seed=50 + t)
        b["action"] = b["action"][:, 0]
        per_step.append(b)
    return make_demonstration(per_step, skill=skill)


def test_a_failure_without_a_strong_alternative_seeds_a_correcting_skill_from_its_demonstration(
    make_policy, make_kvm_config, make_batch, attempt
) -> None:
    # one skill: nothing else could take over once it is suppressed
    policy = make_policy()
    backbone = {k: v.clone() for k, v in policy.backbone.state_dict().items()}
    old_skill = {k: v.clone() for k, v in policy.pool.tasks[0].state_dict().items()}
    encoder = {k: v.clone() for k, v in policy.kvm.encoder.state_dict().items()}
    energy = {k: v.clone() for k, v in policy.kvm.energy.state_dict().items()}
    demo = _demonstration(policy, make_batch)
    report = policy.kvm_feedback("catastrophe", attempt(policy, EGG, steps=6), demonstration=demo, gradient_steps=2)
    # online, E_c learns from routine reconstruction only (there is none here): the failed contexts, safe for the
    # correction and hazardous for the culprit, move the energy model but not the codes the gate reads
    assert all(torch.equal(v, encoder[k]) for k, v in policy.kvm.encoder.state_dict().items())
    assert any(not torch.equal(v, energy[k]) for k, v in policy.kvm.energy.state_dict().items())
    new = report["new_skill"]
    assert new["created"] and new["index"] == 1 and policy.n_skills == 2 and policy.skills[1].gated
    assert report["culprit"] == 0 and report["demo_skill"] == 1 and policy.skills[1].corrects == 0
    assert report["positives_added"] == 5 + 6  # the demonstrated contexts and those the culprit failed in
    assert report["hypothesis"]["gap"] and report["hypothesis"]["new_skill"] == 1
    assert new["seed_frames"] == 5 and "focused_l1" in new
    assert (report["kvm_steps"], report["skill_steps"]) == (1, 1)  # one budget for the KVM and the new skill
    for k, v in policy.backbone.state_dict().items():
        assert torch.equal(v, backbone[k]), k
    for k, v in policy.pool.tasks[0].state_dict().items():
        assert torch.equal(v, old_skill[k]), k
    # a later failure, blamed on the old skill or on its correction, refines the correction (even once it is
    # frozen, as when another skill is being learned) and never makes a second one
    policy.pool.tasks[1].requires_grad_(False)
    frozen = {k: v.clone() for k, v in policy.pool.tasks[1].state_dict().items()}
    again = policy.kvm_feedback("failure", attempt(policy, EGG, steps=6), demonstration=demo, gradient_steps=2)
    assert again["culprit"] in (0, 1) and again["new_skill"]["created"] is False and again["new_skill"]["index"] == 1
    assert policy.n_skills == 2
    assert any(not torch.equal(v, frozen[k]) for k, v in policy.pool.tasks[1].state_dict().items())
    assert not any(p.requires_grad for p in policy.pool.tasks[1].parameters())  # frozen again afterwards


@pytest.mark.parametrize("setting", [{"gap_on_failure": False}, {"gap_alpha": 0.0}])
def test_no_skill_from_a_failure_when_the_gap_test_is_off_or_an_alternative_is_strong(
    make_policy, make_batch, make_kvm_config, attempt, setting
) -> None:
    policy = make_policy(kvm=make_kvm_config(**setting))
    policy.begin_new_skill("gentle_grasp")
    demo = _demonstration(policy, make_batch)
    report = policy.kvm_feedback("catastrophe", attempt(policy, EGG, steps=6), demonstration=demo, gradient_steps=2)
    assert report["new_skill"] is None and policy.n_skills == 2 and report["demo_skill"] in (0, 1)
    assert (report["kvm_steps"], report["skill_steps"]) == (2, 0)
    assert report["demo_skill"] != report["culprit"]


def test_a_demonstration_of_a_skill_the_pool_has_is_no_knowledge_gap(make_policy, make_batch, attempt) -> None:
    unnamed, named = make_policy(), make_policy()
    for policy in (unnamed, named):
        policy.begin_new_skill("gentle_grasp")  # learned on another task: weak in the egg's context, a gap
        policy.pool.observe_queries(policy.encode_query(["open the drawer"]))
    demo = _demonstration(unnamed, make_batch)
    gap = unnamed.kvm_feedback("catastrophe", attempt(unnamed, EGG, steps=6), demonstration=demo, gradient_steps=2)
    assert gap["new_skill"]["created"] and unnamed.n_skills == 3
    demo = _demonstration(named, make_batch, skill="gentle_grasp")
    report = named.kvm_feedback("catastrophe", attempt(named, EGG, steps=6), demonstration=demo, gradient_steps=2)
    assert report["new_skill"] is None and named.n_skills == 2
    # the demonstrated contexts, and the failure contexts (some of the attempt's 6 steps) are safe for that skill
    assert report["demo_skill"] == 1 and 5 < report["positives_added"] <= 5 + 6


def test_the_skill_that_performs_the_demonstration_alone_is_the_demonstrated_one_and_no_gap(
    make_policy, make_batch, attempt
) -> None:
    """An alternative whose own prompt reproduces the corrective demonstration takes its positives, however weak its
    relevance for the failed task: the pool holds the strategy, so no gap skill is grown."""
    policy = make_policy(chunk_size=1, n_action_steps=1)
    policy.begin_new_skill("gentle_grasp")
    policy.pool.observe_queries(policy.encode_query(["gently pick up an egg"]))  # a candidate, far below gap_alpha
    assert float(policy.skill_relevance([EGG])[0, 1]) < 0.5 * policy.config.kvm.gap_alpha
    policy.begin_new_skill("firm_lift")
    policy.pool.observe_queries(policy.encode_query(["firmly pick up an egg"]))  # another candidate
    own = policy.pool.own_weights(1, 1)
    steps = []
    for t in range(5):
        b = make_batch(policy.config, batch_size=1, task=EGG, seed=50 + t)
        b["action"] = policy.predict_action_chunk(b, skill_weights=own)[:, 0]
        steps.append(b)
    report = policy.kvm_feedback(
        "catastrophe", attempt(policy, EGG, steps=6), demonstration=make_demonstration(steps), gradient_steps=2
    )
    assert report["culprit"] == 0 and report["demo_skill"] == 1
    assert report["new_skill"] is None and policy.n_skills == 3
    # the candidate that acts otherwise than shown would take over next: the failure is hazardous for it too
    assert report["refuted"] == [2]
    stored = policy.kvm.fail_online.skill[policy.kvm.fail_online.filled()]
    assert set(stored.tolist()) == {0, 2}


def test_a_failure_with_the_culprit_suppressed_restarts_its_persistence(make_policy, attempt) -> None:
    """The blame stays with the skill the core relied on: it does not pass to the skills left in force."""
    policy = make_policy()
    policy.begin_new_skill("gentle_grasp")
    first = policy.kvm_feedback("catastrophe", attempt(policy, EGG, steps=6, seed=0), gradient_steps=0)
    culprit, h = first["culprit"], first["hypothesis"]["id"]
    for _ in range(2):
        trace = attempt(policy, EGG, steps=6, seed=0)
        _force_suppression(trace, culprit)
        policy.kvm_feedback("success", trace)
    assert policy.kvm.hypotheses.info(h)["counter"] == 2
    trace = attempt(policy, EGG, steps=6, seed=0)
    _force_suppression(trace, culprit)
    report = policy.kvm_feedback("failure", trace, gradient_steps=0)
    assert report["culprit"] == culprit and report["suppressed_at_failure"]
    assert report["hypothesis"]["id"] == h and report["hypothesis"]["failures"] == 2
    assert report["hypothesis"]["counter"] == 0
    assert policy.kvm.hypotheses.ids() == [h]


def test_a_skill_suppressed_from_the_start_is_neither_culprit_nor_demonstrated(
    make_policy, make_kvm_config, make_batch, attempt
) -> None:
    """The most relevant skill, suppressed at every step (another scenario's skill, say), never acted: the failure
    is blamed on the skill that carried the executed prompt, and the demonstration's positives never make the
    suppressed one valid there (the egg broken by its own scenario's firm grasp, docs/measurements.md)."""
    policy = make_policy(kvm=make_kvm_config(gap_on_failure=False), chunk_size=1, n_action_steps=1)
    policy.begin_new_skill("gentle_grasp")
    policy.begin_new_skill("slow_lift")
    trace = attempt(policy, EGG, steps=6)
    relevance = policy.skill_relevance([EGG])[0]
    top = int(relevance.argmax())
    for tele in {id(t): t for t in trace.telemetry if t is not None}.values():
        assert int(tele.candidate[0].sum()) >= 2  # an alternative is proposed with the top skill
        tele.validity[:, top] = 0.0
        tele.skill_weight[:, top] = 0.0
    steps = []
    for t in range(5):
        b = make_batch(policy.config, batch_size=1, task=EGG, seed=50 + t)
        b["action"] = policy.predict_action_chunk(b, skill_weights=torch.ones(1, 3))[:, 0]
        steps.append(b)
    report = policy.kvm_feedback("catastrophe", trace, demonstration=make_demonstration(steps), gradient_steps=0)
    assert report["culprit"] != top and report["hypothesis"]["skill"] != top
    assert report["demo_skill"] is not None and report["demo_skill"] not in (top, report["culprit"])


def test_unnecessary_interventions_do_not_confirm(make_policy, attempt, make_kvm_config) -> None:
    policy = make_policy(kvm=make_kvm_config(tau_high=1.0))  # relevance can never exceed 1: never necessary
    policy.kvm_feedback("catastrophe", attempt(policy, EGG, steps=6, seed=0), gradient_steps=0)
    for _ in range(6):
        trace = attempt(policy, EGG, steps=6, seed=0)
        _force_suppression(trace, 0)
        report = policy.kvm_feedback("success", trace)
        assert report["interventions"] and not report["interventions"][0]["necessary"]
        assert not report["confirmed"]
    assert policy.n_skills == 1


def test_interventions_in_dissimilar_contexts_do_not_count(make_policy, attempt, make_kvm_config) -> None:
    policy = make_policy(kvm=make_kvm_config(similarity=1.0))  # only identical codes are "similar"
    policy.kvm_feedback("catastrophe", attempt(policy, EGG, steps=6, seed=0), gradient_steps=0)
    trace = attempt(policy, "open the drawer", steps=6, seed=7, shift=5.0)
    _force_suppression(trace, 0)
    assert policy.kvm_feedback("success", trace)["interventions"] == []


def test_chronic_failures_prune_a_skill_which_stays_recoverable(make_policy, attempt) -> None:
    policy = make_policy()
    policy.begin_new_skill("gentle_grasp")
    reports = [
        policy.kvm_feedback("failure", attempt(policy, f"task {i}", steps=3, seed=i), gradient_steps=0)
        for i in range(10)
    ]
    # the window of 5 new tasks is full from the 5th; FCRNC must then remain above 0.8 at 5 more arrivals
    assert all(r["pruned"] == [] for r in reports[:9])
    # each interaction charges the one skill the core proposed (the culprit), not every candidate
    proposed = policy.kvm.metabolism.proposed.sum(-1)[:2].tolist()
    assert proposed == [sum(r["culprit"] == i for r in reports[-5:]) for i in range(2)] and sum(proposed) == 5
    pruned = reports[-1]["pruned"]
    fcrnc = reports[-1]["fcrnc"]
    assert pruned and all(fcrnc[i] > 0.8 for i in pruned)
    assert torch.equal(policy.kvm_active_skills(), torch.tensor([i not in pruned for i in range(2)]))
    trace = attempt(policy, "task 0", steps=2, seed=0)
    tele = trace.telemetry[-1]
    for i in pruned:
        assert tele.skill_weight[0, i] == 0 and not tele.candidate[0, i] and tele.validity[0, i] == 0
    assert policy.skills[pruned[0]].name  # never deleted from the skill table
    policy.kvm_restore_skill(pruned[0])
    assert bool(policy.kvm_active_skills()[pruned[0]])


def test_the_safe_experience_is_measured_in_the_spread_of_its_recorded_episodes(make_policy) -> None:
    kvm = make_policy().kvm
    dim = kvm.encoder.raw_dim
    c = torch.zeros(4, dim)
    assert not kvm.safe_experience(0).known(c, 0.95).any()  # empty memory: nothing is known ...
    assert not kvm.safe_experience(0).departed(c, 2.0).any()  # ... and nothing departs from it
    gen = torch.Generator().manual_seed(0)
    for episode in range(4):  # four episodes of the same routine: each about 0.1 * sqrt(dim) from the next
        rows = torch.full((3, dim), 0.1 * episode) + 0.001 * torch.randn(3, dim, generator=gen)
        kvm.safe_offline.add(rows, skill=0, tag=episode)
    experience = kvm.safe_experience(0)
    near = torch.full((1, dim), 0.15)  # between two episodes
    far = torch.full((1, dim), 3.0)
    assert experience.known(torch.cat([near, far]), 0.95).tolist() == [True, False]
    assert not kvm.safe_experience(1).known(near, 0.95).any()  # another skill's experience says nothing of skill 1
    # an attempt that leaves the experience, comes back, then leaves for good: only the last departure counts
    steps = torch.cat([near, far, near, near, 0.5 + near, far])  # 0.65 per dimension: 3.5 spreads from the nearest
    assert experience.departed(steps, 2.0).tolist() == [False, False, False, False, True, True]
    assert experience.departed(steps, 4.0).tolist() == [False] * 5 + [True]
    assert not experience.departed(steps[:4], 2.0).any()  # it ends close: nothing departed


def test_a_failure_that_looks_exactly_like_safe_experience_adds_no_negatives(make_policy, attempt) -> None:
    policy = make_policy()
    trace = attempt(policy, EGG, steps=6, seed=0)
    c_raw = policy.kvm.raw_context(torch.cat(trace.contexts), policy.encode_query([EGG] * len(trace)))
    for episode in range(2):  # the very contexts of this attempt, recorded safe in two episodes
        policy.kvm.safe_offline.add(c_raw, skill=0, tag=episode)
    report = policy.kvm_feedback("catastrophe", trace, gradient_steps=0)
    assert report["culprit"] == 0 and report["negatives_added"] == 0


def test_a_failure_that_leaves_the_safe_experience_for_good_is_blamed_from_where_it_left(
    make_policy, make_kvm_config, attempt
) -> None:
    """The last steps of a failed attempt lie inside the spread of the safe experience's most varied phase (so
    `known`), yet far from everything else the skill met (so `departed`): they are failure context unless
    `kvm.departure_radius` is None."""
    blamed = {}
    for radius in (None, 2.0):
        policy = make_policy(kvm=make_kvm_config(departure_radius=radius))
        trace = attempt(policy, EGG, steps=6, seed=0)
        sensed = torch.zeros(6, trace.contexts[0].shape[-1])
        sensed[4:, 1] = 2.0  # the last two steps: 2 from the nearest safe sample
        trace.contexts = [row.unsqueeze(0) for row in sensed]
        query = policy.encode_query([EGG])
        gen = torch.Generator().manual_seed(0)
        for episode, side in enumerate((1.0, -1.0)):  # two episodes, alike but for a varied phase 4 apart
            rows = 0.001 * torch.randn(20, len(sensed[0]), generator=gen)
            rows[16:, 0] += 4.0 * side
            policy.kvm.safe_offline.add(policy.kvm.raw_context(rows, query.expand(20, -1)), skill=0, tag=episode)
        report = policy.kvm_feedback("catastrophe", trace, gradient_steps=0)
        blamed[radius] = report["failure_context_steps"]
    assert blamed == {None: [], 2.0: [4, 5]}


def test_online_successes_and_demonstrations_are_never_another_skills_negatives(make_policy, monkeypatch) -> None:
    """A demonstration shows that its skill works in its contexts, not that the culprit fails there: before the
    shift shows, those contexts are the culprit's own safe ones. Cross-skill negatives come from recorded frames
    (the synthetic perturbations, negatives of each sample's own skill, are left out here)."""
    policy = make_policy()
    policy.begin_new_skill("gentle_grasp")
    kvm = policy.kvm
    monkeypatch.setattr(kvm, "_synthetic", _no_synthetic)
    dim = kvm.safe_offline.dim
    recorded = torch.randn(6, dim)
    kvm.safe_offline.add(recorded, skill=torch.tensor([0, 0, 0, 1, 1, 1]), tag=torch.arange(6))
    demonstrated = torch.randn(5, dim) + 50.0  # far from every recorded frame: any copy of them is recognisable
    kvm.add_safe(demonstrated, torch.ones(5, dtype=torch.long), routine=False, demo=True)
    seen: list[tuple[torch.Tensor, torch.Tensor]] = []
    loss_terms = kvm.loss_terms

    def spy(safe_c, safe_s, routine, fail_c, fail_s, **kwargs):
        seen.append((fail_c.detach().clone(), fail_s.clone()))
        return loss_terms(safe_c, safe_s, routine, fail_c, fail_s, **kwargs)

    kvm.loss_terms = spy
    partners = policy.kvm_negative_partners()
    kvm.train_online(
        5, partners, (demonstrated, torch.ones(5, dtype=torch.long)), (recorded[:0], torch.zeros(0).long())
    )
    fail_c = torch.cat([c for c, _ in seen])
    fail_s = torch.cat([s for _, s in seen])
    assert len(fail_c) and bool((fail_s == 0).any()) and bool((fail_s == 1).any())  # recorded frames still pair
    assert (fail_c.abs().amax(1) < 25).all()  # no demonstrated context became a negative of any skill

    c_raw = torch.cat([recorded, demonstrated])
    skills = torch.tensor([0, 0, 0, 1, 1, 1, 1, 1, 1, 1, 1])
    flags = torch.cat([torch.ones(6, dtype=torch.bool), torch.zeros(5, dtype=torch.bool)])
    neg_c, neg_s = kvm.negatives_for(c_raw, skills, partners, flags)
    assert torch.equal(neg_c, recorded) and neg_s.tolist() == [1, 1, 1, 0, 0, 0]


def test_skills_the_core_proposes_together_are_never_each_others_negatives(make_policy, monkeypatch) -> None:
    """A scenario's safe alternative is learned under its own instruction on the prior variant: nothing recorded
    says it fails in the prior task's contexts, and it is what a suppression hands over to there. A recorded
    context is a cross-skill negative only for active skills the CL core does not propose for its task."""
    policy = make_policy()
    monkeypatch.setattr(policy.kvm, "_synthetic", _no_synthetic)
    for name in ("gentle_grasp", "push"):
        policy.begin_new_skill(name)
    gen = torch.Generator().manual_seed(0)
    stone = F.normalize(torch.randn(policy.config.query_dim, generator=gen), dim=0)
    push = F.normalize(torch.randn(len(stone), generator=gen), dim=0)  # unrelated: cosine ~0
    gently = F.normalize(stone + 0.1 * push, dim=0)  # cosine ~0.99 with stone: siblings
    for skill, query in enumerate((stone, gently, push)):
        policy.pool.observe_queries(query.unsqueeze(0), skill=skill)
    partners = policy.kvm_negative_partners()
    assert partners.tolist() == [[False, False, True], [False, False, True], [True, True, False]]

    kvm = policy.kvm
    c_raw = torch.randn(60, kvm.safe_offline.dim, generator=gen)
    skills = torch.arange(3).repeat(20)
    recorded = torch.ones(60, dtype=torch.bool)
    _, neg_s = kvm.negatives_for(c_raw, skills, partners, recorded)
    assert torch.equal(neg_s[skills != 2], torch.full((40,), 2))
    assert set(neg_s[skills == 2].tolist()) == {0, 1}

    policy.kvm_prune_skill(2)  # the only partner of skills 0 and 1: their contexts give no cross-skill negative
    neg_c, neg_s = kvm.negatives_for(c_raw, skills, policy.kvm_negative_partners(), recorded)
    assert torch.equal(neg_c, c_raw[skills == 2]) and set(neg_s.tolist()) == {0, 1}
