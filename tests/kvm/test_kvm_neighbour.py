"""The "neighbour" risk model: its calibration against hand-computed held-out scores, and its place in the KVM
(E_theta for skills without failures, rebuilt when E_c or a memory changes)."""

import pytest
import torch

from lerobot_kvm.kvm.energy import validity
from lerobot_kvm.kvm.memory import ROUTINE
from lerobot_kvm.kvm.neighbour import NeighbourEnergy, References, Span, calibrate

SLOPE = 10.0

SAFE = torch.tensor([[0.0], [0.1], [0.2], [0.05], [0.15], [0.25], [1.0], [1.1], [1.2]])
TAGS = torch.tensor([0, 0, 0, 1, 1, 1, 2, 2, 2])
FAIL = torch.tensor([[5.0], [5.1], [5.2]])


def mean3(x: float, points: list[float]) -> float:
    return sum(sorted(abs(x - p) for p in points)[:3]) / 3


def test_calibration_scores_each_recorded_episode_as_held_out() -> None:
    fails = FAIL.flatten().tolist()
    scores = []
    for i, x in enumerate(SAFE.flatten().tolist()):
        others = [p for p, t in zip(SAFE.flatten().tolist(), TAGS.tolist(), strict=True) if t != TAGS[i]]
        scores.append(mean3(x, others) - mean3(x, fails))
    scores_t = torch.tensor(scores)
    threshold = float(torch.quantile(scores_t, 0.9))
    found = calibrate(SAFE, TAGS, FAIL, 0.9)
    assert found.threshold == pytest.approx(threshold, abs=1e-5)
    assert found.width == pytest.approx(threshold - float(scores_t.median()), abs=1e-5)
    # eq. 2 crosses 1/2 at the threshold and gives sigmoid(SLOPE) at the held-out median
    energies = NeighbourEnergy([0], [SAFE], [FAIL], [found], SLOPE)
    x = torch.tensor([[3.0]])
    risk = mean3(3.0, SAFE.flatten().tolist()) - mean3(3.0, fails)
    energy = energies.energy(x, gamma=1.0, l0=-5.0)
    assert energy.shape == (1, 1) and energy.dtype == torch.float32
    assert float(energy) == pytest.approx(5.0 + SLOPE * (risk - threshold) / found.width, abs=1e-4)
    v = validity(energy, 1.0, -5.0)
    assert float(v) < 0.1  # 3.0 lies nearer the failures than any held-out safe sample
    assert float(validity(energies.energy(torch.tensor([[0.1]]), 1.0, -5.0), 1.0, -5.0)) > 0.9


@pytest.mark.parametrize("rank", [4, 2])
def test_the_batched_search_matches_each_skill_searched_alone(rank: int) -> None:
    """Sets of different sizes (one smaller than the neighbour count) in one padded search, in their span (all of
    the space, or a plane of it: then x's distance to the plane counts too)."""
    gen = torch.Generator().manual_seed(0)
    plane = torch.linalg.qr(torch.randn(4, rank, generator=gen))[0]
    sets = [torch.randn(n, rank, generator=gen) @ plane.T * 3 + 10 for n in (7, 2, 12)]
    x = torch.randn(5, 4, generator=gen) * 3 + 10
    span = Span(torch.cat(sets))
    assert span.basis.shape == (4, rank)
    found = References(sets, span).mean_distance(*span.coords(x))
    assert found.shape == (5, 3)
    for i, ref in enumerate(sets):
        expected = torch.cdist(x, ref).topk(min(3, len(ref)), largest=False).values.mean(1)
        assert torch.allclose(found[:, i], expected, atol=1e-4)


def test_calibration_needs_failures_and_two_recorded_episodes() -> None:
    assert calibrate(SAFE, TAGS, FAIL[:0], 0.95) is None
    assert calibrate(SAFE, torch.zeros_like(TAGS), FAIL, 0.95) is None
    assert calibrate(SAFE, torch.full_like(TAGS, -1), FAIL, 0.95) is None


def two_skill_kvm(make_policy, make_kvm_config, skill: int, seed: int, **options):
    """The KVM of a two-skill policy with the neighbour risk model, 24 recorded safe samples of `skill` in
    three episodes; (kvm, safe samples, generator)."""
    policy = make_policy(kvm=make_kvm_config(risk_model="neighbour", **options))
    policy.begin_new_skill("gentle_grasp")
    policy.eval()
    kvm = policy.kvm
    gen = torch.Generator().manual_seed(seed)
    safe = torch.randn(24, kvm.encoder.raw_dim, generator=gen)
    kvm.safe_offline.add(safe, torch.full((24,), skill), ROUTINE, torch.arange(24) // 8)
    return kvm, safe, gen


def test_only_skills_with_failures_leave_the_energy_model(make_policy, make_kvm_config) -> None:
    kvm, safe, gen = two_skill_kvm(make_policy, make_kvm_config, skill=0, seed=0)
    probe = torch.randn(6, kvm.encoder.raw_dim, generator=gen)
    mu = kvm.encode(probe)[0]
    with torch.no_grad():
        assert torch.equal(kvm.skill_energies(mu, probe, 2), kvm.skill_energies(mu, probe, 2, "energy"))  # no failure
        fail = safe[:4] + 5.0
        kvm.add_fail(fail, torch.zeros(4, dtype=torch.long), hypothesis_id=0)
        mixed = kvm.skill_energies(mu, probe, 2)
        plain = kvm.skill_energies(mu, probe, 2, "energy")
        assert torch.equal(mixed[:, 1], plain[:, 1]) and not torch.equal(mixed[:, 0], plain[:, 0])
        v_fail = validity(kvm.skill_energies(kvm.encode(fail)[0], fail, 2), 1.0, -5.0)[:, 0]
        assert (v_fail < 0.5).all()  # the failures themselves are invalid for their skill


def test_the_context_space_searches_the_raw_contexts(make_policy, make_kvm_config) -> None:
    kvm, safe, _ = two_skill_kvm(make_policy, make_kvm_config, skill=1, seed=1)
    fail = safe[:4] + 5.0
    kvm.add_fail(fail, torch.ones(4, dtype=torch.long), hypothesis_id=0)
    probe = torch.cat([safe[8:10] + 0.01, fail[:2] + 0.01])
    found = calibrate(safe, torch.arange(24) // 8, fail, 0.95)
    expected = NeighbourEnergy([1], [safe], [fail], [found], SLOPE).energy(probe, 1.0, -5.0)[:, 0]
    with torch.no_grad():
        energy = kvm.skill_energies(kvm.encode(probe)[0], probe, 2)
        assert torch.allclose(energy[:, 1], expected)
        v = kvm.validity_of(probe, 2)[:, 1]
        assert (v[:2] > 0.9).all() and (v[2:] < 0.1).all()  # near the safe rows valid, near the failures not
        next(kvm.encoder.parameters()).add_(0.5)  # E_c moves: raw contexts do not
        assert torch.allclose(kvm.skill_energies(kvm.encode(probe)[0], probe, 2)[:, 1], expected)
