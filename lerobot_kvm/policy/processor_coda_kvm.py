"""Pre/post-processing pipelines of the `coda_kvm` policy.

LeRobot's default steps (rename -> add batch dim -> device -> normalize; unnormalize -> cpu) plus one step:
LeRobot's batch step only knows the state and image keys, so a single unbatched observation would reach the
policy with a 1-D context vector. The task string travels as complementary data and reaches the policy's
query encoder unchanged; the context is normalized like the state (MEAN_STD).
"""

from dataclasses import dataclass
from typing import Any

import torch
from lerobot.configs import PipelineFeatureType, PolicyFeature
from lerobot.lerobot_types import RobotObservation
from lerobot.processor import PolicyAction, PolicyProcessorPipeline
from lerobot.processor.factory import make_default_policy_processor_steps, make_policy_processor_pipelines
from lerobot.processor.pipeline import ObservationProcessorStep, ProcessorStepRegistry

from ..envs.configuration_kvm_obsolescence import OBS_CONTEXT
from .configuration_coda_kvm import CodaKvmConfig


@dataclass
@ProcessorStepRegistry.register(name="coda_kvm_context_batch")
class ContextBatchDimensionStep(ObservationProcessorStep):
    """Adds the batch dimension to a 1-D sensed-context vector (a single environment observation)."""

    context_key: str = OBS_CONTEXT

    def observation(self, observation: RobotObservation) -> RobotObservation:
        value = observation.get(self.context_key)
        if isinstance(value, torch.Tensor) and value.dim() == 1:
            observation[self.context_key] = value.unsqueeze(0)
        return observation

    def get_config(self) -> dict[str, Any]:
        return {"context_key": self.context_key}

    def transform_features(
        self, features: dict[PipelineFeatureType, dict[str, PolicyFeature]]
    ) -> dict[PipelineFeatureType, dict[str, PolicyFeature]]:
        return features


def make_coda_kvm_pre_post_processors(
    config: CodaKvmConfig,
    dataset_stats: dict[str, dict[str, torch.Tensor]] | None = None,
) -> tuple[
    PolicyProcessorPipeline[dict[str, Any], dict[str, Any]],
    PolicyProcessorPipeline[PolicyAction, PolicyAction],
]:
    s = make_default_policy_processor_steps(config, dataset_stats)
    return make_policy_processor_pipelines(
        input_steps=[
            s.rename_observations,
            s.add_batch_dim,
            ContextBatchDimensionStep(context_key=config.context_key),
            s.to_device,
            s.normalize,
        ],
        output_steps=[s.unnormalize, s.to_cpu],
    )
