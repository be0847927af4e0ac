"""What the KVM decided, per control step (`KvmStepTelemetry`) and per attempt (`KvmTrace`).

Every tensor is detached; shapes use B (batch of environments) and S (skills begun in the pool).
"""

from dataclasses import dataclass, field
from typing import Any

import torch
from torch import Tensor

from .attribution import normalised_relevance
from .fusion import TAU_V, abstains, candidates, decision_weights


class KvmStepTelemetry:
    """One KVM assessment. Tensors a closed gate leaves at their defaults (energy NaN, v = 1, skill weight the
    relevance over the candidates, not invalid) are materialised only when read, so the control loop pays for what
    callers use.

    sigma2 [B]: sigma_c^2, what the gate compares; tau []: tau_adaptive (eq. 1), -inf while there are no statistics;
    gate [B] bool: full assessment ran; alpha [B, S]: the CL core's per-skill relevance alpha_i; candidate [B, S]
    bool: the skills it proposes (computed from alpha when not given); energy [B, S]:
    E_theta(h_i) (or the classifier's energy-equivalent), NaN where not assessed; validity [B, S]: v_i (1 where the
    gate was closed, 0 where invalid or pruned); skill_weight [B, S]: eq. 3's decision weight w_i given to the pool
    (see kvm.fusion); invalid [B, S] bool: non-finite context, code or energy -> v_i = 0 (fail-safe); active [S]
    bool: skills not pruned; mirrored [B, S] bool: corrections whose v mirrors the skill they correct
    (`fusion.mirrored`), None where none does.
    """

    PER_ROW = ("sigma2", "gate", "alpha", "candidate", "energy", "validity", "skill_weight", "invalid")

    def __init__(
        self,
        sigma2: Tensor,
        tau: Tensor,
        gate: Tensor | None,
        alpha: Tensor,
        active: Tensor,
        energy: Tensor | None = None,
        validity: Tensor | None = None,
        skill_weight: Tensor | None = None,
        invalid: Tensor | None = None,
        candidate: Tensor | None = None,
        mirrored: Tensor | None = None,
    ) -> None:
        self.sigma2 = sigma2
        self.tau = tau
        self._gate = gate
        self.alpha = alpha
        self._candidate = candidate
        self.active = active
        self._energy = energy
        self._validity = validity
        self._skill_weight = skill_weight
        self._invalid = invalid
        self.mirrored = mirrored

    @property
    def gate(self) -> Tensor:
        if self._gate is None:  # None: closed everywhere
            self._gate = torch.zeros_like(self.sigma2, dtype=torch.bool)
        return self._gate

    @property
    def energy(self) -> Tensor:
        if self._energy is None:
            self._energy = torch.full_like(self.alpha, float("nan"))
        return self._energy

    @property
    def validity(self) -> Tensor:
        if self._validity is None:
            self._validity = torch.ones_like(self.alpha)
        return self._validity

    @property
    def skill_weight(self) -> Tensor:
        if self._skill_weight is None:
            self._skill_weight = decision_weights(self.validity, self.alpha, self.candidate)
        return self._skill_weight

    @property
    def invalid(self) -> Tensor:
        if self._invalid is None:
            self._invalid = torch.zeros_like(self.alpha, dtype=torch.bool)
        return self._invalid

    # Derived values are computed on access, so that the control loop only pays for what a caller reads.
    @property
    def relevance(self) -> Tensor:
        """[B, S] normalised relevance (see `attribution.normalised_relevance`)."""
        return normalised_relevance(self.alpha, self.active)

    @property
    def candidate(self) -> Tensor:
        """[B, S] bool: proposed by the CL core (see `fusion.candidates`)."""
        if self._candidate is None:
            self._candidate = candidates(self.alpha, self.active)
        return self._candidate

    @property
    def intervention(self) -> Tensor:
        """[B, S] bool: a candidate suppressed (v_i < tau_v); a correction held out where the skill it corrects
        holds is not (its v mirrors that skill's)."""
        suppressed = self.candidate & (self.validity < TAU_V)
        return suppressed if self.mirrored is None else suppressed & ~self.mirrored

    def held(self, necessity: float) -> Tensor:
        """[B, S] bool: the interventions an attempt holds to its end: those on a skill the task relies on
        (normalised relevance above `necessity`, App. D's tau_high). The hidden property that made the skill
        obsolete (the stuck drawer, the paperback) stays for the whole attempt, but the contexts the hand-over
        produces were never judged for that skill: judged afresh at every step, it was valid again one step
        after it was suppressed and resumed into the harm (docs/measurements.md, "A suppression of the relied-on
        skill held for the attempt")."""
        return self.intervention & (self.relevance > necessity)

    @property
    def abstained(self) -> Tensor:
        """[B] bool: every candidate suppressed; the policy held instead of acting (see `fusion.abstains`)."""
        return abstains(self.validity, self.skill_weight, self.candidate)

    @property
    def batch_size(self) -> int:
        return int(self.sigma2.shape[0])

    def row(self, b: int = 0) -> dict[str, Any]:
        """JSON-friendly values of one environment."""

        def plain(t: Tensor) -> Any:
            t = t.detach().cpu()
            if t.dtype == torch.bool:
                return t.tolist()
            return [None if not torch.isfinite(x) else float(x) for x in t.reshape(-1)] if t.ndim else float(t)

        return {
            "sigma2": float(self.sigma2[b]),
            "tau": float(self.tau),
            "gate": bool(self.gate[b]),
            "alpha": plain(self.alpha[b]),
            "relevance": plain(self.relevance[b]),
            "candidate": plain(self.candidate[b]),
            "energy": plain(self.energy[b]),
            "validity": plain(self.validity[b]),
            "skill_weight": plain(self.skill_weight[b]),
            "intervention": plain(self.intervention[b]),
            "abstained": bool(self.abstained[b]),
            "invalid": plain(self.invalid[b]),
        }

    def select(self, b: int) -> "KvmStepTelemetry":
        """The telemetry of environment b alone."""
        values = {name: getattr(self, name) for name in self.PER_ROW}
        return KvmStepTelemetry(
            tau=self.tau,
            active=self.active,
            mirrored=None if self.mirrored is None else self.mirrored[b : b + 1],
            **{k: v[b : b + 1] for k, v in values.items()},
        )


@dataclass
class KvmTrace:
    """What the policy recorded during one attempt (since the last `reset()`), per control step."""

    tasks: list[list[str]] = field(default_factory=list)  # [T][B]
    contexts: list[Tensor] = field(default_factory=list)  # [T] x [B, C] normalized sensed context
    actions: list[Tensor] = field(default_factory=list)  # [T] x [B, A] normalized action executed
    telemetry: list[KvmStepTelemetry | None] = field(default_factory=list)  # [T] the assessment in force
    observations: list[dict[str, Tensor]] = field(default_factory=list)  # [T] policy inputs (optional)
    truncated: bool = False  # more steps than `trace_capacity` happened; the first ones are kept

    def __len__(self) -> int:
        return len(self.contexts)

    @property
    def batch_size(self) -> int:
        return int(self.contexts[0].shape[0]) if self.contexts else 0

    def episode(self, b: int) -> "KvmTrace":
        """The trace of environment b alone (batch size 1)."""
        return KvmTrace(
            tasks=[[t[b]] for t in self.tasks],
            contexts=[c[b : b + 1] for c in self.contexts],
            actions=[a[b : b + 1] for a in self.actions],
            telemetry=[None if t is None else t.select(b) for t in self.telemetry],
            observations=[{k: v[b : b + 1] for k, v in o.items()} for o in self.observations],
            truncated=self.truncated,
        )

    def head(self, n_steps: int) -> "KvmTrace":
        """The first n steps (e.g. up to the step where an environment terminated)."""
        return KvmTrace(
            tasks=self.tasks[:n_steps],
            contexts=self.contexts[:n_steps],
            actions=self.actions[:n_steps],
            telemetry=self.telemetry[:n_steps],
            observations=self.observations[:n_steps],
            truncated=self.truncated,
        )

    def summary(self) -> dict[str, Any]:
        """Per-attempt counts: steps, gate openings, interventions (environment 0)."""
        assessed = [t for t in self.telemetry if t is not None]
        return {
            "steps": len(self),
            "gate_open_steps": sum(int(t.gate[0]) for t in assessed),
            "intervention_steps": sum(int(t.intervention[0].any()) for t in assessed),
            "invalid_steps": sum(int(t.invalid[0].any()) for t in assessed),
            "abstention_steps": sum(int(t.abstained[0]) for t in assessed),
        }
