"""The package layering: receiver, sim and fusion stand on dtmbnav.core and never on each other.

``dtmbnav.core`` (the standard's tables, IQ formats, constants, records, the
file schema and its readers) is imported by the three stage packages; only
the rest of ``dtmbnav`` wires them. The real-data path (receive, fuse,
report) must work without the simulator, so it must not import it.
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

from dtmbnav.core import schema
from dtmbnav.core.h5io import atomic_h5, write_columns
from dtmbnav.core.records import FrameBatch
from dtmbnav.core.sensors import (read_capture_start_s, read_gnss, read_imu, read_tower, read_walk_truth,
                                  read_weinberg_k_m)

ROOT = Path(__file__).resolve().parents[1]
STAGES = ("receiver", "sim", "fusion")
CAPTURES = ROOT / "captures"


def imported_packages(path: Path) -> set[str]:
    """Top-level packages a module imports (module level and inside functions); 'dtmbnav.core' kept apart."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        for name in names:
            if name == "dtmbnav":  # the distribution's version (dtmbnav/__init__ imports nothing)
                found.add("dtmbnav.__init__")
            elif name == "dtmbnav.core" or name.startswith("dtmbnav.core."):
                found.add("dtmbnav.core")
            else:
                found.add(name.split(".")[0])
    return found


def modules_of(package: str) -> list[Path]:
    return sorted((ROOT / package).rglob("*.py"))


@pytest.mark.parametrize("package", STAGES)
def test_stage_packages_import_only_core_and_themselves(package):
    for path in modules_of(package):
        others = imported_packages(path) & {*STAGES, "dtmbnav"} - {package}
        assert not others, f"{path.relative_to(ROOT)} imports {sorted(others)}"


def test_core_imports_no_stage_package_and_no_application_module():
    for path in modules_of("dtmbnav/core"):
        wrong = imported_packages(path) & {*STAGES, "dtmbnav"}
        assert not wrong, f"{path.relative_to(ROOT)} imports {sorted(wrong)}"


def test_the_import_walk_sees_function_level_imports(tmp_path):
    """The checker itself: an import hidden inside a function is found."""
    module = tmp_path / "m.py"
    module.write_text("def f():\n    from sim.walk import simulate_walk\n    import fusion.run\n"
                      "from dtmbnav.core.records import Track\n")
    assert imported_packages(module) == {"sim", "fusion", "dtmbnav.core"}


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
    """The bundled truth file predates dtmbnav.core (no schema-version attribute): the readers take it as is."""
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
