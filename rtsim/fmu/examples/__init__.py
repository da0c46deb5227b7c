"""Example controller FMUs (pythonfmu3 scripts: a PI speed controller and a lane-keeping controller) that
the tests and `rtsim bench --suite fmu` build, and a user may copy (docs/fmu.md)."""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
EXAMPLES = ("pi_speed", "lane_keep")


def build_example(name: str, dest: str | Path) -> Path:
    """The example `name` built into an FMU in dest (needs pythonfmu3: the optional extra rtsim[fmu])."""
    from pythonfmu3.builder import FmuBuilder

    return Path(FmuBuilder.build_FMU(HERE / f"{name}.py", dest=Path(dest), project_files={HERE / "fmu_vars.py"}))


def example_module(name: str):
    """The example's script as a module (its `law` and `PARAMS`), loaded by path beside its helper."""
    if str(HERE) not in sys.path:
        sys.path.append(str(HERE))
    spec = importlib.util.spec_from_file_location(f"rtsim_fmu_example_{name}", HERE / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod
