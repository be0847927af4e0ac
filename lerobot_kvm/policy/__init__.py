"""The `coda_kvm` LeRobot policy; importing this package registers the `coda_kvm` policy type."""

from .configuration_coda_kvm import CodaKvmConfig
from .modeling_coda_kvm import CodaKvmPolicy
from .processor_coda_kvm import make_coda_kvm_pre_post_processors

__all__ = ["CodaKvmConfig", "CodaKvmPolicy", "make_coda_kvm_pre_post_processors"]
