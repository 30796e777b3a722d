"""Driver for the VibeDynaLITE (kevlargrid) run of benchmarks/peer.py.

Runs in the peer's own virtual environment, never in emfabric's:

    /work/peer/venv/bin/python benchmarks/peer_driver.py --peer-dir /work/peer/VibeDynaLITE \
        --config '{"nodes": 100, ...}'

It imports nothing from emfabric and copies no code from the peer: it builds the peer's inputs
(grid, boundary mask, projectile, solver settings) exactly as the peer's own worker
(kevlargrid/solver/worker.py, run_solver_process) does for its Numba backend, then calls the
peer's fused_leapfrog_loop chunk by chunk the same way (chunks of `chunk` steps, history every
`save_interval` steps) without the GUI queue, the log file and the per-frame peak-strain
post-processing. The run is done `repeat + 1` times from a fresh state; the first compiles
(or loads Numba's cache) and is not timed. The result is one JSON line on stdout (the last).

A pack (config "plies" > 1) is the peer's stacked mode ("Mode B": generate_rectangular_grid
with n_plies and t_ply): identical layers t_ply apart along +z (ply 0 at z = 0 at the bottom,
the top one at (plies − 1)·t_ply), every layer's edges clamped, and the sphere `gap` above the
top layer, as its worker places them. t_ply is both the layers' spacing and the distance below
which its penalty acts between a node and the node of the same index in the next layer.

The thread count comes from NUMBA_NUM_THREADS, which the caller sets before this interpreter
starts; the driver also calls numba.set_num_threads(config["threads"]) and reports what Numba
actually used.
"""

from __future__ import annotations

import argparse
import importlib
import json
import math
import os
import sys
import time


def build_inputs(cfg: dict):
    """The peer's grid, boundary mask, projectile and scalar settings for cfg."""
    import numpy as np
    from kevlargrid.solver.grid import generate_rectangular_grid
    from kevlargrid.solver.projectile import Projectile
    from kevlargrid.solver.timestep import compute_cfl_timestep

    n = int(cfg["nodes"])
    dx = float(cfg["size"]) / (n - 1)
    material = {
        "tensile_modulus_gpa": cfg["tensile_modulus_gpa"],
        "fiber_density_gcc": cfg["fiber_density_gcc"],
        "areal_density_kgm2": cfg["areal_density_kgm2"],
        "shear_ratio": cfg["shear_ratio"],
        "failure_strain": cfg["failure_strain"],
        "damage_onset_strain": cfg["damage_onset_strain"],
    }
    plies = int(cfg.get("plies", 1))
    t_ply = float(cfg["t_ply"]) if plies > 1 else None  # None: one layer (n_plies = 1)
    grid = generate_rectangular_grid(nx=n, ny=n, dx=dx, material=material, n_plies=plies,
                                     t_ply=t_ply)
    if grid.n_nodes != plies * n * n:
        raise RuntimeError(f"the peer built {grid.n_nodes} nodes for {plies} × {n}²")
    # as worker.py, boundary_type "fixed": every edge node of every layer is clamped
    mask = np.zeros(grid.n_nodes, dtype=np.int32)
    for ply in range(plies):
        for i in range(n):
            for j in range(n):
                if i == 0 or i == n - 1 or j == 0 or j == n - 1:
                    mask[ply * n * n + i * n + j] = 1
    k_penalty = cfg.get("k_penalty")
    if k_penalty is None:  # the worker's default
        k_penalty = 10.0 * float(np.mean(grid.stiffnesses))
    # the worker's initial step (it sizes the chunks; the loop recomputes Δt every step)
    dt0 = compute_cfl_timestep(np.array([max(np.max(grid.stiffnesses), k_penalty)]),
                               grid.masses, dx, cfg["cfl_factor"])
    radius = float(cfg["radius"])
    z_top = float(grid.nodes[:, 2].max())  # the top layer: (plies − 1)·t_ply (0: one layer)
    proj = Projectile(mass=cfg["mass"], velocity=[0.0, 0.0, -float(cfg["speed"])],
                      position=[0.0, 0.0, z_top + radius + float(cfg["gap"])],
                      shape_type="sphere", radius=radius)
    layers = {"plies": plies, "per_layer": n * n,
              "t_ply": t_ply if t_ply is not None else 0.002}  # 0.002: the worker's unused value
    return grid, mask, proj, float(k_penalty), float(dt0), dx, layers


def rest_overlaps(grid, layers: dict) -> int:
    """Node pairs of neighbouring layers that the peer's inter-ply penalty sees as
    penetrating in the rest state (rounding of ply·t_ply; 0 when t_ply's multiples are exact)."""
    import numpy as np

    z, m, t = grid.nodes[:, 2], layers["per_layer"], layers["t_ply"]
    return int(sum(np.count_nonzero(z[p * m:(p + 1) * m] - z[(p + 1) * m:(p + 2) * m] + t > 0.0)
                   for p in range(layers["plies"] - 1)))


def run_once(cfg: dict) -> dict:
    """One run from t = 0 to cfg["end_time"]: wall time of the stepping loop and its figures."""
    import numpy as np
    from kevlargrid.solver.fused import fused_leapfrog_loop

    t_setup = time.perf_counter()
    grid, mask, proj, k_penalty, dt0, dx, layers = build_inputs(cfg)
    setup_s = time.perf_counter() - t_setup
    positions = grid.nodes.copy()
    z0 = grid.nodes[:, 2].copy()  # every node's initial height
    velocities = np.zeros_like(positions)
    external = np.zeros((grid.n_nodes, 3), dtype=np.float64)
    end_time = float(cfg["end_time"])
    chunk, save_interval = int(cfg["chunk"]), int(cfg["save_interval"])
    t_sim = damp = fail = clamp = contact_e = fric = 0.0
    peak_decel = np.zeros(1)
    steps = 0
    dt_est = dt0
    dts = []  # mean Δt of each chunk
    first_contact = None
    last_frame_t = 0.0
    t0 = time.perf_counter()
    while t_sim < end_time * (1.0 - 1e-12):
        # the worker sizes a chunk from its initial Δt and passes that Δt to every chunk (the
        # loop takes it for the chunk's first half-step, then recomputes Δt from the CFL rule);
        # here both are the Δt the previous chunk took, so that the run ends within about a
        # step of end_time and no chunk starts with a step of another size
        n_steps = max(1, min(chunk, math.ceil((end_time - t_sim) / dt_est)))
        if first_contact is None:
            # one step a chunk until the body touches the sheet: times the first contact to a
            # step, and measures the Δt the loop takes (the worker's initial Δt is not that one)
            n_steps = 1
        if n_steps > save_interval:
            # a whole number of history frames: the loop writes a frame at every step that is
            # a multiple of save_interval into max(1, n_steps // save_interval) rows, so any
            # other count writes past the end of its history arrays (the worker's last chunk
            # can do that: memory corruption, "corrupted double-linked list")
            n_steps -= n_steps % save_interval
        hist_quat = np.zeros((max(1, n_steps // save_interval), 4))
        t_before = t_sim
        (positions, velocities, grid.failed, pos_p, vel_p, damp, fail, clamp, t_sim, hist_pos,
         _hf, _hpp, hist_time, _hke, _hse, _hpke, contact_e, fric) = fused_leapfrog_loop(
            positions, velocities, grid.springs, grid.stiffnesses, grid.rest_lengths,
            grid.failed, grid.masses, grid.tension_only, mask, external,
            proj.position, proj.velocity, proj.mass, proj.blade_width, proj.edge_thickness,
            layers["plies"], layers["per_layer"], layers["t_ply"], dx, k_penalty, 0.0,
            float(cfg["rayleigh_beta"]),
            float(cfg["failure_strain"]), float(cfg["damage_onset_strain"]), 1.5, dt_est,
            n_steps, save_interval, damp, fail, clamp, t_sim, -1.0,
            grid.initial_spring_counts, grid.node_spring_offsets, grid.node_spring_ids,
            grid.node_spring_signs, use_viscous=False, cfl_factor=float(cfg["cfl_factor"]),
            contact_energy_init=contact_e, mu_s=float(cfg["mu_s"]),
            friction_dissipated_init=fric, grid_damage=grid.damage, proj_quat=proj.quat,
            proj_omega=proj.omega, proj_shape_type="sphere", proj_radius=proj.radius,
            proj_length=proj.length, proj_inertia_inv=proj.inertia_inv,
            proj_peak_deceleration=peak_decel, hist_proj_quat=hist_quat)
        proj.position, proj.velocity = pos_p, vel_p
        steps += n_steps
        dt_est = (t_sim - t_before) / n_steps
        dts.append(dt_est)
        if first_contact is None:
            # the sheet is flat and at rest until the body touches it: the first saved frame
            # with a node off its initial height brackets the first contact (to save_interval
            # steps); 1e-12 m: above what rounding of the layers' heights could move a node
            # before contact (rest_overlaps), far below a contact step's displacement
            off = np.abs(np.asarray(hist_pos)[:, :, 2] - z0).max(axis=1)
            moved = np.nonzero(off > (0.0 if layers["plies"] == 1 else 1e-12))[0]
            if len(moved):
                k = int(moved[0])
                first_contact = [float(hist_time[k - 1]) if k > 0 else last_frame_t,
                                 float(hist_time[k])]
            last_frame_t = float(hist_time[-1])
        if not np.all(np.isfinite(positions)):
            raise FloatingPointError(f"the peer's run went non-finite at t = {t_sim:.3e} s")
    wall = time.perf_counter() - t0
    # figures of the end state, for a sanity check of the two set-ups against each other
    s0, s1 = grid.springs[:, 0], grid.springs[:, 1]
    ortho = grid.tension_only
    lengths = np.linalg.norm(positions[s1] - positions[s0], axis=1)
    strain = (lengths - grid.rest_lengths) / grid.rest_lengths
    return {
        "wall_s": wall, "setup_s": setup_s, "steps": steps, "t_end": float(t_sim),
        "dt_initial_worker": dt0, "dt_mean": float(t_sim / steps),
        "dt_min_chunk": float(min(dts)), "dt_max_chunk": float(max(dts)),
        "first_contact_between": first_contact,
        "projectile_vz": float(proj.velocity[2]),
        "max_deflection": float((z0 - positions[:, 2]).max()),
        # per layer, from the top one (the peer's last) down, as emfabric's ply 1, 2, …
        "max_deflection_per_ply": [
            float((z0 - positions[:, 2])[p * layers["per_layer"]:(p + 1) * layers["per_layer"]]
                  .max()) for p in reversed(range(layers["plies"]))],
        "max_strain_yarn": float(strain[ortho].max()),
        "failed_springs": int(np.sum(grid.failed)),
        "k_penalty": k_penalty, "k_yarn": float(grid.stiffnesses[ortho][0]),
        "node_mass_interior": float(grid.masses.max()), "node_mass_min": float(grid.masses.min()),
        "springs": int(grid.n_springs), "springs_yarn": int(np.sum(ortho)),
        "plies": layers["plies"], "t_ply": layers["t_ply"] if layers["plies"] > 1 else None,
        "nodes_total": int(grid.n_nodes), "rest_overlaps": rest_overlaps(grid, layers),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--peer-dir", default="/work/peer/VibeDynaLITE",
                    help="the VibeDynaLITE checkout (its src/ goes first on sys.path)")
    ap.add_argument("--config", required=True, help="the run's inputs as a JSON object")
    args = ap.parse_args()
    cfg = json.loads(args.config)
    sys.path.insert(0, os.path.join(os.path.abspath(args.peer_dir), "src"))
    os.environ["KEVLARGRID_BACKEND"] = "numba"  # the peer's CPU backend (no Taichi, no JAX)

    # the peer's backend module first, as its worker does: it picks Numba's threading layer
    # ("workqueue", through the environment) before Numba is imported
    backend = importlib.import_module("kevlargrid.solver.backend")
    import numba

    backend.BACKEND = "numba"  # as worker.py
    threads = int(cfg["threads"])
    backend.set_numba_threads(threads)
    runs = [run_once(cfg) for _ in range(1 + int(cfg["repeat"]))]
    timed = runs[1:]
    best = min(timed, key=lambda r: r["wall_s"])
    out = dict(best)
    out.update({
        "first_run_wall_s": runs[0]["wall_s"],
        "timed_walls_s": [r["wall_s"] for r in timed],
        "numba_num_threads": numba.config.NUMBA_NUM_THREADS,
        "numba_threads_used": numba.get_num_threads(),
        "threading_layer": numba.threading_layer(),
        "numba_version": numba.__version__,
        "python": sys.version.split()[0],
        "peer_module": os.path.dirname(backend.__file__),
    })
    print(json.dumps(out))


if __name__ == "__main__":
    main()
