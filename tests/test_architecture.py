"""The package layering: every import arrow points down, and no module imports itself back.

``dtmbnav_core`` (the standard's tables, IQ formats, constants, records, the
file schema and its readers) is the bottom layer and imports nothing of the
project; ``receiver``, ``sim`` and ``fusion`` stand on it and never on each
other; only ``dtmbnav`` wires them. The real-data path (receive, fuse,
report) must work without the simulator, so it must not import it.

``dtmbnav`` itself is in rooms, each a package: the command line on top, then
the research harness, the simulator's wiring, the processing chain on files and
the field formats at the bottom. A room imports only the rooms below it; no
module of ``dtmbnav`` lives outside a room.
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from dtmbnav_core import schema
from dtmbnav_core.h5io import atomic_h5, write_columns
from dtmbnav_core.records import FrameBatch
from dtmbnav_core.sensors import (read_capture_start_s, read_gnss, read_imu, read_tower, read_walk_truth,
                                  read_weinberg_k_m)

ROOT = Path(__file__).resolve().parents[1]
FOUNDATION = "dtmbnav_core"
STAGES = ("receiver", "sim", "fusion")
APPLICATION = "dtmbnav"
PACKAGES = (FOUNDATION, *STAGES, APPLICATION)
#: The application's rooms, top to bottom: each may import itself and the rooms after it.
ROOMS = ("cli", "evaluation", "simulation", "chain", "field")
#: No module of the application is longer than this, lines.
MAX_APPLICATION_MODULE_LINES = 600
CAPTURES = ROOT / "captures"


def module_name(path: Path, root: Path = ROOT) -> str:
    """Dotted module name of a source file under ``root`` (a package's ``__init__`` is the package)."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported_modules(path: Path, known: set[str], root: Path = ROOT) -> set[str]:
    """Modules of ``known`` that a source file imports, at module level or inside functions.

    ``from a import b`` names module ``a.b`` where that is a module, else ``a``;
    relative imports are resolved against the file's own package.
    """
    package = module_name(path, root).split(".")
    if path.name != "__init__.py":
        package = package[:-1]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            candidates = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = ".".join(package[:len(package) - node.level + 1] + ([node.module] if node.module else [])) \
                if node.level else node.module
            candidates = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in known else base for alias in node.names]
        else:
            continue
        for name in candidates:
            # The longest known prefix: ``import a.b.c`` runs module a.b.c.
            while name and name not in known:
                name = name.rpartition(".")[0]
            if name:
                found.add(name)
    return found


def project_modules(root: Path = ROOT) -> dict[str, Path]:
    return {module_name(p, root): p for package in PACKAGES for p in sorted((root / package).rglob("*.py"))}


def import_graph(root: Path = ROOT) -> dict[str, set[str]]:
    """Each project module and the project modules it imports."""
    modules = project_modules(root)
    known = set(modules)
    return {name: imported_modules(path, known, root) - {name} for name, path in modules.items()}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle of the graph (its modules in order, the first repeated at the end), or None."""
    state: dict[str, int] = {}  # 1 on the current path, 2 done
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return stack[stack.index(nxt):] + [nxt]
            if nxt not in state and (cycle := visit(nxt)):
                return cycle
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (cycle := visit(node)):
            return cycle
    return None


def top_packages(names: set[str]) -> set[str]:
    return {name.split(".")[0] for name in names}


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    return import_graph()


def test_the_foundation_imports_nothing_of_the_project(graph):
    for name, imports in graph.items():
        if name.split(".")[0] == FOUNDATION:
            wrong = top_packages(imports) - {FOUNDATION}
            assert not wrong, f"{name} imports {sorted(wrong)}"


@pytest.mark.parametrize("package", STAGES)
def test_stage_packages_import_only_the_foundation_and_themselves(graph, package):
    for name, imports in graph.items():
        if name.split(".")[0] == package:
            wrong = top_packages(imports) - {FOUNDATION, package}
            assert not wrong, f"{name} imports {sorted(wrong)}"


def room_of(module: str) -> str | None:
    """The room of an application module (``dtmbnav.ROOM...``), None for the package itself."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else None


def room_violations(graph: dict[str, set[str]], rooms: tuple[str, ...] = ROOMS) -> list[str]:
    """Every import of an application module that points at its own room's superior or at no room, as text."""
    wrong = []
    for name, imports in sorted(graph.items()):
        if name.split(".")[0] != APPLICATION or room_of(name) is None:
            continue
        if room_of(name) not in rooms:
            wrong.append(f"{name} is in no room (rooms: {', '.join(rooms)})")
            continue
        allowed = set(rooms[rooms.index(room_of(name)):])
        for target in sorted(imports):
            if target.split(".")[0] == APPLICATION and room_of(target) is not None and room_of(target) not in allowed:
                wrong.append(f"{name} imports {target}: an arrow up")
    return wrong


def test_the_application_is_in_rooms_and_its_arrows_point_down(graph):
    assert room_violations(graph) == []


def test_no_application_module_outside_a_room():
    loose = sorted(p.name for p in (ROOT / APPLICATION).glob("*.py") if p.name != "__init__.py")
    assert loose == []
    for room in ROOMS:
        init = ROOT / APPLICATION / room / "__init__.py"
        assert init.exists() and ast.get_docstring(ast.parse(init.read_text())), f"{room} needs a docstring"


def test_no_application_module_is_long():
    long = {str(p.relative_to(ROOT)): n for p in (ROOT / APPLICATION).rglob("*.py")
            if (n := len(p.read_text().splitlines())) > MAX_APPLICATION_MODULE_LINES}
    assert long == {}


def test_the_room_check_sees_an_arrow_up_and_a_module_without_a_room():
    graph = {"dtmbnav.field.towers": {"dtmbnav.chain.files"}, "dtmbnav.chain.files": {"dtmbnav.field.towers"},
             "dtmbnav.cli.main": {"dtmbnav.evaluation.bench", "dtmbnav_core.schema"}, "dtmbnav.loose": set(),
             "dtmbnav": set()}
    assert room_violations(graph) == ["dtmbnav.field.towers imports dtmbnav.chain.files: an arrow up",
                                      "dtmbnav.loose is in no room (rooms: cli, evaluation, simulation, chain, field)"]


def test_no_import_cycles(graph):
    assert find_cycle(graph) is None, " -> ".join(find_cycle(graph))


def test_the_import_walk_sees_function_level_relative_and_submodule_imports(tmp_path):
    """The checker itself: imports hidden inside functions, relative imports and ``from pkg import module``."""
    for package in ("receiver", "sim", "dtmbnav_core", "pkg"):
        (tmp_path / package).mkdir()
        (tmp_path / package / "__init__.py").write_text("")
    (tmp_path / "sim" / "walk.py").write_text("")
    (tmp_path / "dtmbnav_core" / "records.py").write_text("")
    (tmp_path / "pkg" / "a.py").write_text("def f():\n    from sim.walk import simulate_walk\n    import receiver\n"
                                           "from dtmbnav_core import records\nfrom . import b\n")
    (tmp_path / "pkg" / "b.py").write_text("from pkg.a import f\n")
    modules = {module_name(p, tmp_path): p for p in tmp_path.rglob("*.py")}
    imports = imported_modules(tmp_path / "pkg" / "a.py", set(modules), tmp_path)
    assert imports == {"sim.walk", "receiver", "dtmbnav_core.records", "pkg.b"}
    graph = {name: imported_modules(path, set(modules), tmp_path) - {name} for name, path in modules.items()}
    assert find_cycle(graph) in (["pkg.a", "pkg.b", "pkg.a"], ["pkg.b", "pkg.a", "pkg.b"])


REAL_DATA_PATH = """
import sys
from pathlib import Path
from dtmbnav.cli import main

out = Path(sys.argv[1])
captures = Path(sys.argv[2])
walk_receiver = sys.argv[3]
loaded = {}
def sim_modules():
    return sorted(m for m in sys.modules if m == "sim" or m.startswith("sim."))
codes = [main(["-q", "receive", str(captures / "park-loop-cw.sigmf-meta"), "-o", str(out / "rx.h5")])]
loaded["receive"] = sim_modules()
codes.append(main(["-q", "pdr", str(captures / "truth.h5"), "-o", str(out / "pdr.h5")]))
loaded["pdr"] = sim_modules()
codes.append(main(["-q", "fuse", "--receiver", walk_receiver, "--sensors", str(captures / "truth.h5"),
                   "-o", str(out / "fused.h5"), "--filters", "pf,ukf", "--particles", "300"]))
loaded["fuse"] = sim_modules()
codes.append(main(["-q", "report", str(out / "fused.h5"), "--truth", str(captures / "truth.h5"),
                   "-o", str(out / "report")]))
loaded["report"] = sim_modules()
import json
print(json.dumps({"codes": codes, "sim_modules": loaded}))
"""


def write_exact_receiver_file(path: Path, truth_path: Path, rate_hz: float = 100.0) -> None:
    """A receiver file whose range is the truth's over the whole walk (the bundled capture covers 1.25 s)."""
    walk = read_walk_truth(truth_path)
    tower_x, tower_y, height = read_tower(truth_path)
    t = np.arange(walk.track.t_s[0], walk.track.t_s[-1], 1.0 / rate_hz)
    x, y = np.interp(t, walk.track.t_s, walk.track.x_m), np.interp(t, walk.track.t_s, walk.track.y_m)
    rng = np.sqrt((x - tower_x) ** 2 + (y - tower_y) ** 2 + height**2)
    frames = FrameBatch.concatenate([]).columns()
    n = len(t)
    columns = {name: np.zeros(n, dtype=values.dtype) for name, values in frames.items()}
    columns.update(t_s=t, frame_index=np.arange(n), range_change_m=rng - rng[0], snr_db=np.full(n, 15.0),
                   si_snr_db=np.full(n, 15.0), peak_metric=np.ones(n))
    with atomic_h5(path) as h5:
        write_columns(h5, schema.RECEIVER_FRAMES, columns, attrs={"pn_mode": "PN420", "si_index": 15})


def test_real_data_path_never_imports_the_simulator(tmp_path):
    walk_receiver = tmp_path / "walk-rx.h5"
    write_exact_receiver_file(walk_receiver, CAPTURES / "truth.h5")
    result = subprocess.run([sys.executable, "-c", REAL_DATA_PATH, str(tmp_path), str(CAPTURES), str(walk_receiver)],
                            capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert result.returncode == 0, result.stderr
    outcome = json.loads(result.stdout.strip().splitlines()[-1])
    assert outcome["codes"] == [0, 0, 0, 0], result.stderr
    assert outcome["sim_modules"] == {"receive": [], "pdr": [], "fuse": [], "report": []}


def test_a_file_written_before_the_foundation_reads_unchanged():
    """The bundled truth file predates dtmbnav_core (no schema-version attribute): the readers take it as is."""
    truth = CAPTURES / "truth.h5"
    with h5py.File(truth, "r") as f:
        assert schema.SCHEMA_VERSION_ATTR not in f.attrs
        trajectory_rows = len(f[schema.TRUTH_TRAJECTORY]["t_s"])
    walk = read_walk_truth(truth)
    assert len(walk.track) == trajectory_rows and walk.walk_start_t_s > 0
    imu = read_imu(truth)
    assert imu.acc_mps2.shape == (len(imu), 3)
    # The phone lies still at the start: the specific force is gravity.
    assert np.linalg.norm(imu.acc_mps2[:50].mean(axis=0)) == pytest.approx(9.8, abs=0.2)
    gnss, fix = read_gnss(truth)
    assert fix == walk.start_fix and len(gnss) > 0
    assert read_weinberg_k_m(truth) is not None
    tower_x, tower_y, height = read_tower(truth)
    assert np.hypot(tower_x, tower_y) > 1000.0 and height > 0
    assert read_capture_start_s(truth) == 0.0


def test_a_new_file_has_the_old_layout_plus_the_schema_version(tmp_path):
    """Same groups, columns and attributes as the bundled file (written before the change), one attribute added."""
    from dtmbnav.cli import main

    assert main(["-q", "simulate", "park-loop", "--seconds", "0.05", "-o", str(tmp_path)]) == 0

    def layout(path: Path) -> dict[str, set[str]]:
        groups: dict[str, set[str]] = {}
        with h5py.File(path, "r") as f:
            f.visititems(lambda name, obj: groups.setdefault(name, set(obj.attrs))
                         if isinstance(obj, h5py.Group) else None)
            groups["/"] = set(f.attrs)
            for name in list(groups):
                if name != "/":
                    groups[name] |= {f"column:{c}" for c in f[name] if isinstance(f[name][c], h5py.Dataset)}
        return groups

    old, new = layout(CAPTURES / "truth.h5"), layout(tmp_path / "truth.h5")
    assert new.pop("/") - old.pop("/") == {schema.SCHEMA_VERSION_ATTR}
    assert new == old
