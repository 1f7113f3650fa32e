"""The shape of the code: no import cycles between app modules; a numeric core without web.

Every module under app/ is parsed with :mod:`ast` (nothing is imported), and every import
statement counts, wherever it is: at module level, inside a function, under ``if
TYPE_CHECKING``. ``from app.x import y`` names the module ``app.x.y`` when that is a module
of its own, else ``app.x`` (importing a submodule runs its package's ``__init__``, which is
not counted as a dependency on the package); relative imports are resolved against the
importing module.
"""

from __future__ import annotations

import ast
from pathlib import Path

APP = Path(__file__).resolve().parent.parent / "app"

#: What app/sim/ (the numeric core) must not import: the web stack, the backend, and Ray
#: (campaigns run the core; app/campaign/sweep_ray.py).
WEB_IMPORTS = ("fastapi", "uvicorn", "viser", "app.backend", "ray", "app.campaign.sweep_ray")


def module_name(path: Path) -> str:
    parts = list(path.relative_to(APP.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def app_modules() -> dict[str, Path]:
    return {module_name(p): p for p in sorted(APP.rglob("*.py"))}


def imported_names(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The module names the import statements of module `name` (file `path`) name."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: from . import x, from ..y import z
                parts = package.split(".")
                parts = parts[: len(parts) - (node.level - 1)]
                base = ".".join([*parts, node.module] if node.module else parts)
            else:
                base = node.module or ""
            for alias in node.names:
                sub = f"{base}.{alias.name}"
                found.add(sub if sub in modules else base)
    return found


def import_graph() -> dict[str, set[str]]:
    """app module -> the app modules it imports (an import of itself left out)."""
    modules = app_modules()
    return {
        name: {m for m in imported_names(name, path, modules) if m in modules and m != name}
        for name, path in modules.items()
    }


def find_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """One cycle (a, b, ..., a) per strongly connected component that has one."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []
    counter = [0]

    def connect(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1 or v in graph.get(v, ()):
                components.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            connect(v)

    cycles = []
    for component in components:
        members = set(component)
        start = component[0]
        # shortest way back to `start` inside the component (breadth first)
        paths = {w: [start, w] for w in sorted(graph[start]) if w in members}
        frontier = list(paths)
        while start not in paths:
            nxt = []
            for v in frontier:
                for w in sorted(graph[v]):
                    if w in members and w not in paths:
                        paths[w] = paths[v] + [w]
                        nxt.append(w)
            frontier = nxt
        cycles.append(paths[start])
    return cycles


def test_the_cycle_finder_finds_and_prints_cycles():
    assert find_cycles({"a": {"b"}, "b": {"c"}, "c": set()}) == []
    assert find_cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c", "a"]]
    assert find_cycles({"a": {"a"}}) == [["a", "a"]]


def test_the_graph_sees_every_kind_of_import():
    graph = import_graph()
    assert {"app.cli", "app.sim.loop", "app.backend.runner", "app.scenarios"} <= set(graph)
    assert "app.sim.loop" in graph["app.backend.loop_process"]  # from app.sim.loop import ...
    assert "app.backend.snapshots" in graph["app.backend.runner"]  # from app.backend import m
    assert "app.runs.headless" in graph["app.cli"]  # inside a function
    assert "app.backend" not in graph["app.backend.runner"]  # only the package of a module


def test_no_import_cycles_between_app_modules():
    cycles = find_cycles(import_graph())
    assert not cycles, "import cycles between app modules:\n" + "\n".join(
        "  " + " -> ".join(cycle) for cycle in cycles
    )


def test_the_numeric_core_has_no_web_imports():
    modules = app_modules()
    offending = []
    for name, path in modules.items():
        if not (name == "app.sim" or name.startswith("app.sim.")):
            continue
        for imported in sorted(imported_names(name, path, modules)):
            if any(imported == w or imported.startswith(w + ".") for w in WEB_IMPORTS):
                offending.append(f"{name} imports {imported}")
    assert not offending, "app/sim/ must not import the web stack:\n" + "\n".join(offending)


def test_one_implementation_per_stage_and_pinocchio_only_in_the_tests():
    """No compiled twins, no switches between a reference and a compiled path, and no
    Pinocchio in app/: its paths live on in tests/oracle.py only."""
    modules = app_modules()
    assert not [p.name for p in APP.rglob("*_kernel.py")]
    for name, path in modules.items():
        text = path.read_text()
        for word in ("use_kernel", "set_compiled"):
            assert word not in text, f"{name} mentions {word}"
        imported = imported_names(name, path, modules)
        assert not [m for m in imported if m == "pinocchio" or m.startswith("pinocchio.")], name


#: The lab-side stages of the contact chain (docs/contact-chain.md): what a lab's loop
#: runs. None may import the simulated world's interaction (the contact law's forces, the
#: operator's hand).
LAB_SIDE = ("app.sim.ft_sensor", "app.sim.contact_gate", "app.sim.contact_estimator",
            "app.sim.contact_identification",
            "app.sim.coupling", "app.sim.passivity", "app.sim.compensation", "app.sim.vfdm",
            "app.sim.orbital", "app.sim.feedforward")
SIMULATED_WORLD = ("app.sim.interaction", "app.sim.hand", "app.sim.reference")


def test_the_lab_side_stages_do_not_import_the_simulated_world():
    modules = app_modules()
    offending = [f"{name} imports {m}" for name in LAB_SIDE
                 for m in sorted(imported_names(name, modules[name], modules))
                 if m in SIMULATED_WORLD]
    assert not offending, "\n".join(offending)


class _Sealed:
    """A stand-in for a simulated-world object: the names in ``allowed`` pass through, any
    other read fails the test (the loop's lab side read it)."""

    def __init__(self, real, allowed: set[str], what: str) -> None:
        object.__setattr__(self, "_real", real)
        object.__setattr__(self, "_allowed", allowed)
        object.__setattr__(self, "_what", what)

    def __getattr__(self, name: str):
        if name in self._allowed:
            return getattr(self._real, name)
        raise AssertionError(f"the loop's lab side read {self._what}.{name}")

    def __setattr__(self, name: str, value) -> None:
        raise AssertionError(f"the loop's lab side wrote {self._what}.{name}")


def _sealed_run(seal: bool, seconds: float = 3.5):
    """The collision (seed 0, hil) with, when ``seal``, the simulated world made
    unreadable to the loop's lab side: of the interaction only the physics' own call
    (wrenches_W: the contact law and the hand acting on the mockups, which the sensors
    then measure), of the contact model only its geometry (the mockups' boxes at their
    measured poses: apart, clearances, frames) and the materials' friction setting."""
    import numpy as np

    from app.config import merge_overrides
    from app.scenarios import load_scenario
    from app.sim.loop import Emulator

    em = Emulator(merge_overrides(load_scenario("collision"), {"loop": {"seed": 0}}))
    if seal:
        contact = _Sealed(em.interaction.contact,
                          {"apart", "clearances", "frames", "friction"}, "contact")
        interaction = em.interaction
        em.interaction = _Sealed(interaction, {"wrenches_W"}, "interaction")
        object.__setattr__(em.interaction, "contact", contact)  # for the gate's query
        em.interaction._allowed.add("contact")
        em.hand = _Sealed(em.hand, {"update", "post"}, "hand")  # the world moves the hand
    em.run(seconds)
    return em.status, np.array(em.telemetry.rows())


def test_no_lab_side_stage_reads_the_simulated_contact_or_hand():
    """The collision runs through its contact (3.1-3.3 s) with the simulated contact and
    hand sealed (nothing but the physics' own call, the boxes' geometry and μ readable):
    no stage of the lab's chain (processing, gate, fusion, estimator, coupling, passivity,
    compensation, VFDM) reads them, and the run is bit for bit the unsealed one."""
    import numpy as np

    status, sealed = _sealed_run(True)
    assert status == "finished"
    _, free = _sealed_run(False)
    np.testing.assert_array_equal(sealed, free)


def test_app_top_level_holds_packages_and_the_cli():
    """One home per responsibility: the run (make, describe, read), campaigns, settings,
    the numeric core, the server; only the CLI lives at the top."""
    modules = sorted(p.name for p in APP.glob("*.py"))
    assert modules == ["__init__.py", "cli.py"]
    packages = sorted(p.name for p in APP.iterdir() if (p / "__init__.py").is_file())
    assert packages == ["backend", "campaign", "config", "runs", "scenarios", "sim"]
