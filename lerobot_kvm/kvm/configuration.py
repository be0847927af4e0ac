"""`KvmConfig`: the Knowledge Validity Module settings, nested in `CodaKvmConfig` as field `kvm`.

A setting is here when something varies it: an ablation of Table 4, the benchmark, a test's small networks and
memories, or a measurement (`docs/measurements.md`). Each names the equation or appendix of the paper
(`contextual-forgetting-kvm`) it implements, or the measurement that justifies it. The values nothing varies are
module constants next to the code that uses them (e.g. gamma and l0' of eq. 2 in `energy`, tau_v in `telemetry`,
N_p in `attribution`, the pruning window in `metabolism`). On the command line every field is reachable as
`--policy.kvm.<field>=...` (draccus nested dataclass).
"""

from dataclasses import dataclass, field

RISK_MODELS = ("energy", "bce", "novelty")


@dataclass
class KvmConfig:
    # ------------------------------------------------------------------ ablation switches (Table 4, same checkpoint)
    enabled: bool = True  # Table 4 "w/o KVM": False gives exactly the CODA-Prompt core's actions
    smart_gate: bool = True  # Table 4 "w/o Smart Gate": False assesses at every step (eq. 1 bypassed)
    # How a (context, skill) pair is scored: "energy" (the default) is E_theta (§3.1, eq. 2); "bce" the Table 4
    # "w/o Energy Model" MLP classifier in E_theta's place; "novelty" the §4.3 out-of-distribution monitor.
    risk_model: str = "energy"
    force_validity: float | None = None  # diagnostics of eq. 3: every candidate's v set to this value

    # ------------------------------------------------------------------ networks (§3.1, App. E)
    encoder_hidden: list[int] = field(default_factory=lambda: [128, 128])  # App. E: E_c is an MLP 2x128
    latent_dim: int = 32  # §3.1: size of E_c's code mu_c (App. E leaves it open)
    energy_hidden: list[int] = field(default_factory=lambda: [256, 256, 256])  # App. E: E_theta is an MLP 3x256
    skill_embed_dim: int = 32  # eq. 11: size of the skill's embedding in h = join(mu_c, skill)
    feature_dim: int = 64  # eq. 11: size of the joint feature h (App. E: E_theta's input layer)

    # ------------------------------------------------------------------ smart gate (eq. 1, App. E)
    # eq. 1's k. App. E's k = 3 put tau above the 99th percentile of a heavy-tailed sigma^2 (the top 1 % of the
    # safe references hold 84 % of its variance): the gate stayed shut on the shifted book after its feedback;
    # 1.5 keeps it shut on 99.5 % of solved routine steps (docs/measurements.md, the smart gate's k).
    gate_k: float = 1.5
    gate_window: int = 1000  # eq. 1, App. E: N = 1000 successful interactions (control steps)
    gate_min_count: int = 32  # eq. 1 needs statistics: with fewer safe interactions the gate stays open

    # ------------------------------------------------------------------ offline learning inside forward() (§3.3)
    learn_offline: bool = True  # §3.3 offline; the benchmark's baselines fine-tune the action loss alone (False)
    replay_size: int = 32  # §3.3: replayed safe/fail samples per offline step (keeps earlier skills' manifold)
    # Rare safe frames (a contact impact) hold a low energy against the negatives only when the ones still judged
    # invalid are replayed every step (docs/measurements.md, hard safe memory); 0: off.
    hard_safe_replay: int = 16

    # ------------------------------------------------------------------ memory (§3.3 D_safe, D_fail; persistent)
    label_capacity: int = 16384  # §3.3: dataset episodes whose (skill, outcome, variant) labels are kept
    safe_offline_capacity: int = 2048  # §3.3 D_safe: reservoir over the dataset's safe (context, skill) samples
    safe_online_capacity: int = 1024  # §3.3 D_safe: FIFO of safe samples met online
    fail_offline_capacity: int = 512  # §3.3 D_fail: reservoir over recorded failure frames (no benchmark shift)
    fail_online_capacity: int = 1024  # App. D: provisional and confirmed h_fail negatives met online

    # ------------------------------------------------------------------ online learning (Algorithm 1, App. D)
    feedback_steps: int = 100  # App. D: gradient steps of one feedback (the benchmark gives every method 100)
    # One failure's few dozen negatives suppressed held-out contexts that moved with the minibatch order; a large
    # batch averages the draw out (kvm-check, docs/measurements.md, feedback batch 512).
    feedback_batch: int = 512
    feedback_hard_safe_replay: int = 64  # the hard safe share (1/8) of a feedback batch (docs/measurements.md)
    # App. D failure context: the steps from which an attempt stays further than this multiple of the median
    # spread of the culprit's safe experience until its end (docs/measurements.md, departure rule); None: off.
    departure_radius: float | None = 2.0
    hypothesis_capacity: int = 64  # App. D: open and confirmed risk hypotheses kept
    # App. D, App. E: an intervention is necessary when normalised alpha_i > tau_high; such a suppression holds to
    # the end of the attempt (`KvmStepTelemetry.held`, docs/measurements.md)
    tau_high: float = 0.8
    similarity: float = 0.9  # App. D: cosine similarity of mu_c that makes a context similar to a hypothesis's
    gap_alpha: float = 0.5  # App. D knowledge gap: every alternative's normalised relevance stays below this
    # App. D: a failure with a corrective demonstration tests the knowledge gap at once (with every alternative
    # weak, suppressing the culprit would leave no strategy at all).
    gap_on_failure: bool = True

    # ------------------------------------------------------------------ telemetry (Algorithm 1: decisions observable)
    trace_capacity: int = 2000  # Algorithm 1's trace: control steps kept per attempt for the feedback

    def __post_init__(self) -> None:
        if self.risk_model not in RISK_MODELS:
            raise ValueError(f"`kvm.risk_model` must be one of {RISK_MODELS}, got {self.risk_model!r}")
        positive_ints = (
            "latent_dim",
            "gate_window",
            "skill_embed_dim",
            "feature_dim",
            "replay_size",
            "label_capacity",
            "safe_offline_capacity",
            "safe_online_capacity",
            "fail_offline_capacity",
            "fail_online_capacity",
            "feedback_batch",
            "hypothesis_capacity",
            "trace_capacity",
        )
        for name in positive_ints:
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value <= 0:
                raise ValueError(f"`kvm.{name}` must be a positive integer, got {value!r}")
        non_negative_ints = (
            "gate_min_count",
            "feedback_steps",
            "hard_safe_replay",
            "feedback_hard_safe_replay",
        )
        for name in non_negative_ints:
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 0:
                raise ValueError(f"`kvm.{name}` must be a non-negative integer, got {value!r}")
        for name in ("encoder_hidden", "energy_hidden"):
            value = getattr(self, name)
            if not value or any(not isinstance(v, int) or v <= 0 for v in value):
                raise ValueError(f"`kvm.{name}` must be a non-empty list of positive ints, got {value!r}")
        if not self.gate_k >= 0:
            raise ValueError(f"`kvm.gate_k` must be >= 0, got {self.gate_k!r}")
        for name in ("tau_high", "similarity"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"`kvm.{name}` must be in [0, 1], got {value!r}")
        if self.force_validity is not None and not 0.0 <= self.force_validity <= 1.0:
            raise ValueError(f"`kvm.force_validity` must be None or in [0, 1], got {self.force_validity!r}")
        if self.departure_radius is not None and not self.departure_radius > 0:
            raise ValueError(f"`kvm.departure_radius` must be None or > 0, got {self.departure_radius!r}")
