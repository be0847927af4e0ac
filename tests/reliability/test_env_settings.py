"""`--env.*` values of `kvm_obsolescence` are refused by name when LeRobot parses them, before any env is built."""

import pytest

from lerobot_kvm.envs.configuration_kvm_obsolescence import KvmObsolescenceEnvConfig


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"episode_length": 0}, r"env.episode_length must be a positive integer .*got 0"),
        ({"episode_length": -5}, r"env.episode_length must be a positive integer .*got -5"),
        ({"fps": 0}, r"env.fps must be a positive integer, got 0"),
        ({"image_size": -96}, r"env.image_size must be a positive integer, got -96"),
        ({"task": "bogus"}, r"unknown task 'bogus'"),
        ({"variant": "melted"}, r"env.variant must be one of .*got 'melted'"),
        ({"instruction": "shout"}, r"env.instruction must be one of .*got 'shout'"),
    ],
)
def test_a_bad_env_setting_is_named(settings, message):
    with pytest.raises(ValueError, match=message):
        KvmObsolescenceEnvConfig(**settings)


def test_the_scenarios_own_length_stays_the_default():
    assert KvmObsolescenceEnvConfig().gym_kwargs["max_episode_steps"] is None
