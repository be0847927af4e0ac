"""The Knowledge Validity Module: E_c, smart gate, energy model, memory, attribution and metabolism in one
`nn.Module` (a submodule of the policy, so all of it is in `model.safetensors`).

`assess()` is Algorithm 1's steps 7-21 for a batch of control steps: encode the context, test the gate,
score every skill in the pool (candidates and the rest) with the energy model when the gate is open, turn the
energies into validities (eq. 2) and the validities into skill weights for the fused prompt (eq. 3).
`offline_step()` is the learning that runs inside `forward()` during `lerobot-train`; `train_online()` is the
update of the feedback API (driven by `policy.feedback`).
"""

import sys
from collections.abc import Iterable

import torch
from torch import Tensor, nn

from .attribution import PERSISTENCE, HypothesisTable
from .configuration import KvmConfig
from .context_encoder import ContextEncoder
from .energy import ENERGY_MAX, GAMMA, L0, EnergyModel, JointFeature, RiskClassifier, SkillScorer, validity
from .experience import SafeExperience
from .fusion import candidates, correction_validity, decision_weights, mirrored
from .gate import SmartGate
from .losses import (
    BCE_WEIGHT,
    CONTRAST_MARGIN,
    ENERGY_FLOOR,
    ENERGY_MARGIN,
    ENERGY_WEIGHT,
    RECON_WEIGHT,
    bce_loss,
    contrastive_loss,
    energy_loss,
    total_loss,
)
from .memory import DEMO, PERMANENT, ROUTINE, EpisodeLabels, SampleBuffer
from .metabolism import METABOLISM_WINDOW, PRUNE_MIN_INTERACTIONS, PRUNE_THRESHOLD, SkillMetabolism
from .telemetry import KvmStepTelemetry

GATE_OVERRIDES = (None, "open", "closed")
_FINITE_MAX = sys.float_info.max
QUERY_WEIGHT = 1.0  # §3.1 multimodal context: weight of the query's reconstruction residual in sigma_c^2
SYNTHETIC_NOISE = 3.0  # §3.3 h_fail: std of the synthetic perturbations, in normalized context units
# Safe samples the energy model still judges invalid (v below HARD_SAFE_VALIDITY) are kept in a FIFO of this size
# and replayed at every step (`kvm.hard_safe_replay`; docs/measurements.md).
HARD_SAFE_CAPACITY = 512
HARD_SAFE_VALIDITY = 0.5
FEEDBACK_LR = 1e-3  # App. D: the feedback's Adam step size


class KnowledgeValidityModule(nn.Module):
    def __init__(self, config: KvmConfig, sensed_dim: int, query_dim: int, max_skills: int) -> None:
        super().__init__()
        self.config = config
        self.max_skills = max_skills
        # c_raw = [sensed context, frozen query embedding q(x)] (§3.1: the multimodal context)
        self.encoder = ContextEncoder(
            sensed_dim, query_dim, config.encoder_hidden, config.latent_dim, True, QUERY_WEIGHT
        )
        raw_dim = self.encoder.raw_dim
        self.joint = JointFeature(config.latent_dim, max_skills, config.skill_embed_dim, config.feature_dim)
        self.energy = EnergyModel(config.feature_dim, config.energy_hidden, ENERGY_MAX)
        self.classifier = RiskClassifier(config.feature_dim, config.energy_hidden)
        n_parts = 2 if self.encoder.query_dim else 1
        self.safe_offline = SampleBuffer(config.safe_offline_capacity, raw_dim, "reservoir")
        self.safe_online = SampleBuffer(config.safe_online_capacity, raw_dim, "ring")
        self.fail_offline = SampleBuffer(config.fail_offline_capacity, raw_dim, "reservoir")
        self.fail_online = SampleBuffer(config.fail_online_capacity, raw_dim, "protected")
        self.gate = SmartGate(
            config.gate_window, raw_dim, config.gate_k, config.gate_min_count, n_parts, similarity=config.similarity
        )
        self.safe_hard = SampleBuffer(HARD_SAFE_CAPACITY, raw_dim, "ring")
        self.hypotheses = HypothesisTable(config.hypothesis_capacity, raw_dim, PERSISTENCE, config.tau_high)
        self.metabolism = SkillMetabolism(max_skills, METABOLISM_WINDOW, PRUNE_THRESHOLD, PRUNE_MIN_INTERACTIONS)
        self.labels = EpisodeLabels(config.label_capacity)
        # Runtime only (never saved): a forced gate state for overhead measurement.
        self.gate_override: str | None = None
        joint = tuple(self.joint.parameters())  # what `scorer` snapshots: the joint feature and one network
        self._scored_params = {
            False: (*joint, *self.energy.parameters()),
            True: (*joint, *self.classifier.parameters()),
        }
        self._scorers: dict[bool, tuple[tuple, SkillScorer]] = {}  # cache of `scorer`

    # ----------------------------------------------------------------- runtime
    def train(self, mode: bool = True) -> "KnowledgeValidityModule":
        if mode or self.training:  # entering or leaving training: the encoder may change / have changed
            self.gate.stale = True
        return super().train(mode)

    @property
    def gate_memory(self) -> SampleBuffer:
        """The long-term safe memory the gate's tau also covers: in a learner grown task by task the last N
        interactions are the latest task's, and every earlier task would look novel."""
        return self.safe_offline

    def set_gate_override(self, mode: str | None) -> None:
        if mode not in GATE_OVERRIDES:
            raise ValueError(f"gate override must be one of {GATE_OVERRIDES}, got {mode!r}")
        self.gate_override = mode

    def learnable_parameters(self) -> list[nn.Parameter]:
        return [
            *self.encoder.parameters(),
            *self.joint.parameters(),
            *self.energy.parameters(),
            *self.classifier.parameters(),
        ]

    # ----------------------------------------------------------------- scoring
    def raw_context(self, sensed: Tensor, query: Tensor | None) -> Tensor:
        return self.encoder.raw_context(sensed, query)

    def _encode_parts(self, c_raw: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """(mu [B, L], residual parts [B, P], valid [B]); non-finite rows are zeroed before encoding and flagged
        (a non-finite code makes the residual non-finite too, so one test covers context, code and residual)."""
        finite = torch.isfinite(c_raw).all(-1)
        if not bool(finite.all()):
            c_raw = torch.where(finite.unsqueeze(-1), c_raw, torch.zeros_like(c_raw))
        mu, parts = self.encoder(c_raw)
        return mu, parts, finite & torch.isfinite(parts).all(-1)

    def encode(self, c_raw: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """(mu [B, L], sigma_c^2 [B], valid [B]) with the gate's current residual scales.

        Rows are independent, so a non-finite context row only makes its own code and sigma_c^2 non-finite: one
        finiteness test of sigma_c^2 flags non-finite contexts and codes alike."""
        self.gate.ensure_fresh(self.encoder, self.gate_memory)
        mu, parts = self.encoder(c_raw)
        sigma2 = self.encoder.sigma2(parts, self.gate.scale)
        return mu, sigma2, torch.isfinite(sigma2)

    def risk_energy(self, h: Tensor, risk_model: str | None = None) -> Tensor:
        """Energy of features h [..., F] under the configured risk model (E_theta, or the BCE classifier's
        energy-equivalent)."""
        if (risk_model or self.config.risk_model) == "bce":
            return RiskClassifier.energy_equivalent(self.classifier(h), GAMMA, L0)
        return self.energy(h)

    def skill_energies(self, mu: Tensor, n_skills: int, risk_model: str | None = None) -> Tensor:
        """E [B, S] of every context (codes mu [B, L]) with every skill begun in the pool."""
        model = risk_model or self.config.risk_model
        if torch.is_grad_enabled():  # learning: through the modules
            return self.risk_energy(self.joint.all_skills(mu, torch.arange(n_skills, device=mu.device)), model)
        if model == "novelty":  # the generic OOD monitor of §4.3: wherever the gate opens, nothing is valid
            return mu.new_full((mu.shape[0], n_skills), ENERGY_MAX)
        if model == "bce":
            return RiskClassifier.energy_equivalent(self.scorer(n_skills, True)(mu), GAMMA, L0)
        return self.scorer(n_skills, False)(mu)

    def scorer(self, n_skills: int, classifier: bool) -> SkillScorer:
        """E_theta's (or, `classifier`, the BCE classifier's) `SkillScorer` over the first n_skills skills, rebuilt
        when a weight has changed since (optimizer steps and loads bump the tensors' version counters)."""
        net = self.classifier.net if classifier else self.energy.net
        params = self._scored_params[classifier]
        key = (n_skills, *_cache_key(params[0], params))
        cached = self._scorers.get(classifier)
        if cached is None or cached[0] != key:
            bound = None if classifier else self.energy.energy_max
            with torch.inference_mode(False):  # a cache built under inference mode must serve outside it too
                cached = self._scorers[classifier] = (key, SkillScorer(self.joint, net, n_skills, bound))
        return cached[1]

    def validity_of(self, c_raw: Tensor, n_skills: int, risk_model: str | None = None) -> Tensor:
        """v [B, S] with the gate bypassed (the energy model's judgement everywhere); invalid rows -> 0."""
        mu, _, valid = self.encode(c_raw)
        energy = self.skill_energies(mu, n_skills, risk_model)
        v = validity(energy, GAMMA, L0)
        ok = valid.unsqueeze(-1) & torch.isfinite(energy)
        return torch.where(ok, v, torch.zeros_like(v))

    def threshold(self) -> Tensor:
        return self.gate.threshold(self.encoder, self.gate_memory)

    def gate_open(self, sigma2: Tensor) -> Tensor:
        """[B] bool: the smart gate's decision (eq. 1): sigma_c^2 above tau, a non-finite one included (call after
        the gate is fresh)."""
        return ~(sigma2 <= self.gate.tau_value)

    def assess(
        self,
        sensed: Tensor,
        query: Tensor | None,
        alphas: Tensor,
        active: Tensor,
        all_active: bool | None = None,
        corrections: tuple[Tensor, Tensor] | None = None,
        held: Tensor | None = None,
    ) -> tuple[Tensor, KvmStepTelemetry]:
        """Eq. 3's decision weights w [B, S] for the pool and the step's telemetry (Algorithm 1, lines 5-20).

        sensed [B, C] normalized context, query [B, D_q], alphas [B, S] the CL core's per-skill relevance, active
        [S] bool (not pruned), corrections: knowledge-gap skills (`CodaPromptPool.corrections`), held [B, S] bool:
        suppressions an earlier step of the attempt holds (`KvmStepTelemetry.held`; v = 0 there, gate open or
        not). Where the gate is closed every other v is 1 and w is the relevance over the candidates; the
        gate-closed path costs E_c and the gate test only. `telemetry.abstained` marks rows where every candidate
        is suppressed.
        """
        cfg = self.config
        self.gate.ensure_fresh(self.encoder, self.gate_memory)
        probe = self.gate.probe(self.encoder)
        sigma2, hidden = probe(sensed, query)
        tau = self.gate.tau_value
        # A non-finite sigma^2 fails `<=` and `isfinite`: non-finite contexts and codes open the gate, and are
        # flagged invalid once it is open (rows are independent, so they spoil no other row).
        # None: closed everywhere, decided in the fewest operations (the telemetry makes the mask on demand). The
        # "closed" override (overhead measurement) takes the same test with a bound no finite sigma^2 exceeds.
        if self.gate_override == "open" or not cfg.smart_gate:
            gate = torch.ones_like(sigma2, dtype=torch.bool)
        elif self.gate_override == "closed":
            gate = None if _at_most(sigma2, _FINITE_MAX) else ~torch.isfinite(sigma2)
        elif _at_most(sigma2, tau):
            gate = None
        else:
            gate = self.gate_open(sigma2)
        if query is not None and self.gate_override is None and cfg.smart_gate:
            novel = self.gate.novel(query)  # an instruction with no safe experience: assess at every step
            if novel is not None:
                gate = novel if gate is None else gate | novel
        if all_active is None:
            all_active = bool(active.all())
        candidate = candidates(alphas, active)
        common = dict(sigma2=sigma2, tau=tau, gate=gate, alpha=alphas, active=active, candidate=candidate)
        anywhere, everywhere = _spread(gate)
        if cfg.force_validity is None and not anywhere:  # closed: v = 1 for every skill in force
            v = active.to(sigma2.dtype).expand(sigma2.shape[0], -1)
            if held is not None:
                v = v.masked_fill(held, 0.0)
            weights = decision_weights(v, alphas, candidate)
            if corrections is not None:
                weights = weights.masked_fill(corrections[0], 0.0)
            return weights, KvmStepTelemetry(validity=v, skill_weight=weights, **common)
        if gate is None:
            gate = common["gate"] = torch.zeros_like(sigma2, dtype=torch.bool)
        valid = None if _at_most(sigma2, _FINITE_MAX) else torch.isfinite(sigma2).unsqueeze(-1)  # None: all rows
        if cfg.force_validity is not None:
            energy = sigma2.new_full((sigma2.shape[0], active.shape[0]), float("nan"))
            v = torch.full_like(energy, cfg.force_validity)
            invalid = torch.zeros_like(v, dtype=torch.bool) if valid is None else ~valid.expand_as(v)
        else:
            mu = probe.code(hidden)
            energy = self.skill_energies(mu, active.shape[0])
            v = validity(energy, GAMMA, L0)
            invalid = ~torch.isfinite(energy) if valid is None else ~(valid & torch.isfinite(energy))
            if not everywhere:  # rows with the gate closed (their sigma^2 is finite): not assessed, E NaN, v = 1
                assessed = gate.unsqueeze(-1)
                energy = energy.masked_fill(~assessed, float("nan"))
                v = v.masked_fill(~assessed, 1.0)
                invalid = invalid & assessed
        off = invalid if all_active else invalid | ~active.unsqueeze(0)
        if held is not None:
            off = off | held
        v = v.masked_fill(off, 0.0)
        mirror = None
        if corrections is not None:
            mirror = mirrored(corrections, alphas, cfg.tau_high, active)
            v = torch.where(off, 0.0, correction_validity(v, corrections, mirror))
            mirror &= ~off
        weights = decision_weights(v, alphas, candidate)
        if corrections is not None:
            weights = weights.masked_fill(corrections[0].unsqueeze(0) & ~gate.unsqueeze(-1), 0.0)
        telemetry = KvmStepTelemetry(
            energy=energy, validity=v, skill_weight=weights, invalid=invalid, mirrored=mirror, **common
        )
        return weights, telemetry

    # ----------------------------------------------------------------- learning
    def _cross_skill(self, c_raw: Tensor, skills: Tensor, partners: Tensor) -> tuple[Tensor, Tensor]:
        """(context of skill i, a skill j drawn from `partners[i]`): negatives that are not benchmark shifts.

        `partners` [S, S] bool says which skills may stand as negatives for skill i's contexts (see
        `negatives_for`); contexts whose skill has none are left out."""
        if not len(skills):
            return c_raw[:0], skills[:0]
        allowed = partners[skills]
        keep = allowed.any(-1)
        if not bool(keep.any()):
            return c_raw[:0], skills[:0]
        other = torch.multinomial(allowed[keep].float(), 1).squeeze(-1)
        return c_raw[keep], other

    def _synthetic(self, c_raw: Tensor, skills: Tensor) -> tuple[Tensor, Tensor]:
        """Off-manifold perturbations of the sensed part (the query part is kept)."""
        if not len(skills):
            return c_raw[:0], skills[:0]
        noisy = c_raw.clone()
        sensed = self.encoder.sensed_dim
        noisy[:, :sensed] += SYNTHETIC_NOISE * torch.randn_like(noisy[:, :sensed])
        return noisy, skills

    def _replay(self, buffer: SampleBuffer, n: int, where: Tensor | None = None) -> tuple[Tensor, Tensor, Tensor]:
        idx = buffer.sample(n, where)
        return buffer.data[idx], buffer.skill[idx], buffer.flags[idx]

    def loss_terms(
        self,
        safe_c: Tensor,
        safe_s: Tensor,
        routine: Tensor,
        fail_c: Tensor,
        fail_s: Tensor,
        code_from_recon_only: bool = False,
    ) -> tuple[Tensor, dict[str, Tensor], Tensor]:
        """recon + L_contrast + lambda * L_energy + BCE on one set of safe and hazardous (context, skill) pairs.

        `code_from_recon_only`: E_c learns from the reconstruction alone; the contrastive and energy terms train
        the joint feature and the energy model. Returns the loss, its metrics and the safe samples' energies
        (detached)."""
        mu_s, parts_s, _ = self._encode_parts(safe_c)
        if code_from_recon_only:
            mu_s = mu_s.detach()
        h_s = self.joint(mu_s, safe_s)
        e_s = self.energy(h_s)
        zero = safe_c.new_zeros(())
        recon = self.encoder.recon_loss(parts_s[routine]).mean() if bool(routine.any()) else zero
        if len(fail_c):
            mu_f, _, _ = self._encode_parts(fail_c)
            h_f = self.joint(mu_f.detach() if code_from_recon_only else mu_f, fail_s)
            e_f = self.energy(h_f)
        else:
            h_f = h_s[:0]
            e_f = e_s[:0]
        e_loss = energy_loss(e_s, e_f, ENERGY_MARGIN, ENERGY_FLOOR)
        contrast = zero
        if len(h_s) and len(h_f):
            positive = h_s[self._same_skill_partner(safe_s)]
            negative = h_f[torch.randint(len(h_f), (len(h_s),), device=h_f.device)]
            contrast = contrastive_loss(h_s, positive, negative, CONTRAST_MARGIN)
        bce = bce_loss(self.classifier(h_s.detach()), self.classifier(h_f.detach()))
        loss = RECON_WEIGHT * recon + total_loss(contrast, e_loss, ENERGY_WEIGHT) + BCE_WEIGHT * bce
        metrics = {
            "loss": loss,
            "recon": recon,
            "contrast": contrast,
            "energy_loss": e_loss,
            "bce": bce,
            "energy_safe": e_s.mean() if len(e_s) else zero,
            "energy_fail": e_f.mean() if len(e_f) else zero,
            "v_safe": validity(e_s, GAMMA, L0).mean() if len(e_s) else zero,
            "v_fail": validity(e_f, GAMMA, L0).mean() if len(e_f) else zero,
            "n_fail": torch.tensor(float(len(e_f))),
        }
        return loss, metrics, e_s.detach()

    @staticmethod
    def _same_skill_partner(skills: Tensor) -> Tensor:
        """For each row, the index of a random row with the same skill (itself if it is alone)."""
        partner = torch.arange(len(skills), device=skills.device)
        for s in torch.unique(skills).tolist():
            idx = torch.nonzero(skills == s).flatten()
            partner[idx] = idx[torch.randperm(len(idx), device=skills.device)]
        return partner

    def negatives_for(
        self, safe_c: Tensor, safe_s: Tensor, partners: Tensor, recorded: Tensor
    ) -> tuple[Tensor, Tensor]:
        """Non-benchmark negatives derived from safe samples: cross-skill pairs and synthetic perturbations.

        Cross-skill pairs come only from the `recorded` [N] bool samples (dataset frames), where a context belongs
        to the skill that was asked for, and pair it only with its skill's `partners` [S, S] bool: active skills
        the CL core does not propose for that task (`CodaKvmPolicy.kvm_negative_partners`). A skill proposed
        alongside, a scenario's safe alternative above all, is valid there as far as anything recorded shows, and
        its validity there is what a suppression hands over to: paired as a negative it was judged invalid on
        every prior-variant frame of drawer, chip_bag and egg_vs_stone (docs/measurements.md, sibling negatives).
        A success or a demonstration met online shows that its skill works there, not that the others fail: a
        corrective demonstration senses what the culprit's own safe episodes sense until the shift shows, and
        pairing it with the culprit would suppress the culprit in its prior contexts."""
        cross_c, cross_s = self._cross_skill(safe_c[recorded], safe_s[recorded], partners)
        synthetic_c, synthetic_s = self._synthetic(safe_c, safe_s)
        return torch.cat([cross_c, synthetic_c]), torch.cat([cross_s, synthetic_s])

    def offline_step(
        self,
        c_raw: Tensor,
        skills: Tensor,
        outcome: Tensor,
        usable: Tensor,
        partners: Tensor,
        episodes: Tensor | None = None,
    ) -> tuple[Tensor, dict[str, float]]:
        """One offline learning step on dataset frames (inside `forward()`); also fills the memories.

        Safe = frames of successful episodes (of the skill that produced them); hazardous = frames of recorded
        failure episodes (never a benchmark-shifted variant: those are not `usable`), the same contexts paired
        with other skills, and synthetic off-manifold perturbations. `episodes` [B] (dataset episode indices)
        tag the safe memory, which is what `safe_experience` measures the spread of the safe experience with.
        """
        n = self.config.replay_size
        safe = usable & (outcome == 0)
        fail = usable & (outcome > 0)
        with torch.no_grad():
            self.gate.push(c_raw[safe].detach())
            tags = episodes.to(skills.device)[safe] if episodes is not None else -1
            self.safe_offline.add(c_raw[safe].detach(), skills[safe], ROUTINE, tags)
            self.fail_offline.add(c_raw[fail].detach(), skills[fail])
        rc, rs, rf = self._replay(self.safe_offline, n)
        oc, os_, of = self._replay(self.safe_online, n if len(self.safe_online) else 0)
        hc, hs, hf = self._replay(self.safe_hard, self.config.hard_safe_replay if len(self.safe_hard) else 0)
        safe_c = torch.cat([c_raw[safe], rc, oc, hc])
        safe_s = torch.cat([skills[safe], rs, os_, hs])
        n_new = int(safe.sum())
        routine = torch.cat([torch.ones(n_new, dtype=torch.int64, device=rf.device), rf, of, hf]) & ROUTINE > 0
        recorded = torch.ones(len(safe_s), dtype=torch.bool, device=safe_s.device)
        recorded[n_new + len(rs) : n_new + len(rs) + len(os_)] = False
        neg_c, neg_s = self.negatives_for(safe_c, safe_s, partners, recorded)
        fc1, fs1, _ = self._replay(self.fail_offline, n if len(self.fail_offline) else 0)
        fc2, fs2, _ = self._replay(self.fail_online, n if len(self.fail_online) else 0)
        fail_c = torch.cat([c_raw[fail], fc1, fc2, neg_c])
        fail_s = torch.cat([skills[fail], fs1, fs2, neg_s])
        loss, metrics, e_safe = self.loss_terms(safe_c, safe_s, routine, fail_c, fail_s)
        with torch.no_grad():
            self.keep_hard_safe(c_raw[safe], skills[safe], e_safe[:n_new], tags)
            tau = self.gate.refresh(self.encoder, self.gate_memory)[0]
            _, sigma2_now, _ = self.encode(c_raw[safe]) if bool(safe.any()) else (None, c_raw.new_zeros(0), None)
        out = {f"kvm_{k}": float(v.detach()) for k, v in metrics.items()}
        out["kvm_tau"] = float(tau)
        out["kvm_sigma2"] = float(sigma2_now.mean()) if len(sigma2_now) else 0.0
        out["kvm_gate_rate"] = float((sigma2_now > tau).float().mean()) if len(sigma2_now) else 0.0
        out["kvm_hard_safe"] = float(len(self.safe_hard))
        return loss, out

    @torch.no_grad()
    def keep_hard_safe(self, c_raw: Tensor, skills: Tensor, energy: Tensor, tags: Tensor | int = -1) -> int:
        """Store the safe samples the energy model still judges invalid (v < HARD_SAFE_VALIDITY) for replay."""
        hard = validity(energy, GAMMA, L0) < HARD_SAFE_VALIDITY
        if isinstance(tags, Tensor):
            tags = tags[hard]
        return self.safe_hard.add(c_raw[hard], skills[hard], ROUTINE, tags)

    def train_online(
        self,
        steps: int,
        partners: Tensor,
        new_safe: tuple[Tensor, Tensor],
        new_fail: tuple[Tensor, Tensor],
        batch: int | None = None,
        lr: float | None = None,
    ) -> dict[str, float]:
        """A fixed budget of gradient steps on the KVM (E_c, join, energy model, classifier).

        Each step mixes the fresh samples of this feedback (half of each side) with replay from the memories,
        so what was safe stays safe; cross-skill and synthetic negatives are added as offline. The recorded safe
        frames a step replays and judges invalid join the hard safe memory, replayed at every later step: a
        failure's few negatives would otherwise suppress the culprit wherever its safe experience resembles them. E_c
        learns only its reconstruction here, so a feedback's few contexts (the failed ones are safe for the
        demonstrated skill and hazardous for its culprit) cannot move the codes, nor the residual the smart gate
        reads: learning the contrastive and energy terms too opened the gate on every routine step of a scenario
        after one of its failures (docs/measurements.md).
        """
        cfg = self.config
        batch = batch or cfg.feedback_batch
        half = max(batch // 2, 1)
        params = self.learnable_parameters()
        optimizer = torch.optim.Adam(params, lr=lr or FEEDBACK_LR)
        metrics: dict[str, Tensor] = {}
        safe_new_c, safe_new_s = new_safe
        fail_new_c, fail_new_s = new_fail
        was_training = self.training
        self.train()
        with torch.enable_grad(), torch.inference_mode(False):
            for _ in range(steps):
                parts_c, parts_s, parts_r, parts_rec = [], [], [], []
                if len(safe_new_c):
                    i = torch.randint(len(safe_new_c), (half,), device=safe_new_c.device)
                    parts_c.append(safe_new_c[i])
                    parts_s.append(safe_new_s[i])
                    parts_r.append(torch.zeros(half, dtype=torch.bool, device=safe_new_c.device))
                    parts_rec.append(torch.zeros_like(parts_r[-1]))  # met online
                replay = half // 2 if len(safe_new_c) else half
                offline = slice(0, 0)  # the rows replayed from the recorded safe memory
                for buffer, k, recorded in (
                    (self.safe_offline, replay, True),
                    (self.safe_online, replay, False),
                    (self.safe_hard, cfg.feedback_hard_safe_replay, True),
                ):
                    if len(buffer):
                        c, s, f = self._replay(buffer, k)
                        if buffer is self.safe_offline:
                            start = sum(len(p) for p in parts_c)
                            offline = slice(start, start + len(c))
                        parts_c.append(c)
                        parts_s.append(s)
                        parts_r.append((f & ROUTINE) > 0)
                        parts_rec.append(torch.full_like(parts_r[-1], recorded))
                if not parts_c:
                    break
                safe_c, safe_s, routine = torch.cat(parts_c), torch.cat(parts_s), torch.cat(parts_r)
                fparts_c, fparts_s = [], []
                if len(fail_new_c):
                    i = torch.randint(len(fail_new_c), (half,), device=fail_new_c.device)
                    fparts_c.append(fail_new_c[i])
                    fparts_s.append(fail_new_s[i])
                for buffer in (self.fail_online, self.fail_offline):
                    if len(buffer):
                        c, s, _ = self._replay(buffer, half // 2)
                        fparts_c.append(c)
                        fparts_s.append(s)
                neg_c, neg_s = self.negatives_for(safe_c, safe_s, partners, torch.cat(parts_rec))
                fparts_c.append(neg_c)
                fparts_s.append(neg_s)
                loss, metrics, e_safe = self.loss_terms(
                    safe_c,
                    safe_s,
                    routine,
                    torch.cat(fparts_c),
                    torch.cat(fparts_s),
                    code_from_recon_only=True,
                )
                self.keep_hard_safe(safe_c[offline], safe_s[offline], e_safe[offline])
                optimizer.zero_grad()
                loss.backward()
                torch.nn.utils.clip_grad_norm_(params, 10.0)
                optimizer.step()
        optimizer.zero_grad(set_to_none=True)
        self.train(was_training)
        self.gate.stale = True
        return {k: float(v.detach()) for k, v in metrics.items()}

    # ----------------------------------------------------------------- helpers for the online API
    def safe_samples(self, skill: int) -> tuple[Tensor, Tensor]:
        """`skill`'s safe memory (recorded and met online) [N, D] and the recorded episode of each sample [N] (the
        `episodes` of `offline_step`; -1: untagged)."""
        return _of_skill((self.safe_offline, self.safe_online), skill)

    @torch.no_grad()
    def safe_experience(self, skill: int) -> SafeExperience:
        """`skill`'s safe memory with the spread of its recorded episodes."""
        samples, tags = self.safe_samples(skill)
        tagged = tags >= 0
        episodes = tags[tagged]
        if len(torch.unique(episodes)) < 2:
            return SafeExperience(samples, samples.new_zeros(0))
        cross = torch.cdist(samples[tagged], samples[tagged])
        cross[episodes.unsqueeze(0) == episodes.unsqueeze(1)] = float("inf")
        return SafeExperience(samples, cross.min(1).values)

    def add_safe(self, c_raw: Tensor, skills: Tensor, routine: bool, demo: bool = False) -> None:
        flags = (ROUTINE if routine else 0) | (DEMO if demo else 0)
        self.safe_online.add(c_raw, skills, flags)
        if routine:
            self.gate.push(c_raw)

    def add_fail(self, c_raw: Tensor, skills: Tensor, hypothesis_id: int, permanent: bool = False) -> None:
        self.fail_online.add(c_raw, skills, PERMANENT if permanent else 0, hypothesis_id)

    @torch.no_grad()
    def make_permanent(self, hypothesis_id: int) -> int:
        mask = (self.fail_online.tag == hypothesis_id) & (self.fail_online.stamp >= 0)
        self.fail_online.set_flags(mask, PERMANENT)
        return int(mask.sum())

    def n_permanent(self) -> int:
        return int(((self.fail_online.flags & PERMANENT) > 0).sum())

    @torch.no_grad()
    def similar_to_hypothesis(self, mu: Tensor, hypothesis_id: int) -> Tensor:
        """[B] bool: context codes similar to a hypothesis's contexts (its prototype and negatives): where an
        intervention or a failure counts as evidence for it (App. D)."""
        table = self.hypotheses
        rows = [table.prototype[table.row(hypothesis_id)].unsqueeze(0)]
        tagged = (self.fail_online.tag == hypothesis_id) & (self.fail_online.stamp >= 0)
        rows.append(self.fail_online.data[tagged])
        return self.gate.similar(mu, self.encode(torch.cat(rows))[0])


def _of_skill(buffers: tuple[SampleBuffer, ...], skill: int) -> tuple[Tensor, Tensor]:
    """The stored rows of `skill` in the buffers [N, D] and their tags [N]."""
    rows, tags = [], []
    for buffer in buffers:
        i = buffer.filled()
        mine = buffer.skill[i] == skill
        rows.append(buffer.data[i][mine])
        tags.append(buffer.tag[i][mine])
    return torch.cat(rows), torch.cat(tags)


def _cache_key(reference: Tensor, watched: Iterable[Tensor]) -> tuple:
    """What a cache built from the `watched` tensors is valid for: the device and dtype of a reference parameter (a
    move) and every watched tensor's version counter (in-place updates and loads bump it)."""
    return (reference.device, reference.dtype, *(t._version for t in watched))


def _spread(gate: Tensor | None) -> tuple[bool, bool]:
    """(open anywhere, open everywhere) of a gate mask (None: closed everywhere); one operation for one row."""
    if gate is None:
        return False, False
    if gate.numel() == 1:
        opened = bool(gate)
        return opened, opened
    return bool(gate.any()), bool(gate.all())


def _at_most(values: Tensor, bound: float) -> bool:
    """Every value <= bound (False where one is NaN), with a single operation for a single row."""
    return float(values if values.numel() == 1 else values.max()) <= bound


__all__ = ["KnowledgeValidityModule"]
