"""The import scan: every import in ``kddrl_trl`` (lazy ones inside functions and ``TYPE_CHECKING`` ones included)
checked against the package's layers, which follow the data flow of the paper's Fig. 2.

    python -m kddrl_trl.devtools.imports        # prints the layers, the findings; exit status 1 if any

Findings: a cycle between modules, a cycle between parts (a part: a subpackage, or a top-level module), and an
*upward* import, a part importing one of a higher layer. A part may import its own layer and any lower one.
"""

from __future__ import annotations

import ast
import sys
from collections import defaultdict
from pathlib import Path

PACKAGE = "kddrl_trl"

#: the layers, lowest first: each part may import only its own layer and the ones below it
LAYERS: tuple[tuple[str, ...], ...] = (
    # shared names and helpers, no project imports
    (
        "keys",
        "atomic_files",
        "provenance",
        "compiling",
        "process_settings",
        "threads",
        "run_folder",
        "main_guard",
        "policies",
        "choices",
        "highway_config",
        "highwayenv_options",
        "protocol",
        "gym_registration",
    ),
    ("physics",),  # IDM and MOBIL (Eqs. 1-2)
    ("envs",),  # the simulator env, its config and its episode metrics
    ("generative", "data"),  # the GANs and the offline data code
    ("transforms", "baselines"),  # the predictive state (Fig. 2), the rule-based policy
    ("modules", "objectives"),  # networks and losses
    ("collectors",),  # acting and storing
    ("training",),  # learners and the trainer
    ("eval",),  # evaluation during and after training: rollouts, episode metrics, validations, traces
    ("reporting",),  # offline: run records read back, statistics over seeds, the paper's verdict, figures, reports
    ("loggers", "gym_env"),  # run logs; the Gymnasium view of the env (its episode metrics, its renderer)
    ("conf",),  # the typed configs
    ("factories",),  # make_* from a config
    ENTRY_POINTS := (
        "train",
        "evaluate",
        "pretrain",
        "report",
        "prepare",
        "record",
        "devtools",
    ),
    (PACKAGE,),  # the package's ``__init__``: its public names
)


def root() -> Path:
    return Path(__file__).resolve().parents[1]


def module_name(path: Path, base: Path) -> str:
    parts = list(path.relative_to(base.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports_of(path: Path, name: str) -> set[str]:
    """The ``kddrl_trl`` modules that ``path`` (module ``name``) imports, anywhere in the file."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.split(".")[0] == PACKAGE}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] != PACKAGE:
                continue
            found.add(target)
            found |= {f"{target}.{a.name}" for a in node.names}  # ``from pkg import module``
    return found


def graph() -> dict[str, set[str]]:
    """Module -> the project modules it imports (names that are not modules resolve to their module)."""
    base = root()
    files = {module_name(p, base): p for p in base.rglob("*.py")}
    edges = {}
    for name, path in files.items():
        targets = set()
        for t in imports_of(path, name):
            while t and t not in files:
                t = t.rpartition(".")[0]
            if t and t != name and t != PACKAGE:
                targets.add(t)
        edges[name] = targets
    return edges


def part(module: str) -> str:
    """A module's part: its subpackage or top-level module, or the entry point it is (``prepare``)."""
    inner = module.split(".", 1)[1] if "." in module else module
    entry = next((e for e in ENTRY_POINTS if inner == e or inner.startswith(e + ".")), None)
    return entry or inner.split(".")[0]


def layer_of(name: str) -> int:
    for i, layer in enumerate(LAYERS):
        if name in layer:
            return i
    raise KeyError(f"part {name!r} is in no layer of kddrl_trl.devtools.imports.LAYERS: give it one")


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one node (Tarjan), each sorted."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(edges.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    sys.setrecursionlimit(10_000)
    for v in sorted(edges):
        if v not in index:
            visit(v)
    return out


def findings() -> list[str]:
    """Every cycle between modules or parts and every upward import, each naming the imports behind it."""
    edges = graph()
    # a module importing its own package's __init__ is no cycle: Python runs the __init__ first
    inner = {m: {t for t in ts if not m.startswith(t + ".")} for m, ts in edges.items()}
    out = [f"cycle between modules: {' <-> '.join(c)}" for c in cycles(inner)]
    parts: dict[str, set[str]] = defaultdict(set)
    why: dict[tuple[str, str], list[str]] = defaultdict(list)
    for m, ts in edges.items():
        for t in ts:
            if part(m) != part(t):
                parts[part(m)].add(part(t))
                why[part(m), part(t)].append(f"{m} -> {t}")
    out += [f"cycle between parts: {' <-> '.join(c)}" for c in cycles(parts)]
    for a, bs in sorted(parts.items()):
        for b in sorted(bs):
            if layer_of(b) > layer_of(a):
                out.append(
                    f"upward import: {a} (layer {layer_of(a)}) imports {b} (layer {layer_of(b)}): "
                    + "; ".join(sorted(why[a, b]))
                )
    return out


def main() -> int:
    for i, layer in enumerate(LAYERS):
        print(f"layer {i}: {', '.join(layer)}")
    found = findings()
    print("\n".join(found) if found else "no cycle, no upward import")
    return 1 if found else 0


if __name__ == "__main__":
    raise SystemExit(main())
