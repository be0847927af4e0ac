"""Measurement tools: rollouts of the policy in the suite and detection AUROC (`rollouts`), the KVM's validity
acceptance per scenario (`validity_check`) and its latency overhead (`overhead`).

Above the policy in the layering (`cli -> benchmark -> evaluation -> policy -> {kvm, envs, datasets}`): what
measures the mechanism is not part of it.
"""
