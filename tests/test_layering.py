"""The package's layers, `cli -> benchmark -> evaluation -> policy -> {kvm, envs, datasets}`, read from the source.

Every import counts (module level, inside functions, under `TYPE_CHECKING`): an arrow that runs back up, or a cycle,
makes a change in one layer reach into the layers it should not know. Loading a policy or the env config must not
import the simulator either.
"""

import ast
import subprocess
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "lerobot_kvm"
RANK = {"cli": 4, "benchmark": 3, "evaluation": 2, "policy": 1, "kvm": 0, "envs": 0, "datasets": 0}
SIBLINGS = {("datasets", "envs")}  # the recorder runs the suite


def _name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _graph() -> dict[str, set[str]]:
    """Module -> the project modules it imports (a `from m import x` naming a submodule x counts as m.x)."""
    paths = {_name(p): p for p in PACKAGE.rglob("*.py")}

    def resolve(name: str) -> str:
        while name not in paths and "." in name:
            name = name.rpartition(".")[0]
        return name

    graph: dict[str, set[str]] = {}
    for module, path in paths.items():
        package = module if path.name == "__init__.py" else module.rpartition(".")[0]
        found: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                found.update(a.name for a in node.names)
            elif isinstance(node, ast.ImportFrom):
                base = package.split(".")[: len(package.split(".")) - node.level + 1] if node.level else []
                name = ".".join([*base, node.module] if node.module else base)
                found.update(f"{name}.{a.name}" for a in node.names)
        graph[module] = {resolve(n) for n in found if n.split(".")[0] == "lerobot_kvm"} - {module}
    return graph


def _layer(module: str) -> str:
    return module.split(".")[1] if module.count(".") else ""


def test_no_layer_imports_upwards_and_kvm_imports_nothing_of_the_project() -> None:
    wrong = []
    for module, targets in _graph().items():
        for target in targets:
            a, b = _layer(module), _layer(target)
            if a == b or a not in RANK:  # within a layer, or the package's own `__init__` (plugin registration)
                continue
            if a == "kvm" or RANK[b] > RANK[a] or (RANK[b] == RANK[a] and (a, b) not in SIBLINGS):
                wrong.append(f"{module} -> {target}")
    assert not wrong


def test_no_import_cycles() -> None:
    graph = _graph()
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    cycles = []

    def visit(module: str, path: list[str]) -> None:
        state[module] = 1
        for target in sorted(graph.get(module, ())):
            if state.get(target) == 1:
                cycles.append(path[path.index(target) :] + [target])
            elif target in graph and target not in state:
                visit(target, [*path, target])
        state[module] = 2

    for module in sorted(graph):
        if module not in state:
            visit(module, [module])
    assert not cycles


def test_loading_a_policy_or_the_env_config_leaves_the_simulator_out() -> None:
    code = (
        "import sys, lerobot_kvm\n"
        "from lerobot_kvm.policy import CodaKvmConfig, CodaKvmPolicy\n"
        "from lerobot_kvm.envs import KvmObsolescenceEnvConfig, resolve_tasks\n"
        "from lerobot_kvm.envs.catalogue import catalogue_markdown\n"
        "KvmObsolescenceEnvConfig(task='all'); catalogue_markdown(resolve_tasks('all'))\n"
        "assert 'mujoco' not in sys.modules, 'mujoco was imported'\n"
        "from lerobot_kvm.envs import KvmObsolescenceEnv  # the env itself loads the simulator on first use\n"
        "assert 'mujoco' in sys.modules and KvmObsolescenceEnv.__name__ == 'KvmObsolescenceEnv'\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
