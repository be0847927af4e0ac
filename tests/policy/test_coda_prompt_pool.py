"""CODA-Prompt pool: alpha, Gram-Schmidt growth, freezing, skills and the fused prompt (no text encoder)."""

import numpy as np
import pytest
import torch

from lerobot_kvm.policy.coda_prompt import PROTOTYPES_PER_SKILL, RELEVANCE_TEMPERATURE, CodaPromptPool, Skill


def make_pool(n_skills: int = 2) -> CodaPromptPool:
    torch.manual_seed(0)
    pool = CodaPromptPool(n_layers=2, pool_size=6, n_tasks=3, prompt_length=4, dim_model=8, query_dim=16)
    for i in range(n_skills):
        pool.begin_skill(f"skill_{i}", f"description {i}")
    return pool


def hand_alphas(pool: CodaPromptPool, query: np.ndarray) -> np.ndarray:
    """[L, B, M] cosine of q * A_m and K_m, computed with numpy one component at a time."""
    keys = np.concatenate([t.keys.detach().numpy() for t in pool.tasks[: pool.n_skills]], axis=1)
    attn = np.concatenate([t.attn.detach().numpy() for t in pool.tasks[: pool.n_skills]], axis=1)
    out = np.zeros((keys.shape[0], query.shape[0], keys.shape[1]))
    for layer in range(keys.shape[0]):
        for b in range(query.shape[0]):
            for m in range(keys.shape[1]):
                qa = query[b] * attn[layer, m]
                k = keys[layer, m]
                out[layer, b, m] = qa @ k / (np.linalg.norm(qa) * np.linalg.norm(k))
    return out


def test_alpha_matches_hand_computation() -> None:
    pool = make_pool(2)
    with torch.no_grad():  # make keys and attention non-trivial, as after training
        for task in pool.tasks[:2]:
            task.keys.add_(0.3 * torch.randn_like(task.keys))
            task.attn.add_(0.3 * torch.randn_like(task.attn))
    query = torch.randn(3, 16)
    expected = hand_alphas(pool, query.numpy().astype(np.float64))
    got = pool.component_alphas(query).detach().numpy()
    np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-6)
    assert (got < 0).any(), "CODA alphas are cosines without softmax and can be negative"
    prompts = np.concatenate([t.prompts.detach().numpy() for t in pool.tasks[:2]], axis=1)  # [L, M, Lp, D]
    own = np.einsum("lbsm,lsmkd->lbskd", expected.reshape(2, 3, 2, 2), prompts.reshape(2, 2, 2, 4, 8))
    np.testing.assert_allclose(pool.skill_prompts(query).detach().numpy(), own, rtol=1e-5, atol=1e-6)


def test_own_prompt_is_the_one_hot_fusion_from_the_skills_rows_alone() -> None:
    pool = make_pool(3)
    with torch.no_grad():
        for task in pool.tasks[:3]:
            task.keys.add_(0.3 * torch.randn_like(task.keys))
            task.attn.add_(0.3 * torch.randn_like(task.attn))
    query = torch.randn(4, 16)
    for skill in range(3):
        fused = pool.prompt_from_alphas(pool.component_alphas(query), pool.own_weights(skill, 4))
        torch.testing.assert_close(pool.own_prompt(query, skill), fused, rtol=1e-6, atol=1e-7)
    pool.own_prompt(query, 2).square().sum().backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in pool.tasks[2].parameters())
    assert all(p.grad is None for task in pool.tasks[:2] for p in task.parameters())


def test_relevance_is_how_close_the_query_is_to_each_skills_training_queries() -> None:
    pool = make_pool(3)
    a, b = torch.randn(2, 16)
    pool.observe_queries(a.expand(4, -1), skill=0)
    pool.observe_queries(torch.stack([b, -a]), skill=1)  # two distinct prompts: two prototypes
    assert pool.prototype_counts[:2, :2].tolist() == [[4, 0], [1, 1]]
    query = torch.stack([a, b, 0.5 * a + 0.5 * b])
    cos = torch.nn.functional.cosine_similarity
    best = torch.stack(
        [
            torch.stack([cos(q, a, dim=0), torch.maximum(cos(q, b, dim=0), cos(q, -a, dim=0)), torch.tensor(1.0)])
            for q in query
        ]
    )
    # relative to the closest skill; skill 2 has seen nothing: cosine 1, so it is the closest
    expected = torch.exp((best - best.amax(-1, keepdim=True)) / RELEVANCE_TEMPERATURE)
    torch.testing.assert_close(pool.skill_relevance(query), expected, rtol=1e-4, atol=1e-6)  # cosines / 0.01
    assert pool.skill_relevance(a.unsqueeze(0))[0, 0].item() == pytest.approx(1.0, abs=1e-4)


def test_prototypes_merge_equal_queries_and_fold_into_the_nearest_when_full() -> None:
    pool = make_pool(1)
    queries = torch.randn(PROTOTYPES_PER_SKILL + 1, 16)
    pool.observe_queries(queries[:PROTOTYPES_PER_SKILL])
    pool.observe_queries(queries[:1])  # the same task string again: counted, not a new prototype
    counts = pool.prototype_counts[0]
    slot = int(torch.nn.functional.cosine_similarity(pool.prototypes[0], queries[:1]).argmax())
    assert int(counts[slot]) == 2 and sorted(counts.tolist()) == [1] * (PROTOTYPES_PER_SKILL - 1) + [2]
    extra = queries[-1]
    nearest = int(torch.nn.functional.cosine_similarity(pool.prototypes[0], extra.unsqueeze(0)).argmax())
    before = pool.prototypes[0, nearest].clone()
    pool.observe_queries(extra.unsqueeze(0))
    n = int(pool.prototype_counts[0, nearest]) - 1
    torch.testing.assert_close(pool.prototypes[0, nearest], (before * n + extra) / (n + 1))
    state = pool.state_dict()
    assert "prototypes" in state and "prototype_counts" in state


def test_gram_schmidt_new_rows_orthogonal_to_all_old_rows() -> None:
    pool = make_pool(1)
    with torch.no_grad():  # trained rows are no longer orthonormal
        for p in pool.tasks[0].parameters():
            p.add_(0.5 * torch.randn_like(p))
    pool.begin_skill("skill_1")
    pool.begin_skill("skill_2")
    for attr in ("prompts", "keys", "attn"):
        for layer in range(2):
            rows = [getattr(t, attr)[layer].detach().flatten(1).double() for t in pool.tasks]
            for t in (1, 2):
                new = rows[t]
                old = torch.cat(rows[:t])
                assert (new @ old.T).abs().max() < 1e-5, f"{attr} layer {layer} task {t} not orthogonal"
                np.testing.assert_allclose((new @ new.T).numpy(), np.eye(new.shape[0]), atol=1e-5)


def test_unbegun_rows_are_zero_and_frozen() -> None:
    pool = make_pool(1)
    assert pool.n_skills == 1
    for t, task in enumerate(pool.tasks):
        for p in task.parameters():
            assert p.requires_grad == (t == 0)
            if t > 0:
                assert not p.any()
    pool.begin_skill("skill_1")
    assert [p.requires_grad for p in pool.tasks[0].parameters()] == [False] * 3
    assert [p.requires_grad for p in pool.tasks[1].parameters()] == [True] * 3


def test_pool_capacity_and_duplicate_names() -> None:
    pool = make_pool(3)
    with pytest.raises(ValueError, match="full"):
        pool.begin_skill("one_too_many")
    with pytest.raises(ValueError, match="skill_0"):
        make_pool(1).begin_skill("skill_0")


def test_fused_prompt_is_eq3_over_each_skills_own_prompt() -> None:
    pool = make_pool(2)
    query = torch.randn(3, 16)
    # Hand prompts: P_i = sum_{m in i} alpha_m P_m over the skill's own components.
    alphas = hand_alphas(pool, query.numpy().astype(np.float64))
    prompts = np.concatenate([t.prompts.detach().numpy() for t in pool.tasks[:2]], axis=1)
    own = [np.einsum("lbm,lmkd->lbkd", alphas[..., 2 * i : 2 * i + 2], prompts[:, 2 * i : 2 * i + 2]) for i in (0, 1)]
    weights = torch.tensor([[0.0, 1.0], [0.5, 2.0], [3.0, 0.0]])
    w = weights.numpy() / weights.numpy().sum(-1, keepdims=True)
    expected = own[0] * w[None, :, 0, None, None] + own[1] * w[None, :, 1, None, None]
    np.testing.assert_allclose(pool(query, weights).detach().numpy(), expected, atol=1e-6)
    with pytest.raises(ValueError, match="skill_weights"):
        pool(query, torch.ones(3, 3))


def test_skill_table_and_counter_round_trip_through_state_dict() -> None:
    pool = make_pool(2)
    fresh = CodaPromptPool(n_layers=2, pool_size=6, n_tasks=3, prompt_length=4, dim_model=8, query_dim=16)
    fresh.load_state_dict(pool.state_dict())
    assert fresh.n_skills == 2
    assert fresh.skills == [Skill(0, "skill_0", "description 0"), Skill(1, "skill_1", "description 1")]
    # Trainability follows the loaded counter: only the last begun skill learns.
    assert [p.requires_grad for t in fresh.tasks for p in t.parameters()] == [False] * 3 + [True] * 3 + [False] * 3


def test_corrections_are_kept_in_the_skill_table_and_default_to_none() -> None:
    pool = make_pool(1)
    assert pool.corrections() is None  # no correcting skill: the plain CODA path stays available
    with pytest.raises(ValueError, match="corrects"):
        pool.begin_skill("fix", corrects=1)  # only an earlier skill can be corrected
    pool.begin_skill("fix", "a knowledge-gap skill", corrects=0)
    mask, target = pool.corrections()
    assert mask.tolist() == [False, True] and target.tolist() == [0, 0]
    fresh = CodaPromptPool(n_layers=2, pool_size=6, n_tasks=3, prompt_length=4, dim_model=8, query_dim=16)
    fresh.load_state_dict(pool.state_dict())
    assert fresh.skills[1] == Skill(1, "fix", "a knowledge-gap skill", corrects=0) and fresh.skills[1].gated
    assert fresh.corrections()[0].tolist() == [False, True]
    # tables written before corrections existed read as plain skills
    legacy = b'[{"index": 0, "name": "old", "description": ""}]'
    table = torch.zeros_like(fresh.skill_table)
    table[: len(legacy)] = torch.frombuffer(bytearray(legacy), dtype=torch.uint8)
    fresh.load_state_dict({**fresh.state_dict(), "skill_table": table, "task_count": torch.ones(1, dtype=torch.int64)})
    assert fresh.skills == [Skill(0, "old", "")] and fresh.corrections() is None


def test_skill_table_overflow_is_an_error() -> None:
    pool = make_pool(0)
    with pytest.raises(ValueError, match="skill table"):
        pool.begin_skill("long", "x" * 10_000)


def test_orthogonality_penalty_is_zero_right_after_gram_schmidt() -> None:
    pool = make_pool(3)
    assert pool.ortho_penalty().item() < 1e-10


def test_each_skill_reads_its_components_with_its_nearest_prototype() -> None:
    pool = make_pool(3)
    a, b, c = torch.randn(3, 16)
    pool.observe_queries(torch.stack([a, b]), skill=0)
    pool.observe_queries(c.unsqueeze(0), skill=1)  # skill 2 has seen nothing: anchored at the query itself
    query = torch.stack([a + 0.1 * b, b])
    relevance, anchors = pool.propose(query)
    assert torch.equal(relevance, pool.skill_relevance(query))
    nearest_0 = [a, b]  # row 0 is nearest to a, row 1 is b itself
    for row in range(2):
        torch.testing.assert_close(anchors[row, 0], nearest_0[row])
        torch.testing.assert_close(anchors[row, 1], c)
        assert torch.equal(anchors[row, 2], query[row])
    alphas = pool.anchored_alphas(anchors)  # [L, B, M]: skill s's block = its components read at its anchor
    for row in range(2):
        for skill in range(3):
            block = slice(2 * skill, 2 * skill + 2)
            expected = pool.component_alphas(anchors[row, skill].unsqueeze(0))[:, 0, block]
            torch.testing.assert_close(alphas[:, row, block], expected)
    # one anchor for every skill: the plain CODA alphas of that query
    torch.testing.assert_close(pool.anchored_alphas(query.unsqueeze(1).expand(-1, 3, -1)), pool.component_alphas(query))
