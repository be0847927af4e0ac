"""Each KVM equation against hand-computed values: eqs. 1, 2, 3, 5, 6, 7, 8 (+ bounded energy, BCE variant)."""

import math

import pytest
import torch
from torch import Tensor, nn

from lerobot_kvm.kvm.context_encoder import ContextEncoder
from lerobot_kvm.kvm.energy import EnergyModel, JointFeature, RiskClassifier, validity
from lerobot_kvm.kvm.fusion import abstains, candidates, correction_validity, decision_weights, mirrored
from lerobot_kvm.kvm.gate import SmartGate, adaptive_threshold
from lerobot_kvm.kvm.losses import bce_loss, contrastive_loss, energy_loss, total_loss
from lerobot_kvm.kvm.metabolism import SkillMetabolism, fcrnc, srnc
from lerobot_kvm.policy.coda_prompt import CodaPromptPool


def test_eq1_adaptive_threshold_is_mean_plus_k_population_std() -> None:
    tau, mean, std = adaptive_threshold(torch.tensor([1.0, 2.0, 3.0, 4.0]), k=3.0)
    assert mean.item() == pytest.approx(2.5)
    assert std.item() == pytest.approx(math.sqrt(1.25))
    assert tau.item() == pytest.approx(2.5 + 3 * math.sqrt(1.25))


class _FirstColumnIsTheResidual(nn.Module):
    """A stand-in encoder: one modality whose mean squared residual is the first column of the raw context."""

    sensed_dim, query_dim = 2, 0

    def forward(self, c_raw: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return c_raw, c_raw[:, :1]

    def sigma2(self, parts: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
        return (parts / scale).sum(-1)


def test_eq1_gate_uses_the_last_n_successful_interactions() -> None:
    gate = SmartGate(window=4, raw_dim=2, k=3.0, min_count=3, n_parts=1)
    enc = _FirstColumnIsTheResidual()
    gate.push(torch.tensor([[9.0, 0.0], [1.0, 0.0]]))
    assert gate.threshold(enc).item() == float("-inf")  # fewer than min_count: no statistics, always assess
    gate.push(torch.tensor([[2.0, 0.0], [3.0, 0.0], [4.0, 0.0]]))  # the ring drops the oldest (9.0)
    assert len(gate.window) == 4
    # residuals 1, 2, 3, 4 in units of their mean 2.5: sigma^2 = 0.4, 0.8, 1.2, 1.6
    assert gate.threshold(enc).item() == pytest.approx(1.0 + 3 * math.sqrt(1.25) / 2.5)
    assert gate.scale.tolist() == [2.5]
    assert gate.stats[1].item() == pytest.approx(1.0) and gate.stats[2].item() == pytest.approx(math.sqrt(1.25) / 2.5)


def test_eq1_gate_also_covers_the_routine_rows_of_a_long_term_safe_memory() -> None:
    from lerobot_kvm.kvm.memory import ROUTINE, SampleBuffer

    gate = SmartGate(window=2, raw_dim=2, k=3.0, min_count=3, n_parts=1)
    enc = _FirstColumnIsTheResidual()
    memory = SampleBuffer(4, 2, "reservoir")
    memory.add(torch.tensor([[1.0, 0.0], [2.0, 0.0]]), torch.zeros(2, dtype=torch.int64), ROUTINE)
    memory.add(torch.tensor([[100.0, 0.0]]), torch.zeros(1, dtype=torch.int64), 0)  # not routine: left out
    gate.push(torch.tensor([[3.0, 0.0], [4.0, 0.0]]))
    assert gate.threshold(enc).item() == float("-inf")  # the window alone has fewer than min_count
    gate.stale = True
    # references 3, 4 (window) + 1, 2 (memory): the same statistics as four window rows 1..4
    assert gate.threshold(enc, memory).item() == pytest.approx(1.0 + 3 * math.sqrt(1.25) / 2.5)
    assert gate.scale.tolist() == [2.5]


def test_sigma2_is_the_residual_of_each_modality_in_units_of_its_safe_scale() -> None:
    enc = ContextEncoder(sensed_dim=2, query_dim=4, hidden=[8], latent_dim=3, use_query=True, query_weight=0.5)
    parts = torch.tensor([[0.2, 0.01], [0.1, 0.0]])
    torch.testing.assert_close(enc.sigma2(parts, torch.tensor([0.1, 0.001])), torch.tensor([2.0 + 5.0, 1.0]))
    torch.testing.assert_close(enc.recon_loss(parts), torch.tensor([0.205, 0.1]))
    c_raw = enc.raw_context(torch.zeros(1, 2), torch.ones(1, 4) / 2)
    assert c_raw.tolist() == [[0.0, 0.0, 1.0, 1.0, 1.0, 1.0]]  # the unit query rescaled by sqrt(D_q)
    mu, parts = enc(c_raw)
    recon = enc.decoder(mu)
    scale = torch.tensor([0.3, 0.02])
    torch.testing.assert_close(((c_raw - recon) ** 2) @ enc.dim_weights(scale), enc.sigma2(parts, scale))
    torch.testing.assert_close(parts[0, 0], ((c_raw - recon)[0, :2] ** 2).mean())
    torch.testing.assert_close(parts[0, 1], ((c_raw - recon)[0, 2:] ** 2).mean())


def test_the_gate_opens_under_an_instruction_no_safe_reference_holds() -> None:
    """The query part is exact: a known instruction (up to scale and float noise) leaves the decision to sigma^2,
    an unknown one opens the gate on its rows only."""
    torch.manual_seed(0)
    enc = ContextEncoder(sensed_dim=3, query_dim=4, hidden=[8], latent_dim=2, use_query=True, query_weight=1.0)
    gate = SmartGate(window=16, raw_dim=7, k=1.0, min_count=4, n_parts=2)
    stone, egg = torch.tensor([1.0, 0.0, 0.5, 0.0]), torch.tensor([1.0, 0.1, 0.5, 0.0])
    assert gate.novel(egg.unsqueeze(0)) is None  # no references yet: no statistics, the gate is open anyway
    gate.push(enc.raw_context(torch.randn(6, 3), stone.expand(6, -1)))
    gate.ensure_fresh(enc)
    assert gate.novel(stone.unsqueeze(0)) is None
    assert gate.novel((stone * 3 + 1e-6).unsqueeze(0)) is None  # the same instruction, scaled, in other bits
    assert gate.novel(torch.stack([stone, egg, stone])).tolist() == [False, True, False]
    assert gate.novel(egg.unsqueeze(0)).tolist() == [True]  # cosine 0.996: another instruction
    gate.push(enc.raw_context(torch.randn(6, 3), egg.expand(6, -1)))  # the egg met safely: known from now on
    gate.ensure_fresh(enc)
    assert gate.novel(egg.unsqueeze(0)) is None


@pytest.mark.parametrize(("hidden", "use_query"), [([8, 6], True), ([8], True), ([8, 6, 5], False)])
def test_gate_probe_gives_the_code_and_sigma2_of_the_encoder(hidden: list[int], use_query: bool) -> None:
    torch.manual_seed(0)
    enc = ContextEncoder(sensed_dim=3, query_dim=4, hidden=hidden, latent_dim=2, use_query=use_query, query_weight=0.5)
    sensed, query = torch.randn(5, 3), torch.randn(5, 4)
    scale = torch.tensor([0.3, 0.02])[: 2 if use_query else 1]
    mu, parts = enc(enc.raw_context(sensed, query))
    sigma2, hidden_code = enc.gate_probe(scale)(sensed, query)
    torch.testing.assert_close(sigma2, enc.sigma2(parts, scale))
    torch.testing.assert_close(enc.gate_probe(scale).code(hidden_code), mu)
    sensed[1, 0] = float("nan")
    assert torch.isfinite(enc.gate_probe(scale)(sensed, query)[0]).tolist() == [True, False, True, True, True]


def test_gate_probe_follows_a_change_of_query() -> None:
    """The query's share is reused while the query stays the same, and recomputed as soon as it changes (in
    value or in batch size), inside or outside inference mode."""
    torch.manual_seed(0)
    enc = ContextEncoder(sensed_dim=3, query_dim=4, hidden=[8, 6], latent_dim=2, use_query=True, query_weight=0.5)
    scale = torch.tensor([0.3, 0.02])
    probe = enc.gate_probe(scale)
    sensed = torch.randn(2, 3)

    def reference(query: Tensor) -> Tensor:
        return enc.sigma2(enc(enc.raw_context(sensed[: len(query)], query))[1], scale)

    first, other = torch.randn(2, 4), torch.randn(2, 4)
    with torch.no_grad():
        for query in (first, first.clone(), other, first, other[:1]):
            torch.testing.assert_close(probe(sensed[: len(query)], query)[0], reference(query))
        with torch.inference_mode():
            torch.testing.assert_close(probe(sensed, other)[0], reference(other))
        torch.testing.assert_close(probe(sensed, other)[0], reference(other))
        torch.testing.assert_close(probe(sensed, first)[0], reference(first))
        query = first.clone()
        probe(sensed, query)
        query += 1.0  # the caller's tensor changes in place: the probe kept a copy to compare with
        torch.testing.assert_close(probe(sensed, query)[0], reference(query))


@pytest.mark.parametrize(
    ("energy", "gamma", "l0", "expected"),
    [
        (0.0, 1.0, -5.0, 1 / (1 + math.exp(-5))),  # 0.99331
        (5.0, 1.0, -5.0, 0.5),
        (10.0, 1.0, -5.0, 1 / (1 + math.exp(5))),  # 0.00669: the energy margin m_e gives v << tau_v
        (6.0, 2.0, -5.0, 1 / (1 + math.exp(2))),
        (-3.0, 1.0, -5.0, 1 / (1 + math.exp(-8))),
    ],
)
def test_eq2_validity(energy, gamma, l0, expected) -> None:
    assert validity(torch.tensor(energy), gamma, l0).item() == pytest.approx(expected, rel=1e-6)


def test_eq2_bce_energy_equivalent_gives_probability_of_safe() -> None:
    logit = torch.tensor([-2.0, 0.0, 3.0])
    v = validity(RiskClassifier.energy_equivalent(logit, 1.0, -5.0), 1.0, -5.0)
    torch.testing.assert_close(v, 1 - torch.sigmoid(logit))


def test_bounded_energy_never_exceeds_e_max() -> None:
    model = EnergyModel(feature_dim=4, hidden=[8], energy_max=20.0)
    with torch.no_grad():
        for p in model.parameters():
            p.fill_(50.0)
    e = model(torch.ones(3, 4))
    assert (e.abs() <= 20.0).all() and e.max().item() == pytest.approx(20.0)
    assert model(-torch.ones(1, 4)).item() >= -20.0


def test_eq3_decision_weights_candidates_and_abstention_hand_values() -> None:
    alphas = torch.tensor([[1.0, 0.2, 4e-11], [0.5, 0.5, 1e-11]])
    active = torch.tensor([True, True, True])
    # candidates: relevance >= 1e-10 of the row's best (4e-11 < 1e-10 in row 0; 1e-11 < 5e-11 in row 1)
    cand = candidates(alphas, active)
    assert cand.tolist() == [[True, True, False], [True, True, False]]
    assert candidates(alphas, torch.tensor([False, True, True])).tolist() == [[False, True, True], [False, True, False]]
    v = torch.tensor([[0.05, 0.9, 1.0], [0.5, 0.02, 1.0]])
    w = decision_weights(v, alphas, cand)
    # w = v * alpha / best candidate alpha; a suppressed candidate (v < tau_v = 0.1) weighs nothing
    torch.testing.assert_close(w, torch.tensor([[0.0, 0.18, 0.0], [0.5, 0.0, 0.0]]))
    assert abstains(v, w, cand).tolist() == [False, False]
    # both candidates suppressed: nothing valid to fuse; the valid non-candidate does not count
    v_low = torch.tensor([[0.05, 0.09, 1.0], [0.05, 0.02, 1.0]])
    assert abstains(v_low, decision_weights(v_low, alphas, cand), cand).tolist() == [True, True]
    # tiny relevances keep their ratios and a best weight of v (no underflow against eq. 3's eps)
    tiny = decision_weights(torch.ones(1, 2), torch.tensor([[1e-20, 5e-21]]), torch.tensor([[True, True]]))
    torch.testing.assert_close(tiny, torch.tensor([[1.0, 0.5]]))


def test_a_correction_is_as_valid_as_the_skill_it_corrects_is_not_where_that_skill_is_relied_on() -> None:
    v = torch.tensor([[0.02, 0.9, 0.1], [0.95, 0.3, 0.05], [0.0, 0.0, 0.0], [0.95, 0.3, 0.9]])
    corrections = (torch.tensor([False, False, True]), torch.tensor([0, 1, 0]))  # skill 2 corrects skill 0
    # relevance: the largest non-correcting skill sets the scale; row 3's skill 0 is a bystander (0.5 < 0.8)
    alphas = torch.tensor([[2.0, 1.0, 5.0], [1.0, 1.0, 1.0], [1.0, 2.0, 1.0], [1.0, 1.0, 1.0]])
    # row 4: skill 0 still holds, so its correction stays out however valid it judges itself (0.9 -> 0.05)
    expected = torch.tensor([[0.02, 0.9, 0.98], [0.95, 0.3, 0.05], [0.0, 0.0, 0.0], [0.95, 0.3, 0.05]])
    torch.testing.assert_close(correction_validity(v, corrections, mirrored(corrections, alphas, 0.8)), expected)
    assert correction_validity(v, None, None) is v
    # where skill 0 is relied on, skill 2's v mirrors it: no judgement of skill 2, so no suppression of it
    assert mirrored(corrections, alphas, 0.8)[:, 2].tolist() == [True, True, False, True]
    assert not mirrored(corrections, alphas, 0.8)[:, :2].any()


def test_of_several_corrections_of_one_skill_only_the_most_valid_takes_over_and_a_pruned_skill_passes_nothing() -> None:
    # skills 2 and 3 both correct skill 0 (made in two different contexts); skill 0 is relied on in every row
    corrections = (torch.tensor([False, False, True, True]), torch.tensor([0, 1, 0, 0]))
    alphas = torch.tensor([[2.0, 1.0, 1.0, 1.0]]).expand(3, -1)
    v = torch.tensor([[0.02, 0.9, 0.1, 0.3], [0.02, 0.9, 0.4, 0.2], [0.02, 0.9, 0.1, 0.1]])
    expected = torch.tensor([[0.02, 0.9, 0.0, 0.98], [0.02, 0.9, 0.98, 0.0], [0.02, 0.9, 0.98, 0.0]])
    torch.testing.assert_close(correction_validity(v, corrections, mirrored(corrections, alphas, 0.8)), expected)
    pruned_0 = torch.tensor([False, True, True, True])
    torch.testing.assert_close(correction_validity(v, corrections, mirrored(corrections, alphas, 0.8, pruned_0)), v)


def test_eq3_fused_prompt_is_the_normalised_weighted_sum_of_skill_prompts() -> None:
    torch.manual_seed(0)
    pool = CodaPromptPool(n_layers=1, pool_size=6, n_tasks=3, prompt_length=2, dim_model=4, query_dim=8)
    for name in ("a", "b", "c"):
        pool.begin_skill(name)
    query = torch.randn(2, 8)
    prompts = pool.skill_prompts(query)  # P_i [L, B, S, Lp, D]
    w = torch.tensor([[0.0, 2.0, 0.5], [1.0, 0.2, 3.0]])
    expected = (prompts * w[None, :, :, None, None]).sum(2) / w.sum(-1)[None, :, None, None]
    torch.testing.assert_close(pool(query, w), expected)
    # suppressing one of two candidates hands the fused prompt to the other, at its own magnitude
    two = torch.tensor([[0.0, 0.7, 0.0], [0.0, 0.0, 0.3]])
    torch.testing.assert_close(pool(query, two), torch.stack([prompts[:, 0, 1], prompts[:, 1, 2]], dim=1))
    # one-hot weights are the skill's own prompt exactly (how a skill is trained and forced)
    for skill in range(3):
        assert torch.equal(pool(query, pool.own_weights(skill, 2)), prompts[:, :, skill])


def test_eq5_triplet_loss_hand_values() -> None:
    anchor = torch.tensor([[0.0, 0.0], [0.0, 0.0]])
    safe = torch.tensor([[1.0, 0.0], [1.0, 0.0]])
    fail = torch.tensor([[0.0, 2.0], [0.0, 1.2]])
    # row 0: relu(1 - 2 + 0.5) = 0; row 1: relu(1 - 1.2 + 0.5) = 0.3
    assert contrastive_loss(anchor, safe, fail, margin=0.5).item() == pytest.approx(0.15)


def test_eq6_energy_loss_hand_values_and_eq13() -> None:
    e_safe = torch.tensor([1.0, -3.0])
    e_fail = torch.tensor([12.0, 4.0])
    # mean(1, -3) + mean(relu(10 - 12), relu(10 - 4)) = -1 + 3
    loss = energy_loss(e_safe, e_fail, margin=10.0)
    assert loss.item() == pytest.approx(2.0)
    assert energy_loss(e_safe, e_fail[:0], 10.0).item() == pytest.approx(-1.0)
    assert total_loss(torch.tensor(0.5), loss, weight=2.0).item() == pytest.approx(4.5)
    # with a floor at -2 the safe term is mean(max(1, -2), max(-3, -2)) = -0.5, and -3 gets no gradient
    e_safe = e_safe.clone().requires_grad_(True)
    floored = energy_loss(e_safe, e_fail, margin=10.0, floor=2.0)
    assert floored.item() == pytest.approx(-0.5 + 3.0)
    floored.backward()
    assert e_safe.grad.tolist() == [0.5, 0.0]


def test_bce_loss_labels_safe_zero_and_fail_one() -> None:
    loss = bce_loss(torch.tensor([0.0]), torch.tensor([0.0]))
    assert loss.item() == pytest.approx(2 * math.log(2))


def test_eq7_eq8_from_counts() -> None:
    proposed = torch.tensor([[2, 1], [4, 4], [0, 0]])
    failed = torch.tensor([[1, 0], [2, 1], [0, 0]])
    suppressed = torch.tensor([[3, 0], [0, 4], [0, 0]])
    torch.testing.assert_close(fcrnc(failed, proposed), torch.tensor([1 / 3, 3 / 8, 0.0]))
    torch.testing.assert_close(srnc(suppressed, proposed), torch.tensor([1.0, 0.5, 0.0]))


def test_eq7_eq8_over_a_sliding_window_of_new_tasks() -> None:
    meta = SkillMetabolism(max_skills=2, window=2, threshold=0.8, min_interactions=1)
    p = torch.tensor([True, True])
    meta.record("task a", p, failed=True, suppressed=torch.tensor([True, False]))
    meta.record("task a", torch.tensor([True, False]), failed=False, suppressed=torch.tensor([False, False]))
    meta.record("task b", p, failed=False, suppressed=torch.tensor([False, True]))
    # skill 0: 3 proposals, 1 suppression (its failure there is the suppression's, not its contribution);
    # skill 1: 2 proposals, 1 failure in force, 1 suppression
    torch.testing.assert_close(meta.fcrnc(), torch.tensor([0.0, 1 / 2]))
    torch.testing.assert_close(meta.srnc(), torch.tensor([1 / 3, 1 / 2]))
    meta.record("task c", torch.tensor([True, False]), failed=True, suppressed=torch.tensor([False, False]))
    # task a left the window of the 2 most recent new tasks: skill 0 has b (ok) and c (failed in force)
    torch.testing.assert_close(meta.fcrnc(), torch.tensor([1 / 2, 0.0]))
    torch.testing.assert_close(meta.srnc(), torch.tensor([0.0, 1.0]))


def test_a_skill_is_pruned_only_when_its_rate_remains_above_the_threshold_over_the_window() -> None:
    meta = SkillMetabolism(max_skills=1, window=2, threshold=0.8, min_interactions=1)
    yes, no = torch.tensor([True]), torch.tensor([False])

    def interact(task: str, failed: bool) -> list[int]:
        meta.record(task, yes, failed=failed, suppressed=no)
        return meta.check_prune(1)

    # above from b on, but only one arrival (c) has seen it above when d succeeds: the rate falls to 1/2
    assert [interact(t, f) for t, f in [("a", True), ("b", True), ("c", True), ("d", False)]] == [[]] * 4
    assert int(meta.streak[0]) == 2 and meta.fcrnc()[0] == 0.5
    # e's arrival finds c, d at 1/2: the streak restarts; failures at e, f, g, h bring it back to 2 at h
    assert [interact(t, True) for t in "efg"] == [[]] * 3
    assert interact("h", True) == [0] and int(meta.pruned[0]) == 1


def test_joint_feature_keeps_the_skill_in_a_far_context() -> None:
    """h = normalize(normalize(W_c mu + b) + normalize(W_s e)): a code far from the safe experience does not drown
    the skill, so two skills keep distinct features (and energies) there."""
    joint = JointFeature(latent_dim=2, n_skills=2, skill_dim=2, feature_dim=2)
    with torch.no_grad():
        joint.context_proj.weight.copy_(torch.eye(2))
        joint.context_proj.bias.zero_()
        joint.skill_proj.weight.copy_(torch.eye(2))
        joint.skill_embed.weight.copy_(torch.tensor([[0.0, 1.0], [0.0, -1.0]]))
    far = torch.tensor([[1e4, 0.0]])
    s = 2**-0.5  # the unit context (1, 0) plus the unit skill (0, +-1), normalized
    h = joint.all_skills(far, torch.arange(2))
    assert h.shape == (1, 2, 2)
    assert torch.allclose(h[0], torch.tensor([[s, s], [s, -s]]))
    assert torch.allclose(joint(far.expand(2, -1), torch.arange(2)), h[0])
