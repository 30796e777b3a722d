"""A second process that compiles some of a run's kernels while the run compiles the others.

On an empty kernel cache a run spends most of its first minute in Numba compiling (docs/
performance.md, "The first run"), one kernel after another, on one core. Numba caches each
kernel on its own, and a kernel that another process has put in the cache is loaded, not
compiled, when the run reaches it. So, on a cold cache and a machine with more than one core,
the run starts ``python -m emfabric.runner.precompile`` beside itself, gives it the scenario
(its TOML on stdin: a scenario file, nothing executable) and goes on compiling the force kernel
and the initial state; the second process compiles the step kernel's largest callees
(``IntegratorBase.precompile_targets``) into the same cache, and the step kernel loads them.

Nothing depends on it: if the second process fails or is late, the run compiles what it needs
itself, with the same result (the cache holds the same machine code either way). It is not
started inside a Dask worker (the study's other cases use the cores) or with
``EMFABRIC_PRECOMPILE=0``. A run that ends before it does waits for it, as for the threaded
kernel's compile, so that no process is left behind.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys

log = logging.getLogger("emfabric.runner.loop")


def wanted() -> bool:
    """Whether a run on a cold cache starts the second process: more than one core, not
    switched off by EMFABRIC_PRECOMPILE=0, and not inside a Dask worker."""
    if os.environ.get("EMFABRIC_PRECOMPILE", "1").strip() == "0":
        return False
    if (os.cpu_count() or 1) < 2:
        return False
    dist = sys.modules.get("distributed")  # only a process that imported it can be a worker
    if dist is None:
        return True
    try:
        dist.get_worker()
    except (AttributeError, ValueError):  # get_worker raises ValueError outside a worker
        return True
    return False


def start(scenario_toml: str) -> subprocess.Popen | None:
    """Start the second process for the scenario (its TOML text); None if it cannot start."""
    try:
        proc = subprocess.Popen([sys.executable, "-m", "emfabric.runner.precompile"],
                                stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL, text=True)
        assert proc.stdin is not None
        proc.stdin.write(scenario_toml)
        proc.stdin.close()
    except OSError as err:
        log.debug("kernel compile in a second process not started: %s", err)
        return None
    return proc


def finish(proc: subprocess.Popen | None) -> None:
    """Wait for the second process (a run that ended before it)."""
    if proc is None or proc.poll() is not None:
        return
    log.info("finishing the second process's kernel compile for later runs (first run only)")
    try:
        proc.wait()
    except KeyboardInterrupt:
        proc.kill()
        raise


def compile_targets(scenario_toml: str) -> int:
    """Build the scenario's model and integrator (no files, nothing run) and compile its
    precompile targets into the kernel cache; returns how many were compiled."""
    import tomllib

    import numba

    from emfabric.config.scenario import scenario_from_dict
    from emfabric.integrators import make_integrator
    from emfabric.sim.builder import build_model
    from emfabric.sim.state import blank_state

    scenario = scenario_from_dict(tomllib.loads(scenario_toml), "<precompile>")
    model = build_model(scenario, writes=False)
    integ = make_integrator(model, threads=1)  # a cold run starts on the serial kernels
    done = 0
    for kernel, args in integ.precompile_targets(blank_state(model)):
        kernel.compile(tuple(numba.typeof(a) for a in args))
        done += 1
    return done


def main() -> None:
    logging.disable(logging.WARNING)  # the run itself says what the scenario deserves
    compile_targets(sys.stdin.read())


if __name__ == "__main__":
    main()
