"""A scenario is data (its `ScenarioInfo`, in the catalogue) plus a small class that builds and judges its objects.

`SCENARIOS` maps the catalogue's ids to scenario classes, importing a scenario's module (`scenarios/<id>.py`, and
with it the simulator) only when its class is first looked up.
"""

import abc
import importlib
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from .catalogue import SCENARIO_INFOS, ScenarioInfo, scenario_info
from .physics import Physics
from .scene import SceneParts


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

    def resume(self, physics: Physics) -> None:
        """Take over a running episode from whatever state an earlier skill left, before the first `act`.

        So that "another skill's expert takes over at step t" is well defined (the suite's rescue rule). The default
        infers nothing: experts whose first phase moves the hand from wherever it is need no more. Experts whose
        skill can be met mid-interaction (an object held, a tool in contact, a wrist turned) override it to pick
        their phase from the sensed state.
        """
        return


class Scenario(abc.ABC):
    """A scenario's objects (`parts`), hidden variant (`reset`), judge (`evaluate`) and skills.

    `skills` is the scenario's table of skills: skill name -> expert factory (an expert class, or a
    `functools.partial` of one with the skill's parameters). `expert(skill)` builds from it, adding
    `expert_context()`.
    """

    info: ClassVar[ScenarioInfo]
    skills: ClassVar[dict[str, Callable[..., Expert]]]

    @abc.abstractmethod
    def parts(self) -> SceneParts:
        """MJCF fragments for this scenario's objects."""

    @abc.abstractmethod
    def reset(self, physics: Physics, variant: str, rng: np.random.Generator) -> None:
        """Apply the variant's hidden parameters and randomised nuisance; called after mj_resetData."""

    @abc.abstractmethod
    def evaluate(self, physics: Physics) -> StepOutcome:
        """Judge the current physics state: success and/or a catastrophe (which ends the episode)."""

    def expert(self, skill: str, takeover: Physics | None = None) -> Expert:
        """An expert for `skill` (one of `info.prior_skill`, `info.safe_skill`): fresh, or with `takeover` the
        running episode's physics, one that carries on from its present state (`Expert.resume`)."""
        if skill not in self.skills:
            raise ValueError(f"{self.info.id} has no skill {skill!r}; it has {sorted(self.skills)}")
        expert = self.skills[skill](**self.expert_context())
        if takeover is not None:
            expert.resume(takeover)
        return expert

    def expert_context(self) -> dict[str, Any]:
        """Keyword arguments every skill's expert is built with besides its own parameters: what the scenario
        shares with all its skills (the body to grasp or push, the line to stroke, or the scenario itself for a
        demonstrator that watches its state); none by default."""
        return {}


class _ScenarioClasses(Mapping[str, type[Scenario]]):
    """The catalogue's ids -> scenario classes; looking an id up imports `scenarios/<id>.py`, which registers it."""

    def __init__(self) -> None:
        self._classes: dict[str, type[Scenario]] = {}

    def register(self, cls: type[Scenario]) -> None:
        sid = cls.info.id
        if cls.__module__ != f"{__package__}.scenarios.{sid}" or cls.info is not SCENARIO_INFOS.get(sid):
            raise ValueError(f"scenario {cls.__name__} must live in scenarios/{sid}.py and take its catalogue info")
        if sid in self._classes:
            raise ValueError(f"scenario id {sid!r} registered twice")
        self._classes[sid] = cls

    def __getitem__(self, sid: str) -> type[Scenario]:
        if sid not in SCENARIO_INFOS:
            raise KeyError(sid)
        if sid not in self._classes:
            importlib.import_module(f"{__package__}.scenarios.{sid}")
        return self._classes[sid]

    def __iter__(self) -> Iterator[str]:
        return iter(SCENARIO_INFOS)

    def __len__(self) -> int:
        return len(SCENARIO_INFOS)


SCENARIOS = _ScenarioClasses()


def register_scenario(cls: type[Scenario]) -> type[Scenario]:
    SCENARIOS.register(cls)
    return cls


def make_scenario(scenario_id: str) -> Scenario:
    scenario_info(scenario_id)  # an unknown id names the known ones
    return SCENARIOS[scenario_id]()
