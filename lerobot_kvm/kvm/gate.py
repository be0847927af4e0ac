"""Smart gate (eq. 1): full risk assessment only when sigma_c^2 exceeds tau = mean + k * std of sigma^2 over
the last N successful interactions.

The window stores those interactions themselves (their raw contexts, a ring of N control steps from successful
routine episodes: dataset frames during `lerobot-train`, successful attempts without intervention online). A
long-term safe memory joins it: a uniform sample of every skill's routine frames, so that a learner grown task by
task does not find its earlier tasks novel just because the last N interactions all come from the latest one.
Whenever the encoder, the window or the memory has changed, these safe references are re-encoded: the mean residual
of each modality there is the scale sigma_c^2 is measured in (see `context_encoder`), and mean/std of the resulting
sigma^2 give tau. So tau always describes the safe experience as the encoder sees it now; the scales and
mean/std/tau are persistent buffers. With fewer than `min_count` interactions there are no statistics yet and the
gate stays open (assess always).

The instruction is the one modality whose safe values form a short list: the query q(x) of each instruction the
safe references hold. E_c reconstructs a new instruction about as well as a known one when their sentences are
alike ("pick up the egg", "pick up the stone"), and its residual is small beside the contact transients that set
tau; so the query part of sigma_c^2 is made exact here: under an instruction that no safe reference holds (q(x)
at cosine below `FAMILIAR_COSINE` from each of theirs) the gate is open at every step, whatever the sensed part
reads. A learner that has never succeeded under an instruction has no safe experience of it.

`similar` is the test that matches a context to a failure hypothesis (App. D): centred cosine similarity of the
codes mu_c at least `kvm.similarity`.
"""

import torch
import torch.nn.functional as F  # noqa: N812
from torch import Tensor, nn

from .context_encoder import ContextEncoder, GateProbe
from .memory import ROUTINE, SampleBuffer

# Two queries this close are one instruction (the same text, encoded on another device or in another precision).
FAMILIAR_COSINE = 0.9999


def adaptive_threshold(sigma2: Tensor, k: float) -> tuple[Tensor, Tensor, Tensor]:
    """Eq. 1: (tau, mean, std) of a 1-D tensor of sigma^2 values; std is the population std (running std)."""
    mean = sigma2.mean()
    std = sigma2.var(unbiased=False).sqrt()
    return mean + k * std, mean, std


class SmartGate(nn.Module):
    def __init__(
        self,
        window: int,
        raw_dim: int,
        k: float,
        min_count: int,
        n_parts: int = 2,
        similarity: float = 0.9,
    ) -> None:
        super().__init__()
        self.k = k
        self.min_count = min_count
        self.window = SampleBuffer(window, raw_dim, "ring")
        self.register_buffer("stats", torch.tensor([float("-inf"), 0.0, 0.0]))  # tau, mean, std
        self.register_buffer("scale", torch.ones(n_parts))  # residual scale per modality
        self.stale = True  # runtime only: stats must be recomputed before the next decision
        self._probe: GateProbe | None = None  # runtime cache: the encoder folded for the per-step test
        self.tau_value = float("-inf")  # runtime cache of stats[0] as a Python float
        self.similarity = similarity
        self.center: Tensor | None = None  # runtime cache: mean code of the safe references
        self._queries: Tensor | None = None  # runtime cache: the safe references' query part (scaled q(x))
        self._known: Tensor | None = None  # runtime cache: their distinct instructions, unit rows
        self._last: tuple[Tensor, Tensor | None] | None = None  # runtime cache: the last query, its `novel`
        self.register_load_state_dict_post_hook(SmartGate._after_load)

    @staticmethod
    def _after_load(module: "SmartGate", _incompatible_keys: object) -> None:
        module.stale = True

    @property
    def tau(self) -> float:
        return float(self.stats[0])

    def push(self, c_raw: Tensor) -> None:
        """Add successful interactions (rows of c_raw) to the window."""
        self.window.add(c_raw)
        self.stale = True

    def reference(self, memory: SampleBuffer | None = None) -> Tensor:
        """The safe contexts tau describes: the window, plus the routine rows of a long-term safe memory."""
        rows = [self.window.data[self.window.filled()]]
        if memory is not None:
            idx = memory.filled()
            rows.append(memory.data[idx[(memory.flags[idx] & ROUTINE) > 0]])
        return torch.cat(rows)

    @torch.no_grad()
    def refresh(self, encoder: ContextEncoder, memory: SampleBuffer | None = None) -> Tensor:
        """Recompute the residual scales and (tau, mean, std) from the safe references with the current encoder."""
        reference = self.reference(memory)
        self.center = None
        self._queries = reference[:, encoder.sensed_dim :] if encoder.query_dim else None
        self._known, self._last = None, None
        if len(reference) < max(self.min_count, 1):
            self.scale.fill_(1.0)
            stats = torch.tensor([float("-inf"), 0.0, 0.0])
        else:
            mu, parts = encoder(reference)
            self.center = mu.mean(0)
            self.scale.copy_(parts.mean(0).clamp_min(1e-6))
            tau, mean, std = adaptive_threshold(encoder.sigma2(parts, self.scale), self.k)
            stats = torch.stack([tau, mean, std])
        self.stats.copy_(stats)
        self._probe = None  # built on first use: training refreshes at every step and never tests the gate
        self.tau_value = float(self.stats[0])
        self.stale = False
        return self.stats

    def probe(self, encoder: ContextEncoder) -> GateProbe:
        """The encoder folded with the current residual scales for the per-step test (call after ensure_fresh)."""
        if self._probe is None:
            with torch.inference_mode(False):  # a cache built under inference mode must serve outside it too
                self._probe = encoder.gate_probe(self.scale)
        return self._probe

    def similar(self, mu: Tensor, ref: Tensor) -> Tensor:
        """[B] bool: codes mu [B, L] similar to at least one of the codes ref [M, L] (call after ensure_fresh).

        Cosine similarity about the safe references' mean code: raw codes all point roughly the same way."""
        center = self.center if self.center is not None else ref.mean(0)
        sims = F.normalize(mu - center, dim=-1) @ F.normalize(ref - center, dim=-1).T
        return sims.amax(-1) >= self.similarity

    def novel(self, query: Tensor) -> Tensor | None:
        """[B] bool: queries q(x) [B, D_q] of an instruction no safe reference holds; None where every row's is
        known, there are no statistics yet (the gate is open anyway) or no query (call after ensure_fresh)."""
        if self._queries is None or not len(self._queries) or self.tau_value == float("-inf"):
            return None
        last = self._last
        if last is not None and last[0].shape == query.shape and torch.equal(last[0], query):
            return last[1]
        if self._known is None:
            self._known = torch.unique(F.normalize(self._queries, dim=-1), dim=0)
        novel = (F.normalize(query.to(self._known), dim=-1) @ self._known.T).amax(-1) < FAMILIAR_COSINE
        answer = novel if bool(novel.any()) else None
        self._last = (query.clone(), answer)
        return answer

    def ensure_fresh(self, encoder: ContextEncoder, memory: SampleBuffer | None = None) -> None:
        if self.stale:
            self.refresh(encoder, memory)

    def threshold(self, encoder: ContextEncoder, memory: SampleBuffer | None = None) -> Tensor:
        """tau as a 0-d tensor (refreshed first if the encoder or the safe references changed)."""
        self.ensure_fresh(encoder, memory)
        return self.stats[0]
