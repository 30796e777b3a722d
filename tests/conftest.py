"""Shared helpers: small scenarios built from the defaults with dotted overrides."""

from __future__ import annotations

import os

import pytest

from emfabric.config.scenario import Scenario


def make(**dotted) -> Scenario:
    """The default scenario with dotted-key overrides (keys with '.' passed via **{...})."""
    return Scenario().replace(**dotted)


def fabric_only(**dotted) -> Scenario:
    """A field-actuated fabric without projectile, no damage, no modulus scatter; yarn area and
    node charge as given at this spacing (rescale off: the tests set q and m per node)."""
    base = {
        "fabric.rescale": False,
        "projectile.shape": "none",
        "fabric.material.modulus_cv": 0.0,
        "fabric.damage.rate": 0.0,
        "field.B": [0.0, 0.0, 0.0],
    }
    base.update(dotted)
    return Scenario().replace(**base)


@pytest.hookimpl(optionalhook=True)  # a hook of pytest-xdist's: none without it
def pytest_xdist_auto_num_workers(config):
    """`-n auto` (the README's test command, with `--dist loadfile`): one worker per core, at
    most four. Every worker compiles the kernels its test files use until the shared kernel cache
    holds them, so more workers than that compile the same kernels side by side for little
    gain. A test file runs on one worker, so its module fixtures are computed once."""
    return max(1, min(os.cpu_count() or 1, 4))


@pytest.fixture
def tmp_run_dir(tmp_path):
    return tmp_path / "run"


def run_demo(out, overrides, progress=None):
    """Run the demo-small scenario with overrides into `out` and return `out`."""
    from emfabric.config.scenario import load_scenario
    from emfabric.runner.loop import run

    run(load_scenario("demo-small", overrides), out, progress=progress)
    return out


def interrupted_demo(out, overrides, after: int):
    """Run demo-small into `out` and press Ctrl-C after `after` steps; return `out`."""
    steps = []

    def stop(state, info) -> None:
        steps.append(state.t)
        if len(steps) >= after:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_demo(out, overrides, progress=stop)
    return out
