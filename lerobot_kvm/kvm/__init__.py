"""Knowledge Validity Module (KVM): contextual forgetting on top of the CODA-Prompt core (paper §3).

Modules: `configuration` (KvmConfig), `context_encoder` (E_c), `gate` (eq. 1), `energy` (E_theta, eq. 2, BCE
variant), `fusion` (eq. 3), `losses` (eqs. 5, 6, 13), `memory` (persistent buffers), `experience` (a skill's safe
experience, what a failure is labelled against), `attribution` (App. D), `metabolism` (eqs. 7-8), `telemetry`
and `supervisor` (the nn.Module tying them together).
"""

from .configuration import KvmConfig

__all__ = ["KvmConfig"]
