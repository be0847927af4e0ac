"""How the suite's modules depend on one another: no cycles, and no simulator behind the config."""

import ast
import subprocess
import sys
from pathlib import Path

import lerobot_kvm.envs

ENVS = Path(lerobot_kvm.envs.__file__).parent


def _module(path: Path) -> str:
    parts = path.relative_to(ENVS.parent.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path, name: str) -> set[str]:
    """Every module `path` imports, at any level (TYPE_CHECKING blocks and function bodies included)."""
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = package.rsplit(".", node.level - 1)[0] if node.level else ""
            stem = ".".join(p for p in (base, node.module or "") if p)
            found.add(stem)
            found |= {f"{stem}.{a.name}" for a in node.names}
    return found


def test_envs_modules_import_no_cycle() -> None:
    graph = {_module(p): p for p in ENVS.rglob("*.py")}
    edges = {name: _imports(path, name) & graph.keys() - {name} for name, path in graph.items()}
    done: set[str] = set()

    def visit(name: str, trail: tuple[str, ...]) -> None:
        assert name not in trail, f"import cycle: {' -> '.join((*trail[trail.index(name) :], name))}"
        if name not in done:
            for other in sorted(edges[name]):
                visit(other, (*trail, name))
            done.add(name)

    for name in sorted(graph):
        visit(name, ())


def test_scenario_hooks_do_not_import_the_env() -> None:
    assert "lerobot_kvm.envs.env" not in _imports(ENVS / "scenario.py", "lerobot_kvm.envs.scenario")


def test_importing_the_package_and_its_env_config_leaves_the_simulator_out() -> None:
    code = (
        "import sys, lerobot_kvm; from lerobot_kvm.envs import KvmObsolescenceEnvConfig, resolve_tasks; "
        "from lerobot_kvm.envs.catalogue import catalogue_markdown; "
        "KvmObsolescenceEnvConfig(task='all'); catalogue_markdown(resolve_tasks('all')); "
        "assert 'mujoco' not in sys.modules, 'mujoco was imported'"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
