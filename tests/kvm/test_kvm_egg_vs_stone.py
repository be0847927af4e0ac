"""Acceptance on egg_vs_stone (reduced): after one failed attempt and its feedback, the prior skill's validity
falls below tau_v in the shifted context and stays above 0.9 in the prior-variant one; v separates hazardous
from safe (skill, context) pairs on held-out episodes; the gate stays mostly closed on routine episodes.

The KVM learns offline from the recorded dataset's contexts alone (the KVM term of forward(); no backbone
training, which does not change v), exactly as the benchmark's pretraining would feed it.
"""

import pytest
import torch
from lerobot.configs.types import FeatureType
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.utils.feature_utils import dataset_to_policy_features

from lerobot_kvm.datasets.recorder import RecordingSpec, RecordItem, load_labels, record_dataset
from lerobot_kvm.envs.env import KvmObsolescenceEnv
from lerobot_kvm.kvm.evaluation import (
    auroc,
    context_validity,
    dataset_contexts,
    expert_rollout,
    gate_rate,
    pretrain_kvm,
    trace_from_demonstration,
)
from lerobot_kvm.policy import CodaKvmConfig, CodaKvmPolicy, make_coda_kvm_pre_post_processors

pytestmark = pytest.mark.slow


def rollouts(pre, variant: str, skill: str, seeds: range) -> list[dict]:
    env = KvmObsolescenceEnv("egg_vs_stone", variant=variant)
    demos = [expert_rollout(env, skill, pre, seed=s)[0] for s in seeds]
    env.close()
    return demos


def test_one_failure_and_its_feedback_suppress_the_prior_skill_only_where_it_is_harmful(tmp_path) -> None:
    torch.manual_seed(0)
    root = tmp_path / "data"
    spec = RecordingSpec(
        name="egg",
        items=[
            RecordItem("egg_vs_stone", "prior", "firm_grasp", 8, "variant"),  # "pick up the stone"
            RecordItem("egg_vs_stone", "prior", "gentle_grasp", 8, "skill"),  # "gently pick up the stone"
        ],
    )
    record_dataset(spec, root, repo_id="local/egg", progress=False)
    meta = LeRobotDataset("local/egg", root=root).meta
    features = dataset_to_policy_features(meta.features)
    config = CodaKvmConfig(
        device="cpu",
        input_features={k: f for k, f in features.items() if k.startswith("observation.")},
        output_features={k: f for k, f in features.items() if f.type is FeatureType.ACTION},
        skill_name="firm_grasp",
        dim_model=32,
        n_layers=1,
        n_heads=2,
        dim_feedforward=64,
        vision_channels=[8, 8],
        prompt_layers=1,
    )
    policy = CodaKvmPolicy(config, dataset_meta=meta)
    data = dataset_contexts(root, "local/egg")
    firm_episodes = {e["episode_index"] for e in load_labels(root)["episodes"] if e["skill"] == "firm_grasp"}
    firm = torch.tensor([int(e) in firm_episodes for e in data["episode_index"]])
    pretrain_kvm(policy, data, steps=300, where=firm)
    policy.begin_new_skill("gentle_grasp")
    pretrain_kvm(policy, data, steps=200, where=~firm)
    policy.eval()
    pre, _ = make_coda_kvm_pre_post_processors(config, data["stats"])

    held_out = range(1000, 1004)
    prior = rollouts(pre, "prior", "firm_grasp", held_out)
    shifted_firm = rollouts(pre, "shifted", "firm_grasp", held_out)
    shifted_gentle = rollouts(pre, "shifted", "gentle_grasp", held_out)
    assert gate_rate(policy, prior) <= 0.06  # routine prior-variant episodes: the gate stays closed
    assert gate_rate(policy, shifted_firm) > 0.5  # the shifted context leaves the safe experience

    env = KvmObsolescenceEnv("egg_vs_stone", variant="shifted")
    failed, outcome = expert_rollout(env, "firm_grasp", pre, seed=3000)  # the prior skill on the egg
    assert outcome == "catastrophe"
    corrective, outcome = expert_rollout(env, "gentle_grasp", pre, seed=3001, policy_skill="gentle_grasp")
    assert outcome == "success"
    report = policy.kvm_feedback("catastrophe", trace_from_demonstration(failed), demonstration=corrective)
    assert report["culprit"] == 0 and report["hypothesis"]["state"] == "open"

    v_prior = context_validity(policy, prior, 0)
    v_shifted = torch.cat([context_validity(policy, shifted_firm, 0), context_validity(policy, shifted_gentle, 0)])
    v_gentle = context_validity(policy, shifted_gentle, 1)
    assert v_shifted.median() < 0.1 and (v_shifted < 0.1).float().mean() > 0.9
    assert v_prior.median() > 0.9 and (v_prior > 0.9).float().mean() > 0.9
    assert auroc(1 - v_shifted, torch.cat([1 - v_prior, 1 - v_gentle])) >= 0.95
