"""CODA-Prompt pool: alpha, Gram-Schmidt growth, freezing, skills and the fused prompt (no text encoder)."""

import numpy as np
import pytest
import torch

from lerobot_kvm.policy.coda_prompt import CodaPromptPool, Skill


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
    contributions = np.einsum("lbsm,lsmkd->bslkd", expected.reshape(2, 3, 2, 2), prompts.reshape(2, 2, 2, 4, 8))
    relevance = pool.skill_relevance(query).detach().numpy()
    np.testing.assert_allclose(relevance, np.sqrt((contributions**2).sum((2, 3, 4))), rtol=1e-5, atol=1e-6)


def test_relevance_is_the_size_of_a_skills_contribution_not_its_alphas() -> None:
    """A skill whose keys barely match the query but whose prompts are large still shapes the prompt most."""
    pool = make_pool(2)
    query = torch.randn(1, 16)
    with torch.no_grad():
        pool.tasks[1].prompts.mul_(1e3)
    alphas = pool.component_alphas(query).unflatten(-1, (2, 2))
    relevance = pool.skill_relevance(query)[0]
    sizes = pool.skill_prompts(query).square().sum((0, 3, 4)).sqrt()[0]
    torch.testing.assert_close(relevance, sizes)
    assert alphas[..., 1, :].abs().sum() < 10 * alphas[..., 0, :].abs().sum()
    assert relevance[1] > 100 * relevance[0]


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


def test_fused_prompt_with_unit_weights_is_exactly_coda() -> None:
    pool = make_pool(2)
    query = torch.randn(3, 16)
    coda = pool(query)
    assert torch.equal(pool(query, torch.ones(3, 2)), coda)
    # Hand CODA prompt: sum_m alpha_m P_m over the visible components.
    alphas = hand_alphas(pool, query.numpy().astype(np.float64))
    prompts = np.concatenate([t.prompts.detach().numpy() for t in pool.tasks[:2]], axis=1)
    np.testing.assert_allclose(coda.detach().numpy(), np.einsum("lbm,lmkd->lbkd", alphas, prompts), atol=1e-6)
    # Per-skill contributions sum to the CODA prompt; weights scale them.
    contributions = pool.skill_prompts(query)
    assert contributions.shape == (2, 3, 2, 4, 8)
    torch.testing.assert_close(contributions.sum(2), coda)
    weights = torch.tensor([[0.0, 1.0], [0.5, 2.0], [1.0, 0.0]])
    torch.testing.assert_close(pool(query, weights), (contributions * weights[None, :, :, None, None]).sum(2))
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


def test_copy_skill_starts_the_learned_skill_as_an_earlier_one() -> None:
    pool = make_pool(2)
    pool.copy_skill(0, 1)
    for attr in ("prompts", "keys", "attn"):
        assert torch.equal(getattr(pool.tasks[1], attr), getattr(pool.tasks[0], attr))
    with pytest.raises(ValueError, match="copy"):
        pool.copy_skill(1, 0)  # only into the skill being learned


def test_skill_table_overflow_is_an_error() -> None:
    pool = make_pool(0)
    with pytest.raises(ValueError, match="skill table"):
        pool.begin_skill("long", "x" * 10_000)


def test_orthogonality_penalty_is_zero_right_after_gram_schmidt() -> None:
    pool = make_pool(3)
    assert pool.ortho_penalty().item() < 1e-10


def test_each_skill_keeps_the_mean_of_its_training_queries() -> None:
    pool = make_pool(1)
    a, b = torch.randn(4, 16), torch.randn(2, 16)
    pool.observe_queries(a)
    pool.observe_queries(b)
    assert torch.allclose(pool.skill_queries[0], torch.cat([a, b]).mean(0), atol=1e-6)
    assert pool.skill_query_counts.tolist() == [6, 0, 0]
    state = pool.state_dict()
    assert "skill_queries" in state and "skill_query_counts" in state


def test_separation_penalty_is_the_new_components_squared_alpha_on_earlier_queries() -> None:
    pool = make_pool(1)
    assert pool.separation_penalty().item() == 0.0  # no earlier skill
    old_query = torch.randn(5, 16)
    pool.observe_queries(old_query)
    pool.begin_skill("next")
    expected = hand_alphas(pool, old_query.mean(0, keepdim=True).numpy().astype(np.float64))[:, :, 2:]  # new rows
    assert pool.separation_penalty().item() == pytest.approx(float((expected**2).mean()), rel=1e-5)


def test_separation_training_silences_new_components_on_old_queries_and_leaves_old_rows_alone() -> None:
    pool = make_pool(1)
    pool.observe_queries(torch.randn(8, 16))
    pool.begin_skill("next")
    old = {k: v.clone() for k, v in pool.tasks[0].state_dict().items()}
    before = pool.separation_penalty().item()
    optimizer = torch.optim.Adam([p for p in pool.parameters() if p.requires_grad], lr=0.05)
    for _ in range(100):
        optimizer.zero_grad()
        pool.separation_penalty().backward()
        optimizer.step()
    assert pool.separation_penalty().item() < 0.01 * before
    assert all(torch.equal(v, pool.tasks[0].state_dict()[k]) for k, v in old.items())
