"""Decision weights and the fused prompt (eqs. 3-4) on the CODA-Prompt core.

The paper fuses P_fused = sum_i w_i P_i / (sum_i w_i + eps) with w_i = v_i * alpha_i. The CODA prompt is the
*unnormalised* sum sum_i c_i of the skills' contributions c_i = sum_{m in i} alpha_m P_m, and its alphas can be
negative. Eq. 3 is therefore applied as a re-weighting of those contributions that reduces to the identity
when every v_i = 1:

    P_fused = sum_i v_i c_i * S / max(sum_i v_i |alpha_i|, eps * S),   S = sum_i |alpha_i|

i.e. skill weights s_i = v_i * S / sum_j v_j |alpha_j| passed to the pool (each component alpha_m of skill i is
multiplied by s_i, so w_i = s_i * alpha_i). At v = 1 the factor is S / S = 1.0 exactly and the prompt is the CODA
prompt bit for bit; suppressing a skill removes its contribution and hands its relevance mass to the others,
as the normalisation of eq. 3 does. With `renormalize=False` the weights are v itself.
"""

import torch
from torch import Tensor


def fuse_weights(v: Tensor, alphas: Tensor, renormalize: bool = True, eps: float = 1e-3) -> Tensor:
    """Skill weights [B, S] for the CODA pool from validity v [B, S] and per-skill relevance alpha [B, S]."""
    if not renormalize:
        return v
    mass = alphas.abs()
    total = mass.sum(-1, keepdim=True)
    kept = (v * mass).sum(-1, keepdim=True)
    factor = torch.where(total > 0, total / torch.maximum(kept, eps * total), torch.ones_like(total))
    return v * factor
