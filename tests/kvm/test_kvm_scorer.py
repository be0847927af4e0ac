"""`SkillScorer`: the gate-open step's E_theta / classifier over every skill gives what the modules give on the joint
feature, and follows weight updates."""

import pytest
import torch

from lerobot_kvm.kvm.configuration import KvmConfig
from lerobot_kvm.kvm.energy import ENERGY_MAX, SkillScorer
from lerobot_kvm.kvm.supervisor import KnowledgeValidityModule


def make_kvm(seed: int = 0) -> KnowledgeValidityModule:
    torch.manual_seed(seed)
    kvm = KnowledgeValidityModule(KvmConfig(), sensed_dim=6, query_dim=16, max_skills=5)
    with torch.no_grad():  # weights far from their initial scale: energies well into tanh's curve, logits of size
        for p in (*kvm.energy.parameters(), *kvm.classifier.parameters(), *kvm.joint.parameters()):
            p.mul_(6.0)
    return kvm


@pytest.mark.parametrize("model", ["energy", "bce"])
def test_scorer_matches_the_modules_on_the_joint_feature(model: str) -> None:
    kvm = make_kvm()
    mu = 3.0 * torch.randn(9, kvm.config.latent_dim)
    with torch.enable_grad():
        reference = kvm.skill_energies(mu, 4, model)
    with torch.no_grad():
        scored = kvm.skill_energies(mu, 4, model)
    assert scored.shape == (9, 4)
    assert reference.abs().max() > 1.0  # not a comparison of near-zero values
    assert torch.allclose(scored, reference, rtol=1e-4, atol=1e-5)
    if model == "energy":  # the bound survives the folding of 1 / E_max into the output layer
        assert scored.abs().max() <= ENERGY_MAX


def test_scorer_is_a_snapshot_rebuilt_after_a_weight_update() -> None:
    kvm = make_kvm()
    before = {k: v.clone() for k, v in kvm.state_dict().items()}
    mu = torch.randn(3, kvm.config.latent_dim)
    with torch.no_grad():
        first = kvm.skill_energies(mu, 3, "energy")
        assert kvm.scorer(3, False) is kvm.scorer(3, False)  # cached while nothing changes
    assert all(torch.equal(v, kvm.state_dict()[k]) for k, v in before.items())  # building it altered nothing
    optimizer = torch.optim.SGD(kvm.energy.parameters(), lr=0.5)
    optimizer.zero_grad()
    kvm.energy(kvm.joint(mu, torch.zeros(3, dtype=torch.long))).sum().backward()
    optimizer.step()
    with torch.no_grad():
        after = kvm.skill_energies(mu, 3, "energy")
    with torch.enable_grad():
        reference = kvm.skill_energies(mu, 3, "energy")
    assert not torch.allclose(after, first)
    assert torch.allclose(after, reference, rtol=1e-4, atol=1e-5)


def test_scorer_covers_the_skills_asked_for() -> None:
    kvm = make_kvm()
    mu = torch.randn(2, kvm.config.latent_dim)
    with torch.no_grad():
        few = SkillScorer(kvm.joint, kvm.energy.net, 2, ENERGY_MAX)(mu)
        more = SkillScorer(kvm.joint, kvm.energy.net, 5, ENERGY_MAX)(mu)
    assert few.shape == (2, 2) and more.shape == (2, 5)
    assert torch.allclose(few, more[:, :2])
