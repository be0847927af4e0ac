"""A scenario is data (`ScenarioInfo`) plus a small class that builds and judges its objects.

The registry maps stable ids to scenario classes; `resolve_tasks` turns the CLI's
`--env.task` (an id, a category letter or `all`) into a list of ids.
"""

import abc
from dataclasses import dataclass
from typing import ClassVar

import mujoco
import numpy as np

from .physics import Physics
from .scene import SceneParts

VARIANTS = ("prior", "shifted", "control")
# What an episode asks for: the variant's own instruction, or the instruction naming the prior / safe skill.
INSTRUCTIONS = ("variant", "prior", "safe")
CATEGORIES = {"A": "physical property mismatch", "B": "interaction precondition", "C": "representational similarity"}


@dataclass(frozen=True)
class ScenarioInfo:
    """Static description of a scenario; nothing here ever reaches the policy except instructions."""

    id: str
    category: str
    title: str
    instructions: dict[str, str]  # variant -> instruction the env reports as its task
    prior_skill: str  # the old skill, right on the prior variant, harmful on the shifted one
    safe_skill: str  # the alternative that succeeds on the shifted variant
    skill_instructions: dict[str, str]  # skill -> instruction asking for that strategy explicitly
    harm: str  # catastrophe kind raised when the prior skill meets the shifted variant
    what_changes: str
    success: str
    max_steps: int = 120
    variants: tuple[str, ...] = ("prior", "shifted")
    particles: bool = False  # many small loose bodies (liquid, grains): a lower simulation-speed bar applies

    def __post_init__(self) -> None:
        if self.category not in CATEGORIES:
            raise ValueError(f"scenario {self.id!r}: unknown category {self.category!r}")
        missing = [v for v in self.variants if v not in self.instructions]
        if missing:
            raise ValueError(f"scenario {self.id!r}: no instruction for variants {missing}")

    def instruction(self, variant: str, ask: str = "variant") -> str:
        """The task string of an episode on `variant` that asks for `ask` (one of `INSTRUCTIONS`)."""
        if ask not in INSTRUCTIONS:
            raise ValueError(f"instruction must be one of {INSTRUCTIONS}, got {ask!r}")
        if ask == "variant":
            return self.instructions[variant]
        return self.skill_instructions[self.prior_skill if ask == "prior" else self.safe_skill]


@dataclass
class StepOutcome:
    success: bool = False
    catastrophe: str | None = None


class Expert(abc.ABC):
    """A scripted demonstrator: a small state machine on sensed signals.

    Experts may look at the simulator (e.g. where the object is) since they stand in for a
    human demonstrator; their recorded actions are what the policy imitates.
    """

    @abc.abstractmethod
    def act(self, physics: Physics) -> np.ndarray: ...


class Scenario(abc.ABC):
    info: ClassVar[ScenarioInfo]

    @abc.abstractmethod
    def parts(self) -> SceneParts:
        """MJCF fragments for this scenario's objects."""

    @abc.abstractmethod
    def reset(self, model: mujoco.MjModel, data: mujoco.MjData, variant: str, rng: np.random.Generator) -> None:
        """Apply the variant's hidden parameters and randomised nuisance; called after mj_resetData."""

    @abc.abstractmethod
    def evaluate(self, physics: Physics) -> StepOutcome:
        """Judge the current physics state: success and/or a catastrophe (which ends the episode)."""

    @abc.abstractmethod
    def expert(self, skill: str) -> Expert:
        """A fresh expert for `skill` (one of `info.prior_skill`, `info.safe_skill`)."""


SCENARIOS: dict[str, type[Scenario]] = {}


def register_scenario(cls: type[Scenario]) -> type[Scenario]:
    sid = cls.info.id
    if sid in SCENARIOS:
        raise ValueError(f"scenario id {sid!r} registered twice")
    SCENARIOS[sid] = cls
    return cls


def make_scenario(scenario_id: str) -> Scenario:
    if scenario_id not in SCENARIOS:
        raise ValueError(f"unknown scenario {scenario_id!r}; known: {sorted(SCENARIOS)}")
    return SCENARIOS[scenario_id]()


def resolve_tasks(task: str) -> list[str]:
    """`egg_vs_stone` -> [it]; `C` -> every category-C id; `all` -> every id; comma lists allowed."""
    ids: list[str] = []
    for part in (p.strip() for p in task.split(",")):
        if part == "all":
            ids += list(SCENARIOS)
        elif part in CATEGORIES:
            ids += [s for s, c in SCENARIOS.items() if c.info.category == part]
        elif part in SCENARIOS:
            ids.append(part)
        else:
            raise ValueError(
                f"unknown task {part!r}: expected a scenario id {sorted(SCENARIOS)}, a category "
                f"{sorted(CATEGORIES)} or 'all'"
            )
    return list(dict.fromkeys(ids))


def check_variant(variant: str, info: ScenarioInfo) -> None:
    if variant not in info.variants:
        raise ValueError(f"scenario {info.id!r} has no variant {variant!r}; it has {list(info.variants)}")
